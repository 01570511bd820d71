//! Proposing classes from the sampled blobs: hue clusters, the lip and forehead choice, each
//! class's ranges, and the `[detect]` snippet.

use std::fmt::Write as _;

use super::check::{dots_found, CheckedProposal, DotsFound};
use super::hue::{
    circular_mean, hue_diff, hue_ranges, hue_set, median_f64, median_u8, percentile_u8,
    set_to_ranges,
};
use super::sampling::{ColourSampler, SampledBlob};
use crate::{ColorClass, DetectConfig, DetectError, DotRole};

impl ColourSampler {
    /// [`propose`](Self::propose), then the detector with `in_use` (the ranges the tracker
    /// runs with now) and with the proposal, on the sampled frames: the dots each finds.
    pub fn propose_checked(&self, in_use: &DetectConfig) -> Result<CheckedProposal, DetectError> {
        let (lip, forehead) = (self.options.lip_dots, self.options.forehead_dots);
        let proposal = self.propose();
        let in_use_found = dots_found(&self.kept, in_use, lip, forehead)?;
        let proposed = if proposal.classes.is_empty() {
            DotsFound {
                frames: in_use_found.frames,
                expected: in_use_found.expected,
                ..DotsFound::default()
            }
        } else {
            dots_found(&self.kept, &proposal.detect_config(in_use), lip, forehead)?
        };
        Ok(CheckedProposal {
            proposal,
            in_use: in_use_found,
            proposed,
        })
    }

    /// Frames kept to check a proposal on.
    pub fn check_frames(&self) -> usize {
        self.kept.len()
    }

    /// Clusters the blobs into paints and proposes a class for each dot role found.
    pub fn propose(&self) -> Proposal {
        let opts = &self.options;
        let frames = self.frames.max(1);
        let clusters = self.clusters();
        let mut warnings = Vec::new();

        // Persistent clusters: seen in at least two frames out of three.
        let (cands, others): (Vec<Cluster>, Vec<Cluster>) = clusters
            .into_iter()
            .partition(|c| c.frames_present * 3 >= frames * 2 && c.per_frame >= 1.0);
        let (l, f) = (opts.lip_dots as f64, opts.forehead_dots as f64);
        let mut chosen: Vec<(Cluster, DotRole)> = Vec::new();
        let mut unused = others;
        if opts.classes == Some(2) && cands.len() == 1 {
            warnings.push("two paint colours were asked for but only one was found".into());
        }
        match cands.len() {
            0 => {}
            n if opts.classes == Some(1) => {
                // The most persistent colour paints every dot.
                let mut cands = cands;
                cands.sort_by_key(|c| std::cmp::Reverse(c.blobs.len()));
                if n > 1 {
                    warnings.push(format!(
                        "one paint colour was asked for but {n} were seen; the most frequent is proposed"
                    ));
                }
                let mut it = cands.into_iter();
                chosen.push((it.next().expect("one"), DotRole::Any));
                unused.extend(it);
            }
            1 => {
                let c = cands.into_iter().next().expect("one");
                let n = c.per_frame;
                if (n - (l + f)).abs() <= (n - l).abs() {
                    warnings.push(format!(
                        "one paint colour only ({n:.0} blobs per frame): proposed as role \"any\"; the tracker tells lips from forehead by geometry"
                    ));
                    chosen.push((c, DotRole::Any));
                } else {
                    warnings.push(format!(
                        "one paint colour only ({n:.0} blobs per frame, {} lip and {} forehead dots expected): no forehead colour found",
                        opts.lip_dots, opts.forehead_dots
                    ));
                    chosen.push((c, DotRole::Lip));
                }
            }
            _ => {
                // Best (lip, forehead) pair: counts near the layout, forehead above the lips.
                let score = |lip: &Cluster, fh: &Cluster| {
                    (lip.per_frame - l).abs() / l
                        + (fh.per_frame - f).abs() / f
                        + if fh.mean_y < lip.mean_y { 0.0 } else { 1.0 }
                };
                let mut pairs = Vec::new();
                for (i, a) in cands.iter().enumerate() {
                    for (j, b) in cands.iter().enumerate() {
                        if i != j {
                            pairs.push((score(a, b), i, j));
                        }
                    }
                }
                pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
                let (best, li, fi) = pairs[0];
                let lip = &cands[li];
                let fh = &cands[fi];
                if best > 0.5 {
                    warnings.push(format!(
                        "ambiguous: the best lip/forehead pair has {:.0} and {:.0} blobs per frame (expected {} and {}){}",
                        lip.per_frame,
                        fh.per_frame,
                        opts.lip_dots,
                        opts.forehead_dots,
                        if fh.mean_y < lip.mean_y { "" } else { ", and the forehead colour is not above the lip colour" }
                    ));
                }
                if let Some(&(second, _, _)) = pairs.iter().find(|p| (p.1, p.2) != (li, fi)) {
                    if cands.len() > 2 && second - best < 0.25 {
                        warnings.push(format!(
                            "ambiguous: {} persistent colours fit the layout almost equally well; check the hues below",
                            cands.len()
                        ));
                    }
                }
                for (k, c) in cands.into_iter().enumerate() {
                    if k == li {
                        chosen.push((c, DotRole::Lip));
                    } else if k == fi {
                        chosen.push((c, DotRole::Forehead));
                    } else {
                        unused.push(c);
                    }
                }
                chosen.sort_by_key(|(_, r)| *r != DotRole::Lip);
            }
        }
        if chosen.is_empty() {
            warnings.push(if self.blobs.is_empty() {
                format!(
                    "no saturated, compact colour blobs in {} frames: no paint colours found",
                    self.frames
                )
            } else {
                format!(
                    "no paint colour seen in at least two thirds of {} frames ({} blobs in all)",
                    self.frames,
                    self.blobs.len()
                )
            });
        }

        let mut classes: Vec<ProposedClass> = chosen
            .iter()
            .map(|(c, role)| self.class_from(c, *role, &mut warnings))
            .collect();
        // Neighbouring paints: no hue shared between two classes.
        separate_hues(&mut classes);
        unused.sort_by_key(|c| std::cmp::Reverse(c.blobs.len()));
        Proposal {
            classes,
            unused: unused
                .iter()
                .map(|c| ClusterSummary {
                    hue: c.centre,
                    blobs: c.blobs.len(),
                    frames_present: c.frames_present,
                    per_frame: c.per_frame,
                })
                .collect(),
            warnings,
            frames: self.frames,
            blobs: self.blobs.len(),
            performer_m: median_f64(&self.performer_m),
            saturation_threshold: median_u8(&self.thresholds),
        }
    }

