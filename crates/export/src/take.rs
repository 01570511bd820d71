//! Streaming reader of a take: `retarget` / `process` JSONL, one frame per line.
//!
//! Each line is parsed as the retarget core's [`OutputLine`] (the documented line format;
//! `process` adds fields, which are skipped), so a file of another kind — the raw dots that
//! go *into* `retarget`, say — is refused on its first line with the field it lacks. Memory is
//! one line and one frame, whatever the take's length.

use std::collections::HashMap;
use std::io::BufRead;

use mouthpiece_retarget::jsonl::{read_line_limited, OutputLine, MAX_LINE_BYTES};
use mouthpiece_retarget::rig::{RigFrame, CURVES, CURVE_NAMES};

use crate::ExportError;

/// One time step of the take: the character's mouth points, in the rig's order.
#[derive(Clone, Debug, PartialEq)]
pub struct TakeFrame {
    /// 1-based line of the input this frame came from (for error messages).
    pub line: u64,
    /// Seconds since the start of the stream.
    pub t: f64,
    /// Mouth-frame position per point. JSONL lines always have every point (`retarget` holds
    /// a lost dot's last value); `None` is for frame sources with gaps: no key there.
    pub points: Vec<Option<[f64; 3]>>,
    /// The smoothed mouth outline (`curve`), when the take has one.
    pub curve: Option<Vec<[f64; 3]>>,
    /// The character's head and eyes (`character_head`), when the take has them.
    pub head: Option<HeadKeys>,
    /// The rig's jaw and named curves (`rig`, docs/rig.md), when the line has them: not
    /// before the neutral pose, nor in takes made before the rig.
    pub rig: Option<RigKeys>,
}

/// One frame's jaw and ARKit-named curves (docs/rig.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigKeys {
    /// Opening angle about the hinge axis (the mouth frame's x axis), degrees, > 0 open.
    pub jaw_angle_deg: f64,
    /// Slide along the hinge axis, metres (the performer's), > 0 towards the left.
    pub jaw_slide_m: f64,
    /// The curves in [`CURVE_NAMES`] order, 0..1.
    pub curves: [f64; CURVES],
    /// The upper and the lower lip's rigid motion from neutral (mouth frame): rotation
    /// `[w, x, y, z]` and translation, metres (the performer's).
    pub lips: [LipKeys; 2],
    /// The performer's neutral mouth width, metres (`rig.performer_width_m`); `None` in takes
    /// made before it.
    pub performer_width_m: Option<f64>,
}

/// One lip's rigid motion from neutral (docs/rig.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LipKeys {
    pub rotation: [f64; 4],
    pub translation_m: [f64; 3],
}

impl LipKeys {
    /// No motion.
    pub const REST: LipKeys = LipKeys {
        rotation: [1.0, 0.0, 0.0, 0.0],
        translation_m: [0.0; 3],
    };
}

/// Narrowest and widest performer mouth a take may state, metres.
pub const PERFORMER_WIDTH_M: (f64, f64) = (0.005, 0.5);

impl RigKeys {
    /// Character units per performer metre for the slide and the lip translations: the
    /// character's mouth width (`width`, its units) over the performer's, as the mouth points
    /// are scaled; in a take without the performer's width, the performer's metres in the
    /// character's units (`metres_per_unit`), unscaled, as before.
    pub fn to_character(&self, width: f64, metres_per_unit: Option<f64>) -> f64 {
        match self.performer_width_m {
            Some(w) if width > 0.0 => width / w,
            _ => 1.0 / metres_per_unit.unwrap_or(1.0),
        }
    }
}

impl RigKeys {
    /// The jaw at rest and every curve 0: what a frame without `rig` shows.
    pub const REST: RigKeys = RigKeys {
        jaw_angle_deg: 0.0,
        jaw_slide_m: 0.0,
        curves: [0.0; CURVES],
        lips: [LipKeys::REST; 2],
        performer_width_m: None,
    };
}

