//! The booth console page end to end, in headless Chromium (Debian's `chromium` and
//! `chromium-driver`): the real daemon on a synthetic performer rendered at test time. The
//! camera image arrives with the dots drawn where the preview's overlay places them (canvas
//! pixels checked), Calibrate and Record/Stop work from the page (a take file appears and
//! reads back), a read-only token hides the controls, and the page comes back by itself
//! when the daemon restarts.

use crate::helper_daemon_run as daemon;
use crate::helper_webdriver as webdriver;

use std::path::Path;
use std::time::{Duration, Instant};

use daemon::{free_port, run_command, Daemon};
use serde_json::Value;
use webdriver::WebDriver;

const CONTROL: &str = "console-control-token-0123";
const READ: &str = "console-read-token-012345";

/// `mouthpiece run` on `dir/mouthpiece.toml` with the test's tokens, until it listens on
/// `port`; its log in `dir/stderr-PORT.log`.
fn start_daemon(dir: &Path, port: u16) -> Daemon {
    let stderr = std::fs::File::create(dir.join(format!("stderr-{port}.log"))).unwrap();
    Daemon::listening(
        run_command(dir, &dir.join("mouthpiece.toml"))
            .env("RUST_LOG", "info")
            .env("MP_TEST_CONTROL", CONTROL)
            .env("MP_TEST_READ", READ)
            .stderr(stderr),
        port,
    )
}

/// Polls `js` (which returns a value or null) until `done` accepts it.
fn wait_until(
    driver: &WebDriver,
    what: &str,
    limit: Duration,
    js: &str,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let deadline = Instant::now() + limit;
    loop {
        let v = driver.script(js);
        if done(&v) {
            return v;
        }
        assert!(Instant::now() < deadline, "{what}: last seen {v}");
        std::thread::sleep(Duration::from_millis(150));
    }
}

/// The pixel under each dot the page drew last, read in the same script turn as the overlay
/// (no image can be drawn in between), and how far (canvas pixels) its nearest neighbour is:
/// a dot whose disc overlaps another's is covered by whichever is drawn last.
const DOT_PIXELS: &str = "const p = window.mouthpiece && window.mouthpiece.preview; \
    if (!p || !p.overlay) return null; \
    const c = document.getElementById('camera').getContext('2d'); \
    const at = p.overlay.dots.map(d => p.toCanvas(d.x, d.y)); \
    return {images: p.images, width: p.width, source_width: p.overlay.source_width, \
      dots: p.overlay.dots.map((d, i) => { const [x, y] = at[i]; \
        const px = c.getImageData(Math.round(x), Math.round(y), 1, 1).data; \
        const near = Math.min(...at.filter((_, j) => j !== i) \
          .map(([u, v]) => Math.hypot(u - x, v - y))); \
        return {name: d.name, state: d.state, rgb: [px[0], px[1], px[2]], nearest: near}; })};";

const STATE: &str = "const m = window.mouthpiece; if (!m) return null; \
    return {connected: m.connected, access: m.access, images: m.preview.images, \
      calibration: m.calibration.phase, said: document.getElementById('calib-say').textContent, \
      recording: !!(m.status && m.status.recording), \
      takes: m.status ? (m.status.takes || []).map(t => [t.slate, t.take, t.file, t.frames]) : [], \
      take_input: document.getElementById('take').value, \
      shown_error: document.getElementById('error').textContent, errors: m.errors.length, frames: m.frames, \
      controls_hidden: document.getElementById('controls').hidden, \
      readonly_hidden: document.getElementById('readonly').hidden, \
      tiles: document.getElementById('status').textContent, \
      health: !!m.health};";

