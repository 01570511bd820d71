//! Pixel format conversions to mouthpiece's BGR8 colour and millimetre depth.
//!
//! YUYV uses OpenCV's own fixed-point BT.601 ("video range") coefficients, so the result is
//! the one `cvtColor(..., COLOR_YUV2BGR_YUYV)` gives; the tests check exactly that against the
//! `opencv` crate.

use std::fmt;

/// Why a buffer could not be converted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ConvertError {
    #[error("{format} frame of {width}x{height} needs {expected} bytes, got {got}")]
    Size {
        format: &'static str,
        width: u32,
        height: u32,
        expected: usize,
        got: usize,
    },
    #[error("YUYV needs an even width, got {0}")]
    OddWidth(u32),
    #[error("MJPG frame does not decode: {0}")]
    Jpeg(String),
    #[error("MJPG frame decodes to {got_w}x{got_h}, the stream is {width}x{height}")]
    JpegSize {
        width: u32,
        height: u32,
        got_w: u32,
        got_h: u32,
    },
}

fn check_size(
    format: &'static str,
    width: u32,
    height: u32,
    bpp: usize,
    got: usize,
) -> Result<(), ConvertError> {
    let expected = width as usize * height as usize * bpp;
    if got < expected {
        return Err(ConvertError::Size {
            format,
            width,
            height,
            expected,
            got,
        });
    }
    Ok(())
}

/// Colour formats mouthpiece converts to BGR8.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorFormat {
    Bgr24,
    Rgb24,
    Yuyv,
    Mjpg,
}

impl fmt::Display for ColorFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ColorFormat::Bgr24 => "BGR3",
            ColorFormat::Rgb24 => "RGB3",
            ColorFormat::Yuyv => "YUYV",
            ColorFormat::Mjpg => "MJPG",
        })
    }
}

/// Converts one colour frame to packed BGR8 (`width * height * 3` bytes).
pub fn to_bgr(
    format: ColorFormat,
    width: u32,
    height: u32,
    data: &[u8],
) -> Result<Vec<u8>, ConvertError> {
    match format {
        ColorFormat::Bgr24 => {
            check_size("BGR3", width, height, 3, data.len())?;
            Ok(data[..width as usize * height as usize * 3].to_vec())
        }
        ColorFormat::Rgb24 => rgb_to_bgr(width, height, data),
        ColorFormat::Yuyv => yuyv_to_bgr(width, height, data),
        ColorFormat::Mjpg => mjpg_to_bgr(width, height, data),
    }
}

/// RGB888 → BGR888.
pub fn rgb_to_bgr(width: u32, height: u32, data: &[u8]) -> Result<Vec<u8>, ConvertError> {
    check_size("RGB3", width, height, 3, data.len())?;
    let n = width as usize * height as usize * 3;
    let mut out = Vec::with_capacity(n);
    for px in data[..n].chunks_exact(3) {
        out.extend_from_slice(&[px[2], px[1], px[0]]);
    }
    Ok(out)
}

// OpenCV's ITU-R BT.601 fixed-point constants (imgproc, color_yuv).
const CY: i32 = 1_220_542;
const CUB: i32 = 2_116_026;
const CUG: i32 = -409_993;
const CVG: i32 = -852_492;
const CVR: i32 = 1_673_527;
const SHIFT: i32 = 20;
const HALF: i32 = 1 << (SHIFT - 1);

#[inline]
fn clamp_u8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// YUYV 4:2:2 (Y0 U Y1 V) → BGR888, bit-exact with OpenCV's `COLOR_YUV2BGR_YUYV`.
pub fn yuyv_to_bgr(width: u32, height: u32, data: &[u8]) -> Result<Vec<u8>, ConvertError> {
    if width % 2 != 0 {
        return Err(ConvertError::OddWidth(width));
    }
    check_size("YUYV", width, height, 2, data.len())?;
    let n = width as usize * height as usize;
    let mut out = Vec::with_capacity(n * 3);
    for quad in data[..n * 2].chunks_exact(4) {
        let u = quad[1] as i32 - 128;
        let v = quad[3] as i32 - 128;
        let ruv = HALF + CVR * v;
        let guv = HALF + CVG * v + CUG * u;
        let buv = HALF + CUB * u;
        for y in [quad[0], quad[2]] {
            let y = (y as i32 - 16).max(0) * CY;
            out.extend_from_slice(&[
                clamp_u8((y + buv) >> SHIFT),
                clamp_u8((y + guv) >> SHIFT),
                clamp_u8((y + ruv) >> SHIFT),
            ]);
        }
    }
    Ok(out)
}