/// One frame's head and eye rotations, unit quaternions `[w, x, y, z]` (docs/head.md): the
/// head in the character's model frame, the eyes relative to the head.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadKeys {
    pub head: [f64; 4],
    pub eye_left: [f64; 4],
    pub eye_right: [f64; 4],
}

impl HeadKeys {
    /// The head and eyes at rest (identities): what a frame without a head shows, as
    /// [`RigKeys::REST`] is for the rig.
    pub const REST: HeadKeys = HeadKeys {
        head: [1.0, 0.0, 0.0, 0.0],
        eye_left: [1.0, 0.0, 0.0, 0.0],
        eye_right: [1.0, 0.0, 0.0, 0.0],
    };

    /// The three rotations in node order: head, left eye, right eye.
    pub fn rotations(&self) -> [[f64; 4]; 3] {
        [self.head, self.eye_left, self.eye_right]
    }
}

/// Reads frames from JSONL, checking each line as it goes.
///
/// Checks: a valid [`OutputLine`]; `t` finite and ≥ 0, strictly increasing, also after
/// rounding to f32 (glTF stores times as f32 and requires them to increase); the same point
/// names on every line (an unknown, missing or repeated name is an error); finite coordinates.
pub struct TakeReader<R> {
    input: R,
    source_name: String,
    line_no: u64,
    buf: String,
    bytes_read: u64,
    names: Option<Vec<String>>,
    index: HashMap<String, usize>,
    last_t: Option<(f64, f32)>,
    character: Option<String>,
}

impl<R: BufRead> TakeReader<R> {
    /// A reader that takes the point names, in order, from the first line.
    pub fn new(input: R, source_name: impl Into<String>) -> Self {
        Self {
            input,
            source_name: source_name.into(),
            line_no: 0,
            buf: String::new(),
            bytes_read: 0,
            names: None,
            index: HashMap::new(),
            last_t: None,
            character: None,
        }
    }

    /// A reader that expects exactly these point names (a character file's), in this order.
    pub fn with_points(input: R, source_name: impl Into<String>, names: Vec<String>) -> Self {
        let mut reader = Self::new(input, source_name);
        reader.set_names(names);
        reader
    }

    fn set_names(&mut self, names: Vec<String>) {
        self.index = names
            .iter()
            .enumerate()
            .map(|(i, n)| (n.clone(), i))
            .collect();
        self.names = Some(names);
    }

    /// The point names in frame order: known once the first frame is read, or given.
    pub fn point_names(&self) -> Option<&[String]> {
        self.names.as_deref()
    }

    /// The first line's `character` field, if it had one.
    pub fn character(&self) -> Option<&str> {
        self.character.as_deref()
    }

    /// Whether the take (once its first frame is read) was made for the character of a file
    /// named `file`: a take made for another character is [`ExportError::CharacterMismatch`].
    pub fn check_character(&self, file: &str) -> Result<(), ExportError> {
        match self.character() {
            Some(take) if take != file => Err(ExportError::CharacterMismatch {
                source_name: self.source_name.clone(),
                take: crate::asset::shown(take),
                file: crate::asset::shown(file),
            }),
            _ => Ok(()),
        }
    }

    /// Bytes consumed so far (for progress).
    pub fn bytes_read(&self) -> u64 {
        self.bytes_read
    }

    /// The input's name as used in error messages.
    pub fn source_name(&self) -> &str {
        &self.source_name
    }

    fn bad(&self, problem: impl Into<String>) -> ExportError {
        ExportError::BadLine {
            source_name: self.source_name.clone(),
            line: self.line_no,
            problem: problem.into(),
        }
    }

