//! Per-class acoustic profiles: the mean and variance of each feature over the frames of a
//! class, learned from speech whose phone timing is known, and the nearest profile per frame
//! (a diagonal-Gaussian log likelihood: each feature weighed by its spread in the class).

use serde::{Deserialize, Serialize};

use super::features::{Feature, FEATURES};
use crate::input::cut;
use crate::{ClassTable, Error};

/// Largest profile file read.
pub const MAX_PROFILE_BYTES: usize = 4 << 20;
/// Version of the profile file format.
pub const PROFILE_VERSION: u32 = 1;
/// Smallest variance kept (a feature constant over a class would otherwise dominate).
const MIN_VAR: f64 = 1e-4;

/// One class's profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassProfile {
    /// Class name (from the class table).
    pub name: String,
    /// Frames it was learned from.
    pub frames: u64,
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
}

/// The profiles of a class table's classes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profiles {
    pub version: u32,
    /// What the profiles were learned from (free text, shown in docs and logs).
    pub learned_on: String,
    #[serde(rename = "class")]
    pub classes: Vec<ClassProfile>,
}

/// Profiles bound to a class table: per class index, its profile and log prior.
#[derive(Debug, Clone)]
pub struct Bound {
    /// Per class of the table, or `None` for a class never seen.
    models: Vec<Option<Model>>,
}

/// One class's profile ready to score: mean, 1/var, constant term (log prior − ½ Σ ln var).
type Model = ([f64; FEATURES], [f64; FEATURES], f64);

impl Profiles {
    /// Parses and checks a profile file; `source_name` names it in errors.
    pub fn from_toml_str(text: &str, source_name: &str) -> Result<Self, Error> {
        let bad = |what: String| Error::Setting {
            what: format!("{source_name}: {what}"),
        };
        if text.len() > MAX_PROFILE_BYTES {
            return Err(bad(format!(
                "the profile file is {} bytes, more than {MAX_PROFILE_BYTES}",
                text.len()
            )));
        }
        let p: Profiles = toml::from_str(text).map_err(|e| bad(cut(&e.to_string())))?;
        if p.version != PROFILE_VERSION {
            return Err(bad(format!(
                "version {} is not {PROFILE_VERSION}, the one this build reads",
                p.version
            )));
        }
        for c in &p.classes {
            if c.mean.len() != FEATURES || c.var.len() != FEATURES {
                return Err(bad(format!(
                    "class {}: mean and var must hold {FEATURES} numbers each, got {} and {}",
                    cut(&c.name),
                    c.mean.len(),
                    c.var.len()
                )));
            }
            if c.mean.iter().any(|v| !v.is_finite() || v.abs() > 1e6)
                || c.var
                    .iter()
                    .any(|v| !v.is_finite() || *v <= 0.0 || *v > 1e6)
            {
                return Err(bad(format!(
                    "class {}: means must be finite and variances finite and positive (at most 1e6)",
                    cut(&c.name)
                )));
            }
        }
        Ok(p)
    }

    /// Writes the profiles as TOML with a comment header.
    pub fn to_toml_string(&self, header: &str) -> String {
        let mut s = String::new();
        for line in header.lines() {
            s.push_str("# ");
            s.push_str(line);
            s.push('\n');
        }
        s.push('\n');
        s.push_str(&toml::to_string(self).unwrap_or_default());
        s
    }

    /// Binds the profiles to a class table; a profile naming a class the table lacks is an
    /// error.
    pub fn bind(&self, table: &ClassTable, source_name: &str) -> Result<Bound, Error> {
        let total: u64 = self.classes.iter().map(|c| c.frames).sum::<u64>().max(1);
        let mut models = vec![None; table.len()];
        for c in &self.classes {
            let Some(k) = table.classes.iter().position(|tc| tc.name == c.name) else {
                return Err(Error::Setting {
                    what: format!(
                        "{source_name}: class {} is not in the class table",
                        cut(&c.name)
                    ),
                });
            };
            let mut mean = [0.0; FEATURES];
            let mut inv = [0.0; FEATURES];
            let mut constant = (c.frames.max(1) as f64 / total as f64).ln();
            for i in 0..FEATURES {
                mean[i] = c.mean[i];
                let v = c.var[i].max(MIN_VAR);
                inv[i] = 1.0 / v;
                constant -= 0.5 * v.ln();
            }
            models[k] = Some((mean, inv, constant));
        }
        Ok(Bound { models })
    }

    /// Learns profiles from labelled features: `(feature, class index)` pairs. Classes with
    /// fewer than `min_frames` frames get no profile (the analyser never picks them).
    pub fn learn(
        table: &ClassTable,
        labelled: &[(Feature, usize)],
        min_frames: u64,
        learned_on: &str,
    ) -> Self {
        let k = table.len();
        let mut n = vec![0u64; k];
        let mut sum = vec![[0.0; FEATURES]; k];
        let mut sq = vec![[0.0; FEATURES]; k];
        for (f, c) in labelled {
            n[*c] += 1;
            for i in 0..FEATURES {
                sum[*c][i] += f.x[i];
                sq[*c][i] += f.x[i] * f.x[i];
            }
        }
        let classes = (0..k)
            .filter(|&c| n[c] >= min_frames.max(2))
            .map(|c| {
                let m: Vec<f64> = sum[c].iter().map(|s| s / n[c] as f64).collect();
                let v = sq[c]
                    .iter()
                    .zip(&m)
                    .map(|(s, m)| (s / n[c] as f64 - m * m).max(MIN_VAR))
                    .collect();
                ClassProfile {
                    name: table.classes[c].name.clone(),
                    frames: n[c],
                    mean: m.iter().map(|v| round(*v)).collect(),
                    var: v_round(v),
                }
            })
            .collect();
        Profiles {
            version: PROFILE_VERSION,
            learned_on: learned_on.to_string(),
            classes,
        }
    }
}

fn round(v: f64) -> f64 {
    (v * 1e5).round() / 1e5
}

fn v_round(v: Vec<f64>) -> Vec<f64> {
    v.into_iter().map(|x| round(x).max(MIN_VAR)).collect()
}

impl Bound {
    /// Log likelihood of `x` under each class's profile (`-inf` for a class without one).
    pub fn scores(&self, x: &[f64; FEATURES], out: &mut [f64]) {
        for (o, m) in out.iter_mut().zip(&self.models) {
            *o = match m {
                Some((mean, inv, constant)) => {
                    let mut d2 = 0.0;
                    for i in 0..FEATURES {
                        let d = x[i] - mean[i];
                        d2 += d * d * inv[i];
                    }
                    constant - 0.5 * d2
                }
                None => f64::NEG_INFINITY,
            };
        }
    }

    /// Whether a class has a profile.
    pub fn has(&self, class: usize) -> bool {
        self.models.get(class).is_some_and(|m| m.is_some())
    }
}
