//! Rest offsets: a lip dot still missing is looked for at its found neighbours' places now
//! (head motion removed) plus its rest offsets to them: the lips move together (the jaw
//! carries the whole lower lip). Only dots with a found neighbour.

use super::{name_moved, Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::camera;
use crate::labels::Small;
use crate::Vec3;

pub(crate) struct RestOffsets;

impl Step for RestOffsets {
    fn name(&self) -> &'static str {
        "rest-offsets"
    }

    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        let n = ctx.layout.lip_dots;
        let (head, k) = (&pass.head, ctx.sensor.k);
        let rest = ctx.head.rest;
        let inverse = head.inverse();
        let moved: Small<(usize, [f64; 2])> = (0..n)
            .filter(|&i| names.get(i).is_none())
            .filter_map(|i| {
                let mut sum = Vec3::zeros();
                let mut count = 0.0;
                for j in [(i + n - 1) % n, (i + 1) % n] {
                    if let Some(c) = names.get(j) {
                        let now = inverse.apply(&cands.list[c].point);
                        sum += now + (rest[i] - rest[j]);
                        count += 1.0;
                    }
                }
                (count > 0.0)
                    .then(|| camera::project(k, &head.apply(&(sum / count))))
                    .flatten()
                    .map(|px| (i, px))
            })
            .collect();
        name_moved(ctx, pass, names, cands, &mut scratch.solver, &moved)
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// D10's prediction is 8 px off (a stale velocity); its neighbours are found where they
    /// were, so their own misses say nothing, but their places plus the rest offsets put D10
    /// right.
    #[test]
    fn a_dot_is_found_at_its_neighbours_places_plus_the_rest_offsets() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut preds = rest.clone();
        preds[9][1] -= 8.0;
        let mut cands = scene.candidates_at(&rest);
        let pass = scene.pass(&preds, &cands);
        let (first, names) = scene.run_after_first_pass(&RestOffsets, &pass, &mut cands);
        assert_eq!(first.get(9), None, "the first pass leaves D10 missing");
        assert_eq!(named(&names), identity());
        // Following the neighbours' misses (none) does not find it.
        let (_, followed) =
            scene.run_after_first_pass(&super::super::FollowNeighbours, &pass, &mut cands);
        assert_eq!(followed.get(9), None);
    }
}
