//! Key-pose weights → a character's points, one step at a time: the performer's lip dots
//! `D⁰ + Σ wᵢ · poseᵢ` in the basic poses' mouth frame, carried by the retarget core bound to
//! the poses' neutral (as the offline take writer does), so the points are in the
//! character's mouth frame like a camera's.

use mouthpiece_retarget::{
    Character, CharacterRetarget, CharacterSettings, CharacterStep, NeutralPose, RigidTransform,
    StabilisedFrame, Vec3,
};

use crate::take::{neutral_of, Tables, TakeError};

/// One character's mouth driven by key-pose weights.
pub struct LiveMouth {
    neutral: NeutralPose,
    retarget: CharacterRetarget,
    performer: StabilisedFrame,
    displacement: Vec<[f64; 3]>,
}

impl LiveMouth {
    /// Binds `character` to the basic poses' neutral; `character_name` names it in errors.
    pub fn new(
        tables: &Tables,
        character: Character,
        character_name: &str,
        settings: CharacterSettings,
    ) -> Result<Self, TakeError> {
        let neutral = neutral_of(&tables.poses).map_err(|source| TakeError::Neutral {
            pose_name: tables.pose_name.clone(),
            source: Box::new(source),
        })?;
        let retarget = CharacterRetarget::new(character, &neutral, settings).map_err(|source| {
            TakeError::Character {
                character_name: character_name.to_string(),
                pose_name: tables.pose_name.clone(),
                source: Box::new(source),
            }
        })?;
        let n = tables.poses.lip_dots();
        let performer = StabilisedFrame {
            t: 0.0,
            lip: neutral.lip.clone(),
            confidence: vec![1.0; n],
            head: RigidTransform::IDENTITY,
            head_lost: false,
        };
        Ok(Self {
            neutral,
            retarget,
            performer,
            displacement: vec![[0.0; 3]; n],
        })
    }

    /// The character's points for `weights` (the class table's pose order) at time `t`.
    pub fn step(&mut self, tables: &Tables, t: f64, weights: &[f64]) -> &CharacterStep {
        self.performer.t = t;
        tables
            .poses
            .displacement(weights, &tables.order, &mut self.displacement);
        for (d, (base, off)) in self
            .performer
            .lip
            .iter_mut()
            .zip(self.neutral.lip.iter().zip(&self.displacement))
        {
            *d = base + Vec3::new(off[0], off[1], off[2]);
        }
        self.retarget.apply(&self.performer)
    }

    /// The basic poses' neutral the character is bound to (the rig's rest).
    pub fn neutral(&self) -> &NeutralPose {
        &self.neutral
    }

    /// The performer dots of the last step (for the rig).
    pub fn performer(&self) -> &StabilisedFrame {
        &self.performer
    }

    /// The last step.
    pub fn output(&self) -> &CharacterStep {
        self.retarget.output()
    }
}
