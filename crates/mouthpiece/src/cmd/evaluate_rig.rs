//! The rig's accuracy table of `mouthpiece evaluate` (the figures: `mouthpiece_evaluate::rig`).

use mouthpiece_evaluate::rig::RigMetrics;
use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};

/// The table's header.
pub fn print_header() {
    println!();
    println!(
        "| seed | noise | head motion | frames | jaw RMS (°) | slide RMS (mm) | worst curve | its RMS | jawOpen r (jaw) | mouthFunnel r (round) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
}

/// One session's row.
pub fn print_row(label: &str, m: &RigMetrics) {
    let (worst, rms) = m.worst_curve();
    println!(
        "| {label} | {} | {:.2} | {:.2} | {worst} | {:.3} | {:.3} | {:.3} |",
        m.frames,
        m.jaw_rms_deg(),
        m.slide_rms_mm(),
        rms,
        m.jaw_open.value(),
        m.funnel.value()
    );
}

/// Every curve's RMS (for `--per-curve`).
pub fn print_curves(m: &RigMetrics) {
    let cells: Vec<String> = (0..CURVES)
        .map(|i| format!("{} {:.3}", CURVE_NAMES[i], m.curve_rms(i)))
        .collect();
    println!("curve RMS: {}", cells.join(", "));
}
