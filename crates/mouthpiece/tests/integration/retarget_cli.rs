//! `mouthpiece retarget` end to end: against the independent numpy reference on unseen random
//! cases, invariance to head motion, and bad input (exit code 2, the line named, no output).

use crate::repo;
use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};

use serde_json::Value;

fn mouthpiece() -> Command {
    let mut c = crate::mouthpiece();
    c.env("RUST_LOG", "warn");
    c
}

/// The Python with numpy and scipy (`MOUTHPIECE_PYTHON`, else `python3`). Without one the
/// test fails: the reference comparison is the point of it (scripts/test prepares one; CI
/// installs numpy and scipy from scripts/packages/test-python.txt).
fn python() -> String {
    let py = std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&py)
        .args(["-c", "import numpy, scipy"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "no Python with numpy and scipy ({py}): set MOUTHPIECE_PYTHON or run scripts/test, \
         which prepares one"
    );
    py
}

fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("spawn");
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn read_jsonl(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn vectors(v: &Value) -> Vec<[f64; 3]> {
    let as3 = |p: &Value| -> [f64; 3] {
        let a = p.as_array().unwrap();
        [
            a[0].as_f64().unwrap(),
            a[1].as_f64().unwrap(),
            a[2].as_f64().unwrap(),
        ]
    };
    match v {
        Value::Object(m) => m.values().map(as3).collect(),
        Value::Array(a) => a.iter().map(as3).collect(),
        _ => panic!("not points: {v}"),
    }
}

fn max_diff(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f64::max)
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// The rig of a line against the reference's (`tests/reference/rig_reference.py`, written from
/// docs/rig.md): the jaw, both lips' rigid motions and every curve, by name and in order.
fn rig_agrees(got: &Value, expected: &Value, at: &str) {
    let numbers = |v: &Value| match v.as_f64() {
        Some(x) => vec![x],
        None => floats(v),
    };
    let close = |what: &str, a: &Value, b: &Value, tol: f64| {
        let (a, b) = (numbers(a), numbers(b));
        assert_eq!(a.len(), b.len(), "{at}: rig {what}: {a:?} vs {b:?}");
        let d = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(d <= tol, "{at}: rig {what} differs by {d}: {a:?} vs {b:?}");
    };
    close(
        "jaw angle",
        &got["jaw"]["angle_deg"],
        &expected["jaw"]["angle_deg"],
        1e-7,
    );
    close(
        "jaw slide",
        &got["jaw"]["slide_m"],
        &expected["jaw"]["slide_m"],
        1e-10,
    );
    for lip in ["upper", "lower"] {
        let (g, e) = (&got["lips"][lip], &expected["lips"][lip]);
        close(
            &format!("{lip} lip rotation"),
            &g["rotation"],
            &e["rotation"],
            1e-8,
        );
        close(
            &format!("{lip} lip translation"),
            &g["translation"],
            &e["translation"],
            1e-10,
        );
        close(
            &format!("{lip} lip residual"),
            &g["residual"],
            &e["residual"],
            1e-10,
        );
    }
    let (gc, ec) = (
        got["curves"].as_object().expect("rig curves"),
        expected["curves"].as_object().expect("reference curves"),
    );
    let names: Vec<_> = gc.keys().collect();
    assert_eq!(names, ec.keys().collect::<Vec<_>>(), "{at}: curve names");
    assert_eq!(names.len(), 27, "{at}: curves");
    for name in names {
        close(name, &gc[name], &ec[name], 1e-9);
    }
}

#[test]
fn agrees_with_numpy_reference_on_unseen_random_cases() {
    let py = python();
    let dir = tempfile::tempdir().unwrap();
    // Seeds never used while developing; each case has its own character and performer.
    for seed in 1000..1016 {
        let case = dir.path().join(format!("case{seed}"));
        run_ok(
            Command::new(&py)
                .arg(repo().join("tests/reference/random_case.py"))
                .args(["--seed", &seed.to_string(), "--dir"])
                .arg(&case),
        );
        let opts: Value =
            serde_json::from_str(&std::fs::read_to_string(case.join("case.json")).unwrap())
                .unwrap();
        let width = opts["mouth_width"].as_f64().unwrap();
        let got = case.join("got.jsonl");
        run_ok(
            mouthpiece()
                .args(["retarget", "--character"])
                .arg(case.join("character.toml"))
                .arg("--input")
                .arg(case.join("input.jsonl"))
                .arg("--out")
                .arg(&got)
                .args(["--smooth", opts["smooth"].as_str().unwrap()])
                .args(["--samples-per-span", &opts["samples_per_span"].to_string()])
                .args(["--ma-radius", &opts["ma_radius"].to_string()])
                .args(["--ma-alpha", &opts["ma_alpha"].to_string()])
                .args(["--hold", &opts["hold"].to_string()])
                .args(["--decay", &opts["decay"].to_string()]),
        );
        let got = read_jsonl(&got);
        let expected = read_jsonl(&case.join("expected.jsonl"));
        assert_eq!(got.len(), expected.len(), "seed {seed}: line count");
        let tol = 1e-4 * width;
        for (g, e) in got.iter().zip(&expected) {
            let at = format!("seed {seed}, seq {}", e["seq"]);
            assert_eq!(g["seq"], e["seq"], "{at}");
            assert_eq!(g["t"], e["t"], "{at}");
            assert_eq!(g["character"], e["character"], "{at}");
            let gk: Vec<_> = g["points"].as_object().unwrap().keys().collect();
            let ek: Vec<_> = e["points"].as_object().unwrap().keys().collect();
            assert_eq!(gk, ek, "{at}: point names and order");
            let d = max_diff(&vectors(&g["points"]), &vectors(&e["points"]));
            assert!(d <= tol, "{at}: points differ by {d} > {tol}");
            assert_eq!(g["confidence"], e["confidence"], "{at}");
            assert_eq!(g["head_lost"], e["head_lost"], "{at}");
            let (gq, eq) = (
                floats(&g["head"]["rotation"]),
                floats(&e["head"]["rotation"]),
            );
            let dq = gq
                .iter()
                .zip(&eq)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(dq < 1e-9, "{at}: head rotation {gq:?} vs {eq:?}");
            let (gt, et) = (
                floats(&g["head"]["translation"]),
                floats(&e["head"]["translation"]),
            );
            let dt = gt
                .iter()
                .zip(&et)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(dt < 1e-9, "{at}: head translation {gt:?} vs {et:?}");
            rig_agrees(&g["rig"], &e["rig"], &at);
            match (&g["curve"], &e["curve"]) {
                (Value::Null, Value::Null) => {}
                (gc, ec) => {
                    assert_eq!(gc["method"], ec["method"], "{at}");
                    let d = max_diff(&vectors(&gc["points"]), &vectors(&ec["points"]));
                    assert!(d <= tol, "{at}: curve differs by {d}");
                }
            }
        }
    }
}

#[test]
fn output_does_not_change_when_only_the_head_moves() {
    let py = python();
    let dir = tempfile::tempdir().unwrap();
    let mut outputs = Vec::new();
    for head in ["none", "strong"] {
        let input = dir.path().join(format!("{head}.jsonl"));
        let out = dir.path().join(format!("{head}.out.jsonl"));
        run_ok(
            Command::new(&py)
                .arg(repo().join("tests/reference/performer.py"))
                .args([
                    "--seed",
                    "77",
                    "--head",
                    head,
                    "--noise",
                    "0",
                    "--full-precision",
                ])
                .args(["--no-forehead-dropout", "--out"])
                .arg(&input),
        );
        run_ok(
            mouthpiece()
                .args(["retarget", "--character"])
                .arg(repo().join("config/characters/wolf.toml"))
                .arg("--input")
                .arg(&input)
                .arg("--out")
                .arg(&out),
        );
        outputs.push(read_jsonl(&out));
    }
    let width = 0.15; // the wolf's mouth
    let mut head_moved = 0.0f64;
    for (still, moving) in outputs[0].iter().zip(&outputs[1]) {
        let d = max_diff(&vectors(&still["points"]), &vectors(&moving["points"]));
        assert!(
            d < 1e-6 * width,
            "seq {}: output moved by {d} with the head",
            still["seq"]
        );
        let ts = floats(&still["head"]["translation"]);
        let tm = floats(&moving["head"]["translation"]);
        head_moved = head_moved.max(ts.iter().zip(&tm).map(|(a, b)| (a - b).abs()).sum());
    }
    assert!(
        head_moved > 0.01,
        "the head should have moved (by {head_moved} m)"
    );
}

fn example_args(cmd: &mut Command, input: &Path, out: &str) {
    cmd.args(["retarget", "--character"])
        .arg(repo().join("config/characters/wolf.toml"))
        .arg("--input")
        .arg(input)
        .args(["--out", out]);
}

#[test]
fn example_runs_and_stdin_streaming_matches_file_input() {
    let example = repo().join("tests/data/example-performer.jsonl");
    let mut from_file = mouthpiece();
    example_args(&mut from_file, &example, "-");
    let from_file = run_ok(&mut from_file).stdout;
    let mut from_stdin = mouthpiece();
    example_args(&mut from_stdin, Path::new("-"), "-");
    let mut child = from_stdin
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(&std::fs::read(&example).unwrap())
        .unwrap();
    let from_stdin = child.wait_with_output().unwrap();
    assert!(from_stdin.status.success());
    assert_eq!(from_file, from_stdin.stdout);
    let lines: Vec<Value> = from_file
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .map(|l| serde_json::from_slice(l).unwrap())
        .collect();
    let input_lines = std::fs::read_to_string(&example).unwrap().lines().count();
    assert_eq!(lines.len(), input_lines);
    assert_eq!(lines[0]["character"], "wolf");
    assert_eq!(lines[0]["points"].as_object().unwrap().len(), 12);
    assert_eq!(lines[0]["curve"]["method"], "bspline");
    assert_eq!(
        lines[0]["curve"]["points"].as_array().unwrap().len(),
        12 * 8
    );
    assert!(
        lines.iter().any(|l| l["head_lost"] == true),
        "example has head-lost frames"
    );
}

/// A small valid performer: `n` lines, the first `neutral` of them flagged.
fn performer_lines(n: usize, neutral: usize) -> Vec<String> {
    (0..n)
        .map(|i| {
            let open = if i >= neutral {
                0.004 * (i as f64 * 0.7).sin()
            } else {
                0.0
            };
            let mut pts = serde_json::Map::new();
            for k in 0..12 {
                let a = k as f64 / 12.0 * std::f64::consts::TAU;
                let y = -0.01 * a.sin() + if a.sin() < 0.0 { open } else { 0.0 };
                let v = [0.025 * a.cos(), y, 0.6 - 0.005 * a.sin().abs()];
                pts.insert(format!("D{}", k + 1), serde_json::json!(v));
            }
            for (k, v) in [[-0.03, -0.1, 0.62], [0.03, -0.1, 0.62], [0.0, -0.12, 0.625]]
                .iter()
                .enumerate()
            {
                pts.insert(format!("F{}", k + 1), serde_json::json!(v));
            }
            let mut line = serde_json::json!({"t": i as f64 / 30.0, "points": pts});
            if i < neutral {
                line["neutral"] = Value::Bool(true);
            }
            line.to_string()
        })
        .collect()
}

/// Runs retarget on `lines` from a file into a file; returns (exit code, stderr, output exists).
fn run_bad(lines: &[String]) -> (i32, String, bool) {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.jsonl");
    std::fs::write(&input, lines.join("\n") + "\n").unwrap();
    let out = dir.path().join("out.jsonl");
    let mut cmd = mouthpiece();
    example_args(&mut cmd, &input, out.to_str().unwrap());
    let o = cmd.output().unwrap();
    let leftovers = std::fs::read_dir(dir.path()).unwrap().count() > 1;
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        leftovers,
    )
}

