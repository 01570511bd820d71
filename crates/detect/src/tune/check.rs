//! Checking a proposal before it is offered: the detector runs with the ranges in use and
//! with the proposed ones on the frames the proposal was made from, and counts the dots each
//! finds. A proposal that finds fewer is never offered: a saturation floor set above part of
//! the paint (lips nearly as saturated as the paint lift the blob threshold, so only the most
//! saturated dots are sampled) would otherwise stop the tracker from ever calibrating.

use mouthpiece_frame::{ColorImage, DepthImage};

use super::proposal::Proposal;
use crate::{DetectConfig, DetectError, Detector, DotRole};

/// Most frames kept for the check; past it every other kept frame is dropped and only every
/// second frame offered is kept (640 × 480 with depth: about 1.5 MB a frame, 45 MB at most).
pub const MAX_CHECK_FRAMES: usize = 30;

/// A frame as the sampler saw it: colour, depth on the colour grid and its scale, `fx`.
#[derive(Debug, Clone)]
struct KeptFrame {
    color: ColorImage,
    depth: Option<(DepthImage, f64)>,
    fx: f64,
}

/// The frames kept for the check: evenly spread over those offered, at most
/// [`MAX_CHECK_FRAMES`].
#[derive(Debug, Clone, Default)]
pub(super) struct KeptFrames {
    frames: Vec<KeptFrame>,
    /// Keep one frame in `stride` (a power of two).
    stride: u32,
    offered: u32,
}

impl KeptFrames {
    pub(super) fn offer(&mut self, color: &ColorImage, depth: Option<(&DepthImage, f64)>, fx: f64) {
        let stride = self.stride.max(1);
        let keep = self.offered.is_multiple_of(stride);
        self.offered = self.offered.wrapping_add(1);
        if !keep {
            return;
        }
        self.frames.push(KeptFrame {
            color: color.clone(),
            depth: depth.map(|(d, s)| (d.clone(), s)),
            fx,
        });
        if self.frames.len() > MAX_CHECK_FRAMES {
            let mut i = 0;
            self.frames.retain(|_| {
                i += 1;
                i % 2 == 1
            });
            self.stride = stride * 2;
        }
    }

    pub(super) fn len(&self) -> usize {
        self.frames.len()
    }
}

/// What one colour class found over the checked frames.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassFound {
    pub name: String,
    pub role: DotRole,
    /// Dots found (per frame at most the dots its role has), summed over the frames.
    pub found: u64,
}

/// The dots one detector configuration finds on the checked frames: per frame, the blobs of
/// each role up to the dots of that role (`any` blobs fill what lips and forehead left).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DotsFound {
    pub frames: u32,
    pub lip: u64,
    pub forehead: u64,
    /// Dots found by classes of role `any`.
    pub any: u64,
    /// Dots there are: (lip + forehead dots) × frames.
    pub expected: u64,
    pub classes: Vec<ClassFound>,
}

impl DotsFound {
    pub fn total(&self) -> u64 {
        self.lip + self.forehead + self.any
    }

    /// Share (0–1) of the dots found.
    pub fn share(&self) -> f64 {
        if self.expected == 0 {
            0.0
        } else {
            self.total() as f64 / self.expected as f64
        }
    }

    /// `"11.0 of 15 dots per frame (73 %): lip 8.0, forehead 3.0"`.
    pub fn summary(&self, lip_dots: usize, forehead_dots: usize) -> String {
        let f = f64::from(self.frames.max(1));
        let mut s = format!(
            "{:.1} of {} dots per frame ({:.0} %)",
            self.total() as f64 / f,
            lip_dots + forehead_dots,
            self.share() * 100.0
        );
        let parts: Vec<String> = [
            ("lip", self.lip),
            ("forehead", self.forehead),
            ("any", self.any),
        ]
        .iter()
        .filter(|(name, n)| *n > 0 || *name != "any")
        .map(|(name, n)| format!("{name} {:.1}", *n as f64 / f))
        .collect();
        s.push_str(": ");
        s.push_str(&parts.join(", "));
        s
    }
}

/// A proposal and what it finds next to the ranges in use.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedProposal {
    pub proposal: Proposal,
    pub in_use: DotsFound,
    pub proposed: DotsFound,
}

impl CheckedProposal {
    /// Whether the proposal may be offered: it finds at least as many dots as the ranges in
    /// use, and some.
    pub fn offered(&self) -> bool {
        self.proposed.total() > 0 && self.proposed.total() >= self.in_use.total()
    }

