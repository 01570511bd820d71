//! Performer dot names and their order (docs/method.md §1).

/// How many dots the performer wears. Lip dots `D1..DN` walk once around the mouth: `D1` is
/// the performer's left corner, `D2..` the upper lip from left to right, `D⌊N/2⌋+1` the right
/// corner, the rest the lower lip from right to left. Forehead dots `F1..FK` carry the head.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PerformerLayout {
    /// Number of lip dots N (at least 4).
    pub lip_dots: usize,
    /// Number of forehead dots K (at least 3 to track the head).
    pub forehead_dots: usize,
}

/// A performer dot, by kind and 0-based index.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DotId {
    /// Lip dot `D{i+1}`.
    Lip(usize),
    /// Forehead dot `F{i+1}`.
    Forehead(usize),
}

impl Default for PerformerLayout {
    /// The default layout: 12 lip dots, 3 forehead dots.
    fn default() -> Self {
        Self {
            lip_dots: 12,
            forehead_dots: 3,
        }
    }
}

impl PerformerLayout {
    /// Index of the performer's left mouth corner (`D1`).
    pub fn left_corner(&self) -> usize {
        0
    }

    /// Index of the performer's right mouth corner (`D⌊N/2⌋+1`, `D7` for 12 dots).
    pub fn right_corner(&self) -> usize {
        self.lip_dots / 2
    }

    /// Name of lip dot `i` (0-based): `D{i+1}`.
    pub fn lip_name(i: usize) -> String {
        format!("D{}", i + 1)
    }

    /// Name of forehead dot `i` (0-based): `F{i+1}`.
    pub fn forehead_name(i: usize) -> String {
        format!("F{}", i + 1)
    }

    /// Name of a dot.
    pub fn name(id: DotId) -> String {
        match id {
            DotId::Lip(i) => Self::lip_name(i),
            DotId::Forehead(i) => Self::forehead_name(i),
        }
    }
}

/// Largest coordinate accepted from outside (a dot's, a character's), in its units: squares
/// of larger ones overflow in the fits' covariance sums.
pub const MAX_COORDINATE: f64 = 1e6;

/// Whether every coordinate is finite and within [`MAX_COORDINATE`].
pub fn coordinates_in_range(a: &[f64; 3]) -> bool {
    a.iter().all(|c| c.abs() <= MAX_COORDINATE)
}

/// Highest dot number in a name (`D999`, `F999`); real faces carry a few dozen.
pub const MAX_DOT_NUMBER: usize = 999;

/// Parses `D3` / `F2` into a dot id, without checking it against a layout.
pub fn parse_dot_name(name: &str) -> Option<DotId> {
    let (kind, digits) = name.split_at_checked(1)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.starts_with('0') {
        return None;
    }
    let number: usize = digits.parse().ok()?;
    if number > MAX_DOT_NUMBER {
        // Layouts are sized from the highest number named: a huge one is not a dot.
        return None;
    }
    match kind {
        "D" => Some(DotId::Lip(number - 1)),
        "F" => Some(DotId::Forehead(number - 1)),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        assert_eq!(parse_dot_name("D1"), Some(DotId::Lip(0)));
        assert_eq!(parse_dot_name("F3"), Some(DotId::Forehead(2)));
        assert_eq!(parse_dot_name("D12"), Some(DotId::Lip(11)));
        assert_eq!(parse_dot_name("D0"), None);
        assert_eq!(parse_dot_name("D01"), None);
        assert_eq!(parse_dot_name("D999"), Some(DotId::Lip(998)));
        assert_eq!(parse_dot_name("F1000"), None);
        assert_eq!(parse_dot_name("F18446744073709551615"), None);
        assert_eq!(parse_dot_name("F18446744073709551616"), None);
        assert_eq!(parse_dot_name("X1"), None);
        assert_eq!(parse_dot_name("D"), None);
        assert_eq!(parse_dot_name(""), None);
        assert_eq!(PerformerLayout::default().right_corner(), 6);
    }
}

/// One time step's raw dots in the camera frame (metres), `None` for a dot not seen.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PerformerDots {
    /// Lip dots `D1..DN`.
    pub lip: Vec<Option<crate::Vec3>>,
    /// Forehead dots `F1..FK`.
    pub forehead: Vec<Option<crate::Vec3>>,
}

impl PerformerDots {
    /// All dots of the layout, none seen.
    pub fn new(layout: PerformerLayout) -> Self {
        Self {
            lip: vec![None; layout.lip_dots],
            forehead: vec![None; layout.forehead_dots],
        }
    }

    /// Marks every dot as not seen, keeping the allocation.
    pub fn clear(&mut self) {
        self.lip
            .iter_mut()
            .chain(self.forehead.iter_mut())
            .for_each(|d| *d = None);
    }

    /// The slot for a dot, if the layout has it.
    pub fn slot_mut(&mut self, id: DotId) -> Option<&mut Option<crate::Vec3>> {
        match id {
            DotId::Lip(i) => self.lip.get_mut(i),
            DotId::Forehead(i) => self.forehead.get_mut(i),
        }
    }

    /// Checks that the dots fit `layout` and are finite.
    pub fn check(&self, layout: PerformerLayout) -> Result<(), crate::Error> {
        if self.lip.len() != layout.lip_dots || self.forehead.len() != layout.forehead_dots {
            return Err(crate::Error::DotCount {
                expected_lip: layout.lip_dots,
                expected_forehead: layout.forehead_dots,
                lip: self.lip.len(),
                forehead: self.forehead.len(),
            });
        }
        let ids = (0..self.lip.len()).map(DotId::Lip).zip(&self.lip).chain(
            (0..self.forehead.len())
                .map(DotId::Forehead)
                .zip(&self.forehead),
        );
        for (id, v) in ids {
            if let Some(v) = v {
                if !v.iter().all(|c| c.is_finite()) {
                    return Err(crate::Error::NonFinite {
                        dot: PerformerLayout::name(id),
                    });
                }
            }
        }
        Ok(())
    }
}