    /// The next frame, `None` at the end. Blank lines are skipped.
    pub fn next_frame(&mut self) -> Result<Option<TakeFrame>, ExportError> {
        loop {
            self.buf.clear();
            self.line_no += 1;
            let n = read_line_limited(&mut self.input, &mut self.buf, MAX_LINE_BYTES).map_err(
                |cause| ExportError::Read {
                    source_name: self.source_name.clone(),
                    line: self.line_no,
                    cause,
                },
            )?;
            if n == 0 {
                self.line_no -= 1;
                return Ok(None);
            }
            self.bytes_read += n as u64;
            if !self.buf.trim().is_empty() {
                break;
            }
        }
        let parsed: OutputLine =
            serde_json::from_str(&self.buf).map_err(|cause| ExportError::Json {
                source_name: self.source_name.clone(),
                line: self.line_no,
                cause,
            })?;
        self.check_time(parsed.t)?;
        if self.character.is_none() {
            self.character = Some(parsed.character.clone());
        }
        if self.names.is_none() {
            let names: Vec<String> = parsed.points.0.iter().map(|(n, _)| n.clone()).collect();
            if names.is_empty() {
                return Err(self.bad("`points` is empty"));
            }
            let mut seen = std::collections::HashSet::new();
            if let Some(dup) = names.iter().find(|n| !seen.insert(n.as_str())) {
                return Err(self.bad(format!("point {dup} appears twice")));
            }
            self.set_names(names);
        }
        let count = self.index.len();
        let mut points = vec![None; count];
        let mut present = vec![false; count];
        for (name, v) in parsed.points.0 {
            let Some(&i) = self.index.get(&name) else {
                return Err(self.bad(format!(
                    "point {name} is not one of the take's points ({})",
                    self.names.as_deref().unwrap_or_default().join(", ")
                )));
            };
            if std::mem::replace(&mut present[i], true) {
                return Err(self.bad(format!("point {name} appears twice")));
            }
            if !v.iter().all(|c| c.is_finite()) {
                return Err(self.bad(format!("point {name} = {v:?} is not finite")));
            }
            points[i] = Some(v);
        }
        if let Some(i) = present.iter().position(|p| !p) {
            let name = &self.names.as_deref().unwrap_or_default()[i];
            return Err(self.bad(format!("point {name} is missing")));
        }
        tracing::trace!(line = self.line_no, t = parsed.t, "take frame");
        let curve = parsed.curve.map(|c| c.points);
        if let Some(bad) = curve
            .iter()
            .flatten()
            .find(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(self.bad(format!("curve point {bad:?} is not finite")));
        }
        let head = parsed.character_head.map(|h| HeadKeys {
            head: h.rotation,
            eye_left: h.eye_left,
            eye_right: h.eye_right,
        });
        if let Some(h) = &head {
            for (what, q) in ["head", "eye_left", "eye_right"].iter().zip(h.rotations()) {
                let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
                if !(norm.is_finite() && (norm - 1.0).abs() <= 1e-3) {
                    return Err(self.bad(format!(
                        "character_head.{what} = {q:?} is not a unit quaternion"
                    )));
                }
            }
        }
        let rig = match &parsed.rig {
            Some(r) => Some(self.rig_keys(r)?),
            None => None,
        };
        Ok(Some(TakeFrame {
            line: self.line_no,
            t: parsed.t,
            points,
            curve,
            head,
            rig,
        }))
    }

