//! Character files (docs/method.md §7): a character's neutral mouth points, where its mouth frame
//! is, which performer dot drives which point, and how the deformation `M` is chosen.
//!
//! The format is documented in `docs/retarget.md`. Parsing is strict: unknown keys, non-finite
//! numbers, duplicate names, a map naming points that do not exist, coincident corners and an
//! `up` parallel to the corner line are errors naming the key, the line and the reason.

use std::ops::Range;

use serde::Deserialize;
use toml::Spanned;

use crate::error::line_of;
use crate::layout::{parse_dot_name, DotId, PerformerLayout};
use crate::named::Named;
use crate::{Error, MouthFrame, Vec3};

mod points;
use points::*;
pub use points::{resample, MAX_POINTS_PER_LIP};

pub use crate::deform::MMode;

/// Units of a character's coordinates, when the file says (`units`). Export uses them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum Units {
    /// Metres.
    #[serde(rename = "m")]
    Metres,
    /// Centimetres.
    #[serde(rename = "cm")]
    Centimetres,
    /// Millimetres.
    #[serde(rename = "mm")]
    Millimetres,
}

impl Units {
    /// The unit as character files and the protocol spell it: `m`, `cm` or `mm`.
    pub fn symbol(self) -> &'static str {
        match self {
            Units::Metres => "m",
            Units::Centimetres => "cm",
            Units::Millimetres => "mm",
        }
    }

    /// Metres per unit.
    pub fn metres_per_unit(self) -> f64 {
        match self {
            Units::Metres => 1.0,
            Units::Centimetres => 0.01,
            Units::Millimetres => 0.001,
        }
    }
}

/// A character ready for retargeting.
#[derive(Debug, Clone, PartialEq)]
pub struct Character {
    /// The character's name (`name`), used on the wire.
    pub name: String,
    /// Units of its coordinates, if given.
    pub units: Option<Units>,
    /// Point names in order around the mouth: `P1..PN` by number (whatever the file's order),
    /// the file's order when a `[map]` says which dot drives which, or `P1..PN` from contours.
    pub point_names: Vec<String>,
    /// The neutral points as given (model frame, or already a mouth frame).
    pub model_points: Vec<Vec3>,
    /// The mouth frame within the model frame (docs/method.md §2).
    pub frame: MouthFrame,
    /// `P⁰`: the neutral points in the mouth frame.
    pub neutral: Vec<Vec3>,
    /// For each point, the 0-based index of the performer lip dot that drives it.
    pub driver: Vec<usize>,
    /// How `M` is chosen.
    pub m_mode: MMode,
    /// With `MMode::Manual`: `M` per point, in point order.
    pub manual_m: Option<Vec<Vec3>>,
    /// The head and eyes (`[head]`; defaults placed from the mouth when absent).
    pub head: crate::head::HeadConfig,
    /// The character's own rig ranges (`[rig.ranges]`, docs/rig.md); empty: the performer's.
    pub rig_ranges: crate::rig::RangeOverrides,
    /// Where the character's jaw hinges (`[rig] jaw_pivot`, model frame, character units):
    /// the exported `jaw` node's place. `None`: placed from the mouth width with the default
    /// hinge ratios.
    pub jaw_pivot: Option<Vec3>,
}

/// Mouth-frame coordinates within this fraction of the mouth width of zero are exactly zero.
pub const SNAP_TO_ZERO: f64 = 1e-9;

/// The character's "up" in its model frame when the file gives none.
pub const DEFAULT_UP: [f64; 3] = [0.0, 1.0, 0.0];

impl Character {
    /// Builds a character from its parts. `driver[n]` is the lip dot driving point `n`; it must
    /// be a permutation of `0..N`. The left corner is the point driven by `D1`, the right
    /// corner the one driven by `D⌊N/2⌋+1`.
    pub fn new(
        name: impl Into<String>,
        point_names: Vec<String>,
        model_points: Vec<Vec3>,
        up: Vec3,
        driver: Vec<usize>,
        m_mode: MMode,
        manual_m: Option<Vec<Vec3>>,
    ) -> Result<Self, Error> {
        let n = model_points.len();
        let bad = |key: &str, reason: String| Error::CharacterInvalid {
            key: key.to_string(),
            line: None,
            reason,
        };
        if n < 4 {
            return Err(bad(
                "points",
                format!("a mouth needs at least 4 points, got {n}"),
            ));
        }
        if point_names.len() != n || driver.len() != n {
            return Err(bad(
                "points",
                "names, points and drivers differ in number".into(),
            ));
        }
        let mut seen = vec![false; n];
        for &d in &driver {
            if d >= n || std::mem::replace(&mut seen[d], true) {
                return Err(bad(
                    "map",
                    "each lip dot must drive exactly one point".into(),
                ));
            }
        }
        if m_mode == MMode::Manual && manual_m.as_ref().map(Vec::len) != Some(n) {
            return Err(bad("m", "manual mode needs a value for every point".into()));
        }
        let layout = PerformerLayout {
            lip_dots: n,
            forehead_dots: 0,
        };
        let left = driver
            .iter()
            .position(|&d| d == layout.left_corner())
            .expect("permutation");
        let right = driver
            .iter()
            .position(|&d| d == layout.right_corner())
            .expect("permutation");
        let frame =
            MouthFrame::from_corners(model_points[left], model_points[right], up).map_err(|e| {
                match e {
                    Error::CoincidentCorners { .. } => Error::CoincidentCorners {
                        left: point_names[left].clone(),
                        right: point_names[right].clone(),
                    },
                    other => other,
                }
            })?;
        // Rounding in the frame change leaves ~1e-17 where the artist wrote an exact 0 (the
        // corners' y and z, a centred point's x); §5 looks at signs, so make those exact.
        let snap = SNAP_TO_ZERO * frame.width;
        let neutral = model_points
            .iter()
            .map(|p| {
                frame
                    .to_mouth(p)
                    .map(|v| if v.abs() <= snap { 0.0 } else { v })
            })
            .collect();
        Ok(Self {
            name: name.into(),
            units: None,
            point_names,
            model_points,
            frame,
            neutral,
            driver,
            m_mode,
            manual_m,
            head: crate::head::HeadConfig::default_for(&frame),
            rig_ranges: crate::rig::RangeOverrides::default(),
            jaw_pivot: None,
        })
    }

