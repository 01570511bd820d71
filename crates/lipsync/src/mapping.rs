//! Segments on the phone timeline.
//!
//! Phone i on [t1, t2] of class a, followed by a phone of class b (silence after the last),
//! takes segment A(a, b):
//! - **t2 − t1 ≥ T**: the change stage fills [t2 − T, t2] unchanged, the stable stage is scaled
//!   onto [t1, t2 − T].
//! - **t2 − t1 < T** (the *short-phone rule*, ours; the source text leaves it out): the change
//!   stage keeps its length T and still ends at t2, so it starts T before t2, before the phone
//!   itself, and the stable stage is dropped. The part before t1 overlaps the curve so far and
//!   is blended into it by the stitching. So a short phone never gets a hurried transition:
//!   the mouth leaves the previous shape early (co-articulation) and the class is approached
//!   but not necessarily reached. The first phone has no curve before it: its change stage is
//!   cut at t1.

use crate::segments::{Segment, SegmentTable};
use crate::{Error, PhoneSpan, T_CHANGE_RANGE};

/// One segment placed on the timeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placed {
    /// Class of the phone and of its successor: the segment is A(from, to).
    pub from: usize,
    pub to: usize,
    /// Where the placed curve starts (t1, or earlier for a short phone) and ends (t2).
    pub start: f64,
    pub end: f64,
    /// The phone's start (the stable stage starts here when there is one).
    pub t1: f64,
    /// Start of the change stage: t2 − T.
    pub change_start: f64,
    /// The change-stage length T.
    pub t_change: f64,
}

impl Placed {
    /// Whether the stable stage is present (a phone at least T long).
    pub fn has_stable(&self) -> bool {
        self.change_start >= self.t1
    }

    /// The placed curve at `t`, all key poses, into `out`.
    pub fn eval(&self, segment: &Segment, t: f64, out: &mut [f64]) {
        if t < self.change_start && self.change_start > self.t1 {
            let u = (t - self.t1) / (self.change_start - self.t1);
            for (o, c) in out.iter_mut().zip(&segment.stable) {
                *o = c.at(u);
            }
        } else {
            let u = (t - self.change_start) / self.t_change;
            for (o, c) in out.iter_mut().zip(&segment.change) {
                *o = c.at(u);
            }
        }
    }
}

/// Checks the change-stage length (30–50 ms).
pub fn check_t_change(t_change: f64) -> Result<(), Error> {
    let (lo, hi) = T_CHANGE_RANGE;
    if !(t_change >= lo - 1e-12 && t_change <= hi + 1e-12) {
        return Err(Error::Setting {
            what: format!(
                "--t-change: the change-stage length T must be within {} to {} ms, got {} ms",
                lo * 1e3,
                hi * 1e3,
                t_change * 1e3
            ),
        });
    }
    Ok(())
}

/// Places one segment per phone. `classes[i]` is phone i's class.
pub fn map_phones(
    phones: &[PhoneSpan],
    classes: &[usize],
    segments: &SegmentTable,
    silence: usize,
    t_change: f64,
) -> Result<Vec<Placed>, Error> {
    check_t_change(t_change)?;
    assert_eq!(phones.len(), classes.len(), "one class per phone");
    let origin = phones.first().map_or(0.0, |p| p.start);
    let mut out = Vec::with_capacity(phones.len());
    for (i, p) in phones.iter().enumerate() {
        let from = classes[i];
        let to = classes.get(i + 1).copied().unwrap_or(silence);
        debug_assert!(from < segments.classes() && to < segments.classes());
        let change_start = p.end - t_change;
        let start = if p.end - p.start >= t_change {
            p.start
        } else {
            change_start.max(origin)
        };
        out.push(Placed {
            from,
            to,
            start,
            end: p.end,
            t1: p.start,
            change_start,
            t_change,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ClassTable;

    fn table() -> (ClassTable, SegmentTable) {
        let t = ClassTable::from_toml_str(crate::segments::tests::TABLE, "t").unwrap();
        let s = SegmentTable::generate(&t);
        (t, s)
    }

    fn span(start: f64, end: f64, phone: &str) -> PhoneSpan {
        PhoneSpan {
            start,
            end,
            phone: phone.into(),
            line: 1,
        }
    }

    #[test]
    fn change_stage_is_the_last_t_of_a_long_phone() {
        let (t, s) = table();
        let phones = [
            span(0.0, 1.0, "sil"),
            span(1.0, 1.2, "m"),
            span(1.2, 1.5, "aa"),
        ];
        let classes = t.classify(&phones, "x").unwrap();
        let placed = map_phones(&phones, &classes, &s, t.silence(), 0.04).unwrap();
        let m = placed[1];
        assert_eq!((m.from, m.to), (1, 2));
        assert!((m.change_start - 1.16).abs() < 1e-12);
        assert_eq!((m.start, m.end), (1.0, 1.2));
        let seg = s.get(m.from, m.to);
        let mut w = [0.0; 2];
        // Stable stage: the bilabial closure held until 1.16.
        for &time in &[1.0, 1.1, 1.159_999] {
            m.eval(seg, time, &mut w);
            assert_eq!(w, [1.0, 0.0], "at {time}");
        }
        // Change stage: moving within [1.16, 1.20], arriving at the vowel's target at 1.20.
        m.eval(seg, 1.18, &mut w);
        assert!(
            (w[0] - 0.5).abs() < 1e-9 && (w[1] - 0.5).abs() < 1e-9,
            "{w:?}"
        );
        m.eval(seg, 1.2, &mut w);
        assert_eq!(w, [0.0, 1.0]);
        // The last phone moves towards silence.
        assert_eq!(placed[2].to, t.silence());
    }

    #[test]
    fn short_phone_starts_its_change_stage_early() {
        let (t, s) = table();
        let phones = [
            span(0.0, 0.5, "aa"),
            span(0.5, 0.52, "m"),
            span(0.52, 0.8, "aa"),
        ];
        let classes = t.classify(&phones, "x").unwrap();
        let placed = map_phones(&phones, &classes, &s, t.silence(), 0.04).unwrap();
        let m = placed[1];
        assert!(!m.has_stable());
        assert!((m.start - 0.48).abs() < 1e-12 && m.end == 0.52);
        // A short first phone is cut at its start.
        let placed = map_phones(&phones[1..], &classes[1..], &s, t.silence(), 0.04).unwrap();
        assert_eq!(placed[0].start, 0.5);
    }

    #[test]
    fn t_change_outside_30_to_50_ms_is_refused() {
        let (t, s) = table();
        let phones = [span(0.0, 0.5, "aa")];
        for bad in [0.02, 0.06, f64::NAN] {
            assert!(map_phones(&phones, &[2], &s, t.silence(), bad).is_err());
        }
        assert!(map_phones(&phones, &[2], &s, t.silence(), 0.03).is_ok());
    }
}
