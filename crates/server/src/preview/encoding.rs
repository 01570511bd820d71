//! Turning one frame into a preview message: box-filter downscale, JPEG, and the binary
//! message (a fixed header, the overlay JSON, the JPEG).

use serde::Serialize;

use super::{
    BgrImage, EncodedPreview, Overlay, PreviewInput, PREVIEW_HEADER_LEN, PREVIEW_MAGIC,
    PREVIEW_VERSION,
};

/// The overlay JSON carried in a preview message (`type` `preview_frame`).
#[derive(Debug, Serialize)]
struct OverlayJson<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    seq: u64,
    t: f64,
    width: u32,
    height: u32,
    source_width: u32,
    source_height: u32,
    #[serde(flatten)]
    overlay: &'a Overlay,
}

/// Integer factor the image is shrunk by so that it is at most `max_width` wide.
pub fn downscale_factor(width: u32, max_width: u32) -> u32 {
    width.div_ceil(max_width.max(1)).max(1)
}

/// Shrinks a packed BGR image by an integer `factor`, each output pixel the mean of a
/// `factor` × `factor` block (a box filter: no aliasing of the fine paint dots into moiré).
/// Returns the new width, height and bytes.
pub fn downscale_bgr(image: &dyn BgrImage, factor: u32) -> (u32, u32, Vec<u8>) {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let f = factor.max(1) as usize;
    let (ow, oh) = ((w / f).max(1), (h / f).max(1));
    let src = image.bgr();
    if f == 1 {
        return (w as u32, h as u32, src[..w * h * 3].to_vec());
    }
    let mut out = vec![0u8; ow * oh * 3];
    let mut sums = vec![0u32; ow * 3];
    let n = (f * f) as u32;
    for oy in 0..oh {
        sums.iter_mut().for_each(|s| *s = 0);
        for y in oy * f..(oy * f + f).min(h) {
            let row = &src[y * w * 3..(y + 1) * w * 3];
            for (ox, sum) in sums.chunks_exact_mut(3).enumerate() {
                for px in row[ox * f * 3..(ox * f + f) * 3].chunks_exact(3) {
                    sum[0] += u32::from(px[0]);
                    sum[1] += u32::from(px[1]);
                    sum[2] += u32::from(px[2]);
                }
            }
        }
        let line = &mut out[oy * ow * 3..(oy + 1) * ow * 3];
        for (o, s) in line.iter_mut().zip(&sums) {
            *o = ((s + n / 2) / n) as u8;
        }
    }
    (ow as u32, oh as u32, out)
}

/// Why an image could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    /// The image's bytes do not match its size.
    #[error("preview image is {width}x{height} but has {bytes} bytes (expected {expected})")]
    BadImage {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Bytes given.
        bytes: usize,
        /// Bytes needed.
        expected: usize,
    },
    /// The JPEG encoder failed.
    #[error("JPEG encoding failed")]
    Jpeg(#[source] jpeg_encoder::EncodingError),
}

/// Downscales and encodes one preview image and builds its binary message.
pub fn encode(
    input: &PreviewInput,
    max_width: u32,
    quality: u8,
) -> Result<EncodedPreview, PreviewError> {
    let image = &*input.image;
    let (sw, sh) = (image.width(), image.height());
    let expected = sw as usize * sh as usize * 3;
    if image.bgr().len() < expected || sw == 0 || sh == 0 || sw > 16384 || sh > 16384 {
        return Err(PreviewError::BadImage {
            width: sw,
            height: sh,
            bytes: image.bgr().len(),
            expected,
        });
    }
    let factor = downscale_factor(sw, max_width.min(sw));
    let (w, h, pixels) = downscale_bgr(image, factor);
    let mut jpeg = Vec::with_capacity(pixels.len() / 8);
    let encoder = jpeg_encoder::Encoder::new(&mut jpeg, quality.clamp(1, 100));
    encoder
        .encode(&pixels, w as u16, h as u16, jpeg_encoder::ColorType::Bgr)
        .map_err(PreviewError::Jpeg)?;
    let mut encoded = EncodedPreview {
        seq: input.seq,
        t: input.t,
        capture_us: input.capture_us,
        wall_us: input.wall_us,
        width: w,
        height: h,
        source_width: sw,
        source_height: sh,
        jpeg,
        overlay: input.overlay.clone(),
        message: Default::default(),
    };
    encoded.message = encode_preview_message(&encoded).into();
    Ok(encoded)
}

/// The overlay JSON of a preview message.
pub fn overlay_json(p: &EncodedPreview) -> String {
    serde_json::to_string(&OverlayJson {
        kind: "preview_frame",
        seq: p.seq,
        t: p.t,
        width: p.width,
        height: p.height,
        source_width: p.source_width,
        source_height: p.source_height,
        overlay: &p.overlay,
    })
    .unwrap_or_default()
}

/// The binary preview message (layout in `docs/protocol.md`): a 56-byte header, the
/// overlay JSON, the JPEG.
pub fn encode_preview_message(p: &EncodedPreview) -> Vec<u8> {
    let json = overlay_json(p);
    let mut out = Vec::with_capacity(PREVIEW_HEADER_LEN + json.len() + p.jpeg.len());
    out.extend_from_slice(PREVIEW_MAGIC);
    out.extend_from_slice(&PREVIEW_VERSION.to_le_bytes());
    let flags: u16 = if p.wall_us.is_some() { 1 } else { 0 };
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&p.seq.to_le_bytes());
    out.extend_from_slice(&p.t.to_le_bytes());
    out.extend_from_slice(&p.capture_us.to_le_bytes());
    out.extend_from_slice(&p.wall_us.unwrap_or(0).to_le_bytes());
    for v in [p.width, p.height, p.source_width, p.source_height] {
        out.extend_from_slice(&(v.min(u32::from(u16::MAX)) as u16).to_le_bytes());
    }
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&(p.jpeg.len() as u32).to_le_bytes());
    debug_assert_eq!(out.len(), PREVIEW_HEADER_LEN);
    out.extend_from_slice(json.as_bytes());
    out.extend_from_slice(&p.jpeg);
    out
}
