//! Following neighbours: speech moves neighbouring dots together (the jaw drops or lifts
//! the whole lower lip between two frames), so a missing lip dot next to a found one is
//! looked for where its prediction lands when moved as that neighbour moved (its miss
//! against its own prediction; the mean of both neighbours' misses when both are found),
//! repeated along the mouth while it finds dots.

use super::{name_moved, Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::labels::Small;

pub(crate) struct FollowNeighbours;

impl Step for FollowNeighbours {
    fn name(&self) -> &'static str {
        "follow-neighbours"
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
        let preds = &pass.preds;
        let mut any = false;
        // Each round names dots next to those the round before found: at most n rounds.
        for _ in 0..n {
            let moved: Small<(usize, [f64; 2])> = (0..n)
                .filter(|&i| names.get(i).is_none())
                .filter_map(|i| {
                    let misses: Small<[f64; 2]> = [(i + n - 1) % n, (i + 1) % n]
                        .iter()
                        .filter_map(|&j| {
                            names.get(j).map(|c| {
                                let p = cands.list[c].pixel;
                                [p[0] - preds[j][0], p[1] - preds[j][1]]
                            })
                        })
                        .collect();
                    if misses.is_empty() {
                        return None;
                    }
                    let k = misses.len() as f64;
                    let dx = misses.iter().map(|m| m[0]).sum::<f64>() / k;
                    let dy = misses.iter().map(|m| m[1]).sum::<f64>() / k;
                    Some((i, [preds[i][0] + dx, preds[i][1] + dy]))
                })
                .collect();
            if !name_moved(ctx, pass, names, cands, &mut scratch.solver, &moved) {
                break;
            }
            any = true;
        }
        any
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The jaw drops the lower lip: D9 and D11 by 3 px (within their gates), D10 by 7 px
    /// (beyond its gate). The first pass leaves D10 missing; its neighbours' miss leads to it.
    #[test]
    fn a_dot_is_found_where_its_neighbours_motion_puts_it() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = rest.clone();
        truth[8][1] += 3.0;
        truth[10][1] += 3.0;
        truth[9][1] += 7.0;
        let mut cands = scene.candidates_at(&truth);
        let pass = scene.pass(&rest, &cands);
        let (first, names) = scene.run_after_first_pass(&FollowNeighbours, &pass, &mut cands);
        assert_eq!(first.get(9), None, "the first pass leaves D10 missing");
        assert_eq!(named(&names), identity());
    }
}
