use super::*;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("/etc/mouthpiece/test.toml"))
}

fn example_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/mouthpiece.toml")
}

#[test]
fn the_documented_example_is_the_default() {
    let config = Config::load(&example_path()).expect("example config is valid");
    let mut expected = Config::default();
    // Paths in a file resolve against its directory.
    let dir = example_path().parent().unwrap().to_owned();
    expected.source.spec = SourceSpec(format!(
        "replay:{}?loop=1&speed=1.0",
        dir.join("../recordings/demo.mcap").display()
    ));
    expected.takes.folder = dir.join("takes");
    expected.origin = config.origin.clone();
    // `[detect]`, `[track]` and `[retarget]` are the pipeline's tables, kept here as TOML: the
    // example lists their defaults, checked against the pipeline's own in mouthpiece-track's
    // tests.
    expected.detect = config.detect.clone();
    expected.track = config.track.clone();
    expected.retarget = config.retarget.clone();
    assert_eq!(config, expected);
}

#[test]
fn an_empty_file_is_the_default() {
    let config = parse("").unwrap();
    assert_eq!(config.server.listen.0.to_string(), "127.0.0.1:9870");
    assert!(config.characters.files.is_empty());
    assert_eq!(config.timecode.rate.0, "30");
}

#[test]
fn unknown_key_names_file_line_and_key() {
    let err = parse("[server]\nlisten = \"127.0.0.1:1\"\nlistn = \"x\"\n").unwrap_err();
    let text = err.to_string();
    assert!(
        text.starts_with("/etc/mouthpiece/test.toml:3:1: key `server.listn`"),
        "{text}"
    );
    assert!(text.contains("unknown field `listn`"), "{text}");
    assert_eq!(err.key(), Some("server.listn"));
}

#[test]
fn bad_value_names_key_and_expectation() {
    let err = parse("[server]\nmax_clients = 4\nlisten = \"localhost\"\n").unwrap_err();
    let text = err.to_string();
    assert!(text.contains(":3:"), "{text}");
    assert_eq!(err.key(), Some("server.listen"), "{text}");
    assert!(
        text.contains("expected an address like 127.0.0.1:9870"),
        "{text}"
    );

    let err = parse("[takes]\nflush_s = -1\n").unwrap_err();
    assert_eq!(err.key(), Some("takes.flush_s"), "{err}");
    assert!(
        err.to_string().contains("expected a number of seconds > 0"),
        "{err}"
    );

    let err = parse("[timecode]\nrate = \"29.98\"\n").unwrap_err();
    assert_eq!(err.key(), Some("timecode.rate"), "{err}");
    assert!(err.to_string().contains("29.97df"), "{err}");

    let err = parse("[source]\nspec = \"camera0\"\n").unwrap_err();
    assert_eq!(err.key(), Some("source.spec"), "{err}");
    // `none`: a booth without a camera (speech alone); `nonesuch` is still refused.
    assert!(parse("[source]\nspec = \"none\"\n")
        .unwrap()
        .source
        .spec
        .is_none());
    let err = parse("[source]\nspec = \"nonesuch\"\n").unwrap_err();
    assert_eq!(err.key(), Some("source.spec"), "{err}");

    let err = parse("[takes]\nslate = \"../etc\"\n").unwrap_err();
    assert_eq!(err.key(), Some("takes.slate"), "{err}");
}

#[test]
fn wrong_type_names_key() {
    let err = parse("[takes]\nrecord_at_start = \"yes\"\n").unwrap_err();
    assert_eq!(err.key(), Some("takes.record_at_start"), "{err}");
    assert!(err.to_string().contains(":2:"), "{err}");
}

#[test]
fn syntax_error_gives_the_line() {
    let err = parse("[server]\nlisten = \n").unwrap_err();
    assert!(err.to_string().contains(":2:"), "{err}");
}

#[test]
fn cross_key_checks_name_the_key() {
    let err = parse("[source]\nretry_initial_s = 5.0\nretry_max_s = 1.0\n").unwrap_err();
    assert_eq!(err.key(), Some("source.retry_max_s"));
    assert!(err.to_string().contains(":3:"), "{err}");

    let err = parse("[server]\nlisten = \"0.0.0.0:9870\"\n").unwrap_err();
    assert_eq!(err.key(), Some("server.listen"));
    assert!(err.to_string().contains("read_token"), "{err}");

    let err = parse("[server]\nread_token = { env = \"A\", file = \"b\" }\n").unwrap_err();
    assert_eq!(err.key(), Some("server.read_token"), "{err}");

    let err = parse("[server]\ntls_cert = \"c.pem\"\n").unwrap_err();
    assert_eq!(err.key(), Some("server.tls_cert"), "{err}");
    assert!(
        err.to_string().contains("expected server.tls_key too"),
        "{err}"
    );
}