/// UYVY 4:2:2 (U Y0 V Y1; OpenNI2's `YUV422`) → BGR888, as OpenCV's `COLOR_YUV2BGR_UYVY`.
pub fn uyvy_to_bgr(width: u32, height: u32, data: &[u8]) -> Result<Vec<u8>, ConvertError> {
    check_size("UYVY", width, height, 2, data.len())?;
    let n = width as usize * height as usize * 2;
    let yuyv: Vec<u8> = data[..n]
        .chunks_exact(4)
        .flat_map(|q| [q[1], q[0], q[3], q[2]])
        .collect();
    yuyv_to_bgr(width, height, &yuyv)
}

/// Motion-JPEG frame → BGR888.
#[cfg(feature = "v4l2")]
pub fn mjpg_to_bgr(width: u32, height: u32, data: &[u8]) -> Result<Vec<u8>, ConvertError> {
    let mut decoder = jpeg_decoder::Decoder::new(data);
    let pixels = decoder
        .decode()
        .map_err(|e| ConvertError::Jpeg(e.to_string()))?;
    let info = decoder
        .info()
        .ok_or_else(|| ConvertError::Jpeg("no image header".into()))?;
    if (info.width as u32, info.height as u32) != (width, height) {
        return Err(ConvertError::JpegSize {
            width,
            height,
            got_w: info.width as u32,
            got_h: info.height as u32,
        });
    }
    match info.pixel_format {
        jpeg_decoder::PixelFormat::RGB24 => rgb_to_bgr(width, height, &pixels),
        jpeg_decoder::PixelFormat::L8 => Ok(pixels.iter().flat_map(|&l| [l, l, l]).collect()),
        other => Err(ConvertError::Jpeg(format!(
            "unsupported JPEG pixel format {other:?}"
        ))),
    }
}

/// Motion-JPEG needs the `v4l2` feature (its decoder comes with it).
#[cfg(not(feature = "v4l2"))]
pub fn mjpg_to_bgr(_width: u32, _height: u32, _data: &[u8]) -> Result<Vec<u8>, ConvertError> {
    Err(ConvertError::Jpeg(
        "built without the v4l2 feature (no JPEG decoder)".into(),
    ))
}

