//! Data sets of procedural heads, training the network, and the evaluation table.

use std::fmt::Write as _;

use rand::SeedableRng;

use crate::eval::{deformation_error, mean_kl, DeformationError};
use crate::network::{target, Adam, Graph, Network, Widths};
use crate::procedural::{Head, HeadParams, MouthState, POINTS};
use crate::reference::{fit_states, reference_weights};
use crate::weights::{distance_weights, heat_weights, joint_distances, Weights};
use crate::BindError;

/// The held-out heads' seed: `bind train` refuses it, `bind evaluate` draws from it.
pub const HELD_OUT_SEED: u64 = 1_319_952;

/// `bind train`'s defaults, with which the shipped network was trained (`--seed 1`).
pub const DEFAULT_HEADS: usize = 16;
pub const DEFAULT_EPOCHS: usize = 150;
pub const DEFAULT_RATE: f32 = 3e-3;

/// Random mouth states the evaluation measures over (a seed of their own, not the fit's).
pub const EVAL_STATES: usize = 60;

/// One procedural head with what training and evaluation need.
#[derive(Clone, Debug)]
pub struct Case {
    pub name: String,
    pub head: Head,
    pub graph: Graph,
    pub reference: Weights,
}

impl Case {
    pub fn new(name: String, params: &HeadParams) -> Self {
        let head = params.build();
        let graph = Graph::new(&head.mesh, &head.params.points);
        let reference = reference_weights(&head, &fit_states());
        Self {
            name,
            head,
            graph,
            reference,
        }
    }
}

/// `count` random heads from `seed` (training and held-out sets use different seeds, so
/// whole characters are held out).
pub fn random_cases(prefix: &str, count: usize, seed: u64) -> Vec<Case> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|i| Case::new(format!("{prefix}{i}"), &HeadParams::random(&mut rng)))
        .collect()
}

/// Training options.
#[derive(Clone, Copy, Debug)]
pub struct TrainOptions {
    pub widths: Widths,
    pub seed: u64,
    pub epochs: usize,
    pub rate: f32,
}

/// Trains a network on the cases: one Adam step per case, cases shuffled each epoch, the
/// rate halved for the last third. `progress(epoch, mean loss)` after each epoch.
pub fn train(
    cases: &[Case],
    options: TrainOptions,
    progress: impl FnMut(usize, f64),
) -> Result<Network, BindError> {
    train_prefix(cases, options, options.epochs, progress)
}

/// The first `run` epochs of [`train`] with `options` (the same schedule: the rate halves
/// at two thirds of `options.epochs`), so a test can check a run's deterministic start.
pub fn train_prefix(
    cases: &[Case],
    options: TrainOptions,
    run: usize,
    mut progress: impl FnMut(usize, f64),
) -> Result<Network, BindError> {
    if cases.is_empty() || options.epochs == 0 {
        return Err(BindError::BadArgument(
            "training needs at least one head and one epoch".into(),
        ));
    }
    let mut net = Network::new(options.widths, options.seed);
    let targets: Vec<_> = cases.iter().map(|c| target(&c.reference)).collect();
    let mut adam = Adam::new(&net, options.rate);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(options.seed ^ 0x7a11);
    let mut order: Vec<usize> = (0..cases.len()).collect();
    for epoch in 0..options.epochs.min(run) {
        if epoch == 2 * options.epochs / 3 {
            adam = Adam::new(&net, options.rate / 2.0);
        }
        use rand::seq::SliceRandom;
        order.shuffle(&mut rng);
        let mut total = 0.0;
        for &i in &order {
            total += adam.step(&mut net, &cases[i].graph, &targets[i]);
        }
        progress(epoch, total / cases.len() as f64);
    }
    Ok(net)
}

/// The three binders' weights for a case (each limited to four influences).
pub fn method_weights(case: &Case, network: &Network) -> [(&'static str, Weights); 3] {
    let points = case.head.params.points.map(nalgebra::Vector3::from);
    let d = joint_distances(&case.head.mesh, &points);
    let mut out = [
        ("network", network.predict(&case.graph)),
        ("heat", heat_weights(&case.head.mesh, &d, 1.0)),
        ("distance", distance_weights(&d, 1.0)),
    ];
    for (_, w) in &mut out {
        w.limit_influences();
    }
    out
}

/// One method's scores on one case.
#[derive(Clone, Copy, Debug)]
pub struct Score {
    pub kl: f64,
    pub error: DeformationError,
}

/// Scores of the network and both baselines (and the reference itself, the floor) on each
/// held-out case: rows `(case, [(method, score)])`.
pub fn evaluate(cases: &[Case], network: &Network) -> Vec<(String, Vec<(&'static str, Score)>)> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xe7a1);
    let states = MouthState::set(EVAL_STATES, &mut rng);
    cases
        .iter()
        .map(|case| {
            let mut scores = Vec::new();
            for (name, w) in method_weights(case, network) {
                scores.push((
                    name,
                    Score {
                        kl: mean_kl(&case.reference, &w),
                        error: deformation_error(&case.head, &w, &states),
                    },
                ));
            }
            scores.push((
                "reference",
                Score {
                    kl: 0.0,
                    error: deformation_error(&case.head, &case.reference, &states),
                },
            ));
            (case.name.clone(), scores)
        })
        .collect()
}

/// The evaluation as a Markdown table: per case, then the mean over cases.
pub fn table(rows: &[(String, Vec<(&'static str, Score)>)]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "| held-out head | method | KL to reference (nats) | RMS error (% mouth width) | max error (% mouth width) |"
    );
    let _ = writeln!(out, "|---|---|---:|---:|---:|");
    let methods: Vec<&str> = rows
        .first()
        .map(|r| r.1.iter().map(|s| s.0).collect())
        .unwrap_or_default();
    for (case, scores) in rows {
        for (m, s) in scores {
            let _ = writeln!(
                out,
                "| {case} | {m} | {:.3} | {:.2} | {:.2} |",
                s.kl, s.error.rms, s.error.max
            );
        }
    }
    for m in methods {
        let picked: Vec<&Score> = rows
            .iter()
            .flat_map(|r| r.1.iter().filter(|s| s.0 == m).map(|s| &s.1))
            .collect();
        let n = picked.len().max(1) as f64;
        let _ = writeln!(
            out,
            "| **mean** | **{m}** | {:.3} | {:.2} | {:.2} |",
            picked.iter().map(|s| s.kl).sum::<f64>() / n,
            picked.iter().map(|s| s.error.rms).sum::<f64>() / n,
            picked.iter().map(|s| s.error.max).fold(0.0, f64::max),
        );
    }
    out
}

/// Held-out heads around given mouths (the characters' own), mouth-width units.
pub fn character_cases(characters: &[(String, [[f64; 3]; POINTS], f64)]) -> Vec<Case> {
    characters
        .iter()
        .map(|(name, points, snout)| {
            Case::new(name.clone(), &HeadParams::around_points(*points, *snout, 3))
        })
        .collect()
}
