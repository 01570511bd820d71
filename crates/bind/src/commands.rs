//! What `mouthpiece bind`, `bind head`, `bind train` and `bind evaluate` do, with their
//! inputs checked: the character that can be bound, the network to bind with, the counts
//! and seeds training and evaluation accept.

use std::path::{Path, PathBuf};

use mouthpiece_export::MouthRig;

use crate::network::Widths;
use crate::training::{self, TrainOptions, HELD_OUT_SEED};
use crate::{BindError, Mesh, Network};

/// Largest network weights file read (the `paper` network is 650 kB).
pub const MAX_MODEL_BYTES: u64 = 64 * 1024 * 1024;

/// Most procedural heads `bind train` and `bind evaluate` build (each takes seconds and
/// megabytes; the shipped network was trained on 16).
pub const MAX_HEADS: usize = 1000;

/// Network weights from a file (from `bind train`), or the shipped network.
pub fn load_network(model: Option<&Path>) -> Result<Network, BindError> {
    match model {
        Some(path) => {
            let bytes =
                mouthpiece_export::asset::read_bounded(path, MAX_MODEL_BYTES).map_err(|cause| {
                    BindError::ReadModel {
                        path: path.to_path_buf(),
                        cause,
                    }
                })?;
            Network::from_bytes(&bytes, path)
        }
        None => crate::shipped_network(),
    }
}

/// A character that can be bound: the twelve points P1…P12 and a mouth of positive width
/// (errors name the file).
pub fn load_rig(path: &Path) -> Result<MouthRig, BindError> {
    let rig = MouthRig::load_character(path)?;
    if rig.points().len() != crate::procedural::POINTS {
        return Err(BindError::NotTwelvePoints {
            path: path.to_path_buf(),
            points: rig.points().len(),
        });
    }
    let width = rig.mouth_width();
    if !(width.is_finite() && width > 0.0) {
        return Err(BindError::NoMouthWidth {
            path: path.to_path_buf(),
            width,
        });
    }
    Ok(rig)
}

fn check_heads(heads: usize) -> Result<(), BindError> {
    if heads > MAX_HEADS {
        return Err(BindError::TooManyHeads {
            heads,
            max: MAX_HEADS,
        });
    }
    Ok(())
}

/// `bind head`: a procedural head around the character's mouth, written as a GLB.
pub fn write_head(
    character: &Path,
    model_up: crate::ModelUp,
    snout: f64,
    resolution: usize,
    out: &Path,
) -> Result<Mesh, BindError> {
    let rig = load_rig(character)?;
    let mesh = crate::character_head(&rig, model_up, snout, resolution)?;
    let name = rig.character().unwrap_or("head").to_owned();
    crate::gltf_io::write_plain_glb(out, &mesh, &name)?;
    Ok(mesh)
}

/// What `bind train` trains.
pub struct TrainRequest {
    pub out: PathBuf,
    pub seed: u64,
    pub heads: usize,
    pub epochs: usize,
    pub rate: f32,
    pub widths: Widths,
}

/// `bind train`: trains on `heads` procedural heads and writes the weights; `progress`
/// hears what to report as it goes.
pub fn train(req: &TrainRequest, mut progress: impl FnMut(String)) -> Result<Network, BindError> {
    if req.seed == HELD_OUT_SEED {
        return Err(BindError::HeldOutSeed {
            seed: HELD_OUT_SEED,
        });
    }
    if !(req.rate > 0.0 && req.rate.is_finite()) {
        return Err(BindError::Rate);
    }
    check_heads(req.heads)?;
    let start = std::time::Instant::now();
    let cases = training::random_cases("train", req.heads, req.seed);
    let vertices: usize = cases.iter().map(|c| c.head.mesh.len()).sum();
    progress(format!(
        "{} training heads, {vertices} vertices, references in {:.1} s",
        cases.len(),
        start.elapsed().as_secs_f64()
    ));
    let options = TrainOptions {
        widths: req.widths,
        seed: req.seed,
        epochs: req.epochs,
        rate: req.rate,
    };
    let net = training::train(&cases, options, |epoch, loss| {
        if epoch % 10 == 0 || epoch + 1 == req.epochs {
            progress(format!(
                "epoch {epoch}: mean KL {loss:.4} ({:.0} s)",
                start.elapsed().as_secs_f64()
            ));
        }
    })?;
    net.save(&req.out)?;
    Ok(net)
}

/// `bind evaluate`: the network against the baselines on `heads` held-out random heads and
/// on the given characters' heads (each with its snout); the Markdown table.
pub fn evaluate(
    model: Option<&Path>,
    heads: usize,
    characters: &[PathBuf],
    snouts: &[f64],
) -> Result<String, BindError> {
    if characters.len() != snouts.len() {
        return Err(BindError::SnoutCount {
            characters: characters.len(),
            snouts: snouts.len(),
        });
    }
    check_heads(heads)?;
    for (k, &snout) in snouts.iter().enumerate() {
        if !(0.0..=1.0).contains(&snout) {
            return Err(BindError::Snout {
                number: k + 1,
                snout,
            });
        }
    }
    let network = load_network(model)?;
    let mut held_out = Vec::new();
    for (path, &snout) in characters.iter().zip(snouts) {
        let rig = load_rig(path)?;
        let w = rig.mouth_width();
        let points = std::array::from_fn(|k| rig.points()[k].rest.map(|c| c / w));
        let name = rig.character().unwrap_or("character").to_owned();
        held_out.push((name, points, snout));
    }
    let mut cases = training::random_cases("held-out ", heads, HELD_OUT_SEED);
    cases.extend(training::character_cases(&held_out));
    let rows = training::evaluate(&cases, &network);
    Ok(training::table(&rows))
}
