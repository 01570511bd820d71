//! What each naming step did over a session (`mouthpiece evaluate --steps`): the frames it
//! changed names on, its runs, and the names it gave or took judged against the ground
//! truth at the time (a later step or check may change them again).

use crate::{EvaluateError, FrameView, Measure};

/// One step's figures over a session.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StepFigures {
    /// Frames on which it changed a name.
    pub frames: usize,
    /// Runs that changed names (a step runs once per naming hypothesis and may run twice).
    pub runs: usize,
    /// Names it changed.
    pub changes: usize,
    /// Found & correctly named dots it added, and took away.
    pub found_gained: usize,
    pub found_lost: usize,
    /// Wrong names it added, and took away.
    pub wrong_gained: usize,
    pub wrong_lost: usize,
}

impl StepFigures {
    /// Found names it added less those it took away.
    pub fn found_net(&self) -> i64 {
        self.found_gained as i64 - self.found_lost as i64
    }

    /// Wrong names it added less those it took away.
    pub fn wrong_net(&self) -> i64 {
        self.wrong_gained as i64 - self.wrong_lost as i64
    }
}

/// Every step's figures, in the order the steps run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepStats {
    pub steps: Vec<(&'static str, StepFigures)>,
}

impl Default for StepStats {
    fn default() -> Self {
        StepStats {
            steps: mouthpiece_track::recovery_steps()
                .into_iter()
                .map(|s| (s, StepFigures::default()))
                .collect(),
        }
    }
}

impl StepStats {
    pub fn get(&self, step: &str) -> Option<&StepFigures> {
        self.steps.iter().find(|(s, _)| *s == step).map(|(_, f)| f)
    }

    /// The table `mouthpiece evaluate --steps` prints for a session (markdown).
    pub fn table(&self) -> String {
        let mut out = String::from(
            "| step | frames | runs | names changed | found + | found − | wrong + | wrong − |\n|---|---|---|---|---|---|---|---|\n",
        );
        for (name, f) in &self.steps {
            out.push_str(&format!(
                "| {name} | {} | {} | {} | {} | {} | {} | {} |\n",
                f.frames,
                f.runs,
                f.changes,
                f.found_gained,
                f.found_lost,
                f.wrong_gained,
                f.wrong_lost
            ));
        }
        out
    }

    /// Sums another session's figures into these.
    pub fn add(&mut self, other: &StepStats) {
        for (name, f) in &other.steps {
            let Some((_, mine)) = self.steps.iter_mut().find(|(s, _)| s == name) else {
                self.steps.push((name, f.clone()));
                continue;
            };
            mine.frames += f.frames;
            mine.runs += f.runs;
            mine.changes += f.changes;
            mine.found_gained += f.found_gained;
            mine.found_lost += f.found_lost;
            mine.wrong_gained += f.wrong_gained;
            mine.wrong_lost += f.wrong_lost;
        }
    }
}

/// How a name is judged: found (right blob, visible dot), wrong (another dot's blob), or
/// neither (missing, or a hidden dot's own place).
fn judge(f: &FrameView, dot: usize, px: Option<[f64; 2]>) -> (bool, bool) {
    let Some(px) = px else {
        return (false, false);
    };
    if !f.names_right(dot, px) {
        return (false, true);
    }
    (f.truth.is_visible(&f.names[dot]), false)
}

impl Measure for StepStats {
    fn frame(&mut self, f: &FrameView) -> Result<(), EvaluateError> {
        if !f.counted {
            return Ok(());
        }
        let mut last: Option<(&str, u16)> = None;
        let mut seen_this_frame: Vec<&str> = Vec::new();
        for e in &f.tracked.steps {
            let Some((_, fig)) = self.steps.iter_mut().find(|(s, _)| *s == e.step) else {
                continue;
            };
            if last != Some((e.step, e.run)) {
                fig.runs += 1;
                last = Some((e.step, e.run));
            }
            if !seen_this_frame.contains(&e.step) {
                fig.frames += 1;
                seen_this_frame.push(e.step);
            }
            fig.changes += 1;
            let dot = e.dot as usize;
            let (found_before, wrong_before) = judge(f, dot, e.before);
            let (found_after, wrong_after) = judge(f, dot, e.after);
            fig.found_gained += usize::from(found_after && !found_before);
            fig.found_lost += usize::from(found_before && !found_after);
            fig.wrong_gained += usize::from(wrong_after && !wrong_before);
            fig.wrong_lost += usize::from(wrong_before && !wrong_after);
        }
        Ok(())
    }
}
