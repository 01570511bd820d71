//! `mouthpiece check-config`: exit 0 for a valid file, 2 with the file, line and key for a
//! bad one.

fn check(text: &str) -> (i32, String, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mouthpiece.toml");
    std::fs::write(&path, text).unwrap();
    let out = crate::mouthpiece()
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
    let out = crate::mouthpiece()
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
    let out = crate::mouthpiece()
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

/// A character's name in a table key (`[characters.settings."…"]`, `[osc.characters]`) is
/// shown quoted and escaped, with its line: no escape sequence or newline reaches the
/// terminal, and a name with a dot or a bracket still finds its line.
#[test]
fn names_in_keys_are_escaped_and_keep_their_line() {
    let (code, _, stderr) = check(
        "[characters]\nfiles = [\"/nonexistent-dir/wolf.toml\"]\n\n[characters.settings.\"w.v2\\u001b[2J\"]\nspeech_hold_ms = 99999999\n",
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(!stderr.contains('\u{1b}'), "{stderr:?}");
    assert!(
        stderr.contains(
            "mouthpiece.toml:5:1: key `characters.settings.\"w.v2\\u001B[2J\".speech_hold_ms`"
        ),
        "{stderr}"
    );
    let (code, _, stderr) = check("[osc.characters]\n\"h\\nforged[0]\" = [\n  \"127.0.0.1\"]\n");
    assert_eq!(code, 2, "{stderr}");
    assert_eq!(
        stderr.lines().filter(|l| l.contains("key `")).count(),
        1,
        "{stderr}"
    );
    assert!(
        stderr.contains("mouthpiece.toml:3:3: key `osc.characters.\"h\\nforged[0]\"[0]`"),
        "{stderr}"
    );
}

/// A `[characters.settings]` name that no character has: the error names its line.
#[test]
fn settings_for_an_unknown_character_name_their_line() {
    let (code, _, stderr) = check(concat!(
        "[characters]\nfiles = [\"",
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/characters/wolf.toml\"]\n\n[characters.settings.\"wolf.v2\"]\nspeech = \"fallback\"\n"
    ));
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("mouthpiece.toml:4:") && stderr.contains("characters.settings.\"wolf.v2\""),
        "{stderr}"
    );
    assert!(stderr.contains("no configured character"), "{stderr}");
}