#[test]
fn tokens_come_from_env_and_file_and_never_print() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("control.token"), "s3cret-control\n").unwrap();
    // A variable name no other test uses: tests run in parallel in one process.
    std::env::set_var("MOUTHPIECE_TEST_READ_TOKEN_1", "s3cret-read");
    let text = "[server]\nlisten = \"0.0.0.0:9870\"\n\
                read_token = { env = \"MOUTHPIECE_TEST_READ_TOKEN_1\" }\n\
                control_token = { file = \"control.token\" }\n";
    let config = Config::parse(text, &dir.path().join("m.toml")).unwrap();
    assert_eq!(
        config.server.tokens.read.as_ref().unwrap().expose(),
        "s3cret-read"
    );
    assert_eq!(
        config.server.tokens.control.as_ref().unwrap().expose(),
        "s3cret-control"
    );
    let shown = format!("{config:?} {}", config.summary());
    assert!(!shown.contains("s3cret"), "a token leaked: {shown}");

    let literal = parse("[server]\nread_token = { value = \"s3cret-literal\" }\n").unwrap();
    assert!(!format!("{literal:?}").contains("s3cret"));
}

#[test]
fn a_missing_token_names_its_key_and_variable() {
    let err =
        parse("[server]\nread_token = { env = \"MOUTHPIECE_TEST_UNSET_TOKEN\" }\n").unwrap_err();
    assert_eq!(err.key(), Some("server.read_token"));
    let chain = format!("{err}: {}", std::error::Error::source(&err).unwrap());
    assert!(
        chain.contains(":2:") && chain.contains("MOUTHPIECE_TEST_UNSET_TOKEN"),
        "{chain}"
    );
}

#[test]
fn relative_paths_resolve_against_the_config_directory() {
    let config = Config::parse(
        "[characters]\nfiles = [\"chars/wolf.toml\", \"/abs/human.toml\"]\n[source]\nspec = \"replay:s.mcap?loop=1\"\n",
        Path::new("/srv/booth/m.toml"),
    )
    .unwrap();
    assert_eq!(
        config.characters.files[0],
        Path::new("/srv/booth/chars/wolf.toml")
    );
    assert_eq!(config.characters.files[1], Path::new("/abs/human.toml"));
    assert_eq!(config.source.spec.0, "replay:/srv/booth/s.mcap?loop=1");
    assert_eq!(config.takes.folder, Path::new("/srv/booth/takes"));
}

#[test]
fn owned_sections_are_extracted_with_file_lines() {
    #[derive(Debug, Default, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct DetectConfig {
        #[serde(default)]
        min_area: u32,
    }
    #[derive(Debug, Default, Deserialize, PartialEq)]
    struct Sections {
        #[serde(default)]
        detect: DetectConfig,
    }
    let config = parse("[detect]\nmin_area = 7\n").unwrap();
    assert_eq!(
        config.extract::<Sections>().unwrap().detect,
        DetectConfig { min_area: 7 }
    );
    let config = parse("[logging]\nlevel = \"debug\"\n\n[detect]\nmin_aera = 7\n").unwrap();
    let err = config.extract::<Sections>().unwrap_err();
    assert_eq!(err.key(), Some("detect.min_aera"), "{err}");
    assert!(err.to_string().contains(":5:"), "{err}");
    assert_eq!(
        Config::default().extract::<Sections>().unwrap(),
        Sections::default()
    );
}

#[test]
fn a_relative_takes_folder_goes_to_the_state_directory_under_systemd() {
    let mut config = Config::default();
    config.resolve_paths(
        Path::new("/etc/mouthpiece"),
        Some(Path::new("/var/lib/mouthpiece")),
    );
    assert_eq!(config.takes.folder, Path::new("/var/lib/mouthpiece/takes"));
    let mut config = Config::default();
    config.takes.folder = PathBuf::from("/srv/takes");
    config.resolve_paths(
        Path::new("/etc/mouthpiece"),
        Some(Path::new("/var/lib/mouthpiece")),
    );
    assert_eq!(config.takes.folder, Path::new("/srv/takes"));
}

