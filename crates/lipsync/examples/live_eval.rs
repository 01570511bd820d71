//! The live analyser measured on Festival speech (docs/lipsync.md, "Live"):
//!
//! ```text
//! cargo run --release -p mouthpiece-lipsync --example live_eval            # the table
//! cargo run --release -p mouthpiece-lipsync --example live_eval -- --write # + rewrite the profiles
//! cargo run --release -p mouthpiece-lipsync --example live_eval -- --tune  # settings on held-out learning lines
//! ```
//!
//! Learns profiles from the learning sentences (never the evaluation ones), then runs the
//! eight evaluation sentences through the analyser at 16 kHz and, upsampled, at 48 kHz in
//! 10 ms blocks, and prints the measures and the processing time per second of sound.

#[path = "../tests/festival/mod.rs"]
mod festival;

use festival::*;
use mouthpiece_lipsync::live::{LiveSettings, Profiles};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = tempfile::tempdir().unwrap();
    let table = table();
    let learning: Vec<Spoken> = LEARNING
        .iter()
        .enumerate()
        .map(|(i, t)| speak(t, dir.path(), &format!("l{i}")))
        .collect();
    if args.iter().any(|a| a == "--tune") {
        let (fit, held) = learning.split_at(30);
        let profiles = learn(&table, fit, "tuning");
        for score_tau in [0.0, 0.005, 0.01] {
            for mouth in [0.002, 0.003, 0.005, 0.007, 0.010] {
                let settings = LiveSettings {
                    score_tau_s: score_tau,
                    mouth_tau_s: mouth,
                    ..LiveSettings::default()
                };
                let mut m = Measures::default();
                for line in held {
                    let mut a = analyser(&profiles, settings);
                    let (steps, _) = analyse(&mut a, &line.samples, line.rate, 160);
                    measure(&table, &line.phones, &steps, &mut m);
                }
                println!(
                    "score_tau {score_tau:.3} mouth_tau {mouth:.3}: class {:.1} % shape {:.1} % boundary median {:.1} ms onset lag median {:.1} p95 {:.1} ms, + mouth halfway {:.1} ms",
                    100.0 * m.class_share(),
                    100.0 * m.shape_share(),
                    1e3 * m.boundary(0.5),
                    1e3 * m.lag(0.5),
                    1e3 * m.lag(0.95),
                    1e3 * (m.lag(0.95) + mouth * std::f64::consts::LN_2),
                );
            }
        }
        return;
    }
    let learned_on = format!(
        "{} Harvard sentences spoken by Festival (kal_diphone, 16 kHz) with its own phone \
         timing; none of the evaluation sentences",
        LEARNING.len()
    );
    let profiles = learn(&table, &learning, &learned_on);
    if args.iter().any(|a| a == "--write") {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/lipsync/live_profiles.toml"
        );
        std::fs::write(
            path,
            profiles.to_toml_string(
                "Live lip-sync profiles: per class, the mean and variance of the live analyser's\n\
                 features (12 MFCCs, their 20 ms deltas, the level; crates/lipsync/src/live).\n\
                 Written by `cargo run --release -p mouthpiece-lipsync --example live_eval -- --write`;\n\
                 checked by `cargo test -p mouthpiece-lipsync --test integration live::shipped_profiles`.",
            ),
        )
        .unwrap();
        println!("wrote {path}");
    }
    let shipped =
        Profiles::from_toml_str(mouthpiece_lipsync::live::SHIPPED_PROFILES, "shipped").unwrap();
    let lines: Vec<(&str, Spoken)> = EVALUATION
        .iter()
        .map(|(n, t)| (*n, speak(t, dir.path(), n)))
        .collect();
    let mut latency = Vec::new();
    println!("| rate | block | sentences | boundary median | boundary p90 | runs matched | class | shape class | processing per second of sound | p95 per block |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (rate, factor, block) in [
        (16_000u32, 1usize, 160usize),
        (48_000, 3, 480),
        (48_000, 3, 960),
    ] {
        let mut m = Measures::default();
        let (mut busy, mut sound, mut per_block) = (0.0, 0.0, Vec::new());
        for (_, line) in &lines {
            let samples = upsample(&line.samples, factor);
            let mut a = analyser(&shipped, LiveSettings::default());
            let (steps, times) = analyse(&mut a, &samples, rate, block);
            busy += times.iter().sum::<f64>();
            per_block.extend(times);
            sound += samples.len() as f64 / f64::from(rate);
            measure(&table, &line.phones, &steps, &mut m);
        }
        per_block.sort_by(f64::total_cmp);
        let p95 = per_block[(0.95 * (per_block.len() - 1) as f64).round() as usize];
        // Sound → points: the analyser's onset lag (stream time), plus the wait for the block
        // holding that sample (at most one block), plus processing, plus the mouth's move to
        // halfway toward the new class (τ ln 2).
        let block_s = block as f64 / f64::from(rate);
        let halfway = LiveSettings::default().mouth_tau_s * std::f64::consts::LN_2;
        latency.push(format!(
            "| {} kHz | {:.0} ms | {:.1} ms | {:.1} ms | {:.1} ms | {:.1} ms |",
            rate / 1000,
            1e3 * block_s,
            1e3 * m.lag(0.5),
            1e3 * m.lag(0.95),
            1e3 * (block_s + p95 + halfway),
            1e3 * (m.lag(0.95) + block_s + p95 + halfway),
        ));
        println!(
            "| {} kHz | {:.0} ms | {} | {:.1} ms | {:.1} ms | {:.0} % | {:.1} % | {:.1} % | {:.2} % of a core | {:.0} µs |",
            rate / 1000,
            1e3 * block as f64 / f64::from(rate),
            lines.len(),
            1e3 * m.boundary(0.5),
            1e3 * m.boundary(0.9),
            100.0 * m.matched_share(),
            100.0 * m.class_share(),
            100.0 * m.shape_share(),
            100.0 * busy / sound,
            1e6 * p95,
        );
    }
    println!();
    println!("| rate | block | onset lag median | onset lag p95 | block + processing p95 + mouth halfway | sound → points p95 |");
    println!("|---|---|---|---|---|---|");
    for l in latency {
        println!("{l}");
    }
}
