//! Continuity of the stitched curves, measured on the shipped classes and generated segments
//! sampled at 10 kHz (docs/lipsync.md, "Continuity, measured").

use mouthpiece_lipsync::{weights_for_phones, ClassTable, PhoneSpan, SegmentTable, Weights};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const CLASSES: &str = include_str!("../../../../config/lipsync/classes.toml");
const FPS: f64 = 10_000.0;
const T: f64 = 0.04;

fn phones(table: &ClassTable, seed: u64, short: bool) -> Vec<PhoneSpan> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut t = 0.0;
    (0..200)
        .map(|i| {
            // Short phones 10–30 ms (overlaps of 10–30 ms), long ones 50–200 ms.
            let d = if short && rng.random_bool(0.3) {
                rng.random_range(0.010..0.030)
            } else {
                rng.random_range(0.050..0.200)
            };
            let c = &table.classes[rng.random_range(0..table.len())];
            let p = PhoneSpan {
                start: t,
                end: t + d,
                phone: c.phones[0].clone(),
                line: i + 1,
            };
            t += d;
            p
        })
        .collect()
}

/// (largest step between samples, largest change of slope between sample steps).
fn steps(w: &Weights) -> (f64, f64) {
    let (mut step, mut kink) = (0.0f64, 0.0f64);
    for k in 1..w.len() - 1 {
        for p in 0..w.poses {
            let (a, b, c) = (w.sample(k - 1)[p], w.sample(k)[p], w.sample(k + 1)[p]);
            step = step.max((b - a).abs());
            kink = kink.max(((c - b) - (b - a)).abs() * FPS);
        }
    }
    (step, kink)
}

#[test]
fn stitched_curves_are_c0_everywhere_and_c1_without_short_phones() {
    let table = ClassTable::from_toml_str(CLASSES, "classes.toml").unwrap();
    let segs = SegmentTable::generate(&table);
    let dt = 1.0 / FPS;
    // Largest slope of a change stage: 1.5 / T (a smoothstep over a weight change ≤ 1); the
    // largest second derivative: 6 / T².
    let (slope_bound, curvature_bound) = (1.5 / T, 6.0 / (T * T));

    let long = phones(&table, 1, false);
    let w = weights_for_phones(&long, "long", &table, &segs, T, FPS).unwrap();
    let (step, kink) = steps(&w);
    eprintln!("long phones only: largest step {step:.2e}, largest slope change {kink:.3} /s");
    assert!(step <= slope_bound * dt * 1.001, "C0: step {step}");
    // C1: the slope changes by at most the curvature bound × dt between sample steps.
    assert!(
        kink <= curvature_bound * dt * 1.01,
        "C1: slope change {kink}"
    );

    let mixed = phones(&table, 2, true);
    let w = weights_for_phones(&mixed, "mixed", &table, &segs, T, FPS).unwrap();
    let (step, kink) = steps(&w);
    eprintln!("with short phones: largest step {step:.2e}, largest slope change {kink:.3} /s");
    // C0: overlaps are ≥ 10 ms, so the blend adds at most 1 / 10 ms to the slope.
    assert!(
        step <= (slope_bound + 100.0) * dt * 1.001,
        "C0: step {step}"
    );
    // Not C1 (nor G1): at the start of a blend the slope jumps by r′ (cᵢ − c).
    assert!(
        kink > 10.0 * curvature_bound * dt,
        "expected slope jumps at blends, largest {kink}"
    );
}
