//! `mouthpiece check-config`: exit 0 for a valid file, 2 with the file, line and key for a
//! bad one.

use std::process::Command;

fn check(text: &str) -> (i32, String, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mouthpiece.toml");
    std::fs::write(&path, text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
        .arg("check-config")
        .arg(&path)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_example_config_is_valid() {
    let out = Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
        .arg("check-config")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/mouthpiece.toml"
        ))
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("ok"));
}

#[test]
fn a_bad_key_exits_2_naming_it() {
    let (code, _, stderr) = check("[source]\nspec = \"replay:x.mcap\"\n\n[takes]\nfoldr = \"t\"\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("mouthpiece.toml:5:1: key `takes.foldr`"),
        "{stderr}"
    );
}

#[test]
fn a_bad_value_exits_2_naming_key_and_expectation() {
    let (code, _, stderr) = check("[timecode]\nrate = \"31\"\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(":2:") && stderr.contains("timecode.rate"),
        "{stderr}"
    );
    assert!(stderr.contains("expected one of"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn a_missing_file_exits_2() {
    let out = Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
        .args(["check-config", "/nonexistent/mouthpiece.toml"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/mouthpiece.toml"));
}

#[test]
fn a_token_is_never_printed() {
    let (code, stdout, stderr) =
        check("[server]\nread_token = { value = \"very-secret-token-123\" }\n");
    assert_eq!(code, 0, "{stderr}");
    assert!(
        !stdout.contains("very-secret") && !stderr.contains("very-secret"),
        "{stdout}{stderr}"
    );
}

#[test]
fn an_inverted_colour_range_exits_2_naming_the_key() {
    let (code, _, stderr) = check(
        "[detect]\n[[detect.class]]\nname = \"lip\"\nrole = \"lip\"\nhue = [[80, 40]]\n\
         saturation = [90, 255]\nvalue = [40, 255]\n",
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("detect.class[0].hue[0]"), "{stderr}");
    // And a [track] value out of range.
    let (code, _, stderr) = check("[track]\nlip_dots = 5\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("track.lip_dots"), "{stderr}");
}

#[test]
fn a_bad_osc_target_or_character_exits_2_naming_the_element() {
    // Port out of range, on the element's own line.
    let (code, _, stderr) =
        check("[osc]\ntargets = [\n  \"127.0.0.1:39539\",\n  \"127.0.0.1:70000\",\n]\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("mouthpiece.toml:4:3: key `osc.targets[1]`")
            && stderr.contains("port out of range"),
        "{stderr}"
    );
    // Not host:port.
    let (code, _, stderr) = check("[osc]\ntargets = [\"39539\"]\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("osc.targets[0]") && stderr.contains("expected host:port"),
        "{stderr}"
    );
    // A name that does not resolve (`.invalid` never does).
    let (code, _, stderr) = check("[osc]\ntargets = [\"no-such-host.invalid:39539\"]\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(":2:") && stderr.contains("osc.targets[0]"),
        "{stderr}"
    );
    assert!(
        stderr.contains("cannot resolve no-such-host.invalid"),
        "{stderr}"
    );
    // A character that is not configured.
    let (code, _, stderr) =
        check("[osc]\ntargets = [\"127.0.0.1:39539\"]\ncharacter = \"ghost\"\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(":3:")
            && stderr.contains("osc.character")
            && stderr.contains("human, wolf"),
        "{stderr}"
    );
    // And a good one.
    let (code, stdout, stderr) =
        check("[osc]\ntargets = [\"localhost:39539\", \"[::1]:39540\"]\ncharacter = \"wolf\"\n");
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("osc localhost:39539, [::1]:39540"),
        "{stdout}"
    );
    // [osc.characters]: a character that is not configured, named by its key and line.
    let (code, _, stderr) = check("[osc]\n[osc.characters]\nghost = [\"127.0.0.1:39540\"]\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(":3:")
            && stderr.contains("osc.characters.ghost[0]")
            && stderr.contains("human, wolf"),
        "{stderr}"
    );
    // Each character its own target.
    let (code, stdout, stderr) = check(
        "[osc]\ntargets = [\"127.0.0.1:39539\"]\ncharacter = \"wolf\"\n\
         [osc.characters]\nhuman = [\"127.0.0.1:39540\"]\n",
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("osc 127.0.0.1:39539, 127.0.0.1:39540 (human)"),
        "{stdout}"
    );
}

#[test]
fn a_bad_ifacialmocap_section_exits_2_naming_the_key() {
    // A character that is not configured (checked against the characters, not by the parser).
    let (code, _, stderr) = check("[ifacialmocap]\nenabled = true\ncharacter = \"ghost\"\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(":3:")
            && stderr.contains("ifacialmocap.character")
            && stderr.contains("human, wolf"),
        "{stderr}"
    );
    // A host name where an address is expected.
    let (code, _, stderr) = check("[ifacialmocap]\naddress = \"booth.local\"\n");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(":2:") && stderr.contains("ifacialmocap.address"),
        "{stderr}"
    );
    // And a good one, shown in the summary.
    let (code, stdout, stderr) =
        check("[ifacialmocap]\nenabled = true\naddress = \"0.0.0.0\"\ncharacter = \"wolf\"\n");
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("ifacialmocap 0.0.0.0:49983"), "{stdout}");
}
