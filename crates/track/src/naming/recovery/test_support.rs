//! Hand-built scenes for the recovery steps' tests: a face at rest (12 lip dots on an
//! ellipse 50 mm wide and 28 mm high at 0.6 m, 3 forehead dots), its neutral pose and
//! tracks, candidates placed by hand, a flat depth image. No rendering, no detector.

use mouthpiece_detect::{Blob, DotRole, PixelRect};
use mouthpiece_frame::{DepthImage, Intrinsics};
use mouthpiece_retarget::{
    NeutralAccumulator, NeutralPose, PerformerDots, PerformerLayout, RigidTransform,
};

use super::{Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::config::TrackConfig;
use crate::head::HeadReference;
use crate::labels::{self, Candidate, Slot, Small};
use crate::naming::checks::disc_area;
use crate::prediction::{self, DotTrack};
use crate::{camera, Sensor, Vec3};

/// The paint's radius (the detector's default), metres.
pub const DOT_RADIUS_M: f64 = 0.00225;

/// The face at rest, camera frame: lip dots D1..D12 (D1 the left corner, D7 the right one,
/// D2..D6 the upper lip), then F1..F3.
pub fn neutral_face() -> Vec<Vec3> {
    let centre = Vec3::new(0.01, 0.03, 0.6);
    let mut out = Vec::new();
    for i in 0..12 {
        let a = std::f64::consts::PI * i as f64 / 6.0;
        out.push(centre + Vec3::new(0.025 * a.cos(), -0.014 * a.sin(), -0.004 * a.sin().abs()));
    }
    for j in 0..3 {
        let up = if j == 1 { 0.025 } else { 0.0 };
        out.push(centre + Vec3::new(0.03 - 0.03 * j as f64, -0.09 - up, 0.01 + up / 3.0));
    }
    out
}

/// A calibrated tracker's state, at rest, every dot seen last frame and standing still.
pub struct Scene {
    pub config: TrackConfig,
    pub layout: PerformerLayout,
    pub rest: Vec<Vec3>,
    pub tracks: Vec<DotTrack>,
    pub neutral: NeutralPose,
    pub forehead: Vec<Vec3>,
    pub roles: Vec<DotRole>,
    pub blobs: Vec<Blob>,
    pub faint: Vec<Blob>,
    pub depth: DepthImage,
    pub k: Intrinsics,
}

/// `rest` with the lower lip between the corners (D8..D12) moved by `by` pixels.
pub(crate) fn lower_lip_moved(rest: &[[f64; 2]], by: [f64; 2]) -> Vec<[f64; 2]> {
    let mut moved = rest.to_vec();
    for p in &mut moved[7..12] {
        p[0] += by[0];
        p[1] += by[1];
    }
    moved
}

impl Scene {
    pub fn calibrated() -> Self {
        let layout = PerformerLayout::default();
        let k = Intrinsics::default_vga();
        let face = neutral_face();
        let mut dots = PerformerDots::new(layout);
        for (i, p) in face.iter().enumerate() {
            if i < 12 {
                dots.lip[i] = Some(*p);
            } else {
                dots.forehead[i - 12] = Some(*p);
            }
        }
        let mut acc = NeutralAccumulator::new(layout);
        for _ in 0..3 {
            acc.push(&dots).unwrap();
        }
        let neutral = acc.finish().unwrap();
        let tracks = face
            .iter()
            .map(|p| {
                DotTrack::new(&Candidate {
                    pixel: camera::project(&k, p).unwrap(),
                    point: *p,
                    role: DotRole::Lip,
                })
            })
            .collect();
        // The lips and forehead at 0.6 m: within every depth gate of every dot.
        let depth = DepthImage {
            width: 640,
            height: 480,
            data: vec![600; 640 * 480],
        };
        Scene {
            config: TrackConfig::default(),
            layout,
            rest: face[..12].to_vec(),
            forehead: face[12..].to_vec(),
            tracks,
            neutral,
            roles: vec![DotRole::Lip, DotRole::Forehead],
            blobs: Vec::new(),
            faint: Vec::new(),
            depth,
            k,
        }
    }

    pub fn ctx(&self) -> Context<'_> {
        Context {
            layout: self.layout,
            config: &self.config,
            tracks: &self.tracks,
            neutral: Some(&self.neutral),
            head: HeadReference {
                layout: self.layout,
                forehead: &self.forehead,
                rest: &self.rest,
                last: RigidTransform::IDENTITY,
            },
            step_ratio: 1.0,
            roles: &self.roles,
            blobs: &self.blobs,
            faint: &self.faint,
            sensor: Sensor {
                depth: &self.depth,
                scale: 0.001,
                k: &self.k,
                depth_range: [0.2, 2.0],
                dot_radius_m: DOT_RADIUS_M,
            },
        }
    }

    /// The dots' pixels at rest.
    pub fn rest_pixels(&self) -> Vec<[f64; 2]> {
        neutral_face()
            .iter()
            .map(|p| camera::project(&self.k, p).unwrap())
            .collect()
    }

    /// A blob of one dot's paint at `pixel`, depth `z`.
    pub fn blob(&self, pixel: [f64; 2], z: f64, class: usize) -> Blob {
        let r = DOT_RADIUS_M * self.k.fx / z;
        Blob {
            class,
            center: pixel,
            area: disc_area(r).round() as u32,
            bbox: PixelRect {
                x: (pixel[0] - r) as i32,
                y: (pixel[1] - r) as i32,
                width: (2.0 * r).ceil() as i32,
                height: (2.0 * r).ceil() as i32,
            },
            depth_m: Some(z),
            spread: [r * r / 4.0, 0.0, r * r / 4.0],
        }
    }

    /// One candidate per pixel (the first 12 lip, the rest forehead), at the depth of the
    /// dot at rest with the same index, each on a blob of one dot's paint.
    pub fn candidates_at(&mut self, pixels: &[[f64; 2]]) -> Candidates {
        self.candidates_except(pixels, None)
    }

    /// As [`Scene::candidates_at`] with dot `hidden` unseen (no candidate for it).
    pub fn candidates_hiding(&mut self, pixels: &[[f64; 2]], hidden: usize) -> Candidates {
        self.candidates_except(pixels, Some(hidden))
    }

    fn candidates_except(&mut self, pixels: &[[f64; 2]], hidden: Option<usize>) -> Candidates {
        let face = neutral_face();
        let mut cands = Candidates::default();
        self.blobs.clear();
        for (i, px) in pixels.iter().enumerate() {
            if Some(i) == hidden {
                continue;
            }
            let role = if i < 12 {
                DotRole::Lip
            } else {
                DotRole::Forehead
            };
            self.push(&mut cands, *px, face[i].z, role, 1.0);
        }
        cands
    }

    /// Appends a candidate at `pixel`, depth `z`, on a blob of `area_dots` dots' paint.
    pub fn push(
        &mut self,
        cands: &mut Candidates,
        pixel: [f64; 2],
        z: f64,
        role: DotRole,
        area_dots: f64,
    ) -> usize {
        let class = usize::from(role == DotRole::Forehead);
        let mut blob = self.blob(pixel, z, class);
        blob.area = (blob.area as f64 * area_dots).round() as u32;
        self.blobs.push(blob);
        cands.push_detected(
            Candidate {
                pixel,
                point: camera::deproject(&self.k, pixel, z),
                role,
            },
            self.blobs.len() - 1,
        );
        cands.len() - 1
    }

    /// The pass a naming hypothesis would make with these lip predictions (head at rest,
    /// the forehead named on the forehead candidates, in order).
    pub fn pass(&self, preds: &[[f64; 2]], cands: &Candidates) -> Pass {
        let preds: Small<[f64; 2]> = preds[..12].iter().copied().collect();
        let head = RigidTransform::IDENTITY;
        let spacing = self.ctx().spacing();
        let gates = prediction::gated(
            &self.config,
            &preds,
            &self.tracks[..12],
            Slot::Lip,
            &head,
            spacing,
        );
        Pass {
            head,
            forehead: (0..cands.len())
                .filter(|&c| cands.list[c].role == DotRole::Forehead)
                .map(Some)
                .collect(),
            preds,
            gates,
            steady_named: 0,
            steady: Small::new(),
        }
    }

    /// The first pass's names: the lips assigned to their predictions, nothing else.
    pub fn first_pass(&self, pass: &Pass, cands: &Candidates) -> NameSet {
        let mut names = NameSet::of(
            std::iter::repeat_n(None, 12).chain(pass.forehead.iter().copied()),
            cands.len(),
        );
        let lips = labels::assign(
            &pass.gates,
            &cands.list,
            names.taken(),
            &mut labels::Assignment::default(),
        );
        for (dot, c) in lips.into_iter().enumerate() {
            if c.is_some() {
                names.set(dot, c);
            }
        }
        names
    }

    /// A hypothesis-stage step as the tracker runs it: the first pass with the lips predicted
    /// at `preds`, its names counted as the steady hypothesis's, then `step` on them.
    pub fn run_as_hypothesis(
        &self,
        step: &dyn Step,
        preds: &[[f64; 2]],
        cands: &mut Candidates,
    ) -> HypothesisRun {
        let mut pass = self.pass(preds, cands);
        let first = self.first_pass(&pass, cands);
        pass.steady_named = first.count();
        pass.steady = first.as_slice().iter().copied().collect();
        let mut names = first.clone();
        let fired = step.run(
            &self.ctx(),
            &pass,
            &mut names,
            cands,
            &mut Scratch::default(),
        );
        HypothesisRun {
            pass,
            first,
            names,
            fired,
        }
    }

    /// The first pass, then `step` on its names.
    pub fn run_after_first_pass(
        &self,
        step: &dyn Step,
        pass: &Pass,
        cands: &mut Candidates,
    ) -> (NameSet, NameSet) {
        let first = self.first_pass(pass, cands);
        let mut names = first.clone();
        step.run(
            &self.ctx(),
            pass,
            &mut names,
            cands,
            &mut Scratch::default(),
        );
        (first, names)
    }
}

/// What [`Scene::run_as_hypothesis`] saw: the pass, the first pass's names, the step's, and
/// whether the step changed them.
pub struct HypothesisRun {
    pub pass: Pass,
    pub first: NameSet,
    pub names: NameSet,
    pub fired: bool,
}

/// Candidate indices per dot (`None`: missing), lip dots then forehead.
pub fn named(names: &NameSet) -> Vec<Option<usize>> {
    names.as_slice().to_vec()
}

/// The names a correct naming gives when candidate `i` is dot `i`.
pub fn identity() -> Vec<Option<usize>> {
    (0..15).map(Some).collect()
}
