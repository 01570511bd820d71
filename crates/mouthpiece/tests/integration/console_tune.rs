//! The console's paint check in headless Chromium (Debian's `chromium` and `chromium-driver`)
//! against the real daemon on synthetic performers rendered here. Saturated red lips under
//! green paint inside the documented ranges: the panel shows what every range finds, in use
//! and proposed, and offers nothing (the proposal finds fewer dots). Red lip paint the
//! ranges in use cannot see: the proposal is offered, **Apply** writes it into the
//! configuration file (the rest of the file kept) and the daemon reloads it.

use crate::helper_daemon_run as daemon;
use crate::helper_webdriver as webdriver;

use std::path::Path;
use std::time::{Duration, Instant};

use daemon::{free_port, run_command, Daemon};
use serde_json::Value;
use webdriver::WebDriver;

const CONTROL: &str = "tune-control-token-012345";

fn synth(dir: &Path, name: &str, layout: &str, extra: &[&str]) -> std::path::PathBuf {
    let out = dir.join(format!("{name}.mcap"));
    let layout_file = dir.join(format!("{name}.layout.toml"));
    std::fs::write(&layout_file, layout).unwrap();
    let status = crate::mouthpiece()
        .args(["synth", "--seed", "7", "--seconds", "3", "--out"])
        .arg(&out)
        .arg("--layout")
        .arg(&layout_file)
        .args(extra)
        .status()
        .unwrap();
    assert!(status.success());
    out
}

/// Starts the daemon on `session` with its configuration in `dir/NAME.toml`; returns it and
/// the page's address.
fn daemon(dir: &Path, name: &str, session: &Path) -> (Daemon, String) {
    let port = free_port();
    let config = dir.join(format!("{name}.toml"));
    std::fs::write(
        &config,
        format!(
            "# the booth's configuration\n[source]\nspec = \"replay:{}?loop=1\"\n\
             [server]\nlisten = \"127.0.0.1:{port}\"\ncontrol_token = {{ env = \"MP_TEST_CONTROL\" }}\n\
             [takes]\nfolder = \"takes\"\nmin_free_mb = 1\n\n[detect]\nmin_area_px = 2\n",
            session.display()
        ),
    )
    .unwrap();
    let stderr = std::fs::File::create(dir.join(format!("{name}.log"))).unwrap();
    let daemon = Daemon::listening(
        run_command(dir, &config)
            .env("MP_TEST_CONTROL", CONTROL)
            .stderr(stderr),
        port,
    );
    (daemon, format!("http://127.0.0.1:{port}/?token={CONTROL}"))
}

const TUNE: &str = "const m = window.mouthpiece; if (!m) return null; \
    const t = m.tuneReport || null; const q = (id) => document.getElementById(id); \
    return {connected: m.connected, access: m.access, hidden: q('tune').hidden, report: t, \
      said: q('tune-say').textContent, totals: q('tune-totals') ? q('tune-totals').textContent : null, \
      rows: [...document.querySelectorAll('#tune-result tr')].length, \
      apply: !!q('tune-apply'), refused: !!q('tune-refused'), \
      dots_found: m.health ? m.health.dots_found : null};";

fn wait(driver: &WebDriver, what: &str, done: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let v = driver.script(TUNE);
        if done(&v) {
            return v;
        }
        assert!(Instant::now() < deadline, "{what}: last seen {v}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn the_paint_check_shows_both_counts_refuses_a_worse_proposal_and_applies_a_better_one() {
    let dir = tempfile::tempdir().unwrap();

    // Saturated red lips under green paint: the proposal finds fewer dots.
    let session = synth(
        dir.path(),
        "red_lips",
        "lip_color = [60, 200, 90]\n",
        &["--lip-skin-colour", "200,102,102"],
    );
    let (d, page) = daemon(dir.path(), "red_lips", &session);
    let profile = tempfile::tempdir().unwrap();
    let driver = webdriver::open_page(&page, profile.path());
    wait(&driver, "control access", |v| {
        v["access"] == "control" && v["hidden"] == false
    });
    driver.script("document.getElementById('tune-run').click(); return null;");
    let v = wait(&driver, "the check's result", |v| {
        v["report"]["state"] == "done"
    });
    let report = &v["report"];
    assert_eq!(report["offered"], false, "{v}");
    assert_eq!(report["in_use"]["per_frame"], 15.0, "{v}");
    assert!(
        report["proposed"]["per_frame"].as_f64().unwrap() < 15.0,
        "{v}"
    );
    assert!(v["refused"] == true && v["apply"] == false, "{v}");
    let totals = v["totals"].as_str().unwrap();
    assert!(
        totals.contains("in use: 15.0 of 15 dots per frame (100 %)")
            && totals.contains("proposed:"),
        "{v}"
    );
    // Every range of both, with what it finds.
    assert_eq!(v["rows"], 1 + 2 + 2, "{v}");
    // Nothing to apply: asking anyway is refused and the file stays.
    let config = dir.path().join("red_lips.toml");
    let before = std::fs::read_to_string(&config).unwrap();
    driver.script(
        "window.mouthpiece.request({type: 'tune_colours', action: 'apply'}, 'tune'); return null;",
    );
    wait(&driver, "apply refused", |v| {
        v["said"]
            .as_str()
            .is_some_and(|s| s.contains("no proposal to apply"))
    });
    assert_eq!(std::fs::read_to_string(&config).unwrap(), before);
    drop(driver);
    drop(d);

    // Red lip paint the ranges in use cannot see: offered, applied, reloaded.
    let session = synth(dir.path(), "red_paint", "lip_color = [225, 40, 30]\n", &[]);
    let (_d, page) = daemon(dir.path(), "red_paint", &session);
    let profile = tempfile::tempdir().unwrap();
    let driver = webdriver::open_page(&page, profile.path());
    wait(&driver, "control access", |v| v["access"] == "control");
    driver.script("document.getElementById('tune-run').click(); return null;");
    let v = wait(&driver, "the check's result", |v| {
        v["report"]["state"] == "done"
    });
    assert_eq!(v["report"]["offered"], true, "{v}");
    assert!(v["apply"] == true, "{v}");
    let in_use = v["report"]["in_use"]["per_frame"].as_f64().unwrap();
    let proposed = v["report"]["proposed"]["per_frame"].as_f64().unwrap();
    assert!(proposed >= 14.5 && in_use < 4.0, "{v}");
    driver.script("document.getElementById('tune-apply').click(); return null;");
    wait(&driver, "applied", |v| v["report"]["state"] == "applied");
    let written = std::fs::read_to_string(dir.path().join("red_paint.toml")).unwrap();
    assert!(
        written.contains("# the booth's configuration") && written.contains("min_area_px = 2"),
        "{written}"
    );
    assert!(written.contains("[[detect.class]]"), "{written}");
    // The daemon reloaded it: the dots are found.
    wait(&driver, "the dots found with the applied ranges", |v| {
        v["dots_found"].as_f64().unwrap_or(0.0) >= 0.95
    });
    let log = std::fs::read_to_string(dir.path().join("red_paint.log")).unwrap();
    assert!(log.contains("configuration reloaded"), "{log}");
}
