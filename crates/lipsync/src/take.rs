//! Weight curves → a take: the performer's lip dots `D⁰ + Σ wᵢ · poseᵢ` in the mouth frame of
//! the basic poses, carried onto a character by the retarget core, one take line per sample
//! (the line format of `mouthpiece process`, so `export` reads lip-sync takes as it reads
//! camera takes).
//!
//! The tables are parsed from text here; reading the files is the caller's.

use std::io::{self, Write};

use mouthpiece_retarget::jsonl::OutputLine;
use mouthpiece_retarget::rig::{RangeOverrides, Rig, RigSettings};
use mouthpiece_retarget::{
    Character, CharacterRetarget, CharacterSettings, NeutralPose, PerformerLayout, RetargetOutput,
    RigidTransform, ShapeSmoothing, StabilisedFrame, Vec3,
};

use crate::{BasicPoses, ClassTable, Error, SegmentTable, Weights};

/// The shipped class table.
pub const DEFAULT_CLASSES: &str = include_str!("../../../config/lipsync/classes.toml");
/// Its name in messages.
pub const DEFAULT_CLASSES_NAME: &str = "config/lipsync/classes.toml";
/// The shipped basic poses (derived from the synthetic performer's mouth model).
pub const DEFAULT_POSES: &str = include_str!("../../../config/lipsync/poses.toml");
/// Its name in messages.
pub const DEFAULT_POSES_NAME: &str = "config/lipsync/poses.toml";

/// A table's text and the name of where it came from (for messages).
#[derive(Debug, Clone, Copy)]
pub struct Source<'a> {
    pub text: &'a str,
    pub name: &'a str,
}

/// The method's tables: classes, segments (with overrides), poses.
pub struct Tables {
    /// The pose file's name, for errors.
    pub pose_name: String,
    pub classes: ClassTable,
    pub segments: SegmentTable,
    pub poses: BasicPoses,
    /// `poses.poses[order[i]]` is the class table's key pose i.
    pub order: Vec<usize>,
}

impl Tables {
    /// The tables from their texts; `segments` overrides the generated segments.
    pub fn parse(classes: Source, poses: Source, segments: Option<Source>) -> Result<Self, Error> {
        let classes = ClassTable::from_toml_str(classes.text, classes.name)?;
        let pose_name = poses.name.to_string();
        let poses = BasicPoses::from_toml_str(poses.text, &pose_name)?;
        let order = poses.order_for(&classes, &pose_name)?;
        let mut table = SegmentTable::generate(&classes);
        if let Some(s) = segments {
            table.apply_overrides(&classes, s.text, s.name)?;
        }
        Ok(Self {
            pose_name,
            classes,
            segments: table,
            poses,
            order,
        })
    }
}

/// Why a take cannot be made from these poses and this character.
#[derive(Debug, thiserror::Error)]
pub enum TakeError {
    /// The pose file's neutral dots do not make a neutral pose (too few, collinear).
    #[error("pose file {pose_name}: the basic poses' neutral dots")]
    Neutral {
        pose_name: String,
        #[source]
        source: Box<mouthpiece_retarget::Error>,
    },
    /// The character does not fit the poses (another number of points).
    #[error("character {character_name} does not fit the basic poses of {pose_name}")]
    Character {
        character_name: String,
        pose_name: String,
        #[source]
        source: Box<mouthpiece_retarget::Error>,
    },
}

/// The performer's neutral pose of a pose file (its mouth frame is the file's frame).
pub fn neutral_of(poses: &BasicPoses) -> Result<NeutralPose, mouthpiece_retarget::Error> {
    let v = |p: &[f64; 3]| Some(Vec3::new(p[0], p[1], p[2]));
    let layout = PerformerLayout {
        lip_dots: poses.lip_dots(),
        forehead_dots: poses.forehead.len(),
    };
    NeutralPose::from_positions(
        layout,
        poses.neutral_lip.iter().map(v).collect(),
        poses.forehead.iter().map(v).collect(),
        1,
    )
}

