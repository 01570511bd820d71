//! `mouthpiece export` end to end, judged by independent tools: Khronos' glTF-Validator
//! (npm `gltf-validator`), a numpy reader of the written file (`tests/python/check_gltf.py`),
//! and Blender importing it headless (`tests/blender/sample_gltf.py`).
//!
//! External tools come from `scripts/test` (Debian packages `nodejs`, `npm`, `blender`,
//! `python3-numpy`; the npm package is installed here on first use if it is missing).

use crate::repo;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use serde_json::{json, Value};

fn mouthpiece(args: &[&str]) -> Output {
    crate::mouthpiece()
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run mouthpiece")
}

fn export_ok(args: &[&str]) -> String {
    let out = mouthpiece(&[&["export"], args].concat());
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        out.status.success(),
        "mouthpiece export {args:?} failed: {stderr}"
    );
    stderr
}

fn python() -> String {
    std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn run_json(cmd: &mut Command, what: &str) -> Value {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot run: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{what} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("{what}: not JSON ({e}): {stdout}"))
}

/// The Khronos validator, installed into tests/js/node_modules from the committed lock file.
fn validator_script() -> PathBuf {
    static READY: OnceLock<PathBuf> = OnceLock::new();
    READY
        .get_or_init(|| {
            let js = repo().join("tests/js");
            if !js.join("node_modules/gltf-validator/package.json").exists() {
                let status = Command::new("npm")
                    .args(["ci", "--silent", "--no-audit", "--no-fund"])
                    .current_dir(&js)
                    .status()
                    .expect("npm (Debian package `npm`, installed by scripts/test)");
                assert!(status.success(), "npm ci in tests/js failed");
            }
            js.join("validate-gltf.js")
        })
        .clone()
}

/// Runs glTF-Validator and insists on a clean report: no errors, warnings, infos or hints.
fn assert_valid(path: &Path) -> Value {
    assert_valid_except(path, &[])
}

/// Like [`assert_valid`], allowing infos with the given codes (and nothing else).
fn assert_valid_except(path: &Path, allowed_infos: &[&str]) -> Value {
    let report = run_json(
        Command::new("node").arg(validator_script()).arg(path),
        "glTF-Validator",
    );
    let issues = &report["issues"];
    let allowed = |m: &Value| m["severity"] == 2 && allowed_infos.iter().any(|c| m["code"] == *c);
    let unexpected_infos = issues["messages"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| !allowed(m))
        .count();
    let infos = if allowed_infos.is_empty() {
        issues["numInfos"].clone()
    } else {
        json!(unexpected_infos.min(issues["numInfos"].as_u64().unwrap() as usize))
    };
    for (kind, count) in [
        ("numErrors", &issues["numErrors"]),
        ("numWarnings", &issues["numWarnings"]),
        ("numInfos", &infos),
        ("numHints", &issues["numHints"]),
    ] {
        let count = count.clone();
        assert_eq!(
            count,
            0,
            "{}: validator {kind}: {}",
            path.display(),
            serde_json::to_string_pretty(&issues["messages"]).unwrap()
        );
    }
    report
}

/// A take in `mouthpiece retarget`'s output format: a mouth of `points` points (human-sized,
/// metres) opening, closing and drifting, with small deterministic jitter, `frames` frames
/// at about 30 fps with uneven spacing.
fn write_take(path: &Path, frames: usize, points: usize) -> Vec<(f64, Vec<[f64; 3]>)> {
    use std::fmt::Write as _;
    let mut text = String::new();
    let mut take = Vec::new();
    let mut t = 0.0;
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut jitter = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for seq in 0..frames {
        let open = 0.5 + 0.5 * (2.0 * std::f64::consts::PI * 0.7 * t).sin();
        let pts: Vec<[f64; 3]> = (0..points)
            .map(|k| {
                let a = 2.0 * std::f64::consts::PI * k as f64 / points as f64;
                [
                    0.025 * a.cos() * (1.0 - 0.1 * open) + 1e-4 * jitter(),
                    0.008 * a.sin() * (1.0 + 1.5 * open) + 1e-4 * jitter(),
                    0.006 * (1.0 - a.cos().abs()) + 0.002 * (3.0 * t + k as f64).sin(),
                ]
            })
            .collect();
        // Written by hand: point order matters (P2 before P10), a JSON map would sort it.
        let field = |f: &dyn Fn(usize) -> String| -> String {
            let entries: Vec<String> = (0..points)
                .map(|k| format!("\"P{}\": {}", k + 1, f(k)))
                .collect();
            format!("{{{}}}", entries.join(", "))
        };
        let line = format!(
            "{{\"t\": {t:?}, \"seq\": {seq}, \"character\": \"human\", \"points\": {}, \"confidence\": {}, \
             \"head\": {{\"rotation\": [1.0, 0.0, 0.0, 0.0], \"translation\": [0.0, 0.0, 0.6]}}, \
             \"head_lost\": false, \"curve\": null}}",
            field(&|k| json!(pts[k]).to_string()),
            field(&|_| "1.0".to_owned()),
        );
        writeln!(text, "{line}").unwrap();
        take.push((t, pts));
        t += 1.0 / 30.0 + 0.004 * jitter();
    }
    std::fs::write(path, text).unwrap();
    take
}

fn check_gltf(take: &Path, gltf: &Path) -> Value {
    check_gltf_with(take, gltf, &[])
}