#[test]
fn valid_small_input_passes() {
    let (code, err, out) = run_bad(&performer_lines(20, 5));
    assert_eq!(code, 0, "{err}");
    assert!(out);
}

#[test]
fn bad_lines_exit_2_naming_the_line_and_write_nothing() {
    type Corrupt = Box<dyn Fn(&mut Vec<String>)>;
    let cases: Vec<(Corrupt, &str, &str)> = vec![
        (
            Box::new(|l| l[7] = "{not json".into()),
            "line 8",
            "not a valid input line",
        ),
        (
            Box::new(|l| l[9] = l[9].replacen("0.6", "1e999", 1)),
            "line 10",
            "not a valid input line",
        ),
        (
            Box::new(|l| l[12] = l[12].replacen("\"t\":0.4", "\"t\":0.1", 1)),
            "line 13",
            "timestamp goes backwards",
        ),
        (
            Box::new(|l| l[11] = l[11].replace("\"D3\"", "\"D13\"")),
            "line 12",
            "unknown dot",
        ),
        (
            Box::new(|l| l[11] = l[11].replace("\"D3\"", "\"nose\"")),
            "line 12",
            "unknown dot",
        ),
        (
            Box::new(|l| l[3] = "[1, 2, 3]".into()),
            "line 4",
            "not a valid input line",
        ),
        (
            Box::new(|l| l[14] = l[14].replace("\"t\":", "\"time\":")),
            "line 15",
            "missing field",
        ),
    ];
    for (i, (corrupt, line, what)) in cases.iter().enumerate() {
        let mut lines = performer_lines(20, 5);
        corrupt(&mut lines);
        let (code, err, leftovers) = run_bad(&lines);
        assert_eq!(code, 2, "case {i}: {err}");
        assert!(err.contains(line) && err.contains(what), "case {i}: {err}");
        assert!(!leftovers, "case {i}: output or temp file left behind");
    }
}