#[test]
fn errors_about_tokens_never_quote_the_secret() {
    let secret = "s3cr3t-s3cr3t-s3cr3t-XYZ";
    for text in [
        format!("[server]\nread_token = \"{secret}\"\n"),
        format!("[server]\ncontrol_token = \"{secret}\"\n"),
        format!("[server]\nread_token = [\"{secret}\"]\n"),
        format!("[server]\nread_token = {{ value = [\"{secret}\"] }}\n"),
        format!("[server]\nread_token = {{ valu = \"{secret}\" }}\n"),
        format!("[server]\nread_token = {{ value = \"{secret}\", env = \"X\" }}\n"),
        format!("[server.read_token]\nvalue = \"{secret}\"\nfile = 3\n"),
        "[server]\nread_token = { value = 1234567890123 }\n".to_owned(),
    ] {
        let err = parse(&text).unwrap_err();
        let mut shown = format!("{err} {err:?}");
        let mut source = std::error::Error::source(&err);
        while let Some(s) = source {
            shown.push_str(&format!(" {s} {s:?}"));
            source = s.source();
        }
        assert!(!shown.contains(secret), "{text}: {shown}");
        assert!(!shown.contains("1234567890123"), "{text}: {shown}");
        assert!(shown.contains("_token"), "names the key: {shown}");
    }
}

#[test]
fn a_token_file_that_never_ends_is_refused() {
    let err = parse("[server]\nread_token = { file = \"/dev/zero\" }\n").unwrap_err();
    let mut text = err.to_string();
    let mut source = std::error::Error::source(&err);
    while let Some(s) = source {
        text.push_str(&format!(": {s}"));
        source = s.source();
    }
    assert!(text.contains("server.read_token"), "{text}");
    // Refused once it runs past a token's length, not when memory runs out.
    assert!(text.contains("longer than 4096 bytes"), "{text}");
}

#[test]
fn limits_above_the_hard_caps_are_refused() {
    for (text, key) in [
        ("[takes]\nqueue_frames = 4294967295\n", "takes.queue_frames"),
        ("[takes]\nqueue_frames = 0\n", "takes.queue_frames"),
        ("[server]\nmax_clients = 4294967295\n", "server.max_clients"),
        ("[takes]\nmax_write_mb_s = -1.0\n", "takes.max_write_mb_s"),
        ("[takes]\nmax_write_mb_s = 1e-300\n", "takes.max_write_mb_s"),
        ("[takes]\nmax_write_mb_s = inf\n", "takes.max_write_mb_s"),
        ("[takes]\nmax_write_mb_s = nan\n", "takes.max_write_mb_s"),
    ] {
        let err = parse(text).unwrap_err();
        assert_eq!(err.key(), Some(key), "{text}: {err}");
    }
    assert!(parse("[takes]\nqueue_frames = 3600\n[server]\nmax_clients = 512\n").is_ok());
    assert!(parse("[takes]\nmax_write_mb_s = 0.5\n").is_ok());
}

#[test]
fn osc_targets_are_host_and_port() {
    let config = parse(
        "[osc]\ntargets = [\"127.0.0.1:39539\", \"localhost:9000\", \"[::1]:39540\"]\ncharacter = \"wolf\"\neyes = false\n",
    )
    .unwrap();
    let targets = config.osc.parsed_targets().unwrap();
    let shown: Vec<String> = targets.iter().map(|t| t.to_string()).collect();
    assert_eq!(shown, ["127.0.0.1:39539", "localhost:9000", "[::1]:39540"]);
    assert_eq!((targets[2].host.as_str(), targets[2].port), ("::1", 39540));
    assert_eq!(config.osc.character.as_deref(), Some("wolf"));
    assert!(config.osc.head && !config.osc.eyes);
    assert!(config
        .summary()
        .contains("osc 127.0.0.1:39539, localhost:9000"));
    // Off unless configured.
    assert!(parse("").unwrap().osc.targets.is_empty());
    assert!(parse("").unwrap().summary().contains("osc off"));
}