#[test]
fn the_console_shows_the_camera_with_dots_calibrates_records_and_recovers() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("performer.mcap");
    let synth = crate::mouthpiece()
        .args(["synth", "--out"])
        .arg(&session)
        .args(["--seconds", "4", "--seed", "3", "--size", "320x240"])
        .output()
        .unwrap();
    assert!(synth.status.success(), "{synth:?}");
    let port = free_port();
    std::fs::write(
        dir.path().join("mouthpiece.toml"),
        format!(
            "[source]\nspec = \"replay:{}?loop=1\"\nretry_initial_s = 0.2\nretry_max_s = 0.4\n\
             [server]\nlisten = \"127.0.0.1:{port}\"\n\
             read_token = {{ env = \"MP_TEST_READ\" }}\ncontrol_token = {{ env = \"MP_TEST_CONTROL\" }}\n\
             [takes]\nfolder = \"takes\"\nflush_s = 0.5\nmin_free_mb = 1\n",
            session.display()
        ),
    )
    .unwrap();
    let mut daemon = start_daemon(dir.path(), port);

    let profile = tempfile::tempdir().unwrap();
    let driver = webdriver::open_page(
        &format!("http://127.0.0.1:{port}/?token={CONTROL}&countdown=0"),
        profile.path(),
    );
    // A desktop-sized window: the 320x240 camera image is drawn about 2.5 times enlarged,
    // so the lip dots' discs lie apart.
    driver.call(
        "POST",
        "/window/rect",
        Some(serde_json::json!({"width": 1600, "height": 1200})),
    );
    driver.call("POST", "/refresh", Some(serde_json::json!({})));

    // The camera image arrives, with the dots drawn where the overlay places them.
    let shown = wait_until(
        &driver,
        "camera image with tracked dots",
        Duration::from_secs(40),
        DOT_PIXELS,
        |v| {
            v["images"].as_u64().unwrap_or(0) >= 3
                && v["dots"]
                    .as_array()
                    .is_some_and(|d| d.iter().filter(|d| d["state"] == "tracked").count() >= 12)
        },
    );
    assert_eq!(shown["source_width"], 320, "{shown}");
    // Dots whose centre no other disc (radius 4 px, rim 5.5 px) reaches.
    let isolated: Vec<&Value> = shown["dots"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|d| d["nearest"].as_f64().unwrap_or(0.0) > 6.0)
        .collect();
    assert!(isolated.len() >= 10, "too few dots apart to check: {shown}");
    for dot in isolated {
        let rgb: Vec<i64> = dot["rgb"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_i64().unwrap())
            .collect();
        let want: [i64; 3] = match dot["state"].as_str().unwrap() {
            "tracked" => [0x3d, 0xdc, 0x84],
            "predicted" => [0xff, 0xd2, 0x3f],
            _ => [0xff, 0x4d, 0x4d],
        };
        let off: i64 = rgb.iter().zip(want).map(|(a, b)| (a - b).abs()).sum();
        assert!(
            off <= 24,
            "dot {} ({}) is not drawn where the overlay says: pixel {rgb:?}, colour {want:?}; {shown}",
            dot["name"],
            dot["state"]
        );
    }
    let names: Vec<&str> = shown["dots"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["name"].as_str().unwrap())
        .collect();
    assert!(names.contains(&"D1") && names.contains(&"D12") && names.contains(&"F3"));

    // Status at a glance.
    let s = wait_until(&driver, "health", Duration::from_secs(10), STATE, |v| {
        v["health"] == true && v["access"] == "control"
    });
    let tiles = s["tiles"].as_str().unwrap();
    for what in [
        "source",
        "dots found",
        "frame rate",
        "latency",
        "clients",
        "free disk",
    ] {
        assert!(tiles.contains(what), "status shows {what}: {tiles}");
    }
    assert_eq!(s["controls_hidden"], false, "{s}");

    // Calibrate from the page: the result is shown.
    driver.script("document.getElementById('calibrate').click(); return null;");
    let s = wait_until(
        &driver,
        "calibration result",
        Duration::from_secs(30),
        STATE,
        |v| v["calibration"] == "done",
    );
    let said = s["said"].as_str().unwrap();
    assert!(
        said.contains("mouth width") && said.contains("lip wobble"),
        "{s}"
    );

    // Record with the button, stop with the keyboard: a take file appears and reads back.
    driver.script(
        "document.getElementById('slate').value = 'booth'; \
         document.getElementById('record').click(); return null;",
    );
    wait_until(&driver, "recording", Duration::from_secs(10), STATE, |v| {
        v["recording"] == true
    });
    std::thread::sleep(Duration::from_millis(1500));
    driver.script("document.dispatchEvent(new KeyboardEvent('keydown', {key: 'r'})); return null;");
    let s = wait_until(
        &driver,
        "take listed",
        Duration::from_secs(10),
        STATE,
        |v| v["recording"] == false && v["takes"].as_array().is_some_and(|t| !t.is_empty()),
    );
    assert_eq!(s["errors"], 0, "{s}");
    let take = &s["takes"][0];
    assert_eq!(take[0], "booth", "{s}");
    let take_number = take[1].as_u64().unwrap();
    assert_eq!(
        s["take_input"],
        (take_number + 1).to_string(),
        "the take number moves on by itself: {s}"
    );
    let file = dir.path().join(take[2].as_str().unwrap());
    let mut reader = mouthpiece_recording::SessionReader::open(&file)
        .unwrap_or_else(|e| panic!("take {} unreadable: {e}", file.display()));
    let mut frames = 0;
    while reader.next_frame().unwrap().is_some() {
        frames += 1;
    }
    assert!(frames >= 10, "{frames} frames in the take");

    // A read-only token: the page watches but shows no controls.
    let profile_ro = tempfile::tempdir().unwrap();
    let reader_page = webdriver::open_page(
        &format!("http://127.0.0.1:{port}/?token={READ}"),
        profile_ro.path(),
    );
    let ro = wait_until(
        &reader_page,
        "read-only page",
        Duration::from_secs(20),
        STATE,
        |v| v["access"] == "read" && v["images"].as_u64().unwrap_or(0) >= 1,
    );
    assert_eq!(ro["controls_hidden"], true, "{ro}");
    assert_eq!(ro["readonly_hidden"], false, "{ro}");
    drop(reader_page);

    // The daemon restarts: the page reconnects and the image flows again.
    daemon.terminate();
    wait_until(
        &driver,
        "disconnected",
        Duration::from_secs(10),
        STATE,
        |v| v["connected"] == false,
    );
    let before = driver.script(STATE)["images"].as_u64().unwrap();
    let _daemon = start_daemon(dir.path(), port);
    wait_until(
        &driver,
        "reconnected",
        Duration::from_secs(30),
        STATE,
        |v| v["connected"] == true && v["images"].as_u64().unwrap_or(0) > before + 2,
    );
}
