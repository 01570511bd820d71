//! Stopped lips: lips that stop dead (closing against each other, a corner at the end of a
//! smile) overshoot a constant-velocity prediction, by up to 6 px when they close onto each
//! other. With lip dots missing and candidates left, the frame is named again with each lip
//! dot predicted where it was last (zero velocity, the same head motion); those names are
//! proposed, and taken when they score better ([`super::take_if_better`]).

use super::{
    lips_missing_with_candidates_left, take_if_better_under, Candidates, Context, NameSet, Pass,
    Scratch, Step,
};
use crate::prediction::LipMotion;

pub(crate) struct StoppedLips;

impl Step for StoppedLips {
    fn name(&self) -> &'static str {
        "stopped-lips"
    }

    fn run(
        &self,
        ctx: &Context,
        pass: &Pass,
        names: &mut NameSet,
        cands: &mut Candidates,
        scratch: &mut Scratch,
    ) -> bool {
        if !lips_missing_with_candidates_left(ctx, pass, names, cands) {
            return false;
        }
        let taken = take_if_better_under(ctx, pass, names, cands, scratch, LipMotion::Stopped);
        if let Some((steady, stopped)) = taken {
            tracing::debug!(
                steady,
                stopped,
                "lips stopped: named from their last places (score, nats)"
            );
        }
        taken.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// The lower lip was closing fast and stopped dead: its constant-velocity predictions lie
    /// 6 px on, beyond the gates, and the steady names leave it missing. Named from where it
    /// was, every dot is found.
    #[test]
    fn lips_that_stopped_dead_are_named_from_their_last_places() {
        let mut scene = Scene::calibrated();
        let rest = scene.rest_pixels();
        let overshot = lower_lip_moved(&rest, [0.0, 6.0]);
        let mut cands = scene.candidates_at(&rest);
        let run = scene.run_as_hypothesis(&StoppedLips, &overshot, &mut cands);
        assert!(
            (8..11).all(|i| run.first.get(i).is_none()),
            "{:?}",
            named(&run.first)
        );
        assert!(run.fired);
        assert_eq!(named(&run.names), identity());
    }
}
