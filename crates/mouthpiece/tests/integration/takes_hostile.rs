//! `mouthpiece takes list|fetch` against a real `nats-server` whose store holds hostile
//! entries: metadata whose texts carry terminal escapes and row-forging newlines, and an
//! object whose info cannot be verified.

use crate::helper_harness as harness;

use std::path::Path;

use harness::NatsServer;
use mouthpiece_nats::store::{TakeRecord, TakeStore};

fn takes_cli(dir: &Path, url: &str, args: &[&str]) -> std::process::Output {
    let config = dir.join("empty.toml");
    std::fs::write(&config, "").unwrap();
    crate::mouthpiece()
        .arg("takes")
        .arg("--config")
        .arg(&config)
        .args(["--server", url])
        .args(args)
        .output()
        .unwrap()
}

fn record(slate: &str) -> TakeRecord {
    TakeRecord {
        booth: "booth-1".into(),
        slate: slate.into(),
        take: 1,
        object: "booth-1/x_T001.mcap".into(),
        file: "x_T001.mcap".into(),
        size: 10,
        started_unix_us: 0,
        timecode: "00:00:00:00".into(),
        timecode_rate: "30".into(),
        duration_s: 1.0,
        frames: 30,
        characters: vec!["wolf\u{1b}]0;owned\u{7}".into()],
        source: "replay".into(),
        uploaded_unix_us: 0,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stored_texts_are_escaped_in_the_list_and_cannot_forge_rows() {
    let server = NatsServer::start();
    let client = async_nats::connect(server.url()).await.unwrap();
    let store = TakeStore::open(&client, "studio").await.unwrap();
    let forged = "s\u{1b}[2J\nbooth-9\tforged\t9\t00:00:00:00\t1.00\t1\twolf\tbooth-9/f.mcap";
    let r = record(forged);
    store
        .meta
        .put(r.key(), serde_json::to_vec(&r).unwrap().into())
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = tokio::task::spawn_blocking({
        let dir = dir.path().to_owned();
        let url = server.url();
        move || takes_cli(&dir, &url, &["list"])
    })
    .await
    .unwrap();
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 2, "a row was forged: {stdout:?}");
    assert_eq!(lines[1].split('\t').count(), 8, "{stdout:?}");
    assert!(
        !stdout.contains('\u{1b}') && !stdout.contains('\u{7}'),
        "{stdout:?}"
    );
    assert!(
        lines[1].contains("s\\u{1b}[2J\\nbooth-9\\tforged")
            && lines[1].contains("wolf\\u{1b}]0;owned\\u{7}"),
        "{stdout:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_object_without_a_digest_is_refused_with_exit_code_2_and_nothing_kept() {
    let server = NatsServer::start();
    let client = async_nats::connect(server.url()).await.unwrap();
    let store = TakeStore::open(&client, "studio").await.unwrap();
    let mut info = store
        .objects
        .put("booth-1/x_T001.mcap", &mut &b"not checked"[..])
        .await
        .unwrap();
    info.digest = None;
    // Written over the object's info as a hostile writer could.
    let js = async_nats::jetstream::new(client.clone());
    let mut headers = async_nats::HeaderMap::new();
    headers.insert("Nats-Rollup", "sub");
    use base64::Engine as _;
    let name = base64::engine::general_purpose::URL_SAFE.encode(&info.name);
    js.publish_with_headers(
        format!("$O.mouthpiece-takes-studio.M.{name}"),
        headers,
        serde_json::to_vec(&info).unwrap().into(),
    )
    .await
    .unwrap()
    .await
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("out");
    std::fs::create_dir(&folder).unwrap();
    let out = tokio::task::spawn_blocking({
        let dir = dir.path().to_owned();
        let url = server.url();
        let folder = folder.to_str().unwrap().to_owned();
        move || {
            takes_cli(
                &dir,
                &url,
                &["fetch", "booth-1/x_T001.mcap", "--out", &folder],
            )
        }
    })
    .await
    .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("booth-1/x_T001.mcap has no digest"),
        "{stderr}"
    );
    assert_eq!(std::fs::read_dir(&folder).unwrap().count(), 0);
}

/// `takes --config` with a CA file that is missing or not a certificate: refused at load
/// with the config's file, line and key, before any connection.
#[test]
fn a_bad_ca_file_in_the_config_is_named_with_its_line() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("not-a-cert.pem"), "hello\n").unwrap();
    for (ca, says) in [
        ("missing.pem", "cannot read"),
        ("not-a-cert.pem", "no PEM certificate"),
    ] {
        let config = dir.path().join("booth.toml");
        std::fs::write(
            &config,
            format!(
                "[nats]\nservers = [\"tls://127.0.0.1:1\"]\nbooth = \"b1\"\ntls_ca = \"{ca}\"\n"
            ),
        )
        .unwrap();
        let out = crate::mouthpiece()
            .args(["takes", "--config"])
            .arg(&config)
            .arg("list")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains("booth.toml:4:1: key `nats.tls_ca`")
                && stderr.contains(ca)
                && stderr.contains(says),
            "{stderr}"
        );
    }
}