    /// Parses and validates a character file.
    pub fn from_toml_str(src: &str) -> Result<Self, Error> {
        let raw: RawCharacter = toml::from_str(src).map_err(|source| Error::CharacterToml {
            line: source.span().map(|s| line_of(src, s.start)),
            source,
        })?;
        raw.validate(src)
    }

    /// Number of points (and of performer lip dots it expects).
    pub fn len(&self) -> usize {
        self.neutral.len()
    }

    /// Always false: a character has at least 4 points.
    pub fn is_empty(&self) -> bool {
        self.neutral.is_empty()
    }

    /// Corner-to-corner width of the mouth, character units.
    pub fn mouth_width(&self) -> f64 {
        self.frame.width
    }

    /// A driver for this character's head and eyes (`[head]`), in its mouth frame's axes.
    pub fn head_driver(&self) -> crate::head::HeadDriver {
        crate::head::HeadDriver::new(self.head, self.frame.axes)
    }

    /// The performer layout this character expects (its lip dot count; 3 forehead dots).
    pub fn performer_layout(&self) -> PerformerLayout {
        PerformerLayout {
            lip_dots: self.len(),
            forehead_dots: 3,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCharacter {
    name: Spanned<String>,
    units: Option<Units>,
    points: Option<Spanned<Named<Spanned<[f64; 3]>>>>,
    up: Option<Spanned<[f64; 3]>>,
    map: Option<Spanned<Named<Spanned<String>>>>,
    m_mode: Option<MMode>,
    m: Option<Spanned<Named<Spanned<[f64; 3]>>>>,
    contour: Option<Spanned<RawContour>>,
    head: Option<Spanned<crate::head_file::RawHead>>,
    rig: Option<RawRig>,
}

/// A character's `[rig]`: its ranges and where its own jaw hinges (the performer's hinge and
/// learning window are in the daemon configuration).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRig {
    ranges: Option<Spanned<Named<Spanned<f64>>>>,
    jaw_pivot: Option<Spanned<[f64; 3]>>,
}

impl RawRig {
    fn jaw_pivot(&self, c: &Checker, frame: &MouthFrame) -> Result<Option<Vec3>, Error> {
        self.jaw_pivot
            .as_ref()
            .map(|v| {
                let p = c.finite("rig.jaw_pivot", v)?;
                c.near_mouth("rig.jaw_pivot", v, &p, frame)
            })
            .transpose()
    }

    fn validate(&self, c: &Checker) -> Result<crate::rig::RangeOverrides, Error> {
        let Some(ranges) = &self.ranges else {
            return Ok(crate::rig::RangeOverrides::default());
        };
        // Each entry on its own first, so that an error names its line.
        for (name, v) in ranges.get_ref().iter() {
            crate::rig::RangeOverrides::from_named([(name, *v.get_ref())]).map_err(
                |(name, reason)| {
                    c.err(
                        format!("rig.ranges.{}", key_excerpt(&name)),
                        Some(v.span()),
                        reason,
                    )
                },
            )?;
        }
        crate::rig::RangeOverrides::from_named(
            ranges.get_ref().iter().map(|(n, v)| (n, *v.get_ref())),
        )
        .map_err(|(name, reason)| {
            c.err(
                format!("rig.ranges.{}", key_excerpt(&name)),
                Some(ranges.span()),
                reason,
            )
        })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawContour {
    upper: Spanned<Vec<[f64; 3]>>,
    lower: Spanned<Vec<[f64; 3]>>,
    points_per_lip: Spanned<usize>,
}

pub(crate) struct Checker<'a> {
    pub(crate) src: &'a str,
}

/// Farthest a character's head pivot, eyes or jaw hinge may sit from the mouth's centre, in
/// mouth widths (a few in the shipped characters): further is a typo or the wrong units.
pub const MAX_MOUTH_WIDTHS_AWAY: f64 = 50.0;

/// A TOML key as shown in an error: cut to its first 80 characters.
fn key_excerpt(key: &str) -> String {
    const MAX_CHARS: usize = 80;
    if key.chars().count() <= MAX_CHARS {
        key.to_string()
    } else {
        let head: String = key.chars().take(MAX_CHARS).collect();
        format!("{head}… ({} bytes)", key.len())
    }
}

impl Checker<'_> {
    /// `p` (model frame) within [`MAX_MOUTH_WIDTHS_AWAY`] mouth widths of the mouth's centre.
    pub(crate) fn near_mouth(
        &self,
        key: &str,
        v: &Spanned<[f64; 3]>,
        p: &Vec3,
        frame: &MouthFrame,
    ) -> Result<Vec3, Error> {
        let away = (p - frame.origin).norm() / frame.width;
        if !away.is_finite() || away > MAX_MOUTH_WIDTHS_AWAY {
            return Err(self.err(
                key,
                Some(v.span()),
                format!(
                    "{:?} is {away:.3e} mouth widths from the mouth's centre (at most \
                     {MAX_MOUTH_WIDTHS_AWAY}: a typo, or other units than the points?)",
                    v.get_ref()
                ),
            ));
        }
        Ok(*p)
    }

    pub(crate) fn err(
        &self,
        key: impl Into<String>,
        span: Option<Range<usize>>,
        reason: impl Into<String>,
    ) -> Error {
        Error::CharacterInvalid {
            key: key.into(),
            line: span.map(|s| line_of(self.src, s.start)),
            reason: reason.into(),
        }
    }

    pub(crate) fn finite(&self, key: &str, v: &Spanned<[f64; 3]>) -> Result<Vec3, Error> {
        let a = v.get_ref();
        if !a.iter().all(|c| c.is_finite()) {
            Err(self.err(key, Some(v.span()), format!("non-finite number in {a:?}")))
        } else if !crate::layout::coordinates_in_range(a) {
            Err(self.err(
                key,
                Some(v.span()),
                format!(
                    "coordinate beyond {} in {a:?}",
                    crate::layout::MAX_COORDINATE
                ),
            ))
        } else {
            Ok(Vec3::new(a[0], a[1], a[2]))
        }
    }
}

impl RawCharacter {
    fn validate(self, src: &str) -> Result<Character, Error> {
        let c = Checker { src };
        let name = self.name.get_ref().trim().to_string();
        if name.is_empty() {
            return Err(c.err("name", Some(self.name.span()), "must not be empty"));
        }

        let (point_names, points, spans): (Vec<String>, Vec<Vec3>, Vec<Option<Range<usize>>>) =
            match (&self.points, &self.contour) {
                (Some(_), Some(contour)) => {
                    return Err(c.err(
                        "contour",
                        Some(contour.span()),
                        "give either [points] or [contour], not both",
                    ))
                }
                (None, None) => {
                    return Err(c.err("points", None, "missing: give [points] or [contour]"))
                }
                (Some(points), None) => {
                    let mut names = Vec::new();
                    let mut values = Vec::new();
                    let mut spans = Vec::new();
                    for (pname, v) in points.get_ref().iter() {
                        let key = format!("points.{pname}");
                        if pname.is_empty() {
                            return Err(c.err(
                                key,
                                Some(v.span()),
                                "point names must not be empty",
                            ));
                        }
                        if names.iter().any(|n: &String| n == pname) {
                            return Err(c.err(key, Some(v.span()), "duplicate point name"));
                        }
                        values.push(c.finite(&key, v)?);
                        names.push(pname.to_string());
                        spans.push(Some(v.span()));
                    }
                    if names.len() < 4 {
                        return Err(c.err(
                            "points",
                            Some(points.span()),
                            format!("a mouth needs at least 4 points, got {}", names.len()),
                        ));
                    }
                    // A TOML table has no order: the names say which point is which.
                    match order_by_name(&names) {
                        Some(order) => (
                            order.iter().map(|&i| names[i].clone()).collect(),
                            order.iter().map(|&i| values[i]).collect(),
                            order.iter().map(|&i| spans[i].clone()).collect(),
                        ),
                        None if self.map.is_some() => (names, values, spans),
                        None => {
                            let odd = names
                                .iter()
                                .zip(&spans)
                                .find(|(n, _)| point_number(n, names.len()).is_none())
                                .or_else(|| names.iter().zip(&spans).next_back())
                                .expect("at least 4 points");
                            return Err(c.err(
                                format!("points.{}", odd.0),
                                odd.1.clone(),
                                format!(
                                    "point names do not say which point is which: name them P1..P{n} \
                                     (P1 the left corner, the upper lip left to right, P{r} the right \
                                     corner, the lower lip right to left), or give a [map] from the \
                                     dots D1..D{n} to the names, or use [contour]",
                                    n = names.len(),
                                    r = names.len() / 2 + 1
                                ),
                            ));
                        }
                    }
                }
                (None, Some(contour)) => {
                    let pts = contour_points(&c, contour)?;
                    let names = (1..=pts.len()).map(|i| format!("P{i}")).collect();
                    let spans = vec![Some(contour.span()); pts.len()];
                    (names, pts, spans)
                }
            };
        let n = points.len();

        let up = match &self.up {
            Some(up) => {
                let v = c.finite("up", up)?;
                if v.norm() == 0.0 {
                    return Err(c.err("up", Some(up.span()), "must not be the zero vector"));
                }
                v
            }
            None => Vec3::from(DEFAULT_UP),
        };

        let driver = match &self.map {
            None => (0..n).collect(),
            Some(map) => {
                let mut driver = vec![usize::MAX; n];
                for (dot, target) in map.get_ref().iter() {
                    let key = format!("map.{dot}");
                    let lip = match parse_dot_name(dot) {
                        Some(DotId::Lip(i)) if i < n => i,
                        _ => {
                            return Err(c.err(
                                key,
                                Some(target.span()),
                                format!("`{dot}` is not a lip dot of this layout (D1..D{n})"),
                            ))
                        }
                    };
                    let Some(p) = point_names.iter().position(|pn| pn == target.get_ref()) else {
                        return Err(c.err(
                            key,
                            Some(target.span()),
                            format!("no point named `{}` in this character", target.get_ref()),
                        ));
                    };
                    if driver[p] != usize::MAX {
                        return Err(c.err(
                            key,
                            Some(target.span()),
                            format!(
                                "point `{}` is already driven by D{}",
                                target.get_ref(),
                                driver[p] + 1
                            ),
                        ));
                    }
                    driver[p] = lip;
                }
                if let Some(p) = driver.iter().position(|&d| d == usize::MAX) {
                    return Err(c.err(
                        "map",
                        Some(map.span()),
                        format!(
                            "point `{}` is driven by no dot; map every point",
                            point_names[p]
                        ),
                    ));
                }
                driver
            }
        };

        let m_mode = self.m_mode.unwrap_or_default();
        let manual_m = match (&self.m, m_mode) {
            (Some(m), MMode::Manual) => {
                let mut values = vec![None; n];
                for (pname, v) in m.get_ref().iter() {
                    let key = format!("m.{pname}");
                    let Some(p) = point_names.iter().position(|pn| pn == pname) else {
                        return Err(c.err(
                            key,
                            Some(v.span()),
                            format!("no point named `{pname}` in this character"),
                        ));
                    };
                    values[p] = Some(c.finite(&key, v)?);
                }
                let mut out = Vec::with_capacity(n);
                for (p, v) in values.into_iter().enumerate() {
                    out.push(v.ok_or_else(|| {
                        c.err(
                            "m",
                            Some(m.span()),
                            format!("no value for point `{}`", point_names[p]),
                        )
                    })?);
                }
                Some(out)
            }
            (None, MMode::Manual) => {
                return Err(c.err("m", None, "m_mode = \"manual\" needs an [m] table"))
            }
            (Some(m), _) => {
                return Err(c.err(
                    "m",
                    Some(m.span()),
                    "[m] is only read with m_mode = \"manual\"",
                ))
            }
            (None, _) => None,
        };

        let names_for_errors = point_names.clone();
        let mut character = Character::new(name, point_names, points, up, driver, m_mode, manual_m)
            .map_err(|e| match e {
                Error::CoincidentCorners { ref left, .. } => {
                    let at = names_for_errors.iter().position(|n| n == left).unwrap_or(0);
                    c.err("points", spans[at].clone(), e.to_string())
                }
                Error::UpParallelToCorners => c.err(
                    "up",
                    self.up.as_ref().map(|u| u.span()),
                    "is parallel to the line through the mouth corners",
                ),
                other => other,
            })?;
        character.units = self.units;
        if let Some(head) = &self.head {
            character.head = head.get_ref().validate(src, &character)?;
        }
        if let Some(rig) = &self.rig {
            character.rig_ranges = rig.validate(&c)?;
            character.jaw_pivot = rig.jaw_pivot(&c, &character.frame)?;
        }
        Ok(character)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    const SQUARE: &str = r#"
name = "square"
[points]
P1 = [1.0, 0.0, 0.0]
P2 = [0.0, 1.0, 0.5]
P3 = [-1.0, 0.0, 0.0]
P4 = [0.0, -1.0, 0.5]
"#;

    fn invalid(src: &str) -> (String, Option<usize>, String) {
        match Character::from_toml_str(src) {
            Err(Error::CharacterInvalid { key, line, reason }) => (key, line, reason),
            Err(Error::CharacterToml { line, source }) => {
                ("<toml>".into(), line, source.message().to_string())
            }
            other => panic!("expected an error, got {other:?}"),
        }
    }

    #[test]
    fn m_mode_names_read_back_as_the_file_spells_them() {
        for mode in [MMode::PerPoint, MMode::PerAxis, MMode::Manual] {
            let parsed: MMode = toml::Value::String(mode.name().to_owned())
                .try_into()
                .unwrap();
            assert_eq!(parsed, mode);
        }
    }

    #[test]
    fn mouth_frame_points_come_out_unchanged() {
        let c = Character::from_toml_str(SQUARE).unwrap();
        assert_eq!(c.point_names, ["P1", "P2", "P3", "P4"]);
        assert_eq!(c.neutral, c.model_points);
        assert_eq!(c.mouth_width(), 2.0);
        assert_eq!(c.driver, [0, 1, 2, 3]);
    }

    #[test]
    fn model_frame_is_converted_with_up() {
        // The square, rotated so its up is model +Z and it faces model -Y, and shifted.
        let src = r#"
name = "turned"
up = [0.3, 0.0, 2.0]   # not orthogonal to the corner line: only its orthogonal part counts
[points]
P1 = [11.0, 5.0, 3.0]
P2 = [10.0, 4.5, 4.0]
P3 = [9.0, 5.0, 3.0]
P4 = [10.0, 4.5, 2.0]
"#;
        let c = Character::from_toml_str(src).unwrap();
        let expect = Character::from_toml_str(SQUARE).unwrap().neutral;
        for (a, b) in c.neutral.iter().zip(&expect) {
            assert_relative_eq!(a, b, epsilon = 1e-12);
        }
    }

    /// The human character as a serialiser that sorts keys writes it (P1, P10, P11, P12,
    /// P2, ...) is the same character: names, not the file's order, place the points.
    #[test]
    fn points_are_ordered_by_name_not_by_the_files_order() {
        let human = include_str!("../../../config/characters/human.toml");
        let (head, table) = human.split_once("[points]").unwrap();
        let mut lines: Vec<&str> = table.lines().filter(|l| l.starts_with('P')).collect();
        lines.sort_unstable(); // P1, P10, P11, P12, P2, ...
        assert!(lines[1].starts_with("P10"));
        let sorted = format!("{head}[points]\n{}\n", lines.join("\n"));
        let want = Character::from_toml_str(human).unwrap();
        let got = Character::from_toml_str(&sorted).unwrap();
        assert_eq!(got.point_names, want.point_names);
        assert_eq!(got.driver, want.driver);
        for (a, b) in got.neutral.iter().zip(&want.neutral) {
            assert_relative_eq!(a, b, epsilon = 1e-12);
        }
        let src = "name = \"o\"\n[points]\nP3 = [-1, 0, 0]\nP1 = [1, 0, 0]\nP2 = [0, 1, 0]\nP4 = [0, -1, 0]\n";
        let c = Character::from_toml_str(src).unwrap();
        assert_eq!(c.point_names, ["P1", "P2", "P3", "P4"]);
        // Corners are the points driven by D1 and D3 (of 4): P1 and P3.
        assert_relative_eq!(c.neutral[0], Vec3::new(c.mouth_width() / 2.0, 0.0, 0.0));
        assert_relative_eq!(c.mouth_width(), 2.0);
    }

    /// Names that do not say which point is which need a `[map]` (or `[contour]`).
    #[test]
    fn free_point_names_need_a_map() {
        let src = "name = \"o\"\n[points]\nleft = [1, 0, 0]\ntop = [0, 1, 0]\nright = [-1, 0, 0]\nbottom = [0, -1, 0]\n";
        let (key, line, reason) = invalid(src);
        assert_eq!((key.as_str(), line), ("points.left", Some(3)));
        assert!(
            reason.contains("[map]") && reason.contains("P1..P4"),
            "{reason}"
        );
        // P0 or P5 of four points, or a name twice over in another spelling, do not say it
        // either.
        let (key, _, _) = invalid("name = \"o\"\n[points]\nP1 = [1, 0, 0]\nP2 = [0, 1, 0]\nP3 = [-1, 0, 0]\nP5 = [0, -1, 0]\n");
        assert_eq!(key, "points.P5");
        let mapped =
            format!("{src}[map]\nD1 = \"left\"\nD2 = \"top\"\nD3 = \"right\"\nD4 = \"bottom\"\n");
        let c = Character::from_toml_str(&mapped).unwrap();
        assert_eq!(c.driver, [0, 1, 2, 3]);
        assert_relative_eq!(c.neutral[0], Vec3::new(1.0, 0.0, 0.0));
    }

    #[test]
    fn map_and_manual_m() {
        // Top-level keys must come before the tables in TOML.
        let src = SQUARE.replace(
            "name = \"square\"\n",
            "name = \"square\"\nm_mode = \"manual\"\n",
        ) + "[map]\nD1 = \"P1\"\nD2 = \"P4\"\nD3 = \"P3\"\nD4 = \"P2\"\n"
            + "[m]\nP1 = [1, 2, 3]\nP2 = [1, 1, 1]\nP3 = [2, 2, 2]\nP4 = [0.5, 0.5, 0.5]\n";
        let c = Character::from_toml_str(&src).unwrap();
        assert_eq!(c.driver, [0, 3, 2, 1]);
        assert_eq!(c.m_mode, MMode::Manual);
        assert_eq!(c.manual_m.as_ref().unwrap()[0], Vec3::new(1.0, 2.0, 3.0));
    }

    #[test]
    fn contour_points_at_equal_arc_length() {
        let src = r#"
name = "c"
[contour]
points_per_lip = 4
upper = [[3.0, 0.0, 0.0], [3.0, 3.0, 0.0], [-3.0, 3.0, 0.0], [-3.0, 0.0, 0.0]]
lower = [[3.0, 0.0, 0.0], [-3.0, 0.0, 0.0]]
"#;
        let c = Character::from_toml_str(src).unwrap();
        assert_eq!(c.len(), 6);
        assert_eq!(c.point_names, ["P1", "P2", "P3", "P4", "P5", "P6"]);
        // Upper: length 12, a point every 4 along it; lower: length 6, every 2, reversed.
        let expect = [
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(2.0, 3.0, 0.0),
            Vec3::new(-2.0, 3.0, 0.0),
            Vec3::new(-3.0, 0.0, 0.0),
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
        ];
        for (a, b) in c.neutral.iter().zip(&expect) {
            assert_relative_eq!(a, b, epsilon = 1e-12);
        }
    }

    #[test]
    fn rejections_name_key_line_and_reason() {
        let (key, line, reason) =
            invalid(&SQUARE.replace("name = \"square\"", "name = \"s\"\ncolour = 1"));
        assert_eq!((key.as_str(), line), ("<toml>", Some(3)));
        assert!(reason.contains("unknown field `colour`"), "{reason}");

        let (key, line, reason) =
            invalid(&SQUARE.replace("P2 = [0.0, 1.0, 0.5]", "P2 = [0.0, nan, 0.5]"));
        assert_eq!((key.as_str(), line), ("points.P2", Some(5)));
        assert!(reason.contains("non-finite"));

        let (key, line, reason) = invalid(&SQUARE.replace("P4", "P2"));
        assert_eq!((key.as_str(), line), ("<toml>", Some(7)));
        assert!(reason.contains("duplicate key"), "{reason}");

        let (key, line, reason) = invalid(&format!("{SQUARE}[map]\nD1 = \"P1\"\nD2 = \"P9\"\n"));
        assert_eq!((key.as_str(), line), ("map.D2", Some(10)));
        assert!(reason.contains("no point named `P9`"));

        let (key, _, reason) = invalid(&format!(
            "{SQUARE}[map]\nD1 = \"P1\"\nD2 = \"P1\"\nD3 = \"P3\"\nD4 = \"P4\"\n"
        ));
        assert_eq!(key, "map.D2");
        assert!(reason.contains("already driven by D1"), "{reason}");

        let (key, _, reason) = invalid(&format!("{SQUARE}[map]\nD1 = \"P1\"\nD5 = \"P2\"\n"));
        assert_eq!(key, "map.D5");
        assert!(reason.contains("not a lip dot"));

        let (key, _, reason) = invalid(&format!("{SQUARE}[map]\nD1 = \"P1\"\n"));
        assert_eq!(key, "map");
        assert!(reason.contains("driven by no dot"));

        let (key, line, reason) =
            invalid(&SQUARE.replace("P3 = [-1.0, 0.0, 0.0]", "P3 = [1.0, 0.0, 0.0]"));
        assert_eq!((key.as_str(), line), ("points", Some(4)));
        assert!(reason.contains("corners P1 and P3 coincide"), "{reason}");

        let (key, line, reason) =
            invalid(&SQUARE.replace("name = \"square\"", "name = \"s\"\nup = [-2, 0, 0]"));
        assert_eq!((key.as_str(), line), ("up", Some(3)));
        assert!(reason.contains("parallel"));

        let (key, _, _) =
            invalid(&SQUARE.replace("name = \"square\"", "name = \"s\"\nup = [0, 0, 0]"));
        assert_eq!(key, "up");

        let (key, _, reason) =
            invalid(&SQUARE.replace("name = \"square\"", "name = \"s\"\nm_mode = \"manual\""));
        assert_eq!(key, "m");
        assert!(reason.contains("needs an [m] table"));

        let (key, _, reason) = invalid(&format!("{SQUARE}[m]\nP1 = [1, 1, 1]\n"));
        assert_eq!(key, "m");
        assert!(reason.contains("only read with"));

        let (key, _, reason) = invalid("name = \"x\"\n[points]\nP1 = [1, 0, 0]\nP2 = [-1, 0, 0]\n");
        assert_eq!(key, "points");
        assert!(reason.contains("at least 4"));

        let (key, line, _) = invalid("name = \"x\"\n[points]\nP1 = [1, 0]\n");
        assert_eq!((key.as_str(), line), ("<toml>", Some(3)));

        let (key, _, reason) = invalid("name = \"x\"\n");
        assert_eq!(key, "points");
        assert!(reason.contains("missing"));

        let (key, _, reason) = invalid(
            "name = \"c\"\n[contour]\npoints_per_lip = 4\nupper = [[1, 0, 0], [0, 1, 0], [-1, 0, 0]]\nlower = [[1, 0, 0], [-2, 0, 0]]\n",
        );
        assert_eq!(key, "contour.lower");
        assert!(reason.contains("must start and end"));

        let (key, _, _) = invalid(
            "name = \"c\"\n[contour]\npoints_per_lip = 2\nupper = [[1, 0, 0], [-1, 0, 0]]\nlower = [[1, 0, 0], [-1, 0, 0]]\n",
        );
        assert_eq!(key, "contour.points_per_lip");

        let (key, _, _) = invalid(&format!("{SQUARE}[contour]\npoints_per_lip = 3\nupper = [[1, 0, 0], [-1, 0, 0]]\nlower = [[1, 0, 0], [-1, 0, 0]]\n"));
        assert_eq!(key, "contour");
    }

    #[test]
    fn head_table_is_read_and_checked() {
        let c = Character::from_toml_str(SQUARE).unwrap();
        // Without [head]: placed from the mouth (width 2): pivot 1.6 widths behind.
        assert_relative_eq!(c.head.pivot, Vec3::new(0.0, 1.0, -3.2), epsilon = 1e-12);
        assert_eq!(c.head.reach, crate::head::Reach::default());
        let src = format!(
            "{SQUARE}[head]\npivot = [0, 1, -2]\nreach_up = 0.5\nturn_time_s = 0\nfollow_max_deg = 45\n"
        );
        let c = Character::from_toml_str(&src).unwrap();
        assert_eq!(c.head.pivot, Vec3::new(0.0, 1.0, -2.0));
        assert_eq!(c.head.reach.up, 0.5);
        assert_eq!(c.head.turn_time, 0.0);
        assert_relative_eq!(c.head.follow_max, std::f64::consts::FRAC_PI_4);
        for (table, key, line, words) in [
            ("reach_up = 1.5", "head.reach_up", 9, "(0, 1]"),
            ("reach_side = 0", "head.reach_side", 9, "(0, 1]"),
            ("turn_time_s = -1", "head.turn_time_s", 9, "[0, 60]"),
            ("follow_gain = nan", "head.follow_gain", 9, "[0, 10]"),
            ("eye_max_deg = 91", "head.eye_max_deg", 9, "[0, 90]"),
            ("pivot = [0, inf, 0]", "head.pivot", 9, "non-finite"),
            (
                "eye_left = [-1, 1, 0]\neye_right = [1, 1, 0]",
                "head.eye_left",
                9,
                "character's left",
            ),
            ("pivot = [1.3, 2.8, -0.4]", "head.eye_left", 9, "pivot"),
        ] {
            let src = format!("{SQUARE}[head]\n{table}\n");
            let (k, l, reason) = invalid(&src);
            assert_eq!((k.as_str(), l), (key, Some(line)), "{table}: {reason}");
            assert!(reason.contains(words), "{table}: {reason}");
        }
        let (k, l, reason) = invalid(&format!("{SQUARE}[head]\nneck = 1\n"));
        assert_eq!((k.as_str(), l), ("<toml>", Some(9)), "{reason}");
        assert!(reason.contains("unknown field `neck`"), "{reason}");
    }

    #[test]
    fn rig_ranges_table_is_read_and_checked() {
        let c = Character::from_toml_str(SQUARE).unwrap();
        assert!(
            c.rig_ranges.is_empty(),
            "without [rig]: the performer's ranges"
        );
        let src = format!("{SQUARE}[rig.ranges]\njawOpen = 30\nmouthFunnel = 0.2\n");
        let c = Character::from_toml_str(&src).unwrap();
        let i = |n: &str| crate::rig::curve_index(n).unwrap();
        assert_eq!(c.rig_ranges.0[i("jawOpen")], Some(30.0));
        assert_eq!(c.rig_ranges.0[i("mouthFunnel")], Some(0.2));
        assert_eq!(c.rig_ranges.0.iter().flatten().count(), 2);
        for (table, key, line, words) in [
            (
                "mouthSmile = 0.1",
                "rig.ranges.mouthSmile",
                9,
                "not a curve name",
            ),
            (
                "jawOpen = 30\nmouthPucker = 0",
                "rig.ranges.mouthPucker",
                10,
                "positive",
            ),
            ("mouthClose = -1", "rig.ranges.mouthClose", 9, "positive"),
            ("mouthClose = nan", "rig.ranges.mouthClose", 9, "positive"),
            (
                "mouthClose = 1e6",
                "rig.ranges.mouthClose",
                9,
                "at most 1000",
            ),
        ] {
            let src = format!("{SQUARE}[rig.ranges]\n{table}\n");
            let (k, l, reason) = invalid(&src);
            assert_eq!((k.as_str(), l), (key, Some(line)), "{table}: {reason}");
            assert!(reason.contains(words), "{table}: {reason}");
        }
        // The hinge and the learning window are the performer's, not the character's.
        let (k, l, reason) = invalid(&format!("{SQUARE}[rig]\nhinge_up = 0.5\n"));
        assert_eq!((k.as_str(), l), ("<toml>", Some(9)), "{reason}");
        assert!(reason.contains("unknown field `hinge_up`"), "{reason}");
        let (k, _, reason) = invalid(&format!("{SQUARE}[rig.ranges]\njawOpen = \"x\"\n"));
        assert_eq!(k, "<toml>", "{reason}");
    }

    /// `[rig] jaw_pivot`: the character's own hinge, model frame, read as given; a bad one is
    /// refused naming the key and its line.
    #[test]
    fn rig_jaw_pivot_is_read_and_checked() {
        assert_eq!(Character::from_toml_str(SQUARE).unwrap().jaw_pivot, None);
        let src = format!("{SQUARE}[rig]\njaw_pivot = [0.0, 1.5, -4.0]\n");
        let c = Character::from_toml_str(&src).unwrap();
        assert_eq!(c.jaw_pivot, Some(Vec3::new(0.0, 1.5, -4.0)));
        let src =
            format!("{SQUARE}[rig]\njaw_pivot = [0.0, 1.5, -4.0]\n[rig.ranges]\njawOpen = 20\n");
        let c = Character::from_toml_str(&src).unwrap();
        assert!(c.jaw_pivot.is_some() && !c.rig_ranges.is_empty());
        for (value, words) in [
            ("[0.0, nan, 1.0]", "non-finite"),
            ("[0.0, 1e12, 1.0]", "beyond"),
        ] {
            let (k, l, reason) = invalid(&format!("{SQUARE}[rig]\njaw_pivot = {value}\n"));
            assert_eq!(
                (k.as_str(), l),
                ("rig.jaw_pivot", Some(9)),
                "{value}: {reason}"
            );
            assert!(reason.contains(words), "{value}: {reason}");
        }
        let (k, _, reason) = invalid(&format!("{SQUARE}[rig]\njaw_pivot = [0.0, 1.0]\n"));
        assert_eq!(k, "<toml>", "{reason}");
    }

    #[test]
    fn shipped_characters_load() {
        for (file, name) in [("human.toml", "human"), ("wolf.toml", "wolf")] {
            let path = format!(
                "{}/../../config/characters/{file}",
                env!("CARGO_MANIFEST_DIR")
            );
            let c = Character::from_toml_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            assert_eq!(c.name, name);
            assert_eq!(c.len(), 12);
            assert_eq!(c.units, Some(Units::Metres));
            // Corners on the x axis, left at +x.
            assert_relative_eq!(c.neutral[0].x, c.mouth_width() / 2.0, epsilon = 1e-12);
            assert_relative_eq!(c.neutral[6].x, -c.mouth_width() / 2.0, epsilon = 1e-12);
            assert!(
                c.neutral[3].y > 0.0 && c.neutral[9].y < 0.0,
                "upper lip up, lower down"
            );
            assert!(c.neutral[3].z > 0.0, "lips in front of the corners");
        }
        let wolf = std::fs::read_to_string(format!(
            "{}/../../config/characters/wolf.toml",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap();
        let wolf = Character::from_toml_str(&wolf).unwrap();
        assert_relative_eq!(wolf.mouth_width(), 0.15, epsilon = 1e-9);
        assert!(wolf.neutral[3].z > 0.1, "a long muzzle");
        // Exact zeros survive the frame change (the §5 sign test depends on them).
        assert_eq!(wolf.neutral[3].x, 0.0);
        assert_eq!((wolf.neutral[0].y, wolf.neutral[0].z), (0.0, 0.0));
        assert_eq!((wolf.neutral[6].y, wolf.neutral[6].z), (0.0, 0.0));
    }
    /// Head points and the jaw hinge far from the mouth (wrong units, a typo): errors naming
    /// key and line.
    #[test]
    fn head_and_jaw_points_far_from_the_mouth_are_refused() {
        // The square's mouth is 2 wide, centred on the origin: 50 widths is 100.
        for (table, key, line) in [
            ("[rig]\njaw_pivot = [0.0, 0.0, 1e6]", "rig.jaw_pivot", 9),
            ("[rig]\njaw_pivot = [101.0, 0.0, 0.0]", "rig.jaw_pivot", 9),
            ("[head]\npivot = [0.0, -1e6, 0.0]", "head.pivot", 9),
            ("[head]\neye_left = [1e5, 1.0, 0.0]", "head.eye_left", 9),
        ] {
            let (k, l, reason) = invalid(&format!("{SQUARE}{table}\n"));
            assert_eq!((k.as_str(), l), (key, Some(line)), "{table}: {reason}");
            assert!(reason.contains("mouth widths"), "{table}: {reason}");
        }
        assert!(Character::from_toml_str(&format!(
            "{SQUARE}[rig]\njaw_pivot = [99.0, 0.0, 0.0]\n"
        ))
        .is_ok());
        let (_, _, reason) = invalid(&format!("{SQUARE}[head]\nturn_time_s = 1e300\n"));
        assert!(reason.contains("got 1e300"), "{reason}");
    }

    /// A range near zero turns the measure's noise into a curve jumping between 0 and 1.
    #[test]
    fn rig_ranges_near_zero_are_refused() {
        let (k, _, reason) = invalid(&format!("{SQUARE}[rig.ranges]\nmouthClose = 1e-300\n"));
        assert_eq!(k, "rig.ranges.mouthClose", "{reason}");
        assert!(reason.contains("1e-300"), "{reason}");
    }

    /// A megabyte-long range name is cut in the error.
    #[test]
    fn a_long_range_name_is_cut_in_errors() {
        let long = "x".repeat(1_000_000);
        let (k, _, reason) = invalid(&format!("{SQUARE}[rig.ranges]\n{long} = 1\n"));
        assert!(
            k.len() < 120 && reason.len() < 600,
            "{} {}",
            k.len(),
            reason.len()
        );
    }
}