#[test]
fn bad_neutral_pose_exits_2() {
    // Right corner D7 never seen in the neutral lines.
    let mut lines = performer_lines(10, 3);
    for l in lines.iter_mut().take(3) {
        let mut v: Value = serde_json::from_str(l).unwrap();
        v["points"]["D7"] = Value::Null;
        *l = v.to_string();
    }
    let (code, err, leftovers) = run_bad(&lines);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("lines 1..3") && err.contains("D7"), "{err}");
    assert!(!leftovers);

    // Forehead dots collinear.
    let mut lines = performer_lines(10, 3);
    for l in &mut lines {
        let mut v: Value = serde_json::from_str(l).unwrap();
        v["points"]["F3"] = serde_json::json!([0.0, -0.1, 0.62]);
        *l = v.to_string();
    }
    let (code, err, _) = run_bad(&lines);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("collinear"), "{err}");

    // Only two forehead dots.
    let mut lines = performer_lines(10, 0);
    let mut v: Value = serde_json::from_str(&lines[0]).unwrap();
    v["points"]["F2"] = Value::Null;
    lines[0] = v.to_string();
    let (code, err, _) = run_bad(&lines);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("line 1 (the first line)") && err.contains("3 non-collinear"),
        "{err}"
    );
}

#[test]
fn stdin_rejects_a_neutral_line_after_the_block() {
    let mut lines = performer_lines(10, 3);
    let mut v: Value = serde_json::from_str(&lines[6]).unwrap();
    v["neutral"] = Value::Bool(true);
    lines[6] = v.to_string();
    let mut cmd = mouthpiece();
    example_args(&mut cmd, Path::new("-"), "-");
    let mut child = cmd
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all((lines.join("\n") + "\n").as_bytes())
        .unwrap();
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("stdin line 7") && err.contains("neutral"),
        "{err}"
    );
    // Streaming: the six lines before it were written, each complete.
    let out = String::from_utf8(o.stdout).unwrap();
    assert_eq!(out.lines().count(), 6);
    for l in out.lines() {
        serde_json::from_str::<Value>(l).unwrap();
    }
    // The same input as a file is fine: neutral lines may be anywhere.
    let (code, err, _) = run_bad(&lines);
    assert_eq!(code, 0, "{err}");
}

