//! What is animated: the character's mouth points, their rest pose, and where the mouth sits
//! in the character's model.

use std::collections::HashSet;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use mouthpiece_retarget::Character;

use crate::ExportError;

/// Longest character file read (a character is a few kilobytes; the daemon's limit too).
pub const MAX_CHARACTER_BYTES: u64 = 1 << 20;

/// One animated point of the character's mouth.
#[derive(Clone, Debug, PartialEq)]
pub struct RigPoint {
    /// The point's name in the character file (`P1` …), also the glTF node's name.
    pub name: String,
    /// Rest position in the mouth frame (character units): the node's translation when no
    /// animation plays.
    pub rest: [f64; 3],
}

/// The character's mouth as the export sees it.
///
/// The animation moves the points in the mouth frame (docs/method.md §2: origin between the
/// corners, x towards the character's left corner, y up, z out of the mouth), which is where
/// `retarget` reports them. `placement` carries the mouth frame into the character's model
/// frame (`model = placement · mouth`); it becomes the `mouth` node's transform, so the
/// points land where the artist put them in the model. Identity when the character is given
/// directly in its mouth frame, or when no character file is known.
#[derive(Clone, Debug)]
pub struct MouthRig {
    character: Option<String>,
    points: Vec<RigPoint>,
    placement: Isometry3<f64>,
    metres_per_unit: Option<f64>,
    head: Option<RigHead>,
    /// Where the jaw hinges, mouth frame (character units), when the character says.
    jaw_pivot: Option<[f64; 3]>,
}

/// Where the character's head pivots and its eyes sit, model frame (character units): the
/// `head`, `eye_L` and `eye_R` nodes (docs/head.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigHead {
    pub pivot: [f64; 3],
    pub eye_left: [f64; 3],
    pub eye_right: [f64; 3],
}

impl MouthRig {
    /// A rig from named points (order kept: it is the order of nodes and CSV columns).
    /// Rejects an empty list, duplicate or empty names, and non-finite numbers.
    pub fn new(
        character: Option<String>,
        points: Vec<RigPoint>,
        placement: Isometry3<f64>,
    ) -> Result<Self, ExportError> {
        if points.is_empty() {
            return Err(ExportError::BadRig("no points".into()));
        }
        let mut seen = HashSet::new();
        for p in &points {
            if p.name.is_empty() {
                return Err(ExportError::BadRig("a point has an empty name".into()));
            }
            if !seen.insert(p.name.as_str()) {
                return Err(ExportError::BadRig(format!(
                    "point {} appears twice",
                    p.name
                )));
            }
            if !p.rest.iter().all(|c| c.is_finite()) {
                return Err(ExportError::BadRig(format!(
                    "point {}: rest position {:?} is not finite",
                    p.name, p.rest
                )));
            }
        }
        let finite = placement.translation.vector.iter().all(|c| c.is_finite())
            && placement.rotation.coords.iter().all(|c| c.is_finite());
        if !finite {
            return Err(ExportError::BadRig("mouth placement is not finite".into()));
        }
        Ok(Self {
            character,
            points,
            placement,
            metres_per_unit: None,
            head: None,
            jaw_pivot: None,
        })
    }

    /// Places the jaw's hinge (the character's `[rig] jaw_pivot`), given in the model frame.
    pub fn with_jaw_pivot(mut self, model: [f64; 3]) -> Result<Self, ExportError> {
        if !model.iter().all(|c| c.is_finite()) {
            return Err(ExportError::BadRig("jaw pivot is not finite".into()));
        }
        let p = self
            .placement
            .inverse_transform_point(&nalgebra::Point3::from(model));
        self.jaw_pivot = Some([p.x, p.y, p.z]);
        Ok(self)
    }

    /// The jaw's hinge in the mouth frame (character units), when the character gave one.
    pub fn jaw_pivot(&self) -> Option<[f64; 3]> {
        self.jaw_pivot
    }

    /// Where the jaw hinges, mouth frame (character units): the character's `[rig] jaw_pivot`,
    /// else `hinge_up` mouth widths above and `hinge_back` behind the mouth centre (the rig's
    /// defaults, with the character's own mouth width). The take's `jaw` node and
    /// `mouthpiece bind`'s `jaw` joint both sit here.
    pub fn jaw_hinge(&self) -> [f64; 3] {
        if let Some(p) = self.jaw_pivot {
            return p;
        }
        let settings = mouthpiece_retarget::rig::RigSettings::default();
        let w = self.mouth_width();
        [0.0, settings.hinge_up * w, -settings.hinge_back * w]
    }

