//! The shipped systemd unit passes `systemd-analyze verify` without a single warning.

use crate::repo;
use std::process::Command;

#[test]
fn unit_verifies_cleanly() {
    // Missing, the test fails: CI installs it (systemd, scripts/packages/test.apt).
    let version = Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .expect("systemd-analyze (Debian package systemd) is not installed");
    assert!(version.status.success());
    let unit = std::fs::read_to_string(repo().join("systemd/mouthpiece.service")).unwrap();
    assert!(unit.contains("ExecStart=/usr/local/bin/mouthpiece run"));
    // verify checks that ExecStart's program exists: point it at the binary under test.
    let unit = unit.replace(
        "/usr/local/bin/mouthpiece",
        env!("CARGO_BIN_EXE_mouthpiece"),
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mouthpiece.service");
    std::fs::write(&path, unit).unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "systemd-analyze verify failed: {stderr}"
    );
    // Unknown keys and bad values are only warnings with exit code 0: require none.
    assert!(
        stderr.trim().is_empty(),
        "systemd-analyze verify warned: {stderr}"
    );
}

#[test]
fn unit_has_the_promised_settings() {
    let unit = std::fs::read_to_string(repo().join("systemd/mouthpiece.service")).unwrap();
    for line in [
        "Type=notify",
        "WatchdogSec=",
        "DynamicUser=yes",
        "ProtectSystem=strict",
        "PrivateTmp=yes",
        "NoNewPrivileges=yes",
        "DeviceAllow=char-video4linux rw",
        "DeviceAllow=char-usb_device rw",
        "StateDirectory=mouthpiece",
        "ExecReload=/bin/kill -HUP $MAINPID",
    ] {
        assert!(unit.lines().any(|l| l.starts_with(line)), "missing {line}");
    }
}

#[test]
fn udev_rule_grants_group_video_to_openni2_vendors() {
    let rules =
        std::fs::read_to_string(repo().join("systemd/55-mouthpiece-openni2.rules")).unwrap();
    for vendor in ["1d27", "045e", "2bc5"] {
        let rule = rules
            .lines()
            .find(|l| !l.starts_with('#') && l.contains(&format!("ATTR{{idVendor}}==\"{vendor}\"")))
            .unwrap_or_else(|| panic!("no rule for vendor {vendor}"));
        assert!(
            rule.contains("SUBSYSTEM==\"usb\"") && rule.contains("GROUP=\"video\""),
            "{rule}"
        );
        assert!(rule.contains("MODE=\"0660\""), "{rule}");
    }
}

/// The booth's Debian package, built around the binary under test, installs, upgrades
/// (keeping an edited configuration) and removes with dpkg, and its service runs the
/// microphone and the paint check's Apply inside the sandbox its unit describes
/// (scripts/package-check, which does all of it in a throwaway copy-on-write root).
#[test]
fn the_package_installs_upgrades_runs_sandboxed_and_removes() {
    // SAFETY: getuid has no preconditions.
    assert_eq!(
        unsafe { libc::getuid() },
        0,
        "the package check needs root (mount namespaces, dpkg), as the README's test command runs"
    );
    let dir = tempfile::tempdir().unwrap();
    let mut debs = Vec::new();
    for version in ["0.1.0~check1", "0.1.0~check2"] {
        let out = Command::new("bash")
            .arg(repo().join("scripts/package"))
            .args(["--binary", env!("CARGO_BIN_EXE_mouthpiece")])
            .args(["--version", version, "--compress", "none", "--out"])
            .arg(dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "scripts/package failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        debs.push(String::from_utf8(out.stdout).unwrap().trim().to_owned());
    }
    let fields = Command::new("dpkg-deb")
        .args(["-f", &debs[0], "Package", "Depends"])
        .output()
        .unwrap();
    let fields = String::from_utf8_lossy(&fields.stdout);
    assert!(fields.contains("Package: mouthpiece"), "{fields}");
    assert!(fields.contains("libopencv-core"), "{fields}");
    let out = Command::new("bash")
        .arg(repo().join("scripts/package-check"))
        .args(&debs)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "scripts/package-check failed:\n{stderr}"
    );
    for step in [
        "install",
        "upgrade",
        "microphone live",
        "paint check applied under the unit",
        "purge",
        "== package-check: ok",
    ] {
        assert!(stderr.contains(step), "no `{step}` in:\n{stderr}");
    }
}