/// 16-bit little-endian depth in `units_m` metres per unit → millimetres (0 stays 0, values
/// past 65535 mm saturate). `units_m = 0.001` copies.
pub fn depth_to_mm(
    width: u32,
    height: u32,
    data: &[u8],
    units_m: f64,
) -> Result<Vec<u16>, ConvertError> {
    check_size("Z16", width, height, 2, data.len())?;
    let n = width as usize * height as usize;
    let raw = data[..n * 2]
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]));
    if (units_m - 0.001).abs() < 1e-12 {
        return Ok(raw.collect());
    }
    let scale = units_m * 1000.0;
    Ok(raw
        .map(|d| {
            if d == 0 {
                0
            } else {
                (d as f64 * scale).round().clamp(1.0, 65535.0) as u16
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use opencv::core::{Mat, CV_8UC2, CV_8UC3};
    use opencv::imgproc;
    use opencv::prelude::*;

    /// A deterministic buffer that covers every byte value in every channel position.
    fn fixture(len: usize, seed: u32) -> Vec<u8> {
        let mut x = seed;
        (0..len)
            .map(|i| {
                x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                if i < 1024 {
                    (i / 4) as u8 // all values, in each position of a YUYV quad
                } else {
                    (x >> 24) as u8
                }
            })
            .collect()
    }

    /// A Mat over a copy of `data`: `height` rows of `channels`-channel u8 pixels.
    fn mat_from(data: &[u8], height: u32, channels: i32) -> Mat {
        let flat = Mat::new_rows_cols_with_data(
            height as i32,
            (data.len() / height as usize) as i32,
            data,
        )
        .unwrap();
        flat.reshape(channels, height as i32)
            .unwrap()
            .try_clone()
            .unwrap()
    }

    fn bytes(m: &Mat) -> Vec<u8> {
        m.data_bytes().unwrap().to_vec()
    }

    #[test]
    fn yuyv_matches_opencv_exactly() {
        for (w, h) in [(64u32, 48u32), (320, 240), (2, 1)] {
            let src = fixture(w as usize * h as usize * 2, w + h);
            let mine = yuyv_to_bgr(w, h, &src).unwrap();
            let mat = mat_from(&src, h, 2);
            assert_eq!(mat.typ(), CV_8UC2);
            let mut dst = Mat::default();
            imgproc::cvt_color_def(&mat, &mut dst, imgproc::COLOR_YUV2BGR_YUYV).unwrap();
            assert_eq!(dst.typ(), CV_8UC3);
            let reference = bytes(&dst);
            let diffs = mine.iter().zip(&reference).filter(|(a, b)| a != b).count();
            assert_eq!(diffs, 0, "{w}x{h}: {diffs} bytes differ from OpenCV");
        }
    }

    #[test]
    fn uyvy_matches_opencv_exactly() {
        let (w, h) = (64u32, 48u32);
        let src = fixture(w as usize * h as usize * 2, 3);
        let mat = mat_from(&src, h, 2);
        let mut dst = Mat::default();
        imgproc::cvt_color_def(&mat, &mut dst, imgproc::COLOR_YUV2BGR_UYVY).unwrap();
        assert_eq!(uyvy_to_bgr(w, h, &src).unwrap(), bytes(&dst));
    }

    #[test]
    fn rgb_and_bgr_match_opencv() {
        let (w, h) = (80u32, 60u32);
        let src = fixture(w as usize * h as usize * 3, 7);
        let mat = mat_from(&src, h, 3);
        let mut dst = Mat::default();
        imgproc::cvt_color_def(&mat, &mut dst, imgproc::COLOR_RGB2BGR).unwrap();
        assert_eq!(to_bgr(ColorFormat::Rgb24, w, h, &src).unwrap(), bytes(&dst));
        assert_eq!(to_bgr(ColorFormat::Bgr24, w, h, &src).unwrap(), src);
    }

    #[test]
    fn short_or_odd_buffers_are_errors_not_panics() {
        assert!(matches!(
            yuyv_to_bgr(4, 2, &[0; 15]),
            Err(ConvertError::Size { expected: 16, .. })
        ));
        assert_eq!(yuyv_to_bgr(3, 2, &[0; 12]), Err(ConvertError::OddWidth(3)));
        assert!(rgb_to_bgr(4, 4, &[0; 47]).is_err());
        assert!(depth_to_mm(4, 4, &[0; 31], 0.001).is_err());
        assert!(matches!(
            mjpg_to_bgr(4, 4, b"not a jpeg"),
            Err(ConvertError::Jpeg(_))
        ));
    }

    #[test]
    fn depth_units_convert_to_millimetres() {
        let raw: Vec<u8> = [0u16, 1, 1000, 65535]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert_eq!(
            depth_to_mm(2, 2, &raw, 0.001).unwrap(),
            vec![0, 1, 1000, 65535]
        );
        // RealSense D4xx default: 1 unit = 0.1 mm... here 100 µm units.
        assert_eq!(
            depth_to_mm(2, 2, &raw, 0.0001).unwrap(),
            vec![0, 1, 100, 6554]
        );
        // 0.25 mm units round; sub-millimetre non-zero readings stay non-zero.
        assert_eq!(
            depth_to_mm(2, 2, &raw, 0.00025).unwrap(),
            vec![0, 1, 250, 16384]
        );
    }
}
