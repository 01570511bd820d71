//! `check` (behind `check-config`, the start and every reload) refuses what serving would.

use mouthpiece_config::Config;
use mouthpiece_daemon::check::check;

fn load(text: &str) -> (tempfile::TempDir, Result<Config, String>) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mouthpiece.toml");
    std::fs::write(&path, text).unwrap();
    let config = Config::load(&path).map_err(|e| e.to_string());
    (dir, config)
}

#[test]
fn unreadable_tls_files_are_refused_by_the_check() {
    let (_dir, config) = load("[server]\ntls_cert = \"nope.pem\"\ntls_key = \"nope.key\"\n");
    let err = check(&config.unwrap()).unwrap_err().to_string();
    assert!(err.contains("server.tls_cert"), "{err}");
}

#[test]
fn a_character_file_that_never_ends_is_refused() {
    let (_dir, config) = load("[characters]\nfiles = [\"/dev/zero\"]\n");
    // The key and the file, then the cause.
    let err = mouthpiece_daemon::source::error_chain(&check(&config.unwrap()).unwrap_err());
    assert!(err.contains("characters.files[0]"), "{err}");
    // Refused once it runs past a megabyte, not when memory runs out.
    assert!(err.contains("longer than 1048576 bytes"), "{err}");
}

/// The live pipeline, except that processing panics on the first frame.
struct PanickingFactory;

struct PanickingProcessor(mouthpiece_daemon::live::LiveProcessor);

impl mouthpiece_daemon::pipeline::Processor for PanickingProcessor {
    type Reload =
        <mouthpiece_daemon::live::LiveProcessor as mouthpiece_daemon::pipeline::Processor>::Reload;

    fn process(
        &mut self,
        _frame: &mouthpiece_frame::Frame,
        _out: &mut mouthpiece_daemon::pipeline::Output,
    ) {
        panic!("index out of bounds: the len is 0 but the index is 7");
    }
    fn calibrate(&mut self, duration: Option<std::time::Duration>) {
        self.0.calibrate(duration)
    }
    fn stream_info(&self, frame_rate: f64, source: &str) -> mouthpiece_server::StreamInfo {
        self.0.stream_info(frame_rate, source)
    }
    fn take_info_changed(&mut self) -> bool {
        self.0.take_info_changed()
    }
    fn performer_names(&self) -> &[String] {
        self.0.performer_names()
    }
    fn reload(&mut self, update: Self::Reload) -> Result<(), String> {
        self.0.reload(update)
    }
}

impl mouthpiece_daemon::daemon::Factory for PanickingFactory {
    type Processor = PanickingProcessor;
    fn processor(
        &self,
        config: &Config,
    ) -> Result<PanickingProcessor, mouthpiece_daemon::error::CheckError> {
        mouthpiece_daemon::live::LiveFactory
            .processor(config)
            .map(PanickingProcessor)
    }
    fn reload(
        &self,
        config: &Config,
    ) -> Result<
        <PanickingProcessor as mouthpiece_daemon::pipeline::Processor>::Reload,
        mouthpiece_daemon::error::CheckError,
    > {
        mouthpiece_daemon::live::LiveFactory.reload(config)
    }
    fn opener(
        &self,
        spec: &str,
        stall_timeout: std::time::Duration,
    ) -> mouthpiece_daemon::source::Opener {
        mouthpiece_daemon::live::LiveFactory.opener(spec, stall_timeout)
    }
}

#[test]
fn a_panic_on_the_processing_thread_stops_the_daemon_with_an_error() {
    let demo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings/demo.mcap");
    let (dir, config) = load(&format!(
        "[source]\nspec = \"replay:{}?loop=1\"\n[server]\nlisten = \"127.0.0.1:0\"\n[takes]\nfolder = \"takes\"\n",
        demo.display()
    ));
    let config = config.unwrap();
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    std::thread::spawn(move || {
        let result = mouthpiece_daemon::daemon::run(
            config,
            PanickingFactory,
            mouthpiece_daemon::RunOptions::default(),
        );
        let _ = tx.send(result.map_err(|e| e.to_string()));
    });
    let result = rx
        .recv_timeout(std::time::Duration::from_secs(30))
        .expect("the daemon notices the dead thread and stops");
    let err = result.unwrap_err();
    assert!(
        err.contains("processing thread died") && err.contains("index out of bounds"),
        "{err}"
    );
    drop(dir);
}
