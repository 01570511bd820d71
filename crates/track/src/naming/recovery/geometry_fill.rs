//! Geometry filling in: when the prediction leaves dots missing although there are exactly
//! as many candidates as dots, geometry may name the frame, but only if it agrees with
//! every name the prediction gave (geometry alone can be fooled by extreme mouth shapes,
//! prediction alone by fast motion; agreement of both is trusted).

use super::{Candidates, Context, NameSet, Pass, Scratch, Step};
use crate::naming::geometry;

pub(crate) struct GeometryFill;

impl Step for GeometryFill {
    fn name(&self) -> &'static str {
        "geometry-fill"
    }

    fn run(
        &self,
        ctx: &Context,
        _pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        _scratch: &mut Scratch,
    ) -> bool {
        let total = ctx.layout.lip_dots + ctx.layout.forehead_dots;
        if names.all_named() || cands.len() != total {
            return false;
        }
        match geometry(ctx, &cands.list) {
            Some(geo)
                if names
                    .as_slice()
                    .iter()
                    .zip(&geo)
                    .all(|(p, g)| p.is_none_or(|p| p == *g)) =>
            {
                *names = NameSet::of(geo.into_iter().map(Some), cands.len());
                true
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// D4 moved 6 px up, beyond its gate, and nothing else: 15 candidates for 15 dots, and
    /// geometry names D4 the way the prediction named every other dot.
    #[test]
    fn geometry_names_the_missing_dot_when_it_agrees() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = rest.clone();
        truth[3][1] -= 6.0;
        let mut cands = scene.candidates_at(&truth);
        let pass = scene.pass(&rest, &cands);
        let (first, names) = scene.run_after_first_pass(&GeometryFill, &pass, &mut cands);
        assert_eq!(first.get(3), None);
        assert_eq!(named(&names), identity());
    }

    /// When geometry disagrees with a name the prediction gave, nothing changes.
    #[test]
    fn geometry_that_disagrees_changes_nothing() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let mut truth = rest.clone();
        truth[3][1] -= 6.0;
        let mut cands = scene.candidates_at(&truth);
        let pass = scene.pass(&rest, &cands);
        let mut names = scene.first_pass(&pass, &cands);
        // D5 named on D6's blob and D6 missing: geometry says otherwise.
        names.set(5, None);
        names.set(4, Some(5));
        let before = named(&names);
        GeometryFill.run(
            &scene.ctx(),
            &pass,
            &mut names,
            &mut cands,
            &mut Scratch::default(),
        );
        assert_eq!(named(&names), before);
    }
}