/// The retarget core bound to a character and the basic poses' neutral, ready to turn
/// weight curves into take lines. Made before any output file is created: a character that
/// does not fit the poses is bad input, not a half-written take.
pub struct TakeWriter {
    neutral: NeutralPose,
    retarget: CharacterRetarget,
    line: OutputLine,
    /// The rig on the speech-driven dots, as on a camera's (docs/rig.md): jaw, curves and
    /// visemes in every line; `None` for a layout the rig cannot measure.
    rig: Option<Rig>,
    ranges: RangeOverrides,
}

impl TakeWriter {
    /// `character_name` names the character file in errors; `smoothing` makes each line's
    /// `curve`.
    pub fn new(
        tables: &Tables,
        character: Character,
        character_name: &str,
        smoothing: ShapeSmoothing,
    ) -> Result<Self, TakeError> {
        let neutral = neutral_of(&tables.poses).map_err(|source| TakeError::Neutral {
            pose_name: tables.pose_name.clone(),
            source: Box::new(source),
        })?;
        let settings = CharacterSettings {
            smoothing,
            one_euro: None,
        };
        let line = OutputLine::for_character(&character, &settings.smoothing);
        let ranges = character.rig_ranges;
        let rig = Rig::new(&neutral, RigSettings::default()).ok();
        let retarget = CharacterRetarget::new(character, &neutral, settings).map_err(|source| {
            TakeError::Character {
                character_name: character_name.to_string(),
                pose_name: tables.pose_name.clone(),
                source: Box::new(source),
            }
        })?;
        Ok(Self {
            neutral,
            retarget,
            line,
            rig,
            ranges,
        })
    }

    /// Writes one take line per sample of `weights` to `out`, as it goes.
    pub fn write(
        mut self,
        weights: &Weights,
        tables: &Tables,
        out: &mut dyn Write,
    ) -> io::Result<()> {
        let n = tables.poses.lip_dots();
        let mut performer = StabilisedFrame {
            t: 0.0,
            lip: self.neutral.lip.clone(),
            confidence: vec![1.0; n],
            head: RigidTransform::IDENTITY,
            head_lost: false,
        };
        let mut displacement = vec![[0.0; 3]; n];
        for k in 0..weights.len() {
            performer.t = weights.time(k);
            // D = D⁰ + Σ wᵢ poseᵢ, in the mouth frame (blend from a zero neutral: displacement).
            tables
                .poses
                .displacement(weights.sample(k), &tables.order, &mut displacement);
            for (d, (base, off)) in performer
                .lip
                .iter_mut()
                .zip(self.neutral.lip.iter().zip(&displacement))
            {
                *d = base + Vec3::new(off[0], off[1], off[2]);
            }
            let frame = self.retarget.apply(&performer);
            self.line.update(
                k as u64,
                &RetargetOutput {
                    performer: &performer,
                    character: frame,
                },
            );
            if let Some(rig) = &mut self.rig {
                rig.step(&performer);
                // With the character's own ranges where it has them (docs/rig.md).
                rig.output_for(
                    &self.ranges,
                    self.line.rig.get_or_insert_with(Default::default),
                );
            }
            serde_json::to_writer(&mut *out, &self.line)?;
            out.write_all(b"\n")?;
        }
        out.flush()
    }
}