/// `mouthpiece retarget` of the example performer onto `character`, its JSONL to stdout.
fn retarget_example_to_stdout(character: &Path) -> Output {
    mouthpiece()
        .args(["retarget", "--character"])
        .arg(character)
        .arg("--input")
        .arg(repo().join("tests/data/example-performer.jsonl"))
        .args(["--out", "-"])
        .output()
        .unwrap()
}

#[test]
fn bad_character_file_exits_2_with_key_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let character = dir.path().join("c.toml");
    let wolf = std::fs::read_to_string(repo().join("config/characters/wolf.toml")).unwrap();
    let broken = wolf.replace("units = \"m\"", "units = \"m\"\ncolour = \"grey\"");
    std::fs::write(&character, broken).unwrap();
    let o = retarget_example_to_stdout(&character);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("c.toml") && err.contains("line 6") && err.contains("colour"),
        "{err}"
    );
    assert!(o.stdout.is_empty());
}

/// A character's own `[rig.ranges]` reaches the `rig` of its lines; a bad one exits 2 naming
/// the file, the key and the line.
#[test]
fn a_characters_rig_ranges_reach_its_lines() {
    let dir = tempfile::tempdir().unwrap();
    let wolf = std::fs::read_to_string(repo().join("config/characters/wolf.toml")).unwrap();
    let run = |text: &str| {
        let character = dir.path().join("c.toml");
        std::fs::write(&character, text).unwrap();
        retarget_example_to_stdout(&character)
    };
    // (jawOpen, jaw angle) per line that has a rig.
    let jaw = |o: &std::process::Output| -> Vec<(f64, f64)> {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter_map(|l| {
                let v: Value = serde_json::from_str(l).unwrap();
                let rig = v.get("rig")?;
                Some((
                    rig["curves"]["jawOpen"].as_f64().unwrap(),
                    rig["jaw"]["angle_deg"].as_f64().unwrap(),
                ))
            })
            .collect()
    };
    let own = jaw(&run(&format!("{wolf}\n[rig.ranges]\njawOpen = 1000\n")));
    let default = jaw(&run(&wolf));
    assert!(!own.is_empty() && own.len() == default.len());
    assert!(
        default
            .iter()
            .any(|&(c, a)| a > 1.0 && (c - a / 1000.0).abs() > 1e-3),
        "the jaw opens in the example"
    );
    for &(c, a) in &own {
        assert!((c - (a / 1000.0).clamp(0.0, 1.0)).abs() < 1e-9, "{c} {a}");
    }
    let line = wolf.lines().count() + 3;
    let o = run(&format!("{wolf}\n[rig.ranges]\nmouthSmile = 0.1\n"));
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("c.toml")
            && err.contains(&format!("line {line}"))
            && err.contains("rig.ranges.mouthSmile"),
        "{err}"
    );
}