    /// Blob clusters by hue: a circular histogram of blob hues, smoothed, split at valleys.
    fn clusters(&self) -> Vec<Cluster> {
        const SIGMA: f64 = 2.0;
        let mut hist = [0.0f64; 180];
        for b in &self.blobs {
            hist[(b.hue.round() as usize) % 180] += 1.0;
        }
        let mut smooth = [0.0f64; 180];
        for (i, s) in smooth.iter_mut().enumerate() {
            for k in -6i32..=6 {
                let j = (i as i32 + k).rem_euclid(180) as usize;
                *s += hist[j] * (-(k * k) as f64 / (2.0 * SIGMA * SIGMA)).exp();
            }
        }
        let at = |i: i32| smooth[i.rem_euclid(180) as usize];
        // Local maxima (plateaus: first bin), then merge neighbours without a real valley.
        let mut peaks: Vec<usize> = (0..180)
            .filter(|&i| {
                let i = i as i32;
                at(i) > 0.0 && at(i) > at(i - 1) && at(i) >= at(i + 1)
            })
            .collect();
        loop {
            if peaks.len() < 2 {
                break;
            }
            let mut merged = false;
            for k in 0..peaks.len() {
                let (a, b) = (peaks[k], peaks[(k + 1) % peaks.len()]);
                let span = (b + 180 - a) % 180;
                let valley = (0..=span)
                    .map(|d| smooth[(a + d) % 180])
                    .fold(f64::INFINITY, f64::min);
                if valley > 0.5 * smooth[a].min(smooth[b]) {
                    let drop = if smooth[a] >= smooth[b] { b } else { a };
                    peaks.retain(|&p| p != drop);
                    merged = true;
                    break;
                }
            }
            if !merged {
                break;
            }
        }
        if peaks.is_empty() {
            return Vec::new();
        }
        peaks.sort_unstable();
        // Each bin belongs to the peak whose region holds it: boundaries at the valleys.
        let mut owner = [usize::MAX; 180];
        for k in 0..peaks.len() {
            let a = peaks[k];
            let b = if peaks.len() == 1 {
                a + 180
            } else {
                let nb = peaks[(k + 1) % peaks.len()];
                if nb > a {
                    nb
                } else {
                    nb + 180
                }
            };
            let valley = (a..b)
                .min_by(|&x, &y| smooth[x % 180].total_cmp(&smooth[y % 180]))
                .unwrap_or(a);
            let next = (k + 1) % peaks.len();
            for d in a..b {
                owner[d % 180] = if d <= valley || peaks.len() == 1 {
                    k
                } else {
                    next
                };
            }
        }
        let frames = self.frames.max(1) as usize;
        let mut clusters = Vec::new();
        for (k, &peak) in peaks.iter().enumerate() {
            // Outliers far down the peak's flank belong to no paint.
            let members: Vec<(usize, &SampledBlob)> = self
                .blobs
                .iter()
                .enumerate()
                .filter(|(_, b)| {
                    let bin = (b.hue.round() as usize) % 180;
                    owner[bin] == k && smooth[bin] >= 0.05 * smooth[peak]
                })
                .collect();
            if members.is_empty() {
                continue;
            }
            let mut per_frame = vec![0u32; frames];
            for (_, b) in &members {
                per_frame[b.frame as usize] += 1;
            }
            let frames_present = per_frame.iter().filter(|&&n| n > 0).count() as u32;
            per_frame.sort_unstable();
            let centre = circular_mean(members.iter().map(|(_, b)| b.hue));
            let mean_y =
                members.iter().map(|(_, b)| b.center[1]).sum::<f64>() / members.len() as f64;
            clusters.push(Cluster {
                centre,
                per_frame: per_frame[frames / 2] as f64,
                frames_present,
                mean_y,
                blobs: members.iter().map(|(i, _)| *i).collect(),
            });
        }
        clusters.sort_by_key(|c| std::cmp::Reverse(c.blobs.len()));
        clusters
    }

