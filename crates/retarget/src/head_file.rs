//! The `[head]` table of a character file (`docs/head.md`), validated with the key, the line
//! and the reason in every error.

use serde::Deserialize;
use toml::Spanned;

use crate::character::Checker;
use crate::head::{HeadConfig, Reach};
use crate::{Character, Error};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawHead {
    pivot: Option<Spanned<[f64; 3]>>,
    eye_left: Option<Spanned<[f64; 3]>>,
    eye_right: Option<Spanned<[f64; 3]>>,
    reach_side: Option<Spanned<f64>>,
    reach_up: Option<Spanned<f64>>,
    reach_down: Option<Spanned<f64>>,
    reach_diagonal: Option<Spanned<f64>>,
    turn_time_s: Option<Spanned<f64>>,
    follow_gain: Option<Spanned<f64>>,
    follow_max_deg: Option<Spanned<f64>>,
    eye_max_deg: Option<Spanned<f64>>,
}

impl RawHead {
    /// The head of `character` (whose defaults it starts from) with this table's values.
    pub(crate) fn validate(&self, src: &str, character: &Character) -> Result<HeadConfig, Error> {
        let c = Checker { src };
        let mut head = character.head;
        let point = |key: &str, v: &Option<Spanned<[f64; 3]>>, into: &mut crate::Vec3| {
            if let Some(v) = v {
                let key = format!("head.{key}");
                let p = c.finite(&key, v)?;
                *into = c.near_mouth(&key, v, &p, &character.frame)?;
            }
            Ok::<(), Error>(())
        };
        point("pivot", &self.pivot, &mut head.pivot)?;
        point("eye_left", &self.eye_left, &mut head.eye_left)?;
        point("eye_right", &self.eye_right, &mut head.eye_right)?;
        let number = |key: &str,
                      v: &Option<Spanned<f64>>,
                      min: f64,
                      min_inclusive: bool,
                      max: f64,
                      what: &str|
         -> Result<Option<f64>, Error> {
            let Some(v) = v else { return Ok(None) };
            let x = *v.get_ref();
            let low_ok = if min_inclusive { x >= min } else { x > min };
            if !(x.is_finite() && low_ok && x <= max) {
                return Err(c.err(
                    format!("head.{key}"),
                    Some(v.span()),
                    format!("must be {what}, got {x:?}"),
                ));
            }
            Ok(Some(x))
        };
        let unit = "a number in (0, 1] (a component of a unit direction)";
        let mut reach = Reach::default();
        for (key, v, slot) in [
            ("reach_side", &self.reach_side, &mut reach.side),
            ("reach_up", &self.reach_up, &mut reach.up),
            ("reach_down", &self.reach_down, &mut reach.down),
            ("reach_diagonal", &self.reach_diagonal, &mut reach.diagonal),
        ] {
            if let Some(x) = number(key, v, 0.0, false, 1.0, unit)? {
                *slot = x;
            }
        }
        head.reach = reach;
        if let Some(x) = number(
            "turn_time_s",
            &self.turn_time_s,
            0.0,
            true,
            60.0,
            "seconds in [0, 60] (0 turns at once)",
        )? {
            head.turn_time = x;
        }
        if let Some(x) = number(
            "follow_gain",
            &self.follow_gain,
            0.0,
            true,
            10.0,
            "a factor in [0, 10]",
        )? {
            head.follow_gain = x;
        }
        if let Some(x) = number(
            "follow_max_deg",
            &self.follow_max_deg,
            0.0,
            true,
            180.0,
            "degrees in [0, 180]",
        )? {
            head.follow_max = x.to_radians();
        }
        if let Some(x) = number(
            "eye_max_deg",
            &self.eye_max_deg,
            0.0,
            true,
            90.0,
            "degrees in [0, 90]",
        )? {
            head.eye_max = x.to_radians();
        }
        // The eyes must be told apart: the left one on the character's left.
        let left = character.frame.to_mouth(&head.eye_left);
        let right = character.frame.to_mouth(&head.eye_right);
        if left.x <= right.x {
            let span = self.eye_left.as_ref().or(self.eye_right.as_ref());
            return Err(c.err(
                "head.eye_left",
                span.map(|s| s.span()),
                format!(
                    "the left eye must be on the character's left of the right eye (further \
                     along the mouth frame's x, from the right corner to the left one); \
                     here it is at x = {:.4} and the right eye at x = {:.4}",
                    left.x, right.x
                ),
            ));
        }
        let scale = character.mouth_width() * 1e-6;
        for (key, v, p) in [
            ("eye_left", &self.eye_left, head.eye_left),
            ("eye_right", &self.eye_right, head.eye_right),
        ] {
            if (p - head.pivot).norm() <= scale {
                return Err(c.err(
                    format!("head.{key}"),
                    v.as_ref().or(self.pivot.as_ref()).map(|s| s.span()),
                    "must not sit on the head's pivot",
                ));
            }
        }
        Ok(head)
    }
}
