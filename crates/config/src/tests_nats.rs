//! `[nats]`: validation with key and line, secrets read and never printed.

use super::*;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("/etc/mouthpiece/test.toml"))
}

#[test]
fn nats_is_off_by_default_and_on_with_servers_and_a_booth() {
    let config = parse("").unwrap();
    assert!(!config.nats.enabled());
    assert!(
        config.summary().contains("nats off"),
        "{}",
        config.summary()
    );
    let config = parse(
        "[nats]\nservers = [\"nats://127.0.0.1:4222\", \"tls://n2:4222\"]\nbooth = \"booth-a\"\n",
    )
    .unwrap();
    assert!(config.nats.enabled());
    assert_eq!(config.nats.booth.as_deref(), Some("booth-a"));
}

#[test]
fn bad_nats_settings_name_their_key_and_line() {
    for (text, key, line, says) in [
        (
            "[nats]\nservers = [\"nats://h:4222\"]\nbooth = \"a.b\"\n",
            "nats.booth",
            3,
            "subject token",
        ),
        (
            "[nats]\nservers = [\"nats://h:4222\"]\n",
            "nats.servers",
            2,
            "nats.booth",
        ),
        (
            "[nats]\nbooth = \"a\"\nservers = [\"nats://h:4222\", \"http://h:1\"]\n",
            "nats.servers[1]",
            3,
            "nats:// or tls://",
        ),
        (
            "[nats]\nbooth = \"a\"\nservers = [\"nats://h:99999\"]\n",
            "nats.servers[0]",
            3,
            "port",
        ),
        (
            "[nats]\nbooth = \"a\"\nstudio = \"my studio\"\n",
            "nats.studio",
            3,
            "names buckets",
        ),
        (
            "[nats]\nbooth = \"a\"\n\nqueue_frames = 0\n",
            "nats.queue_frames",
            4,
            "1 to 4096",
        ),
        (
            "[nats]\nbooth = \"a\"\nuser = \"u\"\n",
            "nats.user",
            3,
            "nats.password too",
        ),
        (
            "[nats]\nbooth = \"a\"\ntoken = { value = \"t\" }\nnkey = { value = \"SU\" }\n",
            "nats.nkey",
            4,
            "one way to authenticate",
        ),
        (
            "[nats]\nbooth = \"a\"\ntls_cert = \"c.pem\"\n",
            "nats.tls_cert",
            3,
            "nats.tls_key too",
        ),
        (
            "[nats]\nbooth = \"a\"\nbroker = \"x\"\n",
            "nats.broker",
            3,
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

#[test]
fn nats_credentials_are_read_and_never_printed() {
    let secret = "s3cret-nats-password";
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.toml");
    std::fs::write(dir.path().join("token"), "tok-abc-123\n").unwrap();
    let text = format!(
        "[nats]\nservers = [\"nats://127.0.0.1:4222\"]\nbooth = \"b1\"\nuser = \"booth\"\npassword = {{ value = \"{secret}\" }}\n"
    );
    let config = Config::parse(&text, &path).unwrap();
    assert_eq!(
        config.nats.secrets.password.as_ref().map(Secret::expose),
        Some(secret)
    );
    let shown = format!("{config:?} {}", config.summary());
    assert!(!shown.contains(secret), "{shown}");
    assert!(shown.contains("user/password"), "{shown}");
    // A token from a file next to the config.
    let text = "[nats]\nservers = [\"nats://127.0.0.1:4222\"]\nbooth = \"b1\"\ntoken = { file = \"token\" }\n";
    let config = Config::parse(text, &path).unwrap();
    assert_eq!(
        config.nats.secrets.token.as_ref().map(Secret::expose),
        Some("tok-abc-123")
    );
    assert!(!format!("{config:?}").contains("tok-abc-123"));
    // A password of the wrong type: the message names the key, not the value.
    let text = format!("[nats]\nbooth = \"b1\"\npassword = \"{secret}\"\n");
    let err = Config::parse(&text, &path).unwrap_err().to_string();
    assert!(!err.contains(secret), "{err}");
    assert!(err.contains("nats.password"), "{err}");
    // Credentials in a URL are refused without echoing them.
    let text = format!("[nats]\nbooth = \"b1\"\nservers = [\"nats://u:{secret}@h:4222\"]\n");
    let err = Config::parse(&text, &path).unwrap_err().to_string();
    assert!(!err.contains(secret), "{err}");
    assert!(err.contains("nats.servers[0]"), "{err}");
}

#[test]
fn a_missing_nats_password_variable_names_its_key() {
    let text = "[nats]\nservers = [\"nats://127.0.0.1:4222\"]\nbooth = \"b1\"\nuser = \"u\"\npassword = { env = \"MOUTHPIECE_TEST_NO_SUCH_VARIABLE\" }\n";
    let err = parse(text).unwrap_err();
    assert_eq!(err.key(), Some("nats.password"));
    assert!(err.to_string().contains(":5:"), "{err}");
}

#[test]
fn a_nul_or_a_control_character_in_a_server_url_is_refused() {
    for url in [
        "nats://h\\u0000x:4222",
        "nats://h:4222\\n",
        "nats://h\\u001b[2J:4222",
    ] {
        let text = format!("[nats]\nbooth = \"a\"\nservers = [\n  \"{url}\"]\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), Some("nats.servers[0]"), "{err}");
        let message = err.to_string();
        assert!(
            message.starts_with("/etc/mouthpiece/test.toml:4:"),
            "{message}"
        );
        assert!(message.contains("control characters"), "{message}");
        assert!(!message.contains(['\0', '\n', '\u{1b}']), "{message:?}");
    }
}

const CERT: &str = "-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n";
const KEY: &str = "-----BEGIN PRIVATE KEY-----\nMIIE\n-----END PRIVATE KEY-----\n";

/// `[nats]`'s TLS files are read at load time: a missing file, a certificate given as the
/// key or a key given as the certificate (or CA) are refused with the key's line.
#[test]
fn nats_tls_files_must_exist_and_hold_what_their_key_says() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.toml");
    std::fs::write(dir.path().join("ca.pem"), CERT).unwrap();
    std::fs::write(dir.path().join("cert.pem"), CERT).unwrap();
    std::fs::write(dir.path().join("key.pem"), KEY).unwrap();
    let head = "[nats]\nservers = [\"tls://127.0.0.1:4222\"]\nbooth = \"b1\"\n";
    let good =
        format!("{head}tls_ca = \"ca.pem\"\ntls_cert = \"cert.pem\"\ntls_key = \"key.pem\"\n");
    let config = Config::parse(&good, &path).unwrap();
    assert_eq!(config.nats.tls_ca, Some(dir.path().join("ca.pem")));
    for (files, key, line, says) in [
        (
            "tls_ca = \"missing.pem\"\n",
            "nats.tls_ca",
            4,
            "missing.pem",
        ),
        (
            "tls_ca = \"ca.pem\"\ntls_cert = \"cert.pem\"\ntls_key = \"cert.pem\"\n",
            "nats.tls_key",
            6,
            "no PEM private key",
        ),
        (
            "tls_cert = \"key.pem\"\ntls_key = \"key.pem\"\n",
            "nats.tls_cert",
            4,
            "no PEM certificate",
        ),
        (
            "tls_ca = \"key.pem\"\n",
            "nats.tls_ca",
            4,
            "no PEM certificate",
        ),
        (
            "tls_cert = \"cert.pem\"\ntls_key = \"gone.pem\"\n",
            "nats.tls_key",
            5,
            "gone.pem",
        ),
    ] {
        let err = Config::parse(&format!("{head}{files}"), &path).unwrap_err();
        assert_eq!(err.key(), Some(key), "{err}");
        let message = err.to_string();
        assert!(message.contains(&format!("m.toml:{line}:")), "{message}");
        assert!(message.contains(says), "{message}");
    }
}
