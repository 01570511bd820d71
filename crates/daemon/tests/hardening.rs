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
    let err = check(&config.unwrap()).unwrap_err().to_string();
    assert!(err.contains("characters.files[0]"), "{err}");
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

/// One daemon at a time in this test binary: a signal sent to the process reaches all.
static ONE_DAEMON: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn a_panic_on_the_processing_thread_stops_the_daemon_with_an_error() {
    let _one = ONE_DAEMON.lock().unwrap_or_else(|e| e.into_inner());
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

/// Set by the test below: the next frame takes `SLOW_FRAME` to process.
static SLOW_NEXT: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
const SLOW_FRAME: std::time::Duration = std::time::Duration::from_secs(4);

/// The live pipeline, except that one frame is slow when the test asks.
struct SlowFactory;

struct SlowProcessor(mouthpiece_daemon::live::LiveProcessor);

impl mouthpiece_daemon::pipeline::Processor for SlowProcessor {
    type Reload =
        <mouthpiece_daemon::live::LiveProcessor as mouthpiece_daemon::pipeline::Processor>::Reload;

    fn process(
        &mut self,
        frame: &mouthpiece_frame::Frame,
        out: &mut mouthpiece_daemon::pipeline::Output,
    ) {
        if SLOW_NEXT.swap(false, std::sync::atomic::Ordering::AcqRel) {
            std::thread::sleep(SLOW_FRAME);
        }
        self.0.process(frame, out)
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

impl mouthpiece_daemon::daemon::Factory for SlowFactory {
    type Processor = SlowProcessor;
    fn processor(
        &self,
        config: &Config,
    ) -> Result<SlowProcessor, mouthpiece_daemon::error::CheckError> {
        mouthpiece_daemon::live::LiveFactory
            .processor(config)
            .map(SlowProcessor)
    }
    fn reload(
        &self,
        config: &Config,
    ) -> Result<
        <SlowProcessor as mouthpiece_daemon::pipeline::Processor>::Reload,
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

/// The take files in `folder`.
fn takes_in(folder: &std::path::Path) -> Vec<std::path::PathBuf> {
    std::fs::read_dir(folder)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn sigterm_while_a_take_is_busy_waits_for_the_take_to_be_finished() {
    let _one = ONE_DAEMON.lock().unwrap_or_else(|e| e.into_inner());
    let demo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings/demo.mcap");
    let (dir, config) = load(&format!(
        "[source]\nspec = \"replay:{}?loop=1\"\n[server]\nlisten = \"127.0.0.1:0\"\n[takes]\nfolder = \"takes\"\n",
        demo.display()
    ));
    let config = config.unwrap();
    let folder = dir.path().join("takes");
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    std::thread::spawn(move || {
        let result = mouthpiece_daemon::daemon::run(
            config,
            SlowFactory,
            mouthpiece_daemon::RunOptions {
                record: Some(("drain".into(), None)),
                ..mouthpiece_daemon::RunOptions::default()
            },
        );
        let _ = tx.send(result.map_err(|e| e.to_string()));
    });
    // The take is being written (and the daemon's signal handlers are long in place).
    let started = std::time::Instant::now();
    loop {
        let size: u64 = takes_in(&folder)
            .iter()
            .filter_map(|p| std::fs::metadata(p).ok())
            .map(|m| m.len())
            .sum();
        if size > 20_000 && started.elapsed() > std::time::Duration::from_secs(2) {
            break;
        }
        assert!(
            started.elapsed() < std::time::Duration::from_secs(30),
            "no take written"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // The processing thread is busy (a slow frame) when SIGTERM comes: the exit must wait
    // for it to finish the take rather than give up after a second and a half.
    SLOW_NEXT.store(true, std::sync::atomic::Ordering::Release);
    std::thread::sleep(std::time::Duration::from_millis(200));
    let status = std::process::Command::new("kill")
        .args(["-TERM", &std::process::id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let result = rx
        .recv_timeout(std::time::Duration::from_secs(30))
        .expect("the daemon stops");
    result.unwrap();
    // When `run` returns the take is complete: MCAP's closing magic is on disk.
    let takes = takes_in(&folder);
    assert_eq!(takes.len(), 1, "{takes:?}");
    let bytes = std::fs::read(&takes[0]).unwrap();
    assert!(
        bytes.ends_with(b"\x89MCAP0\r\n"),
        "the take {} was not finished when the daemon returned ({} bytes)",
        takes[0].display(),
        bytes.len()
    );
    drop(dir);
}
