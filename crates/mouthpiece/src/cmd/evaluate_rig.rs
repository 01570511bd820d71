//! The rig's accuracy table of `mouthpiece evaluate` (the figures: `mouthpiece_evaluate::rig`).

use mouthpiece_evaluate::rig::RigMetrics;
use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};

/// The table's header.
pub fn print_header() {
    println!();
    println!(
        "| seed | noise | head motion | frames | jaw RMS (°) | slide RMS (mm) | worst curve | its RMS | jawOpen r (jaw) | rounding r (mouthFunnel + mouthPucker, round) | rounding r, true dots | round SD |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
}

/// One session's row.
pub fn print_row(label: &str, m: &RigMetrics) {
    let (worst, rms) = m.worst_curve();
    println!(
        "| {label} | {} | {:.2} | {:.2} | {worst} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
        m.frames,
        m.jaw_rms_deg(),
        m.slide_rms_mm(),
        rms,
        m.jaw_open.value(),
        m.funnel.value(),
        m.funnel_true.value(),
        m.funnel.y_sd()
    );
}

/// Every curve's RMS (for `--per-curve`).
pub fn print_curves(m: &RigMetrics) {
    let cells: Vec<String> = (0..CURVES)
        .map(|i| format!("{} {:.3}", CURVE_NAMES[i], m.curve_rms(i)))
        .collect();
    println!("curve RMS: {}", cells.join(", "));
}

/// The `--rig-frames` CSV: one row per counted frame of every session.
pub struct FramesCsv {
    path: std::path::PathBuf,
    out: std::io::BufWriter<std::fs::File>,
}

impl FramesCsv {
    /// Creates the file and writes the header: the session, the time, the synthetic mouth's
    /// state (jaw in degrees, rounding, spread, raise, roll-in), every curve from the tracked
    /// dots and from the true dots, every lip dot's stabilised position (metres, neutral mouth
    /// frame), tracked and true, each rig's neutral dots, the ranges both rigs' curves
    /// were computed with, whether each tracked dot was seen (1) or held (0), where the camera
    /// is in the tracked neutral mouth frame, and the tracked lip dots as the stabiliser gave
    /// them to the rig (before the rig's estimate).
    pub fn create(path: &std::path::Path, lip_dots: usize) -> anyhow::Result<Self> {
        use anyhow::Context;
        let file = std::fs::File::create(path)
            .with_context(|| format!("--rig-frames: cannot create {}", path.display()))
            .map_err(crate::exit::bad_input)?;
        let mut header = vec![
            "seed,noise,head_motion,t,true_jaw_deg,true_round,true_spread,true_raise,true_roll_in"
                .to_string(),
        ];
        for side in ["tracked", "reference"] {
            header.extend(CURVE_NAMES.iter().map(|c| format!("{side}_{c}")));
        }
        for side in [
            "tracked",
            "reference",
            "tracked_neutral",
            "reference_neutral",
        ] {
            for i in 0..lip_dots {
                let dot = mouthpiece_retarget::PerformerLayout::lip_name(i);
                header.extend(["x", "y", "z"].map(|a| format!("{side}_{dot}_{a}")));
            }
        }
        header.extend(CURVE_NAMES.iter().map(|c| format!("range_{c}")));
        header.extend(
            (0..lip_dots)
                .map(|i| format!("seen_{}", mouthpiece_retarget::PerformerLayout::lip_name(i))),
        );
        header.extend(["camera_x", "camera_y", "camera_z"].map(String::from));
        for i in 0..lip_dots {
            let dot = mouthpiece_retarget::PerformerLayout::lip_name(i);
            header.extend(["x", "y", "z"].map(|a| format!("stabilised_{dot}_{a}")));
        }
        let mut csv = Self {
            path: path.to_path_buf(),
            out: std::io::BufWriter::new(file),
        };
        csv.line(&header.join(","))?;
        Ok(csv)
    }

    fn line(&mut self, text: &str) -> anyhow::Result<()> {
        use anyhow::Context;
        use std::io::Write;
        writeln!(self.out, "{text}").with_context(|| format!("writing {}", self.path.display()))
    }

    /// One session's frames; `session` is its first three cells, `seed,noise,head_motion`.
    pub fn session(
        &mut self,
        session: &str,
        frames: &[mouthpiece_evaluate::rig::RigFrameRecord],
    ) -> anyhow::Result<()> {
        for f in frames {
            let mut row = vec![session.to_string()];
            let m = &f.mouth;
            let truth = [
                f.t,
                m.jaw.to_degrees(),
                m.round,
                m.spread,
                m.raise,
                m.roll_in,
            ];
            row.extend(truth.map(|v| v.to_string()));
            row.extend(f.tracked.iter().chain(&f.reference).map(|v| v.to_string()));
            let dots = f.tracked_lip.iter().chain(&f.reference_lip);
            for p in dots.chain(&f.tracked_neutral).chain(&f.reference_neutral) {
                row.extend(p.map(|v| v.to_string()));
            }
            row.extend(f.ranges.iter().map(|v| v.to_string()));
            row.extend(f.tracked_seen.iter().map(|&s| u8::from(s).to_string()));
            row.extend(f.camera.map(|v| v.to_string()));
            for p in &f.stabilised_lip {
                row.extend(p.map(|v| v.to_string()));
            }
            debug_assert_eq!(row.len(), 10 + 3 * CURVES + 16 * f.tracked_lip.len());
            self.line(&row.join(","))?;
        }
        Ok(())
    }

    pub fn finish(mut self) -> anyhow::Result<()> {
        use anyhow::Context;
        use std::io::Write;
        self.out
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))
    }
}
