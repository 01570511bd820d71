//! Shape smoothing against values computed by scipy (tests/reference/smoothing_fixtures.py).

use mouthpiece_retarget::smooth::smooth_closed;
use mouthpiece_retarget::{ShapeSmoothing, Vec3};
use serde_json::Value;

fn fixtures() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/reference/smoothing_fixtures.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn points(v: &Value) -> Vec<Vec3> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let a: Vec<f64> = p
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            Vec3::new(a[0], a[1], a[2])
        })
        .collect()
}

fn assert_close(got: &[Vec3], expected: &[Vec3], what: &str) {
    assert_eq!(got.len(), expected.len(), "{what}: length");
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        assert!((g - e).norm() < 1e-12, "{what}[{i}]: {g:?} vs scipy {e:?}");
    }
}

#[test]
fn savitzky_golay_matches_scipy_savgol_filter_wrap() {
    let f = fixtures();
    let cases = f["cases"].as_array().unwrap();
    assert!(cases.len() >= 4);
    for (i, case) in cases.iter().enumerate() {
        let mut out = Vec::new();
        smooth_closed(
            &points(&case["points"]),
            &ShapeSmoothing::SavitzkyGolay5,
            &mut out,
        );
        assert_close(&out, &points(&case["sg5"]), &format!("case {i} sg5"));
    }
}

#[test]
fn closed_bspline_matches_scipy_bspline() {
    let f = fixtures();
    for (i, case) in f["cases"].as_array().unwrap().iter().enumerate() {
        let samples = case["samples_per_span"].as_u64().unwrap() as usize;
        let mut out = Vec::new();
        smooth_closed(
            &points(&case["points"]),
            &ShapeSmoothing::BSpline {
                samples_per_span: samples,
            },
            &mut out,
        );
        assert_close(
            &out,
            &points(&case["bspline"]),
            &format!("case {i} bspline"),
        );
    }
}

/// The head's turn (`head::slerp`) against scipy's `Slerp` (tests/reference/slerp_reference.py)
/// on random quaternion pairs, including nearly equal and nearly opposite ones: the same
/// rotations to 1e-12.
#[test]
fn head_slerp_agrees_with_scipy() {
    use mouthpiece_retarget::head::{slerp, Quat};
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(2);
    let random_quat = |rng: &mut rand::rngs::StdRng| {
        let q = nalgebra::Quaternion::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        Quat::new_normalize(q)
    };
    let mut pairs = Vec::new();
    for i in 0..200 {
        let a = random_quat(&mut rng);
        let b = match i % 4 {
            // Nearly the same rotation.
            0 => a * Quat::from_scaled_axis(nalgebra::Vector3::new(1e-4, -2e-4, 3e-5)),
            // Nearly half a turn apart.
            1 => a * Quat::from_scaled_axis(nalgebra::Vector3::new(0.0, 3.1, 0.0)),
            _ => random_quat(&mut rng),
        };
        pairs.push((a, b));
    }
    let s: Vec<f64> = vec![0.0, 0.1, 1.0 / 3.0, 0.5, 2.0 / 3.0, 0.9, 1.0];
    let wxyz = |q: &Quat| [q.w, q.i, q.j, q.k];
    let input = serde_json::json!({
        "pairs": pairs.iter().map(|(a, b)| [wxyz(a), wxyz(b)]).collect::<Vec<_>>(),
        "s": s,
    });
    let python = std::env::var("MOUTHPIECE_PYTHON").unwrap_or_else(|_| {
        let venv = concat!(env!("CARGO_MANIFEST_DIR"), "/../../target/py/bin/python");
        if std::path::Path::new(venv).exists() {
            venv.into()
        } else {
            "python3".into()
        }
    });
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/reference/slerp_reference.py"
    );
    let mut child = std::process::Command::new(&python)
        .arg(script)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{python} (with scipy, from scripts/test): {e}"));
    std::io::Write::write_all(child.stdin.as_mut().unwrap(), input.to_string().as_bytes()).unwrap();
    drop(child.stdin.take());
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "slerp_reference.py failed");
    let reference: Value = serde_json::from_slice(&out.stdout).unwrap();
    let mut worst = 0.0f64;
    for ((a, b), expected) in pairs.iter().zip(reference["results"].as_array().unwrap()) {
        for (&si, e) in s.iter().zip(expected.as_array().unwrap()) {
            let e: Vec<f64> = e
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            let got = wxyz(&slerp(a, b, si));
            let same: f64 = (0..4).map(|k| (got[k] - e[k]).abs()).fold(0.0, f64::max);
            let opposite: f64 = (0..4).map(|k| (got[k] + e[k]).abs()).fold(0.0, f64::max);
            worst = worst.max(same.min(opposite));
        }
    }
    assert!(worst <= 1e-12, "largest difference from scipy: {worst:e}");
}