fn check_gltf_with(take: &Path, gltf: &Path, extra: &[&str]) -> Value {
    let script = repo().join("tests/python/check_gltf.py");
    run_json(
        Command::new(python())
            .arg(script)
            .arg("--take")
            .arg(take)
            .arg("--gltf")
            .arg(gltf)
            .args(extra),
        "check_gltf.py",
    )
}

#[test]
fn every_layout_passes_the_validator_and_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("take.jsonl");
    write_take(&take, 240, 12);
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    let cases: &[(&str, &[&str])] = &[
        ("take.glb", &[]),
        ("take.gltf", &[]),
        ("embedded.gltf", &["--embed"]),
        ("empties.glb", &["--no-markers"]),
        ("explicit.glb", &["--format", "glb"]),
    ];
    for (name, extra) in cases {
        let out = dir.path().join(name);
        let mut args = vec![s(&take), "--out".into(), s(&out)];
        args.extend(extra.iter().map(|a| a.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let stderr = export_ok(&args);
        assert!(stderr.contains("240 frames, 2880 keys"), "{stderr}");
        // Empties are what --no-markers asks for; the validator notes them (NODE_EMPTY).
        let allowed: &[&str] = if extra.contains(&"--no-markers") {
            &["NODE_EMPTY"]
        } else {
            &[]
        };
        assert_valid_except(&out, allowed);
        let check = check_gltf(&take, &out);
        assert_eq!(check["keys"], 2880, "{check}");
        // Only f32 rounding (values ~2.5 cm, times ~8 s) separates the keys from the take.
        assert!(
            check["max_error"].as_f64().unwrap() < 1e-7,
            "{name}: {check}"
        );
        assert_eq!(check["max_key_time_error"], 0.0, "{check}");
        // A take without `rig` (made before the rig existed) exports as before: no jaw, no
        // blend shapes.
        assert_eq!(check["rig_frames"], 0, "{check}");
        assert!(check.get("rig_keys").is_none(), "{check}");
        assert!(!stderr.contains("jaw"), "{stderr}");
    }
    assert!(dir.path().join("take.bin").exists());
    assert!(!dir.path().join("embedded.bin").exists());
    assert_no_temporary_files(dir.path());
}

#[test]
fn reduce_drops_keys_within_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("take.jsonl");
    write_take(&take, 600, 12);
    for tolerance in [0.0, 1e-4, 5e-4] {
        let out = dir.path().join(format!("reduced-{tolerance}.glb"));
        let stderr = export_ok(&[
            take.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--reduce",
            &tolerance.to_string(),
        ]);
        assert!(stderr.contains("dropped by --reduce"), "{stderr}");
        assert_valid(&out);
        let check = check_gltf(&take, &out);
        let keys = check["keys"].as_u64().unwrap();
        let error = check["max_error"].as_f64().unwrap();
        assert!(error <= tolerance + 1e-7, "tolerance {tolerance}: {check}");
        if tolerance >= 1e-4 {
            // The jitter is ±5e-5: a tolerance above it must drop most keys.
            assert!(
                keys < 7200 / 2,
                "tolerance {tolerance}: only down to {keys} keys"
            );
        }
        let dropped = 7200 - keys;
        assert!(
            stderr.contains(&format!("{dropped} of 7200 dropped")),
            "{stderr}"
        );
    }
}

