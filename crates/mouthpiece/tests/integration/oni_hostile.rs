//! Corrupt `.oni` files never reach OpenNI2's player: each is refused with exit code 2, an
//! error naming the file and the byte offset of the bad record, and no output file.
//!
//! The variants are made from a valid recording written by `mouthpiece synth` (the plain-Rust
//! writer), record by record, with every stored file position moved to match so that only the
//! intended fault is left. The first five crashed OpenNI2 2.2's file player with signal 11
//! before the file was validated (the test runs the binary as a child process: a crash fails
//! the test instead of killing it); the others played wrong frames or none, or failed with
//! exit code 1 while converting a frame.

use crate::repo;
use std::collections::HashMap;
use std::path::Path;
use std::process::Output;

use openni2::oni_file::record_type::{
    GENERAL_PROPERTY, NEW_DATA, NODE_ADDED, NODE_STATE_READY, SEEK_TABLE,
};

const DEPTH: u32 = 1;
const COLOUR: u32 = 2;

fn mouthpiece(args: &[&str]) -> Output {
    crate::mouthpiece()
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run mouthpiece")
}

#[derive(Clone)]
struct Record {
    offset: u64,
    kind: u32,
    node: u32,
    fields: u32,
    bytes: Vec<u8>,
}

impl Record {
    fn property(&self) -> Option<String> {
        (3..=6).contains(&self.kind).then(|| {
            let len = u32::from_le_bytes(self.bytes[28..32].try_into().unwrap()) as usize;
            String::from_utf8_lossy(&self.bytes[32..32 + len])
                .trim_end_matches('\0')
                .to_string()
        })
    }

    fn set_payload(&mut self, payload: &[u8]) {
        self.bytes.truncate(self.fields as usize);
        self.bytes.extend_from_slice(payload);
        self.bytes[16..20].copy_from_slice(&(payload.len() as u32).to_le_bytes());
    }

