//! A real ALSA capture PCM for tests, without a sound card: `tests/alsa/asound.conf.in`
//! with the test's own raw files, over a `jackd` of its own (dummy driver, 48 kHz, a unique
//! server name), killed when the [`Booth`] is dropped. Included by the tests that need it
//! with `#[path]`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};

pub struct Booth {
    jack: Child,
    pub dir: tempfile::TempDir,
    pub server: String,
    pub conf: PathBuf,
    /// The S16_LE file `booth` streams.
    pub s16: PathBuf,
    /// The FLOAT_LE file `booth_float` streams.
    pub f32: PathBuf,
}

/// Reads a mono 16-bit WAV (as Festival's `text2wave` writes it) into samples.
pub fn read_wav(path: &Path) -> (u32, Vec<i16>) {
    let mut reader = hound::WavReader::open(path).expect("a WAV file");
    let rate = reader.spec().sample_rate;
    let samples = reader.samples::<i16>().map(|s| s.unwrap()).collect();
    (rate, samples)
}

/// Festival speaking `line` at 48 kHz (`text2wave -F 48000`).
pub fn festival(line: &str, dir: &Path) -> Vec<i16> {
    let text = dir.join("line.txt");
    let wav = dir.join("line.wav");
    std::fs::write(&text, line).unwrap();
    let status = Command::new("text2wave")
        .arg("-F")
        .arg("48000")
        .arg("-o")
        .arg(&wav)
        .arg(&text)
        .status()
        .expect("Festival's text2wave (apt: festival festvox-kallpc16k)");
    assert!(status.success());
    let (rate, samples) = read_wav(&wav);
    assert_eq!(rate, 48_000);
    samples
}

impl Booth {
    /// Starts a jackd and writes the config streaming `samples` (48 kHz mono).
    pub fn start(samples: &[i16]) -> Booth {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let server = format!(
            "mptest{}x{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let dir = tempfile::tempdir().unwrap();
        let s16 = dir.path().join("sound.s16");
        let f32 = dir.path().join("sound.f32");
        let mut bytes = Vec::new();
        let mut floats = Vec::new();
        for s in samples {
            bytes.extend_from_slice(&s.to_le_bytes());
            floats.extend_from_slice(&(f32::from(*s) / 32768.0).to_le_bytes());
        }
        std::fs::write(&s16, bytes).unwrap();
        std::fs::write(&f32, floats).unwrap();
        let template = include_str!("asound.conf.in");
        let conf = dir.path().join("asound.conf");
        std::fs::write(
            &conf,
            template
                .replace("@S16@", s16.to_str().unwrap())
                .replace("@F32@", f32.to_str().unwrap()),
        )
        .unwrap();
        let jack = Command::new("jackd")
            .args([
                "-n", &server, "-r", "-t", "2000", "-d", "dummy", "-r", "48000", "-p", "512",
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("jackd (apt: jackd2 libasound2-plugins)");
        let booth = Booth {
            jack,
            dir,
            server,
            conf,
            s16,
            f32,
        };
        booth.wait_ready();
        booth
    }

    fn wait_ready(&self) {
        // `jack_wait -w` exits 0 once the server answers, 1 at its timeout.
        let ok = Command::new("jack_wait")
            .args(["-s", &self.server, "-w", "-t", "30"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "jackd {} did not start", self.server);
    }

    /// The environment a process needs to see the booth's PCMs.
    pub fn env(&self) -> Vec<(&'static str, String)> {
        vec![
            (
                "ALSA_CONFIG_PATH",
                format!("/usr/share/alsa/alsa.conf:{}", self.conf.display()),
            ),
            ("JACK_DEFAULT_SERVER", self.server.clone()),
            ("JACK_NO_START_SERVER", "1".to_owned()),
        ]
    }

    /// Kills the jackd under the booth: the device's clock stops, as when a microphone is
    /// pulled out.
    ///
    /// jackd is asked to stop (SIGTERM) so it leaves JACK's shared server registry: a killed
    /// jackd keeps its slot there, and after a handful of those no jackd on the machine can
    /// start ("Too many servers already active"). SIGKILL only if it has not stopped in 10 s.
    pub fn pull_the_plug(&mut self) {
        if matches!(self.jack.try_wait(), Ok(Some(_))) {
            return;
        }
        let _ = Command::new("kill")
            .args(["-TERM", &self.jack.id().to_string()])
            .status();
        for _ in 0..100 {
            if matches!(self.jack.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        let _ = self.jack.kill();
        let _ = self.jack.wait();
    }
}

impl Drop for Booth {
    fn drop(&mut self) {
        self.pull_the_plug();
    }
}