    /// Lowest saturation at which the face (away from the blobs) shows at most one pixel in
    /// 5000 inside `hue`.
    fn face_saturation_limit(&self, hue: &[[u8; 2]]) -> u8 {
        let set = hue_set(hue);
        let budget = self.face_pixels / 5000;
        let mut count = 0;
        for s in (0..256).rev() {
            count += (0..180)
                .filter(|&h| set[h])
                .map(|h| self.face_hist[h * 256 + s])
                .sum::<u64>();
            if count > budget {
                return (s + 1).min(255) as u8;
            }
        }
        0
    }

    fn class_from(&self, c: &Cluster, role: DotRole, warnings: &mut Vec<String>) -> ProposedClass {
        let opts = &self.options;
        let mut dh: Vec<f64> = Vec::new();
        let mut sat = [0u64; 256];
        let mut val = [0u64; 256];
        for &i in &c.blobs {
            for p in &self.pixels[self.blobs[i].pixels.clone()] {
                dh.push(hue_diff(p[0] as f64, c.centre));
                sat[p[1] as usize] += 1;
                val[p[2] as usize] += 1;
            }
        }
        dh.sort_by(f64::total_cmp);
        let q = |v: &[f64], q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        // 2nd to 98th percentile, at most 20 hue units from the centre, plus the margin.
        let margin = opts.hue_margin as f64;
        let lo = (c.centre + q(&dh, 0.02).max(-20.0) - margin).floor() as i32;
        let hi = (c.centre + q(&dh, 0.98).min(20.0) + margin).ceil() as i32;
        let hue = hue_ranges(lo, hi);
        // Saturation: as low as the face allows in this hue (rim pixels count in the
        // detector's centre), but no lower than half the paint's low tail.
        let paint_lo = percentile_u8(&sat, 0.02);
        let face = self.face_saturation_limit(&hue).saturating_add(10);
        let s_lo = face.max(paint_lo / 2).max(opts.min_saturation);
        if s_lo > percentile_u8(&sat, 0.25) {
            warnings.push(format!(
                "hue {:.0}: the face is nearly as saturated as the paint in this hue (saturation floor {s_lo}, paint's lower quartile {}); dots may break up",
                c.centre,
                percentile_u8(&sat, 0.25)
            ));
        }
        let v_lo = percentile_u8(&val, 0.02)
            .saturating_sub(opts.value_margin)
            .max(opts.min_value);
        let name = match role {
            DotRole::Lip => "lip",
            DotRole::Forehead => "forehead",
            DotRole::Any => "dots",
        };
        ProposedClass {
            class: ColorClass {
                name: name.into(),
                role,
                hue,
                saturation: [s_lo, 255],
                value: [v_lo, 255],
            },
            hue_centre: c.centre,
            blobs: c.blobs.len(),
            frames_present: c.frames_present,
            per_frame: c.per_frame,
        }
    }
}

