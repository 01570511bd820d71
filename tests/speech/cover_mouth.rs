//! A hand over the mouth, for the speech tests: the lip dots' part of a synthetic frame's
//! colour image painted with the skin beside the mouth. Included with `#[path]`.

/// Paints the lip dots' part of the colour image with the skin beside the mouth: a hand over
/// the mouth.
pub fn cover_mouth(frame: &mut mouthpiece_frame::Frame, truth: &mouthpiece_recording::GroundTruth) {
    let c = &frame.calibration.color;
    let pixels: Vec<(f64, f64)> = truth
        .points
        .iter()
        .filter(|(n, _)| n.starts_with('D'))
        .map(|(_, p)| (c.fx * p[0] / p[2] + c.cx, c.fy * p[1] / p[2] + c.cy))
        .collect();
    let (u0, u1) = pixels
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (v0, v1) = pixels
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let img = &mut frame.color;
    let w = img.width as i64;
    let at = |u: i64, v: i64| ((v * w + u) * 3) as usize;
    let (left, top, right, bottom) = (
        u0 as i64 - 25,
        v0 as i64 - 15,
        u1 as i64 + 25,
        v1 as i64 + 15,
    );
    let skin_at = at(left - 10, (top + bottom) / 2);
    let skin = [
        img.data[skin_at],
        img.data[skin_at + 1],
        img.data[skin_at + 2],
    ];
    for v in top.max(0)..bottom.min(img.height as i64) {
        for u in left.max(0)..right.min(w) {
            let i = at(u, v);
            img.data[i..i + 3].copy_from_slice(&skin);
        }
    }
}