#[test]
fn existing_output_is_not_clobbered_on_error() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.jsonl");
    let mut lines = performer_lines(10, 2);
    lines[9] = "garbage".into();
    std::fs::write(&input, lines.join("\n")).unwrap();
    let out = dir.path().join("out.jsonl");
    std::fs::write(&out, "precious\n").unwrap();
    let mut cmd = mouthpiece();
    example_args(&mut cmd, &input, out.to_str().unwrap());
    assert_eq!(cmd.output().unwrap().status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "precious\n");
}

#[test]
fn one_euro_smooths_over_time_and_bad_values_exit_2() {
    let example = repo().join("tests/data/example-performer.jsonl");
    let parse = |bytes: &[u8]| -> Vec<Value> {
        String::from_utf8_lossy(bytes)
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    };
    let mut plain = mouthpiece();
    example_args(&mut plain, &example, "-");
    let plain = parse(&run_ok(&mut plain).stdout);
    let mut filtered = mouthpiece();
    example_args(&mut filtered, &example, "-");
    filtered.args(["--one-euro", "0.5,0.0", "--smooth", "none"]);
    let filtered = parse(&run_ok(&mut filtered).stdout);
    assert_eq!(plain.len(), filtered.len());
    // The first sample passes unchanged; afterwards the filter lags and smooths.
    assert_eq!(
        vectors(&plain[0]["points"]),
        vectors(&filtered[0]["points"])
    );
    assert_eq!(filtered[0]["curve"], Value::Null);
    let roughness = |lines: &[Value]| -> f64 {
        let mut sum = 0.0;
        for w in lines.windows(3) {
            let (a, b, c) = (
                vectors(&w[0]["points"]),
                vectors(&w[1]["points"]),
                vectors(&w[2]["points"]),
            );
            for i in 0..a.len() {
                for k in 0..3 {
                    sum += (a[i][k] - 2.0 * b[i][k] + c[i][k]).powi(2);
                }
            }
        }
        sum
    };
    let (rp, rf) = (roughness(&plain), roughness(&filtered));
    assert!(rf < 0.25 * rp, "One Euro should smooth: {rf} vs {rp}");

    for bad in ["1", "0,0.1", "1,-1", "x,1"] {
        let mut cmd = mouthpiece();
        example_args(&mut cmd, &example, "-");
        let o = cmd.args(["--one-euro", bad]).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "--one-euro {bad}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("--one-euro"));
    }
    // A bad duration is the flag's fault, said before any input line is read.
    for (flag, bad) in [("--hold", "-1"), ("--decay", "inf"), ("--hold", "x")] {
        let mut cmd = mouthpiece();
        example_args(&mut cmd, &example, "-");
        let o = cmd.arg(format!("{flag}={bad}")).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{flag} {bad}: {stderr}");
        assert!(
            stderr.contains(flag) && !stderr.contains("neutral pose"),
            "{stderr}"
        );
    }
    let mut cmd = mouthpiece();
    example_args(&mut cmd, &example, "-");
    let o = cmd
        .args(["--smooth", "bspline", "--samples-per-span", "0"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("samples_per_span"));
}

/// `--out` naming a FIFO (or `/dev/null`) writes into it: the output is never renamed over a
/// destination that is not a regular file (as root, that would replace `/dev/null`).
#[test]
fn an_output_that_is_not_a_regular_file_is_written_in_place() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("out.fifo");
    let status = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(status.success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read_to_string(fifo).unwrap())
    };
    let o = mouthpiece()
        .args(["retarget", "--character"])
        .arg(repo().join("config/characters/wolf.toml"))
        .arg("--input")
        .arg(repo().join("tests/data/example-performer.jsonl"))
        .arg("--out")
        .arg(&fifo)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Checked before joining: a reader still waiting on a replaced FIFO would never return.
    use std::os::unix::fs::FileTypeExt as _;
    let kind = std::fs::metadata(&fifo).unwrap().file_type();
    assert!(kind.is_fifo(), "the FIFO was replaced: {kind:?}");
    let text = reader.join().unwrap();
    assert!(text.lines().count() > 10, "{text}");
}

