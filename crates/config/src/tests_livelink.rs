//! `[livelink]`: defaults, the derived device id, and errors naming key and line.

use super::*;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("/etc/mouthpiece/test.toml"))
}

#[test]
fn livelink_defaults_and_a_character_with_targets() {
    let config = parse("").unwrap();
    assert!(config.livelink.enabled);
    assert!(config.livelink.characters.is_empty());
    assert_eq!(config.livelink.control_addr(), None);
    assert_eq!(
        config.livelink.allowed(),
        vec![
            "127.0.0.1".parse::<std::net::IpAddr>().unwrap(),
            "::1".parse().unwrap()
        ]
    );
    let config = parse(
        "[livelink]\ncontrol = \"127.0.0.1:8000\"\n[livelink.characters.wolf]\nsubject = \"Wolf\"\ntargets = [\"127.0.0.1:11111\", \"studio-pc:11111\"]\n",
    )
    .unwrap();
    let wolf = &config.livelink.characters["wolf"];
    assert_eq!(wolf.subject_or("wolf"), "Wolf");
    assert_eq!(wolf.targets.len(), 2);
    assert_eq!(
        config.livelink.control_addr(),
        Some("127.0.0.1:8000".parse().unwrap())
    );
    assert!(
        config
            .summary()
            .contains("livelink Wolf -> 127.0.0.1:11111"),
        "{}",
        config.summary()
    );
}

#[test]
fn the_default_device_id_is_a_stable_uuid_of_the_subject() {
    let a = default_device_id("wolf");
    assert!(is_uuid(&a), "{a}");
    assert_eq!(a, default_device_id("wolf"));
    assert_ne!(a, default_device_id("human"));
    // Version 8, RFC 9562 variant, upper case as iOS writes UUIDs.
    assert_eq!(&a[14..15], "8");
    assert!(matches!(&a[19..20], "8" | "9" | "A" | "B"), "{a}");
    assert_eq!(a, a.to_ascii_uppercase());
    let configured = LiveLinkCharacter {
        device_id: Some("0b2c5e4f-6a7d-4e8f-9a0b-1c2d3e4f5a6b".into()),
        ..Default::default()
    };
    assert_eq!(
        configured.device_id_or("wolf"),
        "0B2C5E4F-6A7D-4E8F-9A0B-1C2D3E4F5A6B"
    );
}

#[test]
fn an_ipv4_sender_matches_its_mapped_ipv6_form() {
    let allowed = ["127.0.0.1".parse().unwrap()];
    assert!(source_allowed(&allowed, "127.0.0.1".parse().unwrap()));
    assert!(source_allowed(
        &allowed,
        "::ffff:127.0.0.1".parse().unwrap()
    ));
    assert!(!source_allowed(&allowed, "127.0.0.2".parse().unwrap()));
    assert!(!source_allowed(&allowed, "::1".parse().unwrap()));
}

#[test]
fn bad_livelink_settings_name_their_key_and_line() {
    for (text, key, line, says) in [
        (
            "[livelink]\ncontrol = \"localhost:8000\"\n",
            "livelink.control",
            2,
            "IP address and a port",
        ),
        (
            "[livelink]\nallow = [\"127.0.0.1\", \"10.0.0.0/8\"]\n",
            "livelink.allow[1]",
            2,
            "expected an IP address",
        ),
        (
            "[livelink.characters.wolf]\ntargets = [\"127.0.0.1:11111\", \"127.0.0.1\"]\n",
            "livelink.characters.wolf.targets[1]",
            2,
            "host:port",
        ),
        (
            "[livelink.characters.wolf]\ntargets = [\"127.0.0.1:11111\", \"127.0.0.1:11111\"]\n",
            "livelink.characters.wolf.targets[1]",
            2,
            "listed twice",
        ),
        (
            "[livelink.characters.wolf]\n\ndevice_id = \"not-a-uuid\"\n",
            "livelink.characters.wolf.device_id",
            3,
            "expected a UUID",
        ),
        (
            "[livelink.characters.wolf]\nsubject = \"\"\n",
            "livelink.characters.wolf.subject",
            2,
            "1 to 255 bytes",
        ),
        (
            "[livelink.characters.wolf]\nsubject = \"a\\nb\"\n",
            "livelink.characters.wolf.subject",
            2,
            "control characters",
        ),
        (
            "[livelink]\nenabled = \"yes\"\n",
            "livelink.enabled",
            2,
            "boolean",
        ),
        (
            "[livelink.characters.wolf]\nport = 11111\n",
            "livelink.characters.wolf.port",
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