/// `[osc] names` and `visemes`: the defaults, each value, and a bad one refused with its key
/// and line.
#[test]
fn osc_names_and_visemes_are_checked() {
    use mouthpiece_output::{CurveNaming, VisemeNaming};
    let config = parse("").unwrap();
    assert_eq!(
        (config.osc.names, config.osc.visemes),
        (CurveNaming::Arkit, VisemeNaming::Vrm0)
    );
    let config = parse("[osc]\nnames = \"arkit-pascal\"\nvisemes = \"vrm1\"\n").unwrap();
    assert_eq!(
        (config.osc.names, config.osc.visemes),
        (CurveNaming::ArkitPascal, VisemeNaming::Vrm1)
    );
    assert_eq!(
        parse("[osc]\nvisemes = \"none\"\n").unwrap().osc.visemes,
        VisemeNaming::None
    );
    for (text, key) in [
        ("[osc]\nhead = true\nvisemes = \"vrm2\"\n", "osc.visemes"),
        ("[osc]\nhead = true\nnames = \"JawOpen\"\n", "osc.names"),
    ] {
        let err = parse(text).unwrap_err();
        let shown = err.to_string();
        assert_eq!(err.key(), Some(key), "{text}: {shown}");
        assert!(shown.contains("test.toml:3:"), "{text}: {shown}");
    }
}

#[test]
fn a_bad_osc_target_names_its_line_and_key() {
    for (target, expected) in [
        ("127.0.0.1", "expected host:port"),
        ("127.0.0.1:", "expected host:port"),
        (":39539", "expected host:port"),
        ("127.0.0.1:65536", "port out of range"),
        ("127.0.0.1:0", "port out of range"),
        ("127.0.0.1:99999999999", "port out of range"),
        ("127.0.0.1:-1", "expected host:port"),
        ("::1:39539", "goes in brackets"),
        ("[::1:39539", "expected host:port"),
        ("[nope]:39539", "IPv6 address"),
        ("a host:1", "expected host:port"),
    ] {
        let text = format!("[osc]\ntargets = [\n  \"127.0.0.1:9000\",\n  \"{target}\",\n]\n");
        let err = parse(&text).unwrap_err();
        let shown = err.to_string();
        assert!(shown.contains("test.toml:4:3: "), "{target}: {shown}");
        assert_eq!(err.key(), Some("osc.targets[1]"), "{target}: {shown}");
        assert!(shown.contains(expected), "{target}: {shown}");
    }
    let err = parse("[osc]\ntargets = \"127.0.0.1:1\"\n").unwrap_err();
    assert_eq!(err.key(), Some("osc.targets"), "{err}");
    let err = parse("[osc]\ntargets = [\"127.0.0.1:1\",\n \"127.0.0.1:1\"]\n").unwrap_err();
    assert_eq!(err.key(), Some("osc.targets[1]"), "{err}");
    assert!(err.to_string().contains("test.toml:3:"), "{err}");
    assert!(err.to_string().contains("listed twice"), "{err}");
    let err = parse("[osc]\ncharacter = \"\"\n").unwrap_err();
    assert_eq!(err.key(), Some("osc.character"), "{err}");
    let err = parse("[osc]\nport = 1\n").unwrap_err();
    assert_eq!(err.key(), Some("osc.port"), "{err}");
}

/// `[osc.characters]`: more characters, each with its own targets; a bad one or a destination
/// listed for two characters names its key and line.
#[test]
fn osc_characters_have_their_own_targets() {
    let config = parse(
        "[osc]\ntargets = [\"127.0.0.1:39539\"]\n[osc.characters]\nhuman = [\"127.0.0.1:39540\"]\n",
    )
    .unwrap();
    let all = config.osc.all_targets();
    assert_eq!(
        all,
        [
            ("osc.targets[0]".to_owned(), "127.0.0.1:39539", None),
            (
                "osc.characters.human[0]".to_owned(),
                "127.0.0.1:39540",
                Some("human")
            ),
        ]
    );
    assert!(
        config
            .summary()
            .contains("osc 127.0.0.1:39539, 127.0.0.1:39540 (human)"),
        "{}",
        config.summary()
    );
    let err = parse(
        "[osc]\ntargets = [\"127.0.0.1:1\"]\n[osc.characters]\nhuman = [\n \"127.0.0.1:1\"]\n",
    )
    .unwrap_err();
    assert_eq!(err.key(), Some("osc.characters.human[0]"), "{err}");
    assert!(err.to_string().contains("test.toml:5:"), "{err}");
    assert!(err.to_string().contains("listed twice"), "{err}");
    let err = parse("[osc.characters]\nhuman = [\"127.0.0.1\"]\n").unwrap_err();
    assert_eq!(err.key(), Some("osc.characters.human[0]"), "{err}");
    let err = parse("[osc.characters]\nhuman = \"127.0.0.1:1\"\n").unwrap_err();
    assert!(err.to_string().contains("osc.characters"), "{err}");
}

