//! The evaluation's KL divergence against scipy (tests/reference/bind_kl_fixtures.py).

use mouthpiece_bind::eval::kl_divergence;

#[test]
fn kl_matches_scipy_entropy_on_the_fixtures() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/reference/bind_kl_fixtures.json"
    ))
    .unwrap();
    let fixtures: serde_json::Value = serde_json::from_str(&text).unwrap();
    let cases = fixtures["cases"].as_array().unwrap();
    assert!(cases.len() >= 20);
    for (i, case) in cases.iter().enumerate() {
        let row = |k: &str| -> Vec<f64> {
            case[k]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect()
        };
        let (p, q) = (row("p"), row("q"));
        let want = case["kl"].as_f64().unwrap();
        let got = kl_divergence(&p, &q);
        assert!(
            (got - want).abs() <= 1e-12 * want.abs().max(1.0),
            "case {i}: {got} vs scipy {want}"
        );
    }
}