    fn set_u32(&mut self, at: usize, v: u32) {
        self.bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

fn parse(file: &[u8]) -> Vec<Record> {
    let mut out = Vec::new();
    let mut at = 24usize;
    while at + 28 <= file.len() {
        let kind = u32_at(file, at + 4);
        let fields = u32_at(file, at + 12);
        let len = fields as usize + u32_at(file, at + 16) as usize;
        out.push(Record {
            offset: at as u64,
            kind,
            node: u32_at(file, at + 8),
            fields,
            bytes: file[at..at + len].to_vec(),
        });
        at += len;
        if kind == 0x0B {
            break;
        }
    }
    out
}

/// The file of these records, with every stored position (undo positions, NODE_ADDED's
/// seek-table position, seek-table entries) moved to where its record now is.
fn build(header: &[u8], records: &[Record]) -> Vec<u8> {
    let mut moved: HashMap<u64, u64> = HashMap::new();
    let mut at = header.len() as u64;
    for r in records {
        moved.entry(r.offset).or_insert(at);
        at += r.bytes.len() as u64;
    }
    let mv = |p: u64| moved.get(&p).copied().unwrap_or(p);
    let mut out = header.to_vec();
    for r in records {
        let mut b = r.bytes.clone();
        let undo = u64_at(&b, 20);
        b[20..28].copy_from_slice(&mv(undo).to_le_bytes());
        if r.kind == NODE_ADDED {
            let at = r.fields as usize - 8;
            let p = mv(u64_at(&b, at));
            b[at..at + 8].copy_from_slice(&p.to_le_bytes());
        }
        if r.kind == SEEK_TABLE {
            let entries = (b.len() - r.fields as usize) / 20;
            for i in 0..entries {
                let at = r.fields as usize + i * 20 + 12;
                let p = mv(u64_at(&b, at));
                b[at..at + 8].copy_from_slice(&p.to_le_bytes());
            }
        }
        out.extend_from_slice(&b);
    }
    out
}

fn nth(records: &[Record], kind: u32, node: u32, n: usize) -> usize {
    records
        .iter()
        .enumerate()
        .filter(|(_, r)| r.kind == kind && r.node == node)
        .nth(n)
        .map(|(i, _)| i)
        .unwrap()
}

fn property(records: &[Record], node: u32, name: &str) -> usize {
    records
        .iter()
        .position(|r| r.node == node && r.property().as_deref() == Some(name))
        .unwrap()
}

type Variant = (&'static str, fn(&mut Vec<Record>));

/// The faults. The first five crashed OpenNI2's player (signal 11) without the validation.
const VARIANTS: &[Variant] = &[
    ("frame_before_its_node_is_ready", |r| {
        let f = r.remove(nth(r, NEW_DATA, DEPTH, 3));
        let added = nth(r, NODE_ADDED, DEPTH, 0);
        r.insert(added + 1, f);
    }),
    ("colour_frame_before_its_node_is_ready", |r| {
        let f = r.remove(nth(r, NEW_DATA, COLOUR, 3));
        let added = nth(r, NODE_ADDED, COLOUR, 0);
        r.insert(added + 1, f);
    }),
    ("no_node_made_ready", |r| {
        r.retain(|x| x.kind != NODE_STATE_READY)
    }),
    ("colour_node_never_ready", |r| {
        r.retain(|x| !(x.kind == NODE_STATE_READY && x.node == COLOUR))
    }),
    ("uncropped_file_with_a_frame_before_ready", |r| {
        // Without cropping records the file is played through a fixed copy.
        r.retain(|x| x.property().as_deref() != Some("xnCropping"));
        let f = r.remove(nth(r, NEW_DATA, DEPTH, 3));
        let added = nth(r, NODE_ADDED, DEPTH, 0);
        r.insert(added + 1, f);
    }),
    ("frame_before_any_node", |r| {
        let f = r.remove(nth(r, NEW_DATA, DEPTH, 3));
        r.insert(0, f);
    }),
    ("frame_shorter_than_its_resolution", |r| {
        let i = nth(r, NEW_DATA, DEPTH, 2);
        r[i].set_payload(&[7; 100]);
    }),
    ("empty_frame", |r| {
        let i = nth(r, NEW_DATA, DEPTH, 2);
        r[i].set_payload(&[]);
    }),
    ("frame_longer_than_the_players_buffer", |r| {
        let i = nth(r, NEW_DATA, COLOUR, 1);
        r[i].set_payload(&vec![7; 1600 * 1200 * 3 + 100]);
    }),
    ("resolution_larger_than_the_frames", |r| {
        let i = property(r, DEPTH, "xnMapOutputMode");
        let at = 28 + 4 + "xnMapOutputMode".len() + 1 + 4;
        r[i].set_u32(at, 640);
        r[i].set_u32(at + 4, 480);
    }),
    ("depth_frame_on_the_colour_node", |r| {
        let i = nth(r, NEW_DATA, DEPTH, 3);
        r[i].set_u32(8, COLOUR);
    }),
    ("frame_of_a_node_never_added", |r| {
        let i = nth(r, NEW_DATA, DEPTH, 3);
        r[i].set_u32(8, 7);
    }),
    ("frame_without_its_timestamp", |r| {
        let i = nth(r, NEW_DATA, DEPTH, 2);
        let payload = r[i].bytes[r[i].fields as usize..].to_vec();
        r[i].bytes.truncate(28);
        r[i].fields = 28;
        r[i].set_u32(12, 28);
        r[i].bytes.extend_from_slice(&payload);
    }),
    ("seek_table_pointing_nowhere", |r| {
        let i = nth(r, SEEK_TABLE, DEPTH, 0);
        let fields = r[i].fields as usize;
        let entries = (r[i].bytes.len() - fields) / 20;
        for e in 1..entries {
            let at = fields + e * 20 + 12;
            r[i].bytes[at..at + 8].copy_from_slice(&0xdead_beef_deadu64.to_le_bytes());
        }
    }),
    ("unknown_record_type", |r| {
        let i = nth(r, NEW_DATA, DEPTH, 3);
        r[i].set_u32(4, 0x55);
    }),
];

fn valid_recording(dir: &Path) -> Vec<u8> {
    let path = dir.join("valid.oni");
    let out = mouthpiece(&[
        "synth",
        "--out",
        path.to_str().unwrap(),
        "--seconds",
        "0.5",
        "--seed",
        "3",
        "--size",
        "64x48",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::read(&path).unwrap()
}

#[test]
fn corrupt_oni_files_are_refused_before_openni2_plays_them() {
    let dir = tempfile::tempdir().unwrap();
    let valid = valid_recording(dir.path());
    let header = &valid[..24];
    let records = parse(&valid);
    assert!(records.iter().any(|r| r.kind == GENERAL_PROPERTY));
    let character = repo().join("config/characters/wolf.toml");
    // The unchanged file plays: the rebuilding changes nothing by itself.
    let same = dir.path().join("same.oni");
    std::fs::write(&same, build(header, &records)).unwrap();
    assert_eq!(std::fs::read(&same).unwrap(), valid);
    let out_path = dir.path().join("same.jsonl");
    let out = mouthpiece(&[
        "process",
        "--character",
        character.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
        same.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let mut failures = Vec::new();
    for (i, (name, change)) in VARIANTS.iter().enumerate() {
        let mut changed = records.clone();
        change(&mut changed);
        let path = dir.path().join(format!("{name}.oni"));
        std::fs::write(&path, build(header, &changed)).unwrap();
        let out_path = dir.path().join(format!("{name}.jsonl"));
        let mut runs = vec![(
            "process",
            mouthpiece(&[
                "process",
                "--character",
                character.to_str().unwrap(),
                "--out",
                out_path.to_str().unwrap(),
                path.to_str().unwrap(),
            ]),
            out_path,
        )];
        if i < 5 {
            let rec_path = dir.path().join(format!("{name}.mcap"));
            let source = format!("replay:{}?speed=0", path.display());
            runs.push((
                "record",
                mouthpiece(&[
                    "record",
                    "--source",
                    &source,
                    "--out",
                    rec_path.to_str().unwrap(),
                ]),
                rec_path,
            ));
        }
        for (command, out, written) in runs {
            let stderr = String::from_utf8_lossy(&out.stderr);
            let named = stderr.contains(&format!("{name}.oni: corrupt record at byte "));
            if out.status.code() != Some(2) || !named || written.exists() {
                failures.push(format!(
                    "{name} ({command}): status {:?}, output left: {}, stderr: {}",
                    out.status,
                    written.exists(),
                    stderr.lines().rev().take(3).collect::<Vec<_>>().join(" | ")
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