/// Removes hue shared by two classes, giving each side the half nearer its own centre.
pub(super) fn separate_hues(classes: &mut [ProposedClass]) {
    for a in 0..classes.len() {
        for b in a + 1..classes.len() {
            let sa = hue_set(&classes[a].class.hue);
            let sb = hue_set(&classes[b].class.hue);
            if !(0..180).any(|h| sa[h] && sb[h]) {
                continue;
            }
            let (ca, cb) = (classes[a].hue_centre, classes[b].hue_centre);
            let keep = |set: &[bool; 180], own: f64, other: f64| {
                let mut out = *set;
                for (h, slot) in out.iter_mut().enumerate() {
                    if sa[h] && sb[h] {
                        *slot = hue_diff(h as f64, own).abs() < hue_diff(h as f64, other).abs();
                    }
                }
                out
            };
            let na = keep(&sa, ca, cb);
            let nb = keep(&sb, cb, ca);
            classes[a].class.hue = set_to_ranges(&na);
            classes[b].class.hue = set_to_ranges(&nb);
        }
    }
}

#[derive(Debug, Clone)]
struct Cluster {
    centre: f64,
    /// Median blobs per frame (frames without any counted as 0).
    per_frame: f64,
    frames_present: u32,
    mean_y: f64,
    blobs: Vec<usize>,
}

/// A proposed colour class and where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct ProposedClass {
    pub class: ColorClass,
    pub hue_centre: f64,
    pub blobs: usize,
    pub frames_present: u32,
    pub per_frame: f64,
}

/// A colour seen but not proposed.
#[derive(Debug, Clone, PartialEq)]
pub struct ClusterSummary {
    pub hue: f64,
    pub blobs: usize,
    pub frames_present: u32,
    pub per_frame: f64,
}

/// What [`ColourSampler::propose`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Proposal {
    /// Lip class first, then forehead; empty when nothing usable was found.
    pub classes: Vec<ProposedClass>,
    pub unused: Vec<ClusterSummary>,
    /// No or ambiguous colours; also printed as comments.
    pub warnings: Vec<String>,
    pub frames: u32,
    pub blobs: usize,
    pub performer_m: Option<f64>,
    pub saturation_threshold: Option<u8>,
}

impl Proposal {
    /// The proposal as a detector configuration: `base` with its classes replaced.
    pub fn detect_config(&self, base: &DetectConfig) -> DetectConfig {
        DetectConfig {
            classes: self.classes.iter().map(|c| c.class.clone()).collect(),
            ..base.clone()
        }
    }

    /// The `[detect]` snippet: `[[detect.class]]` entries with the keys a configuration file
    /// takes (valid TOML on its own and anywhere in a configuration file whose `[detect]`
    /// table has no classes), comments saying where each came from, `# warning:` lines.
    pub fn to_toml(&self, source: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# Proposed by `mouthpiece tune-colours` from {} frames of {source}",
            self.frames
        );
        let _ = writeln!(
            s,
            "# ({} colour blobs{}{}).",
            self.blobs,
            match self.performer_m {
                Some(z) => format!(", performer at {z:.2} m"),
                None => ", no depth: background not masked".into(),
            },
            match self.saturation_threshold {
                Some(t) => format!(", blob saturation >= {t}"),
                None => String::new(),
            }
        );
        for w in &self.warnings {
            let _ = writeln!(s, "# warning: {w}");
        }
        for c in &self.unused {
            let _ = writeln!(
                s,
                "# not used: hue {:.0}, {} blobs in {} of {} frames ({:.0} per frame)",
                c.hue, c.blobs, c.frames_present, self.frames, c.per_frame
            );
        }
        // No `[detect]` line: the entries create the table on their own, and can be pasted
        // into a file that has one (TOML refuses a table defined twice).
        for p in &self.classes {
            let c = &p.class;
            let _ = writeln!(s);
            let _ = writeln!(
                s,
                "# hue {:.0}: {} blobs in {} of {} frames ({:.0} per frame)",
                p.hue_centre, p.blobs, p.frames_present, self.frames, p.per_frame
            );
            let _ = writeln!(s, "[[detect.class]]");
            let _ = writeln!(s, "name = \"{}\"", c.name);
            let role = match c.role {
                DotRole::Lip => "lip",
                DotRole::Forehead => "forehead",
                DotRole::Any => "any",
            };
            let _ = writeln!(s, "role = \"{role}\"");
            let hue: Vec<String> = c.hue.iter().map(|[a, b]| format!("[{a}, {b}]")).collect();
            let _ = writeln!(s, "hue = [{}]", hue.join(", "));
            let _ = writeln!(s, "saturation = [{}, {}]", c.saturation[0], c.saturation[1]);
            let _ = writeln!(s, "value = [{}, {}]", c.value[0], c.value[1]);
        }
        s
    }
}