#[test]
fn an_array_element_is_located_on_its_own_line() {
    let config = parse("[osc]\ntargets = [\n  \"127.0.0.1:1\",\n  \"127.0.0.1:2\",\n]\n").unwrap();
    let location = config.locate("osc.targets[1]");
    assert_eq!((location.line, location.column), (4, 3), "{location}");
    assert_eq!(location.key.as_deref(), Some("osc.targets[1]"));
    // Past the end: the key itself.
    assert_eq!(config.locate("osc.targets[7]").line, 2);
}

/// A megabyte-long OSC target or thousands of targets: errors name the key and quote at
/// most the first 80 characters of a value.
#[test]
fn huge_osc_values_are_refused_without_echoing_them() {
    for target in [
        format!("{}:39539", "a".repeat(1_000_000)),
        format!("127.0.0.1:{}", "9".repeat(1_000_000)),
        "b".repeat(1_000_000),
    ] {
        let err = parse(&format!("[osc]\ntargets = [\"{target}\"]\n")).unwrap_err();
        let shown = err.to_string();
        assert_eq!(err.key(), Some("osc.targets[0]"), "{}", &shown[..200]);
        assert!(shown.len() < 400, "the error echoes {} bytes", shown.len());
    }
    let many: Vec<String> = (0..5000)
        .map(|i| format!("\"127.0.0.1:{}\"", 1000 + i))
        .collect();
    let err = parse(&format!("[osc]\ntargets = [{}]\n", many.join(", "))).unwrap_err();
    assert_eq!(err.key(), Some("osc.targets"), "{err}");
    assert!(err.to_string().contains("at most 16"), "{err}");
}

/// `[characters.settings.NAME]`: speech off by default; modes, hold and blend read; a bad
/// mode or an absurd time is an error naming the key and line.
#[test]
fn character_speech_settings_are_read_and_checked() {
    let config = parse("").unwrap();
    assert!(config.characters.settings.is_empty());
    let config = parse(
        "[characters.settings.human]\nspeech = \"fallback\"\nspeech_hold_ms = 250\n\
         [characters.settings.wolf]\nspeech = \"always\"\n",
    )
    .unwrap();
    let human = config.characters.settings["human"];
    assert_eq!(human.speech, SpeechSetting::Fallback);
    assert_eq!((human.speech_hold_ms, human.speech_blend_ms), (250, 150));
    assert_eq!(
        config.characters.settings["wolf"].speech,
        SpeechSetting::Always
    );
    let err = parse("[characters.settings.human]\nspeech = \"loud\"\n").unwrap_err();
    assert!(err.to_string().contains("test.toml:2:"), "{err}");
    assert!(err.to_string().contains("loud"), "{err}");
    let err = parse("[characters.settings.human]\n\nspeech_hold_ms = 99999\n").unwrap_err();
    assert_eq!(
        err.key(),
        Some("characters.settings.human.speech_hold_ms"),
        "{err}"
    );
    assert!(err.to_string().contains("test.toml:3:"), "{err}");
    let err = parse("[characters.settings.human]\nspeech_blend_ms = 5000\n").unwrap_err();
    assert_eq!(
        err.key(),
        Some("characters.settings.human.speech_blend_ms"),
        "{err}"
    );
    let err = parse("[characters.settings.human]\nspeech_hold_ms = -1\n").unwrap_err();
    assert!(err.to_string().contains("speech_hold_ms"), "{err}");
}

#[test]
fn audio_is_off_when_absent_and_defaults_when_present() {
    assert_eq!(parse("").unwrap().audio, None);
    let audio = parse("[audio]\n").unwrap().audio.unwrap();
    assert_eq!(audio, AudioConfig::default());
    assert_eq!(
        (audio.device.as_str(), audio.sample_rate, audio.channels),
        ("default", 48_000, 1)
    );
    let audio = parse("[audio]\ndevice = \"booth\"\nsample_rate = 44100\nchannels = 2\nperiod_frames = 256\nbuffer_frames = 1024\n")
        .unwrap()
        .audio
        .unwrap();
    assert_eq!((audio.sample_rate, audio.channels), (44_100, 2));
}