/// Phones as JSONL `{start, end, phone}` (what a `.jsonl` phone file holds).
pub fn phones_jsonl(phones: &[crate::PhoneSpan]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for p in phones {
        let _ = writeln!(
            s,
            "{}",
            serde_json::json!({"start": p.start, "end": p.end, "phone": p.phone})
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped() -> Tables {
        Tables::parse(
            Source {
                text: DEFAULT_CLASSES,
                name: DEFAULT_CLASSES_NAME,
            },
            Source {
                text: DEFAULT_POSES,
                name: DEFAULT_POSES_NAME,
            },
            None,
        )
        .unwrap()
    }

    fn human() -> Character {
        Character::from_toml_str(include_str!("../../../config/characters/human.toml")).unwrap()
    }

    /// The rig runs on the speech-driven dots as on a camera's: every line carries the
    /// jaw, the curves and the visemes; the neutral mouth reads nothing, the "open" pose an
    /// open jaw (viseme `aa`), the "round" pose a rounding.
    #[test]
    fn lines_carry_the_rig_of_the_speech_driven_dots() {
        let tables = shipped();
        let k = tables.classes.poses.len();
        let pose = |name: &str| tables.classes.poses.iter().position(|p| p == name).unwrap();
        let mut values = vec![0.0; 3 * k];
        values[k + pose("open")] = 1.0;
        values[2 * k + pose("round")] = 1.0;
        let weights = Weights {
            fps: 10.0,
            poses: k,
            values,
            owner: vec![0; 3],
        };
        let writer = TakeWriter::new(&tables, human(), "human.toml", ShapeSmoothing::None).unwrap();
        let mut out = Vec::new();
        writer.write(&weights, &tables, &mut out).unwrap();
        let lines: Vec<serde_json::Value> = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        let curve = |i: usize, name: &str| lines[i]["rig"]["curves"][name].as_f64().unwrap();
        let viseme = |i: usize, name: &str| lines[i]["rig"]["visemes"][name].as_f64().unwrap();
        assert!(
            curve(0, "jawOpen") < 1e-9 && viseme(0, "aa") < 1e-9,
            "{}",
            lines[0]
        );
        assert!(curve(1, "jawOpen") > 0.2, "{}", lines[1]["rig"]);
        assert!(viseme(1, "aa") > 0.1, "{}", lines[1]["rig"]);
        let rounding = curve(2, "mouthFunnel") + curve(2, "mouthPucker");
        assert!(rounding > 0.2, "{}", lines[2]["rig"]);
        assert_eq!(
            lines[2]["rig"]["curves"].as_object().unwrap().len(),
            mouthpiece_retarget::rig::CURVES
        );
    }

    #[test]
    fn one_line_per_sample_and_neutral_weights_give_the_characters_neutral() {
        let tables = shipped();
        let k = tables.classes.poses.len();
        let weights = Weights {
            fps: 10.0,
            poses: k,
            values: vec![0.0; 3 * k],
            owner: vec![0; 3],
        };
        let character = human();
        let neutral: Vec<(String, [f64; 3])> = (0..character.len())
            .map(|i| {
                let p = character.neutral[i];
                (character.point_names[i].clone(), [p.x, p.y, p.z])
            })
            .collect();
        let writer =
            TakeWriter::new(&tables, character, "human.toml", ShapeSmoothing::None).unwrap();
        let mut out = Vec::new();
        writer.write(&weights, &tables, &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        let lines: Vec<serde_json::Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(lines.len(), 3);
        assert_eq!(lines[2]["t"], 0.2);
        let points = lines[1]["points"].as_object().unwrap();
        for (name, n) in &neutral {
            let p = &points[name];
            for axis in 0..3 {
                let v = p[axis].as_f64().unwrap();
                assert!((v - n[axis]).abs() < 1e-9, "{p} vs {n:?}");
            }
        }
    }

    #[test]
    fn a_character_that_does_not_fit_the_poses_is_named() {
        let tables = shipped();
        // Eight points for the poses' twelve dots.
        let mut toml = String::from("name = \"octo\"\nunits = \"m\"\n[points]\n");
        for i in 0..8 {
            let a = i as f64 / 8.0 * std::f64::consts::TAU;
            toml.push_str(&format!(
                "P{} = [{}, {}, 0.0]\n",
                i + 1,
                0.025 * a.cos(),
                0.01 * a.sin()
            ));
        }
        let eight = Character::from_toml_str(&toml).unwrap();
        let e = TakeWriter::new(&tables, eight, "octo.toml", ShapeSmoothing::None)
            .err()
            .expect("eight points do not fit twelve dots");
        assert!(matches!(e, TakeError::Character { .. }), "{e:?}");
        assert!(e.to_string().contains("octo.toml"), "{e}");
    }
}
