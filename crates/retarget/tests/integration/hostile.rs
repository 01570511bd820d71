//! Inputs crafted to overflow: huge dot numbers, huge `points_per_lip`, coordinates whose
//! squares overflow. Each must be an error (or, inside a fit, no answer), never a panic or
//! a hang.

use mouthpiece_retarget::jsonl::InputLine;
use mouthpiece_retarget::kabsch::kabsch;
use mouthpiece_retarget::{Character, Error, PerformerDots, PerformerLayout};
use nalgebra::Vector3;

#[test]
fn huge_dot_numbers_are_unknown_dots() {
    for name in [
        "F18446744073709551615",
        "F18446744073709551614",
        "D99999999999",
    ] {
        let line =
            InputLine::parse(&format!(r#"{{"t": 0, "points": {{"{name}": [0, 0, 1]}}}}"#)).unwrap();
        let layout = PerformerLayout {
            lip_dots: 4,
            forehead_dots: line.forehead_count(),
        };
        assert_eq!(layout.forehead_dots, 0, "{name}");
        let mut dots = PerformerDots::default();
        let err = line.dots_into(layout, &mut dots).unwrap_err();
        assert!(matches!(err, Error::UnknownDot { .. }), "{name}: {err}");
    }
}

#[test]
fn coordinates_whose_squares_overflow_are_refused() {
    let line = InputLine::parse(r#"{"t": 0, "points": {"D1": [1e200, 0, 1]}}"#).unwrap();
    let layout = PerformerLayout {
        lip_dots: 4,
        forehead_dots: 3,
    };
    let err = line
        .dots_into(layout, &mut PerformerDots::default())
        .unwrap_err();
    assert!(err.to_string().contains("D1"), "{err}");
    // Inside a fit, an overflowed covariance gives no rotation instead of an endless SVD.
    let big = [
        Vector3::new(1e200, 0.0, 0.0),
        Vector3::new(0.0, 1e200, 0.0),
        Vector3::new(0.0, 0.0, 1e200),
        Vector3::new(-1e200, 0.0, 0.0),
    ];
    let small = [
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(0.0, 0.0, 1.0),
        Vector3::new(-1.0, 0.0, 0.0),
    ];
    assert!(kabsch(&big, &small).is_none());
    assert!(kabsch(&small, &big).is_none());
}

#[test]
fn a_character_with_absurd_sizes_is_refused() {
    for (points_per_lip, coordinate) in [
        ("9223372036854775807", "1"),
        ("9223372036854775000", "1"),
        ("4000", "1"),
        ("4", "1e200"),
    ] {
        let src = format!(
            "name = \"c\"\n[contour]\npoints_per_lip = {points_per_lip}\n\
             upper = [[{coordinate}, 0, 0], [0, 1, 0], [-1, 0, 0]]\n\
             lower = [[1, 0, 0], [0, -1, 0], [-1, 0, 0]]\n"
        );
        let err = Character::from_toml_str(&src).unwrap_err().to_string();
        assert!(
            err.contains("points_per_lip") || err.contains("contour.upper"),
            "{points_per_lip} {coordinate}: {err}"
        );
    }
}
