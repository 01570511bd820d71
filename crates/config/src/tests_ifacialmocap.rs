//! `[ifacialmocap]`: defaults, and each bad value refused with its key and line.

use super::*;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("/etc/mouthpiece/test.toml"))
}

#[test]
fn ifacialmocap_is_off_by_default_on_loopback_at_the_apps_port() {
    let config = parse("").unwrap();
    let ifm = &config.ifacialmocap;
    assert!(!ifm.enabled);
    assert_eq!(ifm.listen().unwrap(), "127.0.0.1:49983".parse().unwrap());
    assert_eq!(ifm.reply_port, 49983);
    assert!(
        config.summary().contains("ifacialmocap off"),
        "{}",
        config.summary()
    );
    let config = parse(
        "[ifacialmocap]\nenabled = true\naddress = \"0.0.0.0\"\nport = 50000\nreply_port = 0\ncharacter = \"wolf\"\n",
    )
    .unwrap();
    let ifm = &config.ifacialmocap;
    assert!(ifm.enabled);
    assert_eq!(ifm.listen().unwrap(), "0.0.0.0:50000".parse().unwrap());
    assert_eq!(ifm.reply_port, 0);
    assert_eq!(ifm.character.as_deref(), Some("wolf"));
}

#[test]
fn bad_ifacialmocap_settings_name_their_key_and_line() {
    for (text, key, line, says) in [
        (
            "[ifacialmocap]\nenabled = true\naddress = \"localhost\"\n",
            "ifacialmocap.address",
            3,
            "IP address",
        ),
        (
            "[ifacialmocap]\n\nport = 0\n",
            "ifacialmocap.port",
            3,
            "1 to 65535",
        ),
        (
            "[ifacialmocap]\nport = 70000\n",
            "ifacialmocap.port",
            2,
            "1 to 65535",
        ),
        (
            "[ifacialmocap]\nreply_port = 65536\n",
            "ifacialmocap.reply_port",
            2,
            "handshake's own port",
        ),
        (
            "[ifacialmocap]\ncharacter = \"\"\n",
            "ifacialmocap.character",
            2,
            "character's name",
        ),
        (
            "[ifacialmocap]\nenable = true\n",
            "ifacialmocap.enable",
            2,
            "unknown field",
        ),
    ] {
        let err = parse(text).unwrap_err();
        let message = err.to_string();
        assert_eq!(err.key(), Some(key), "{message}");
        assert!(
            message.starts_with(&format!("/etc/mouthpiece/test.toml:{line}:")),
            "{message}"
        );
        assert!(message.contains(says), "{message}");
    }
}