#[test]
fn single_frame_take_is_valid() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("one.jsonl");
    write_take(&take, 1, 4);
    let out = dir.path().join("one.glb");
    export_ok(&[take.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_valid(&out);
}

#[test]
fn csv_has_a_header_and_the_take_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let take_path = dir.path().join("take.jsonl");
    let take = write_take(&take_path, 50, 12);
    let out = dir.path().join("take.csv");
    export_ok(&[take_path.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let text = std::fs::read_to_string(&out).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    // The points, then the rig's jaw, lips and curves (empty: this take has no `rig`).
    assert_eq!(header.len(), 1 + 3 * 12 + 16 + 27);
    assert_eq!(&header[..4], ["t", "P1_x", "P1_y", "P1_z"]);
    assert_eq!(header[36], "P12_z");
    assert_eq!(
        &header[37..40],
        ["jaw_angle_deg", "jaw_slide", "lip_upper_qw"]
    );
    assert_eq!(header[53], "jawOpen");
    for ((t, points), line) in take.iter().zip(lines.by_ref()) {
        let cells: Vec<&str> = line.split(',').collect();
        let numbers: Vec<f64> = cells[..37].iter().map(|c| c.parse().unwrap()).collect();
        assert_eq!(numbers[0], *t);
        let flat: Vec<f64> = points.iter().flatten().copied().collect();
        assert_eq!(&numbers[1..], &flat[..]);
        assert!(cells[37..].iter().all(|c| c.is_empty()), "{line}");
    }
    assert!(lines.next().is_none());
}

#[test]
fn blender_imports_the_glb_and_its_nodes_follow_the_take() {
    let dir = tempfile::tempdir().unwrap();
    let take_path = dir.path().join("take.jsonl");
    let take = write_take(&take_path, 90, 12);
    let out = dir.path().join("take.glb");
    export_ok(&[take_path.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    // Frame times and midpoints between frames (where the keys are interpolated).
    let probes: Vec<(f64, Vec<[f64; 3]>)> = [0usize, 17, 45, 89]
        .iter()
        .map(|&i| take[i].clone())
        .chain([10usize, 60].iter().map(|&i| {
            let ((t0, a), (t1, b)) = (&take[i], &take[i + 1]);
            let mid: Vec<[f64; 3]> = a
                .iter()
                .zip(b)
                .map(|(p, q)| [0, 1, 2].map(|k| 0.5 * (p[k] + q[k])))
                .collect();
            (0.5 * (t0 + t1), mid)
        }))
        .collect();
    let result = blender_samples(&out, probes.iter().map(|p| p.0));
    let width = 0.05;
    for (t, expected) in &probes {
        let at = &result["samples"][format!("{t:?}")];
        for (k, p) in expected.iter().enumerate() {
            let name = format!("P{}", k + 1);
            let got = at[&name]
                .as_array()
                .unwrap_or_else(|| panic!("{name} at {t}: {at}"));
            // glTF (x, y, z) is Blender's (x, -z, y).
            let want = [p[0], -p[2], p[1]];
            for a in 0..3 {
                let err = (got[a].as_f64().unwrap() - want[a]).abs();
                assert!(
                    err <= 1e-4 * width,
                    "{name} at t={t} axis {a}: Blender {got:?}, take {want:?}"
                );
            }
        }
    }
    assert_eq!(result["objects"]["P1"]["parent"], "mouth");
}

fn blender_samples(file: &Path, times: impl Iterator<Item = f64>) -> Value {
    let script = repo().join("tests/blender/sample_gltf.py");
    let mut cmd = Command::new("blender");
    cmd.args([
        "-b",
        "--factory-startup",
        "--python-exit-code",
        "1",
        "--python",
    ])
    .arg(script)
    .arg("--")
    .arg(file)
    .args(times.map(|t| format!("{t:?}")));
    let out = cmd
        .output()
        .expect("blender (Debian package `blender`, installed by scripts/test)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "blender failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("SAMPLES "))
        .unwrap_or_else(|| panic!("no SAMPLES line from Blender:\n{stdout}"));
    serde_json::from_str(line).unwrap()
}

#[test]
fn bad_input_is_exit_2_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let take = dir.path().join("take.jsonl");
    write_take(&take, 5, 12);
    let mut text = std::fs::read_to_string(&take).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let broken = lines[2].replacen("\"t\": ", "\"t\": -", 1);
    text = format!("{}\n{}\n{}\n{}\n", lines[0], lines[1], broken, lines[3]);
    std::fs::write(&take, text).unwrap();
    let out = dir.path().join("out.glb");
    let run = |args: &[&str]| {
        let o = mouthpiece(&[&["export"], args].concat());
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (code, stderr) = run(&[take.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("line 3") && stderr.contains("not a finite time"),
        "{stderr}"
    );
    assert!(!out.exists(), "no partial output");

    let good = dir.path().join("good.jsonl");
    write_take(&good, 5, 12);
    let g = good.to_str().unwrap();
    // The take is named with the character it was made for.
    let mismatch =
        format!("{g}: the take was made for character `human`, the character file is `wolf`");
    // Every line's curve empty (a `process` take that never took the neutral pose).
    let shapeless = dir.path().join("shapeless.jsonl");
    let text = std::fs::read_to_string(&good).unwrap().replace(
        "\"curve\": null",
        r#""curve": {"method": "bspline", "closed": true, "points": []}"#,
    );
    std::fs::write(&shapeless, text).unwrap();
    let e = shapeless.to_str().unwrap();
    let wolf = repo()
        .join("config/characters/wolf.toml")
        .to_str()
        .unwrap()
        .to_owned();
    for (args, needle) in [
        (
            vec![g, "--out", "x.csv", "--reduce", "0.1"],
            "--reduce applies to glTF",
        ),
        (
            vec![g, "--out", "x.glb", "--reduce", "-1"],
            "not a finite number",
        ),
        (
            vec![g, "--out", "x.glb", "--embed"],
            "--embed applies to --format gltf",
        ),
        (
            vec![g, "--out", "x.obj"],
            "does not end in .gltf, .glb or .csv",
        ),
        (
            vec!["/nonexistent/take.jsonl", "--out", "x.glb"],
            "opening the take",
        ),
        (
            vec!["session.mcap", "--out", "x.glb"],
            "exporting a recording needs --character",
        ),
        (
            vec![g, "--out", "x.glb", "--character", wolf.as_str()],
            mismatch.as_str(),
        ),
        (
            vec![g, "--out", "x.csv", "--curve"],
            "--curve applies to glTF",
        ),
        (
            vec![g, "--out", "x.glb", "--curve"],
            "good.jsonl: line 1: no `curve` on this line",
        ),
        (
            vec![e, "--out", "x.glb", "--curve"],
            "shapeless.jsonl: no line has a `curve` with points",
        ),
    ] {
        let (code, stderr) = run(&args);
        assert_eq!(code, Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
    }
}

/// `mouthpiece retarget` of the example performer onto `character`, written to `take`, with
/// `extra` arguments; fails the test with retarget's stderr if it does not succeed.
fn retarget_example(character: &Path, take: &Path, extra: &[&str]) {
    let out = crate::mouthpiece()
        .args(["retarget", "--character"])
        .arg(character)
        .arg("--input")
        .arg(repo().join("tests/data/example-performer.jsonl"))
        .arg("--out")
        .arg(take)
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "retarget: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The real chain: `mouthpiece retarget` puts the example performer on the wolf (modelled
/// Z-up, head tilted), then export with the character file, `--model-up z` and the curve.
#[test]
fn wolf_take_from_retarget_lands_on_the_wolf_model() {
    use mouthpiece_retarget::Character;
    let dir = tempfile::tempdir().unwrap();
    let root = repo();
    let wolf_toml = root.join("config/characters/wolf.toml");
    let take = dir.path().join("wolf.jsonl");
    retarget_example(&wolf_toml, &take, &[]);

    let glb = dir.path().join("wolf.glb");
    let (t, c, g) = (
        take.to_str().unwrap(),
        wolf_toml.to_str().unwrap(),
        glb.to_str().unwrap(),
    );
    let stderr = export_ok(&[
        t,
        "--out",
        g,
        "--character",
        c,
        "--model-up",
        "z",
        "--curve",
    ]);
    assert!(stderr.contains("120 frames"), "{stderr}");
    assert_valid(&glb);
    let check = check_gltf_with(&take, &glb, &["--character", c, "--model-up", "z"]);
    let character =
        Character::from_toml_str(&std::fs::read_to_string(&wolf_toml).unwrap()).unwrap();
    let width = character.mouth_width();
    assert!(
        check["max_error"].as_f64().unwrap() < 1e-6 * width,
        "{check}"
    );
    assert!(
        check["max_curve_error"].as_f64().unwrap() < 1e-6 * width,
        "{check}"
    );
    assert!(check["curve_points"].as_u64().unwrap() > 12, "{check}");
    // Rest pose through the node hierarchy = the wolf file's model points (glTF axes).
    assert!(
        check["max_rest_world_error"].as_f64().unwrap() < 1e-6 * width,
        "{check}"
    );
    // The rig: every frame's jaw and curves, as the take has them.
    assert!(
        stderr.contains("jaw, blendshapes: 120 frames of the rig"),
        "{stderr}"
    );
    assert_rig_matches(&check, 120);
    let names: Vec<&str> = mouthpiece_retarget::rig::CURVE_NAMES.to_vec();
    assert_eq!(check["target_names"], json!(names), "{check}");
    // The jaw node at the wolf's own hinge (`[rig] jaw_pivot`, model frame), in its mouth frame.
    let pivot = character.jaw_pivot.expect("the wolf places its jaw");
    let want = character.frame.to_mouth(&pivot);
    let rest: Vec<f64> = serde_json::from_value(check["jaw_rest"].clone()).unwrap();
    for (got, want) in rest.iter().zip(want.iter()) {
        assert!(
            (got - want).abs() < 1e-6 * width,
            "jaw at {rest:?}, want {want}"
        );
    }
    // Without it, at the default hinge ratios scaled to the wolf's mouth.
    let text = std::fs::read_to_string(&wolf_toml).unwrap();
    let no_pivot = dir.path().join("wolf-no-pivot.toml");
    std::fs::write(&no_pivot, &text[..text.find("\n[rig]").unwrap()]).unwrap();
    let glb2 = dir.path().join("wolf-no-pivot.glb");
    let c2 = no_pivot.to_str().unwrap();
    export_ok(&[
        t,
        "--out",
        glb2.to_str().unwrap(),
        "--character",
        c2,
        "--model-up",
        "z",
    ]);
    let check2 = check_gltf_with(&take, &glb2, &["--character", c2, "--model-up", "z"]);
    let rest: Vec<f64> = serde_json::from_value(check2["jaw_rest"].clone()).unwrap();
    for (got, want) in rest.iter().zip([0.0, 0.5 * width, -1.6 * width]) {
        assert!((got - want).abs() < 1e-6 * width, "default jaw at {rest:?}");
    }
    // The performer opens the jaw in this take.
    assert!(
        check["max_jaw_angle_deg"].as_f64().unwrap() > 2.0,
        "{check}"
    );

    // CSV: the rig's columns are the take's numbers, digit for digit (the slide and the lips'
    // translations scaled to the wolf's mouth).
    let xs = character.neutral.iter().map(|p| p.x);
    let wolf_width = xs.clone().fold(f64::MIN, f64::max) - xs.fold(f64::MAX, f64::min);
    let csv = dir.path().join("wolf.csv");
    export_ok(&[t, "--out", csv.to_str().unwrap(), "--character", c]);
    let csv_text = std::fs::read_to_string(&csv).unwrap();
    let mut rows = csv_text.lines();
    let header: Vec<&str> = rows.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let take_lines: Vec<Value> = std::fs::read_to_string(&take)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for (row, line) in rows.zip(&take_lines) {
        let cells: Vec<&str> = row.split(',').collect();
        let cell = |name: &str| cells[column(name)].parse::<f64>().unwrap();
        let rig = &line["rig"];
        assert_eq!(
            cell("jaw_angle_deg"),
            rig["jaw"]["angle_deg"].as_f64().unwrap()
        );
        // The slide and the lips' translations in the wolf's units: its mouth width over the
        // performer's.
        let scale = wolf_width / rig["performer_width_m"].as_f64().unwrap();
        let slide = rig["jaw"]["slide_m"].as_f64().unwrap() * scale;
        assert!((cell("jaw_slide") - slide).abs() <= 1e-15, "{row}");
        for lip in ["upper", "lower"] {
            for (axis, a) in ["x", "y", "z"].iter().enumerate() {
                let t = rig["lips"][lip]["translation"][axis].as_f64().unwrap() * scale;
                let name = format!("lip_{lip}_{a}");
                assert!((cell(&name) - t).abs() <= 1e-15, "{name}: {row}");
            }
        }
        for name in &names {
            assert_eq!(cell(name), rig["curves"][name].as_f64().unwrap(), "{name}");
        }
    }

    let gltf = dir.path().join("wolf.gltf");
    export_ok(&[
        t,
        "--out",
        gltf.to_str().unwrap(),
        "--character",
        c,
        "--model-up",
        "z",
        "--reduce",
        "0.0005",
    ]);
    assert_valid(&gltf);
    let check = check_gltf_with(&take, &gltf, &["--character", c, "--model-up", "z"]);
    assert!(
        check["max_error"].as_f64().unwrap() <= 0.0005 + 1e-6,
        "{check}"
    );
    // --reduce leaves the rig's keys alone (every frame).
    assert_rig_matches(&check, 120);

    // Blender: after import the points sit on the wolf model as the artist built it (Blender
    // is Z-up like the model), following the take: model = frame origin + axes · point.
    let frames: Vec<Value> = std::fs::read_to_string(&take)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let probes = [0usize, 40, 77, 119];
    let result = blender_samples(
        &glb,
        probes.iter().map(|&i| frames[i]["t"].as_f64().unwrap()),
    );
    for &i in &probes {
        let t = frames[i]["t"].as_f64().unwrap();
        let at = &result["samples"][format!("{t:?}")];
        for name in &character.point_names {
            let p: Vec<f64> = serde_json::from_value(frames[i]["points"][name].clone()).unwrap();
            let model = character
                .frame
                .to_parent(&nalgebra::Vector3::new(p[0], p[1], p[2]));
            let got: Vec<f64> = serde_json::from_value(at[name].clone()).unwrap();
            for a in 0..3 {
                assert!(
                    (got[a] - model[a]).abs() <= 1e-4 * width,
                    "{name} at t={t}: Blender {got:?}, wolf model {model:?}"
                );
            }
        }
        // The jaw turns about the hinge (the mouth frame's x axis) by the take's angle: its
        // rotation relative to `mouth` (Blender's axis change is a turn about x as well, so
        // it does not change a rotation about x).
        let m = &result["matrices"][format!("{t:?}")];
        let basis = |name: &str| -> nalgebra::Matrix3<f64> {
            let rows: Vec<Vec<f64>> = serde_json::from_value(m[name].clone()).unwrap();
            nalgebra::Matrix3::from_fn(|r, c| rows[r][c])
        };
        let relative = basis("mouth").try_inverse().unwrap() * basis("jaw");
        let angle = relative[(2, 1)].atan2(relative[(1, 1)]).to_degrees();
        let want = frames[i]["rig"]["jaw"]["angle_deg"].as_f64().unwrap();
        assert!(
            (angle - want).abs() < 0.01,
            "jaw at t={t}: Blender {angle}°, take {want}°"
        );
        assert!(
            relative[(0, 0)] > 1.0 - 1e-5,
            "jaw turns about x only: {relative}"
        );
        // The morph weights drive Blender's shape keys, named after the curves.
        let keys = &result["shape_keys"][format!("{t:?}")]["blendshapes"];
        for name in ["jawOpen", "mouthFunnel", "mouthSmileLeft"] {
            let got = keys[name]
                .as_f64()
                .unwrap_or_else(|| panic!("shape key {name} at {t}: {keys}"));
            let want = frames[i]["rig"]["curves"][name].as_f64().unwrap();
            assert!(
                (got - want).abs() < 1e-4,
                "{name} at t={t}: Blender {got}, take {want}"
            );
        }
    }
}

/// The rig's keys of an exported file (as `check_gltf.py` read them) equal the take's: every
/// weight (f32 rounding), the jaw angle and slide.
fn assert_rig_matches(check: &Value, frames: u64) {
    assert_eq!(check["rig_keys"], frames, "{check}");
    assert!(
        check["max_weight_error"].as_f64().unwrap() < 1e-7,
        "{check}"
    );
    assert!(
        check["max_jaw_angle_error_deg"].as_f64().unwrap() < 1e-4,
        "{check}"
    );
    assert!(
        check["max_jaw_slide_error"].as_f64().unwrap() < 1e-7,
        "{check}"
    );
    assert!(check["max_lip_error"].as_f64().unwrap() < 1e-6, "{check}");
}

/// A small synthetic recording (320x240, the camera 0.35 m from the mouth) of `seconds`
/// from `seed`, written to `path` (`.mcap` or `.oni`).
fn synth_small(path: &Path, seconds: &str, seed: &str) {
    let out = mouthpiece(&[
        "synth",
        "--out",
        path.to_str().unwrap(),
        "--seconds",
        seconds,
        "--seed",
        seed,
        "--size",
        "320x240",
        "--distance",
        "0.35",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A recording (`.mcap`, `.oni`) goes through the processing pipeline first: a GLB the
/// validator accepts, one key per frame and point (fewer with --reduce), the same keys as
/// exporting `mouthpiece process`'s own output.
#[test]
fn recordings_are_processed_then_exported() {
    let dir = tempfile::tempdir().unwrap();
    let wolf = repo().join("config/characters/wolf.toml");
    let c = wolf.to_str().unwrap();
    for ext in ["mcap", "oni"] {
        let session = dir.path().join(format!("session.{ext}"));
        let r = session.to_str().unwrap();
        synth_small(&session, "2.5", "5");

        let glb = dir.path().join(format!("{ext}.glb"));
        let stderr = export_ok(&[r, "--character", c, "--out", glb.to_str().unwrap()]);
        // 75 frames × 12 wolf points.
        assert!(stderr.contains("75 frames, 900 keys"), "{ext}: {stderr}");
        assert_valid(&glb);

        let take = dir.path().join(format!("{ext}.jsonl"));
        let out = mouthpiece(&[
            "process",
            r,
            "--character",
            c,
            "--out",
            take.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let check = check_gltf_with(&take, &glb, &["--character", c]);
        assert_eq!(check["keys"], 900, "{check}");
        // The mouth outline (`process`'s default smoothing) from the neutral pose on: the
        // lines before it have no curve points and get no curve keys.
        let with_curve = dir.path().join(format!("{ext}-curve.glb"));
        let stderr = export_ok(&[
            r,
            "--character",
            c,
            "--out",
            with_curve.to_str().unwrap(),
            "--curve",
        ]);
        assert!(stderr.contains("75 frames"), "{ext}: {stderr}");
        assert_valid(&with_curve);
        let curved = check_gltf_with(&take, &with_curve, &["--character", c]);
        assert!(curved["curve_points"].as_u64().unwrap() > 12, "{curved}");
        assert!(
            curved["max_curve_error"].as_f64().unwrap() < 1e-6,
            "{ext}: {curved}"
        );
        assert_rig_matches(&curved, 75);
        assert!(
            check["max_error"].as_f64().unwrap() < 1e-6,
            "{ext}: {check}"
        );
        // The rig from the neutral pose on (rest keys while calibrating), equal to
        // `process`'s own `rig`.
        let rig_frames = check["rig_frames"].as_u64().unwrap();
        assert!(rig_frames > 0 && rig_frames < 75, "{ext}: {check}");
        assert_rig_matches(&check, 75);

        let reduced = dir.path().join(format!("{ext}-reduced.glb"));
        let stderr = export_ok(&[
            r,
            "--character",
            c,
            "--out",
            reduced.to_str().unwrap(),
            "--reduce",
            "0.002",
        ]);
        assert!(stderr.contains("75 frames"), "{ext}: {stderr}");
        assert_valid(&reduced);
        let check = check_gltf_with(&take, &reduced, &["--character", c]);
        assert!(check["keys"].as_u64().unwrap() < 900, "{ext}: {check}");
        assert!(
            check["max_error"].as_f64().unwrap() <= 0.002 + 1e-6,
            "{ext}: {check}"
        );

        let out = mouthpiece(&["export", r, "--out", glb.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(2), "{ext}: no --character");
        assert!(String::from_utf8_lossy(&out.stderr).contains("needs --character"));
    }
    assert_no_temporary_files(dir.path());
}

/// Outputs are written to hidden temporary files and renamed into place: none may be left.
fn assert_no_temporary_files(dir: &Path) {
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(
        leftovers.is_empty(),
        "temporary files left behind: {leftovers:?}"
    );
}

/// A take with a turn: the wolf retargeted with `--look-at` (a viewpoint 25° to its left,
/// 10° down, 3 m from its head pivot, set at 1.5 s), exported with its head and eyes. The
/// validator's report is empty, the rotation keys read back equal to the take's, and after
/// Blender imports the GLB the head's forward axis points at the viewpoint at the last frame
/// (within 0.1°), as do both eyes.
#[test]
fn a_turn_exported_faces_the_viewpoint_in_blender() {
    use mouthpiece_retarget::head::direction_deg;
    use mouthpiece_retarget::Character;
    use nalgebra::{Matrix3, Vector3};
    let dir = tempfile::tempdir().unwrap();
    let root = repo();
    let wolf_toml = root.join("config/characters/wolf.toml");
    let character =
        Character::from_toml_str(&std::fs::read_to_string(&wolf_toml).unwrap()).unwrap();
    let axes = character.frame.axes;
    let viewpoint = character.head.pivot + axes * direction_deg(25.0, -10.0) * 3.0;
    let take = dir.path().join("turn.jsonl");
    let look_at = format!("{},{},{}@1.5", viewpoint.x, viewpoint.y, viewpoint.z);
    retarget_example(&wolf_toml, &take, &["--look-at", &look_at]);
    let frames: Vec<Value> = std::fs::read_to_string(&take)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let last = frames.last().unwrap();
    assert_eq!(last["character_head"]["mode"], "look_at", "{last}");
    assert_eq!(last["character_head"]["in_reach"], true, "{last}");
    assert_eq!(last["character_head"]["progress"], 1.0, "{last}");
    assert_eq!(frames[0]["character_head"]["mode"], "follow");

    let glb = dir.path().join("turn.glb");
    let c = wolf_toml.to_str().unwrap();
    let stderr = export_ok(&[
        take.to_str().unwrap(),
        "--out",
        glb.to_str().unwrap(),
        "--character",
        c,
        "--model-up",
        "z",
    ]);
    assert!(
        stderr.contains("head, eye_L, eye_R: 360 rotation keys"),
        "{stderr}"
    );
    assert_valid(&glb);
    let check = check_gltf_with(&take, &glb, &["--character", c, "--model-up", "z"]);
    assert_eq!(check["head_keys"], 360, "{check}");
    assert!(check["max_head_error"].as_f64().unwrap() < 1e-6, "{check}");

    let t_last = last["t"].as_f64().unwrap();
    let result = blender_samples(&glb, [t_last].into_iter());
    assert_eq!(result["objects"]["eye_L"]["parent"], "head", "{result}");
    let matrices = &result["matrices"][format!("{t_last:?}")];
    let world = |name: &str| -> (Matrix3<f64>, Vector3<f64>) {
        let rows: Vec<Vec<f64>> = serde_json::from_value(matrices[name].clone()).unwrap();
        let m = Matrix3::from_fn(|r, c| rows[r][c]);
        (m, Vector3::new(rows[0][3], rows[1][3], rows[2][3]))
    };
    // Blender's local axes are glTF's turned Z-up, (x, y, z) -> (x, -z, y); the head node's
    // glTF axes are the wolf's model axes; the wolf is modelled Z-up, so Blender's world is
    // the model frame again.
    let forward_model = axes.column(2).into_owned();
    let forward_local = Vector3::new(forward_model.x, -forward_model.z, forward_model.y);
    let angle_deg = |a: &Vector3<f64>, b: &Vector3<f64>| {
        let c = a.normalize().dot(&b.normalize()).clamp(-1.0, 1.0);
        c.acos().to_degrees()
    };
    let (m, at) = world("head");
    assert!(
        (at - character.head.pivot).norm() < 1e-5,
        "head at {at:?}, pivot {:?}",
        character.head.pivot
    );
    let facing = angle_deg(&(m * forward_local), &(viewpoint - at));
    assert!(facing <= 0.1, "the head is {facing}° off the viewpoint");
    for eye in ["eye_L", "eye_R"] {
        let (m, at) = world(eye);
        let gaze = angle_deg(&(m * forward_local), &(viewpoint - at));
        assert!(gaze <= 0.1, "{eye} looks {gaze}° off the viewpoint");
    }
    // The head did turn: at the start of the turn it faced elsewhere.
    let before = &frames[44]["character_head"]["rotation"];
    let after = &last["character_head"]["rotation"];
    let dot: f64 = (0..4)
        .map(|k| before[k].as_f64().unwrap() * after[k].as_f64().unwrap())
        .sum();
    assert!(dot.abs() < 0.99, "{before} vs {after}");
}

/// A recording whose bytes are damaged, not MCAP at all, or empty is the user's bad input:
/// exit 2, naming the file, and no output left behind.
#[test]
fn damaged_recordings_are_exit_2_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let wolf = repo().join("config/characters/wolf.toml");
    let session = dir.path().join("session.mcap");
    synth_small(&session, "1", "3");
    let mut bytes = std::fs::read(&session).unwrap();
    // Overwrite the middle of the file: a chunk whose CRC no longer matches.
    let mid = bytes.len() / 2;
    for b in &mut bytes[mid..mid + 4096] {
        *b ^= 0x5a;
    }
    let damaged = dir.path().join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(
        &garbage,
        b"not an mcap file, though long enough to have a magic",
    )
    .unwrap();
    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    let w = wolf.to_str().unwrap();
    for (file, needle) in [
        (&damaged, "damaged.mcap: not readable as an MCAP session"),
        (&garbage, "garbage.mcap: not readable as an MCAP session"),
        (&empty, "empty.mcap: no frames"),
    ] {
        let f = file.to_str().unwrap();
        let jsonl = dir.path().join("out.jsonl");
        let glb = dir.path().join("out.glb");
        for args in [
            vec![
                "process",
                f,
                "--character",
                w,
                "--out",
                jsonl.to_str().unwrap(),
            ],
            vec![
                "export",
                f,
                "--character",
                w,
                "--out",
                glb.to_str().unwrap(),
            ],
        ] {
            let o = mouthpiece(&args);
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(stderr.contains(needle), "{args:?}: {stderr}");
        }
        assert!(!jsonl.exists() && !glb.exists(), "no output from {f}");
    }
    assert_no_temporary_files(dir.path());
}

/// `--format livelink-csv`: read back by Python's `csv` module (not our reader) and compared
/// with the take: the app's header, 61 values a row, each column the value its name says
/// (the rig's curves as they are, the head and eyes in radians, a turn to the character's
/// left a negative yaw), and the timecodes on the take's clock (a JSONL take: from
/// 00:00:00:00 at 30 fps).
#[test]
fn a_take_exported_as_livelink_csv_reads_back_with_pythons_csv() {
    let dir = tempfile::tempdir().unwrap();
    let take_path = dir.path().join("take.jsonl");
    let take = write_take(&take_path, 40, 12);
    let curves = |i: usize| -> Vec<(&str, f64)> {
        let x = i as f64 / 40.0;
        vec![
            ("jawOpen", 0.8 * x),
            ("mouthLeft", 0.25 * x),
            ("jawRight", 0.5 - 0.5 * x),
            ("mouthSmileLeft", 0.125),
        ]
    };
    // The head turns to the character's left (about +y: forward, +z, towards left, +x) by
    // 0.5° a frame; the eyes look 10° down.
    let yaw_deg = |i: usize| 0.5 * i as f64;
    let quat = |axis: [f64; 3], deg: f64| {
        let h = deg.to_radians() / 2.0;
        [
            h.cos(),
            axis[0] * h.sin(),
            axis[1] * h.sin(),
            axis[2] * h.sin(),
        ]
    };
    let text: String = std::fs::read_to_string(&take_path)
        .unwrap()
        .lines()
        .enumerate()
        .map(|(i, line)| {
            let named: Vec<String> = mouthpiece_output::CURVE_NAMES
                .iter()
                .map(|n| {
                    let v = curves(i).iter().find(|c| c.0 == *n).map_or(0.0, |c| c.1);
                    format!("\"{n}\": {v:?}")
                })
                .collect();
            let extra = format!(
                r#", "rig": {{"jaw": {{"angle_deg": 0.0, "slide_m": 0.0}}, "lips": {{"upper": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}, "lower": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}}}, "curves": {{{}}}}}, "character_head": {{"rotation": {}, "eye_left": {}, "eye_right": {}, "mode": "follow", "in_reach": null, "progress": 1.0}}"#,
                named.join(", "),
                json!(quat([0.0, 1.0, 0.0], yaw_deg(i))),
                json!(quat([1.0, 0.0, 0.0], 10.0)),
                json!(quat([1.0, 0.0, 0.0], 10.0)),
            );
            format!(
                "{}\n",
                line.replace("\"curve\": null", &format!("\"curve\": null{extra}"))
            )
        })
        .collect();
    std::fs::write(&take_path, text).unwrap();
    let out = dir.path().join("take.csv");
    export_ok(&[
        take_path.to_str().unwrap(),
        "--format",
        "livelink-csv",
        "--out",
        out.to_str().unwrap(),
    ]);
    // Python's csv module reads the file; the timecode `HH:MM:SS:FF.fff` becomes seconds at
    // 30 fps (the sub-frame in thousandths of a frame).
    let script = r#"
import csv, json, re, sys
with open(sys.argv[1], newline="") as f:
    rows = list(csv.reader(f))
header, body = rows[0], rows[1:]
out = {"header": header, "rows": []}
for row in body:
    assert len(row) == len(header), row
    m = re.fullmatch(r"(\d\d):(\d\d):(\d\d):(\d\d)\.(\d\d\d)", row[0])
    assert m, row[0]
    h, mi, s, ff, sub = (int(g) for g in m.groups())
    seconds = (h * 60 + mi) * 60 + s + (ff + sub / 1000) / 30
    values = {name: float(v) for name, v in zip(header[2:], row[2:])}
    out["rows"].append({"seconds": seconds, "count": row[1], "values": values})
print(json.dumps(out))
"#;
    let got = run_json(
        Command::new(python()).arg("-c").arg(script).arg(&out),
        "python csv",
    );
    let header: Vec<&str> = got["header"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(header.len(), 63);
    assert_eq!(
        &header[..4],
        [
            "Timecode",
            "BlendShapeCount",
            "EyeBlinkLeft",
            "EyeLookDownLeft"
        ]
    );
    // The app's header has Right before Left for the jaw's and the mouth's sideways shapes.
    assert_eq!(
        &header[16..20],
        ["JawForward", "JawRight", "JawLeft", "JawOpen"]
    );
    assert_eq!(&header[23..25], ["MouthRight", "MouthLeft"]);
    assert_eq!(header[53], "TongueOut");
    assert_eq!(
        &header[54..],
        [
            "HeadYaw",
            "HeadPitch",
            "HeadRoll",
            "LeftEyeYaw",
            "LeftEyePitch",
            "LeftEyeRoll",
            "RightEyeYaw",
            "RightEyePitch",
            "RightEyeRoll"
        ]
    );
    let rows = got["rows"].as_array().unwrap();
    assert_eq!(rows.len(), take.len());
    let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol;
    for (i, (row, (t, _))) in rows.iter().zip(&take).enumerate() {
        assert_eq!(row["count"], "61");
        // Within one thousandth of a frame (the sub-frame's resolution) of the take's time.
        let seconds = row["seconds"].as_f64().unwrap();
        assert!(
            seconds <= *t + 1e-6 && *t - seconds < 1.0 / 30_000.0 + 1e-6,
            "{i}: {seconds} vs {t}"
        );
        let v = |name: &str| row["values"][name].as_f64().unwrap();
        for (name, want) in curves(i) {
            let column = format!("{}{}", name[..1].to_uppercase(), &name[1..]);
            assert!(
                close(v(&column), want, 1e-6),
                "{i} {column}: {} vs {want}",
                v(&column)
            );
        }
        assert_eq!(v("MouthRight"), 0.0);
        assert_eq!(v("JawLeft"), 0.0);
        for unmeasured in ["EyeBlinkLeft", "BrowInnerUp", "CheekPuff", "TongueOut"] {
            assert_eq!(v(unmeasured), 0.0, "{unmeasured}");
        }
        // A turn to the character's left: a negative yaw, radians.
        assert!(
            close(v("HeadYaw"), -yaw_deg(i).to_radians(), 1e-6),
            "{i}: {}",
            v("HeadYaw")
        );
        assert!(close(v("HeadPitch"), 0.0, 1e-6) && close(v("HeadRoll"), 0.0, 1e-6));
        for eye in ["LeftEye", "RightEye"] {
            assert!(close(v(&format!("{eye}Pitch")), 10f64.to_radians(), 1e-6));
            assert!(close(v(&format!("{eye}Yaw")), 0.0, 1e-6));
        }
        // 10° down of the 30° full scale.
        assert!(close(v("EyeLookDownLeft"), 1.0 / 3.0, 1e-6));
        assert_eq!(v("EyeLookUpRight"), 0.0);
    }
}