    /// The jaw and the curves of a line's `rig`: every curve of [`CURVE_NAMES`] present (in
    /// any order; names this version does not know are skipped), values finite and in 0..1.
    fn rig_keys(&self, rig: &RigFrame) -> Result<RigKeys, ExportError> {
        let jaw = &rig.jaw;
        for (what, v) in [("angle_deg", jaw.angle_deg), ("slide_m", jaw.slide_m)] {
            if !v.is_finite() {
                return Err(self.bad(format!("rig.jaw.{what} = {v} is not finite")));
            }
        }
        let mut curves = [0.0; CURVES];
        for (dst, name) in curves.iter_mut().zip(CURVE_NAMES) {
            let mut values = rig.curves.0.iter().filter(|(n, _)| n == name);
            let Some(&(_, v)) = values.next() else {
                return Err(self.bad(format!("rig.curves has no {name}")));
            };
            if values.next().is_some() {
                return Err(self.bad(format!("rig.curves has {name} twice")));
            }
            if !(0.0..=1.0).contains(&v) {
                return Err(self.bad(format!("rig.curves.{name} = {v} is not in 0..1")));
            }
            *dst = v;
        }
        let mut lips = [LipKeys::REST; 2];
        for (dst, (name, lip)) in lips
            .iter_mut()
            .zip([("upper", &rig.lips.upper), ("lower", &rig.lips.lower)])
        {
            if !lip
                .translation
                .iter()
                .all(|c| c.is_finite() && c.abs() <= 1.0)
            {
                return Err(self.bad(format!(
                    "rig.lips.{name}.translation = {:?} is not finite metres within ±1",
                    lip.translation
                )));
            }
            let norm = lip.rotation.iter().map(|c| c * c).sum::<f64>().sqrt();
            if !(norm.is_finite() && (norm - 1.0).abs() <= 1e-3) {
                return Err(self.bad(format!(
                    "rig.lips.{name}.rotation = {:?} is not a unit quaternion",
                    lip.rotation
                )));
            }
            *dst = LipKeys {
                rotation: lip.rotation,
                translation_m: lip.translation,
            };
        }
        if let Some(w) = rig.performer_width_m {
            let (lo, hi) = PERFORMER_WIDTH_M;
            if !(lo..=hi).contains(&w) {
                return Err(self.bad(format!(
                    "rig.performer_width_m = {w} is not a mouth width in metres ({lo} to {hi})"
                )));
            }
        }
        Ok(RigKeys {
            jaw_angle_deg: jaw.angle_deg,
            jaw_slide_m: jaw.slide_m,
            curves,
            lips,
            performer_width_m: rig.performer_width_m,
        })
    }

    fn check_time(&mut self, t: f64) -> Result<(), ExportError> {
        if !t.is_finite() || t < 0.0 {
            return Err(self.bad(format!("t = {t} is not a finite time ≥ 0")));
        }
        let t32 = t as f32;
        if let Some((prev, prev32)) = self.last_t {
            if t <= prev {
                return Err(self.bad(format!(
                    "t = {t} does not come after the previous line's t = {prev}"
                )));
            }
            if t32 <= prev32 {
                return Err(self.bad(format!(
                    "t = {t} and the previous t = {prev} are the same time in glTF's 32-bit \
                     floats (frames too close for this time offset)"
                )));
            }
        }
        self.last_t = Some((t, t32));
        Ok(())
    }
}

impl<R: BufRead> Iterator for TakeReader<R> {
    type Item = Result<TakeFrame, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame().transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line in retarget's output format.
    fn line(t: &str, points: &str) -> String {
        format!(
            r#"{{"t": {t}, "seq": 0, "character": "wolf", "points": {points}, "confidence": {{}}, "head": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0]}}, "curve": null}}"#
        )
    }

    fn read_all(text: &str) -> Result<Vec<TakeFrame>, ExportError> {
        TakeReader::new(text.as_bytes(), "take.jsonl").collect()
    }