/// The last table row of `text` whose first cell is `first`, split into its cells.
fn table_row(text: &str, first: &str) -> Vec<String> {
    text.lines()
        .rfind(|l| l.starts_with(&format!("| {first} |")))
        .unwrap_or_else(|| panic!("no row for {first} in:\n{text}"))
        .trim_matches('|')
        .split('|')
        .map(|c| c.trim().to_string())
        .collect()
}

/// `evaluate --rig-frames` writes what the rig table is made of: the numpy reference
/// recomputes every curve from the file's stabilised dots, neutral dots and ranges
/// (`scripts/rig-error-split.py`), and the worst curve, its RMS and both correlations come
/// out as `evaluate` printed them; a file that cannot be created is a bad input. The session
/// (seed 32, Kinect-like, strong head motion, 5 s) widens the `mouthSmileRight` range while
/// learning (at 4.57 s), so each frame's own ranges must be in the file.
#[test]
fn evaluate_rig_frames_are_what_the_rig_table_is_made_of() {
    let py = python();
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("rig.csv");
    let out = run_ok(
        mouthpiece()
            .args([
                "evaluate",
                "--seeds",
                "32",
                "--noise",
                "kinect",
                "--head-motion",
            ])
            .args(["strong", "--seconds", "5", "--character"])
            .arg(repo().join("config/characters/human.toml"))
            .arg("--rig-frames")
            .arg(&csv),
    );
    let table = String::from_utf8(out.stdout).unwrap();
    // seed | noise | motion | frames | jaw | slide | worst | its RMS | jawOpen r | funnel r |
    // funnel r on the true dots | round SD
    let rig = table_row(&table, "32");
    let out = run_ok(
        Command::new(&py)
            .arg(repo().join("scripts/rig-error-split.py"))
            .arg(&csv),
    );
    let split = String::from_utf8(out.stdout).unwrap();
    // seed | noise | motion | frames | recomputed | worst | its RMS | jawOpen r | funnel r |
    // on the true dots | …
    let mine = table_row(&split, "32");
    let recomputed: f64 = mine[4].parse().unwrap();
    assert!(
        recomputed <= 1e-9,
        "curves recomputed differ by {recomputed}:\n{split}"
    );
    assert_eq!(rig[3], mine[3], "frames:\n{table}\n{split}");
    assert_eq!(
        rig[6..11],
        mine[5..10],
        "worst curve, RMS, r, r on the true dots:\n{table}\n{split}"
    );

    let bad = mouthpiece()
        .args(["evaluate", "--seeds", "1", "--character"])
        .arg(repo().join("config/characters/human.toml"))
        .arg("--rig-frames")
        .arg(dir.path().join("missing/rig.csv"))
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("--rig-frames") && err.contains("missing"),
        "{err}"
    );
}