    /// Gives the rig a head (from the character's `[head]`).
    pub fn with_head(mut self, head: RigHead) -> Result<Self, ExportError> {
        let finite = [head.pivot, head.eye_left, head.eye_right]
            .iter()
            .flatten()
            .all(|c| c.is_finite());
        if !finite {
            return Err(ExportError::BadRig("head placement is not finite".into()));
        }
        self.head = Some(head);
        Ok(self)
    }

    /// The head's placement, when the character file gave the rig.
    pub fn head(&self) -> Option<&RigHead> {
        self.head.as_ref()
    }

    /// Declares the character's units (metres per unit, from the character file's `units`).
    /// glTF is in metres: the `mouth` node then scales the character's units to metres, so the
    /// keys stay the take's numbers. Unknown units are taken to be metres.
    pub fn with_metres_per_unit(mut self, metres_per_unit: f64) -> Result<Self, ExportError> {
        if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
            return Err(ExportError::BadRig(format!(
                "units: {metres_per_unit} metres per unit is not a positive number"
            )));
        }
        self.metres_per_unit = Some(metres_per_unit);
        Ok(self)
    }

    /// Metres per character unit, if the character said.
    pub fn metres_per_unit(&self) -> Option<f64> {
        self.metres_per_unit
    }

    /// The placement of a mouth frame given by its origin and axes in model coordinates
    /// (columns of the rotation model ← mouth). The axes must be orthonormal and
    /// right-handed (within 1e-6), as a character's mouth frame is by construction.
    pub fn placement_from_axes(
        origin: [f64; 3],
        x: [f64; 3],
        y: [f64; 3],
        z: [f64; 3],
    ) -> Result<Isometry3<f64>, ExportError> {
        let m = Matrix3::from_columns(&[Vector3::from(x), Vector3::from(y), Vector3::from(z)]);
        let orthonormal = (m.transpose() * m - Matrix3::identity()).amax() < 1e-6;
        if !orthonormal || (m.determinant() - 1.0).abs() > 1e-6 {
            return Err(ExportError::BadRig(format!(
                "mouth frame axes x={x:?} y={y:?} z={z:?} are not orthonormal and right-handed"
            )));
        }
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
        Ok(Isometry3::from_parts(
            Translation3::from(Vector3::from(origin)),
            rotation,
        ))
    }

    /// The rig of a character from the retarget core: its point names in file order, `P⁰`
    /// (neutral points in the mouth frame) as rest pose, its mouth frame as placement, and its
    /// units.
    pub fn from_character(character: &Character) -> Result<Self, ExportError> {
        let points = character
            .point_names
            .iter()
            .zip(&character.neutral)
            .map(|(name, p)| RigPoint {
                name: name.clone(),
                rest: [p.x, p.y, p.z],
            })
            .collect();
        let frame = &character.frame;
        let axis = |k: usize| {
            let c = frame.axes.column(k);
            [c[0], c[1], c[2]]
        };
        let placement = Self::placement_from_axes(
            [frame.origin.x, frame.origin.y, frame.origin.z],
            axis(0),
            axis(1),
            axis(2),
        )?;
        let h = &character.head;
        let arr = |v: &mouthpiece_retarget::Vec3| [v.x, v.y, v.z];
        let mut rig =
            Self::new(Some(character.name.clone()), points, placement)?.with_head(RigHead {
                pivot: arr(&h.pivot),
                eye_left: arr(&h.eye_left),
                eye_right: arr(&h.eye_right),
            })?;
        if let Some(p) = &character.jaw_pivot {
            rig = rig.with_jaw_pivot(arr(p))?;
        }
        match character.units {
            Some(units) => rig.with_metres_per_unit(units.metres_per_unit()),
            None => Ok(rig),
        }
    }

    /// Reads a character file (TOML, parsed and checked by the retarget core) of at most
    /// [`MAX_CHARACTER_BYTES`].
    pub fn load_character(path: &Path) -> Result<Self, ExportError> {
        let read_err = |cause| ExportError::CharacterRead {
            path: path.to_path_buf(),
            cause,
        };
        let bytes = crate::asset::read_bounded(path, MAX_CHARACTER_BYTES).map_err(read_err)?;
        let text = String::from_utf8(bytes).map_err(|_| {
            read_err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "not UTF-8 text",
            ))
        })?;
        let character =
            Character::from_toml_str(&text).map_err(|cause| ExportError::Character {
                path: path.to_path_buf(),
                cause: Box::new(cause),
            })?;
        Self::from_character(&character)
    }

    /// The character's name, when known (character file or the take's `character` field).
    pub fn character(&self) -> Option<&str> {
        self.character.as_deref()
    }

    /// The points in node / column order.
    pub fn points(&self) -> &[RigPoint] {
        &self.points
    }

    /// The point names in order.
    pub fn names(&self) -> Vec<String> {
        self.points.iter().map(|p| p.name.clone()).collect()
    }

    /// Mouth frame → model frame.
    pub fn placement(&self) -> &Isometry3<f64> {
        &self.placement
    }

    /// The mouth's width: the extent of the rest points along the mouth frame's x axis (the
    /// corners sit at ±w/2). The scale for tolerances and marker sizes.
    pub fn mouth_width(&self) -> f64 {
        let (lo, hi) = self
            .points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.rest[0]), hi.max(p.rest[0]))
            });
        hi - lo
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(name: &str, rest: [f64; 3]) -> RigPoint {
        RigPoint {
            name: name.into(),
            rest,
        }
    }

    #[test]
    fn rejects_duplicates_and_non_finite() {
        let dup = vec![point("P1", [0.0; 3]), point("P1", [1.0, 0.0, 0.0])];
        let err = MouthRig::new(None, dup, Isometry3::identity()).unwrap_err();
        assert!(err.to_string().contains("P1 appears twice"), "{err}");
        let nan = vec![point("P1", [f64::NAN, 0.0, 0.0])];
        assert!(MouthRig::new(None, nan, Isometry3::identity()).is_err());
        assert!(MouthRig::new(None, vec![], Isometry3::identity()).is_err());
    }

    #[test]
    fn placement_maps_mouth_axes_to_model_axes() {
        // Mouth x = model -Z, y = model +Y, z = model +X: a rotation of -90° about Y.
        let p = MouthRig::placement_from_axes(
            [1.0, 2.0, 3.0],
            [0.0, 0.0, -1.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
        )
        .unwrap();
        let q = p * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((q - nalgebra::Point3::new(1.0, 2.0, 2.0)).norm() < 1e-12);
        let left_handed = MouthRig::placement_from_axes(
            [0.0; 3],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, -1.0],
        );
        assert!(left_handed.is_err());
    }

    #[test]
    fn character_rest_points_land_on_the_model_points() {
        let toml = r#"
            name = "tilted"
            units = "cm"
            up = [0.0, 0.2588, 0.9659]
            [points]
            P1 = [7.5, -30.0, 52.0]
            P2 = [0.0, -42.0, 58.0]
            P3 = [-7.5, -30.0, 52.0]
            P4 = [0.0, -43.0, 52.0]
        "#;
        let character = Character::from_toml_str(toml).unwrap();
        let rig = MouthRig::from_character(&character).unwrap();
        assert_eq!(rig.names(), ["P1", "P2", "P3", "P4"]);
        assert_eq!(rig.character(), Some("tilted"));
        assert_eq!(rig.metres_per_unit(), Some(0.01));
        for (p, model) in rig.points().iter().zip(&character.model_points) {
            let world = rig.placement() * nalgebra::Point3::from(p.rest);
            assert!(
                (world.coords - model).norm() < 1e-9,
                "{}: {world} vs {model}",
                p.name
            );
        }
        assert!((rig.mouth_width() - 15.0).abs() < 1e-9);
    }

    #[test]
    fn width_is_x_extent() {
        let rig = MouthRig::new(
            None,
            vec![
                point("P1", [0.03, 0.0, 0.0]),
                point("P7", [-0.02, 0.01, 0.0]),
            ],
            Isometry3::identity(),
        )
        .unwrap();
        assert!((rig.mouth_width() - 0.05).abs() < 1e-15);
    }
}