#[test]
fn absurd_audio_formats_name_their_key_and_line() {
    for (text, key, line) in [
        ("[audio]\nsample_rate = 0\n", "audio.sample_rate", 2),
        (
            "[audio]\ndevice = \"x\"\nsample_rate = 10000000\n",
            "audio.sample_rate",
            3,
        ),
        ("[audio]\nchannels = 0\n", "audio.channels", 2),
        ("[audio]\nchannels = 300\n", "audio.channels", 2),
        ("[audio]\nperiod_frames = 0\n", "audio.period_frames", 2),
        (
            "[audio]\nperiod_frames = 480\nbuffer_frames = 480\n",
            "audio.buffer_frames",
            3,
        ),
        ("[audio]\ndevice = \"\"\n", "audio.device", 2),
        ("[audio]\nqueue_blocks = 0\n", "audio.queue_blocks", 2),
        ("[audio]\nsample_rate = -1\n", "audio.sample_rate", 2),
        ("[audio]\nsample_rat = 48000\n", "audio.sample_rat", 2),
    ] {
        let err = parse(text).unwrap_err();
        assert_eq!(err.key(), Some(key), "{text}: {err}");
        let shown = err.to_string();
        assert!(
            shown.starts_with(&format!("/etc/mouthpiece/test.toml:{line}:")),
            "{text}: {shown}"
        );
    }
    let long = format!("[audio]\ndevice = \"{}\"\n", "x".repeat(100_000));
    let err = parse(&long).unwrap_err().to_string();
    assert!(
        err.len() < 400,
        "the error does not echo the value: {} bytes",
        err.len()
    );
}

/// The protocol page's limits table states the client cap the configuration decides.
#[test]
fn the_documented_client_limit_is_the_default() {
    let page = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/protocol.md"),
    )
    .unwrap();
    let row = page
        .lines()
        .find(|l| l.starts_with("| WebSocket clients |"))
        .expect("docs/protocol.md has the WebSocket clients row");
    let expected = format!(
        "| WebSocket clients | {} (`[server] max_clients`, at most {MAX_CLIENTS}) |",
        Config::default().server.max_clients
    );
    assert!(row.starts_with(&expected), "{row}\nexpected {expected}");
}

/// Device strings that would make alsa-lib write a file or run a command are refused unless
/// `allow_file_plugin` says otherwise; names of PCMs (an asound.conf's too) pass.
#[test]
fn alsa_devices_that_write_files_or_run_commands_are_refused() {
    for good in [
        "default",
        "hw:1,0",
        "plughw:CARD=USB,DEV=0",
        "dsnoop:CARD=PCH",
        "booth_file",
        "profile",
    ] {
        let text = format!("[audio]\ndevice = \"{good}\"\n");
        assert!(parse(&text).is_ok(), "{good}");
    }
    for (bad, says) in [
        ("file:'|touch /tmp/x'", "pipe"),
        ("file:FILE=/tmp/out.raw", "`file` plugin"),
        ("plug:'file:FILE=/tmp/x'", "`file` plugin"),
        ("tee:hw,/tmp/x,raw", "`tee` plugin"),
        (
            "plug:{type file slave.pcm null file x}",
            "inline definition",
        ),
        ("ladspa:x", "`ladspa` plugin"),
        ("hw:0\\u001b[2J", "control characters"),
    ] {
        let text = format!("[audio]\n\ndevice = \"{}\"\n", bad.replace('"', "\\\""));
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), Some("audio.device"), "{bad}: {err}");
        let shown = err.to_string();
        assert!(shown.starts_with("/etc/mouthpiece/test.toml:3:"), "{shown}");
        assert!(shown.contains(says), "{bad}: {shown}");
        assert!(!shown.contains('\u{1b}'), "{shown:?}");
        if says != "control characters" {
            assert!(shown.contains("audio.allow_file_plugin = true"), "{shown}");
            let allowed = format!(
                "[audio]\nallow_file_plugin = true\ndevice = \"{}\"\n",
                bad.replace('"', "\\\"")
            );
            assert!(parse(&allowed).is_ok(), "{bad}");
        }
    }
}