/// The rig measures a dot the tracker did not see where the seen ones put it (docs/rig.md,
/// "The dots the rig measures"). Seed 46, Kinect-like, strong head motion, 5 s: the
/// lips' press and pucker lose dots for a few frames; measured as held, `mouthPressRight`
/// was 0.070 against its definition on the true dots; filled, every curve is within 0.05
/// (0.035 at worst when this test was written). The file says which dots were unseen, and
/// they are where the rig measured them.
#[test]
fn evaluate_with_dots_unseen_keeps_every_curve_within_its_target() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("rig.csv");
    let out = run_ok(
        mouthpiece()
            .args(["evaluate", "--seeds", "46", "--noise", "kinect"])
            .args(["--head-motion", "strong", "--seconds", "5", "--character"])
            .arg(repo().join("config/characters/human.toml"))
            .arg("--rig-frames")
            .arg(&csv),
    );
    let table = String::from_utf8(out.stdout).unwrap();
    // seed | noise | motion | frames | jaw | slide | worst | its RMS | jawOpen r | funnel r
    let rig = table_row(&table, "46");
    let worst: f64 = rig[7].parse().unwrap();
    assert!(worst <= 0.05, "worst curve {} {worst}:\n{table}", rig[6]);
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let seen: Vec<usize> = (0..header.len())
        .filter(|&i| header[i].starts_with("seen_D"))
        .collect();
    assert_eq!(seen.len(), 12, "{header:?}");
    let unseen = lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .map(|cells| seen.iter().filter(|&&i| cells[i] == "0").count())
        .sum::<usize>();
    assert!(
        unseen >= 5,
        "only {unseen} unseen dots (13 when written): the test needs a session that loses some"
    );
}

/// Runs `retarget` on the example with `args` added: it must exit 2 naming `named`, before
/// any input is read, and leave no output file.
fn refused_before_reading(args: &[&str], named: &str) {
    let dir = tempfile::tempdir().unwrap();
    let example = repo().join("tests/data/example-performer.jsonl");
    let out = dir.path().join("out.jsonl");
    let mut cmd = mouthpiece();
    example_args(&mut cmd, &example, out.to_str().unwrap());
    let o = cmd.args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(stderr.contains(named), "{args:?}: {stderr}");
    assert!(!out.exists(), "{args:?} left an output file");
}

/// A B-spline of 10^12 samples a span asked for terabytes (the allocation aborted).
#[test]
fn absurd_samples_per_span_exit_2() {
    refused_before_reading(
        &["--smooth", "bspline", "--samples-per-span", "1000000000000"],
        "samples_per_span",
    );
    refused_before_reading(&["--samples-per-span", "65"], "samples_per_span");
}

/// A moving average of radius 10^9 took hours a line.
#[test]
fn absurd_moving_average_radius_exits_2() {
    refused_before_reading(&["--smooth", "ma", "--ma-radius", "1000000000"], "radius");
    refused_before_reading(&["--smooth", "ma-exp", "--ma-radius", "501"], "radius");
}

/// A `--look-at` time no take reaches.
#[test]
fn absurd_look_at_times_exit_2() {
    refused_before_reading(&["--look-at", "0,0.1,2@1e300"], "--look-at");
    refused_before_reading(&["--look-at", "0,0.1,2@-1e10"], "--look-at");
}

/// `evaluate` with no `--character`, run outside the repository, measures the built-in wolf
/// (the daemon's default) instead of failing on a path relative to the working directory.
#[test]
fn evaluate_outside_the_repository_uses_the_built_in_wolf() {
    let dir = tempfile::tempdir().unwrap();
    let out = mouthpiece()
        .current_dir(dir.path())
        .args([
            "evaluate",
            "--seeds",
            "3",
            "--seconds",
            "2.5",
            "--head-motion",
            "mild",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.lines().any(|l| l.starts_with("| 3 | ")), "{table}");
}