    #[test]
    fn reads_points_in_document_order_and_skips_other_fields() {
        let text = format!(
            "{}\n\n{}\n",
            line("0.0", r#"{"P2": [1, 2, 3], "P10": [4, 5, 6], "P1": [0, 0, 0]}"#)
                .replace("\"curve\": null", r#""curve": {"method": "sg5", "closed": true, "points": [[1, 2, 3]]}, "performer": {"D1": null}"#),
            line("0.5", r#"{"P1": [0, 0, 1], "P2": [1, 2, 3.5], "P10": [4, 5, 6]}"#),
        );
        let mut reader = TakeReader::new(text.as_bytes(), "take.jsonl");
        let first = reader.next_frame().unwrap().unwrap();
        assert_eq!(reader.point_names().unwrap(), ["P2", "P10", "P1"]);
        assert_eq!(reader.character(), Some("wolf"));
        assert_eq!(
            first.points,
            vec![Some([1.0, 2.0, 3.0]), Some([4.0, 5.0, 6.0]), Some([0.0; 3])]
        );
        assert_eq!(first.curve, Some(vec![[1.0, 2.0, 3.0]]));
        let second = reader.next_frame().unwrap().unwrap();
        assert_eq!(second.line, 3);
        assert_eq!(second.points[2], Some([0.0, 0.0, 1.0]));
        assert_eq!(second.curve, None);
        assert!(reader.next_frame().unwrap().is_none());
    }

    /// The error and its causes, as `main` prints them.
    fn error_of(text: &str) -> String {
        let err = read_all(text).unwrap_err();
        let mut message = err.to_string();
        let mut cause = std::error::Error::source(&err);
        while let Some(c) = cause {
            message += &format!(": {c}");
            cause = c.source();
        }
        message
    }

    #[test]
    fn errors_name_the_line_and_problem() {
        let ok = line("0.1", r#"{"P1": [0, 0, 0]}"#);
        let e = error_of(&format!("{ok}\nnot json\n"));
        assert!(e.starts_with("take.jsonl: line 2: not a take line"), "{e}");
        let e = error_of(&format!("{ok}\n{ok}\n"));
        assert!(e.contains("line 2: t = 0.1 does not come after"), "{e}");
        let e = error_of(&format!("{ok}\n{}\n", line("0.2", r#"{"P9": [0, 0, 0]}"#)));
        assert!(
            e.contains("line 2: point P9 is not one of the take's points (P1)"),
            "{e}"
        );
        let e = error_of(&format!("{ok}\n{}\n", line("0.2", "{}")));
        assert!(e.contains("line 2: point P1 is missing"), "{e}");
        let e = error_of(&line("-1", r#"{"P1": [0, 0, 0]}"#));
        assert!(e.contains("line 1: t = -1 is not a finite time"), "{e}");
        let e = error_of(&line("0", r#"{"P1": [0, 0]}"#));
        assert!(e.contains("line 1: not a take line"), "{e}");
        let e = error_of(&line("0", r#"{"P1": [0, 0, 1e999]}"#));
        assert!(e.contains("line 1"), "{e}");
        let e = error_of(&line("0", r#"{"P1": [0, 0, 0], "P1": [0, 0, 0]}"#));
        assert!(e.contains("line 1: point P1 appears twice"), "{e}");
        let e = error_of(&format!(
            "{}\n{}\n",
            line("100000.0", r#"{"P1": [0, 0, 0]}"#),
            line("100000.001", r#"{"P1": [0, 0, 0]}"#)
        ));
        assert!(e.contains("line 2") && e.contains("32-bit"), "{e}");
        // The raw dots that go into `retarget` are not a take.
        let e = error_of(r#"{"t": 0, "points": {"D1": [0, 0, 0.6]}, "neutral": true}"#);
        assert!(
            e.contains("line 1: not a take line") && e.contains("seq"),
            "{e}"
        );
    }

    /// `line` with a `rig` whose jaw angle is `angle` and curve k is k/20, curves written
    /// in reverse order.
    fn rig_line(t: &str, angle: f64) -> String {
        let curves: Vec<String> = CURVE_NAMES
            .iter()
            .enumerate()
            .rev()
            .map(|(k, n)| format!("\"{n}\": {}", k as f64 / CURVES as f64))
            .collect();
        let rig = format!(
            r#""rig": {{"jaw": {{"angle_deg": {angle}, "slide_m": -0.001}}, "lips": {{"upper": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}, "lower": {{"rotation": [1, 0, 0, 0], "translation": [0, 0, 0], "residual": 0}}}}, "curves": {{{}}}}}"#,
            curves.join(", ")
        );
        line(t, r#"{"P1": [0, 0, 0]}"#)
            .replace("\"curve\": null", &format!("\"curve\": null, {rig}"))
    }

    #[test]
    fn the_rig_is_read_by_curve_name_and_old_takes_have_none() {
        // A take made before the rig: no `rig` on any line, read as ever.
        let old = read_all(&line("0", r#"{"P1": [0, 0, 0]}"#)).unwrap();
        assert_eq!(old[0].rig, None);
        // A process take: no rig while calibrating, then one.
        let text = format!(
            "{}\n{}\n",
            line("0", r#"{"P1": [0, 0, 0]}"#),
            rig_line("0.1", 12.5)
        );
        let frames = read_all(&text).unwrap();
        assert_eq!(frames[0].rig, None);
        let rig = frames[1].rig.unwrap();
        assert_eq!((rig.jaw_angle_deg, rig.jaw_slide_m), (12.5, -0.001));
        for (k, v) in rig.curves.iter().enumerate() {
            assert_eq!(*v, k as f64 / CURVES as f64, "{}", CURVE_NAMES[k]);
        }
        // Bad rigs name the key.
        let e =
            error_of(&rig_line("0", 12.5).replace("\"mouthPressLeft\"", "\"mouthPressLeftish\""));
        assert!(
            e.contains("line 1: rig.curves has no mouthPressLeft"),
            "{e}"
        );
        let press = format!("\"mouthPressRight\": {}", 17.0 / CURVES as f64);
        let e = error_of(&rig_line("0", 12.5).replace(&press, "\"mouthPressRight\": 1.5"));
        assert!(
            e.contains("line 1: rig.curves.mouthPressRight = 1.5 is not in 0..1"),
            "{e}"
        );
        let e =
            error_of(&rig_line("0", 12.5).replace("\"angle_deg\": 12.5", "\"angle_deg\": null"));
        assert!(e.contains("line 1: not a take line"), "{e}");
    }

    /// The performer's mouth width is read when the line has it (takes before it have none)
    /// and refused naming the line when it is no mouth width; absurd lip motions too.
    #[test]
    fn the_performers_width_and_the_lips_are_checked() {
        assert_eq!(
            read_all(&rig_line("0", 1.0)).unwrap()[0]
                .rig
                .unwrap()
                .performer_width_m,
            None
        );
        let with = |w: &str| {
            rig_line("0", 1.0).replace(
                "\"curves\"",
                &format!("\"performer_width_m\": {w}, \"curves\""),
            )
        };
        let rig = read_all(&with("0.052")).unwrap()[0].rig.unwrap();
        assert_eq!(rig.performer_width_m, Some(0.052));
        for bad in ["0", "-0.05", "1e300", "0.001"] {
            let e = error_of(&with(bad));
            assert!(
                e.contains("line 1: rig.performer_width_m") && e.contains("0.005 to 0.5"),
                "{bad}: {e}"
            );
        }
        let e = error_of(&with("\"wide\""));
        assert!(e.contains("line 1: not a take line"), "{e}");
        let upper = r#""upper": {"rotation": [1, 0, 0, 0], "translation": [0, 0, 0]"#;
        let far = rig_line("0", 1.0).replace(
            upper,
            r#""upper": {"rotation": [1, 0, 0, 0], "translation": [0, 1e300, 0]"#,
        );
        let e = error_of(&far);
        assert!(e.contains("line 1: rig.lips.upper.translation"), "{e}");
        let skew = rig_line("0", 1.0).replace(
            upper,
            r#""upper": {"rotation": [2, 0, 0, 0], "translation": [0, 0, 0]"#,
        );
        let e = error_of(&skew);
        assert!(e.contains("line 1: rig.lips.upper.rotation"), "{e}");
    }

    #[test]
    fn given_names_fix_the_order() {
        let text = line("0", r#"{"P2": [2, 0, 0], "P1": [1, 0, 0]}"#);
        let mut reader =
            TakeReader::with_points(text.as_bytes(), "x", vec!["P1".into(), "P2".into()]);
        let frame = reader.next_frame().unwrap().unwrap();
        assert_eq!(
            frame.points,
            vec![Some([1.0, 0.0, 0.0]), Some([2.0, 0.0, 0.0])]
        );
    }
}
