//! Mapping and stitching against the independent numpy implementation
//! (`tests/reference/lipsync_reference.py`) on random class tables, segments and phone
//! sequences (short phones included): every sample within 1e-9, the same dominant phone.
//!
//! Needs Python 3 with numpy (`MOUTHPIECE_PYTHON`, else the test venv `target/py`, else
//! `python3`); fails without it (scripts/test prepares it).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use mouthpiece_lipsync::curve::StageCurve;
use mouthpiece_lipsync::{map_phones, stitch, ClassTable, PhoneSpan, Segment, SegmentTable};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> String {
    if let Ok(p) = std::env::var("MOUTHPIECE_PYTHON") {
        return p;
    }
    let venv = repo().join("target/py/bin/python");
    if venv.exists() {
        return venv.display().to_string();
    }
    "python3".into()
}

struct Case {
    json: Value,
    table: ClassTable,
    segments: SegmentTable,
    phones: Vec<PhoneSpan>,
    classes: Vec<usize>,
    fps: f64,
    t_change: f64,
}

fn curve_points(rng: &mut ChaCha8Rng, first: f64, last: f64) -> Vec<(f64, f64)> {
    let inner = rng.random_range(0..3);
    let mut us: Vec<f64> = (0..inner).map(|_| rng.random_range(0.05..0.95)).collect();
    us.sort_by(f64::total_cmp);
    us.dedup_by(|a, b| (*a - *b).abs() < 0.01);
    let mut pts = vec![(0.0, first)];
    pts.extend(us.into_iter().map(|u| (u, rng.random_range(0.0..1.0))));
    pts.push((1.0, last));
    pts
}

fn random_case(seed: u64) -> Case {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let k = rng.random_range(1..=4);
    let n = rng.random_range(2..=6);
    let poses: Vec<String> = (0..k).map(|p| format!("\"p{p}\"")).collect();
    let mut toml = format!("poses = [{}]\n", poses.join(", "));
    toml.push_str("[[class]]\nname = \"sil\"\nphones = [\"sil\"]\n");
    for c in 1..n {
        let target: Vec<String> = (0..k)
            .map(|p| format!("p{p} = {}", rng.random_range(0.0..1.0)))
            .collect();
        toml.push_str(&format!(
            "[[class]]\nname = \"c{c}\"\nphones = [\"x{}\"]\ntarget = {{ {} }}\n",
            (b'a' + c as u8) as char,
            target.join(", ")
        ));
    }
    let table = ClassTable::from_toml_str(&toml, "random").unwrap();
    let mut segments = SegmentTable::generate(&table);
    let mut seg_json = serde_json::Map::new();
    for a in 0..n {
        for b in 0..n {
            let mut stable = Vec::new();
            let mut change = Vec::new();
            for p in 0..k {
                let mid = rng.random_range(0.0..1.0);
                stable.push(
                    StageCurve::from_points(&curve_points(
                        &mut rng,
                        table.classes[a].target[p],
                        mid,
                    ))
                    .unwrap(),
                );
                change.push(
                    StageCurve::from_points(&curve_points(
                        &mut rng,
                        mid,
                        table.classes[b].target[p],
                    ))
                    .unwrap(),
                );
            }
            let pts = |c: &StageCurve| c.points().map(|(u, w)| json!([u, w])).collect::<Vec<_>>();
            seg_json.insert(
                format!("{a},{b}"),
                json!({
                    "stable": stable.iter().map(pts).collect::<Vec<_>>(),
                    "change": change.iter().map(pts).collect::<Vec<_>>(),
                }),
            );
            segments
                .set(&table, a, b, Segment { stable, change })
                .unwrap();
        }
    }
    let count = rng.random_range(1..=25);
    let mut t = rng.random_range(0.0..0.3);
    let mut phones = Vec::new();
    let mut classes = Vec::new();
    for i in 0..count {
        let d = if rng.random_bool(0.3) {
            rng.random_range(0.003..0.05)
        } else {
            rng.random_range(0.05..0.25)
        };
        let c = rng.random_range(0..n);
        phones.push(PhoneSpan {
            start: t,
            end: t + d,
            phone: table.classes[c].phones[0].clone(),
            line: i + 1,
        });
        classes.push(c);
        t += d;
    }
    let fps = [30.0, 60.0, 100.0, 997.0][rng.random_range(0..4)];
    let t_change = rng.random_range(0.03..0.05);
    let json = json!({
        "fps": fps,
        "t_change": t_change,
        "silence": table.silence(),
        "phones": phones.iter().zip(&classes).map(|(p, c)| json!([p.start, p.end, c])).collect::<Vec<_>>(),
        "segments": seg_json,
    });
    Case {
        json,
        table,
        segments,
        phones,
        classes,
        fps,
        t_change,
    }
}

#[test]
fn mapping_and_stitching_match_numpy_to_1e_9() {
    let cases: Vec<Case> = (0..40).map(random_case).collect();
    let input = serde_json::to_vec(&cases.iter().map(|c| &c.json).collect::<Vec<_>>()).unwrap();
    let script = repo().join("tests/reference/lipsync_reference.py");
    let py = python();
    let mut child = Command::new(&py)
        .arg(&script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {py} (Python 3 with numpy is required): {e}"));
    child.stdin.take().unwrap().write_all(&input).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{py} {} failed (Python 3 with numpy is required): {}",
        script.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let results: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    let mut compared = 0;
    let mut short = 0;
    for (case, expect) in cases.iter().zip(&results) {
        let placed = map_phones(
            &case.phones,
            &case.classes,
            &case.segments,
            case.table.silence(),
            case.t_change,
        )
        .unwrap();
        short += placed.iter().filter(|p| !p.has_stable()).count();
        let w = stitch(&placed, &case.segments, case.fps);
        let values = expect["values"].as_array().unwrap();
        let owner = expect["owner"].as_array().unwrap();
        assert_eq!(values.len(), w.len(), "sample count");
        for (k, row) in values.iter().enumerate() {
            for (p, v) in row.as_array().unwrap().iter().enumerate() {
                let (a, b) = (w.sample(k)[p], v.as_f64().unwrap());
                assert!(
                    (a - b).abs() <= 1e-9,
                    "sample {k} pose {p}: {a} vs numpy {b}"
                );
                compared += 1;
            }
            assert_eq!(
                w.owner[k] as u64,
                owner[k].as_u64().unwrap(),
                "owner of sample {k}"
            );
        }
    }
    assert!(compared > 10_000, "{compared} values compared");
    assert!(short > 20, "short phones exercised ({short})");
}
