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