    /// Both counts, one line each: `ranges in use: …` and `proposed: …`, then what each
    /// class finds.
    pub fn report(&self, lip_dots: usize, forehead_dots: usize) -> Vec<String> {
        let mut lines = vec![
            format!(
                "checked on {} of the sampled frames: the ranges in use find {}",
                self.in_use.frames,
                self.in_use.summary(lip_dots, forehead_dots)
            ),
            format!(
                "the proposed ranges find {}",
                self.proposed.summary(lip_dots, forehead_dots)
            ),
        ];
        let f = f64::from(self.in_use.frames.max(1));
        for (which, found) in [("in use", &self.in_use), ("proposed", &self.proposed)] {
            for c in &found.classes {
                lines.push(format!(
                    "{which} class {:?}: {:.1} dots per frame",
                    c.name,
                    c.found as f64 / f
                ));
            }
        }
        lines
    }
}

/// Runs the detector with `config` (full frame) on every kept frame and counts the dots.
pub(super) fn dots_found(
    kept: &KeptFrames,
    config: &DetectConfig,
    lip_dots: usize,
    forehead_dots: usize,
) -> Result<DotsFound, DetectError> {
    let mut detector = Detector::new(config.clone())?;
    let mut out = DotsFound {
        classes: config
            .classes
            .iter()
            .map(|c| ClassFound {
                name: c.name.clone(),
                role: c.role,
                found: 0,
            })
            .collect(),
        ..DotsFound::default()
    };
    let mut per_class = vec![0usize; config.classes.len()];
    for f in &kept.frames {
        let found =
            detector.detect(&f.color, f.depth.as_ref().map(|(d, s)| (d, *s)), f.fx, None)?;
        per_class.fill(0);
        for b in &found.blobs {
            per_class[b.class] += 1;
        }
        let mut by_role = [0usize; 3];
        for (class, n) in config.classes.iter().zip(&per_class) {
            let role = match class.role {
                DotRole::Lip => 0,
                DotRole::Forehead => 1,
                DotRole::Any => 2,
            };
            by_role[role] += n;
        }
        let lip = by_role[0].min(lip_dots);
        let forehead = by_role[1].min(forehead_dots);
        let any = by_role[2].min(lip_dots + forehead_dots - lip - forehead);
        out.lip += lip as u64;
        out.forehead += forehead as u64;
        out.any += any as u64;
        for ((entry, class), n) in out.classes.iter_mut().zip(&config.classes).zip(&per_class) {
            let cap = match class.role {
                DotRole::Lip => lip_dots,
                DotRole::Forehead => forehead_dots,
                DotRole::Any => lip_dots + forehead_dots,
            };
            entry.found += (*n).min(cap) as u64;
        }
        out.frames += 1;
    }
    out.expected = u64::from(out.frames) * (lip_dots + forehead_dots) as u64;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kept_frames_stay_few_and_spread_over_the_sampling() {
        let mut kept = KeptFrames::default();
        let color = ColorImage::new(4, 2);
        for i in 0..100u32 {
            kept.offer(&color, None, f64::from(i));
            assert!(kept.len() <= MAX_CHECK_FRAMES, "{} kept", kept.len());
        }
        let seen: Vec<f64> = kept.frames.iter().map(|f| f.fx).collect();
        // Every fourth frame of the hundred: evenly spread, first to near the last.
        assert_eq!(seen.len(), 25);
        assert!(seen.windows(2).all(|w| w[1] - w[0] == 4.0), "{seen:?}");
        assert_eq!((seen[0], seen[24]), (0.0, 96.0));
    }

    #[test]
    fn a_proposal_is_offered_only_when_it_finds_as_many() {
        let found = |total: u64| DotsFound {
            frames: 1,
            lip: total,
            expected: 15,
            ..DotsFound::default()
        };
        let checked = |in_use: u64, proposed: u64| CheckedProposal {
            proposal: Proposal {
                classes: Vec::new(),
                unused: Vec::new(),
                warnings: Vec::new(),
                frames: 1,
                blobs: 0,
                performer_m: None,
                saturation_threshold: None,
            },
            in_use: found(in_use),
            proposed: found(proposed),
        };
        assert!(checked(12, 12).offered());
        assert!(checked(0, 12).offered());
        assert!(!checked(12, 8).offered());
        assert!(!checked(0, 0).offered(), "a proposal that finds nothing");
        let lines = checked(12, 8).report(12, 3);
        assert!(
            lines[0].contains("12.0 of 15 dots per frame (80 %)"),
            "{lines:?}"
        );
        assert!(lines[1].contains("8.0 of 15"), "{lines:?}");
    }
}
