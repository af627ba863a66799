//! Raw camera buffers → 8-bit gray. Pure functions (no device access), so every format the node
//! accepts is tested on real-format buffers without a camera attached.
//!
//! Formats: 8-bit gray (V4L2 `GREY`, GenICam `Mono8`), 16-bit gray little-endian (V4L2 `Y16`,
//! GenICam `Mono16`), packed YUV 4:2:2 (V4L2 `YUYV`), Motion-JPEG (V4L2 `MJPG`) and 8-bit Bayer
//! mosaics (GenICam `BayerRG8`/`BayerBG8`/`BayerGR8`/`BayerGB8`).

// The conversions serve the feature-gated camera back ends (V4L2: gray, YUYV, MJPEG; Aravis:
// Mono, Bayer); a build without one of them leaves its formats unused.
#![cfg_attr(not(all(feature = "v4l", feature = "aravis")), allow(dead_code))]

use image::GrayImage;
use std::fmt;

/// Why a buffer could not be converted. Short and corrupt frames are transient faults (the next
/// frame is usually fine); the capture loop retries them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum ConvertError {
    /// Fewer bytes than the geometry needs (a truncated transfer).
    Short {
        /// Bytes the geometry needs.
        expected: usize,
        /// Bytes received.
        got: usize,
    },
    /// The payload does not decode (bad JPEG, geometry mismatch).
    Corrupt(String),
}

impl fmt::Display for ConvertError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConvertError::Short { expected, got } => {
                write!(f, "short frame: {got} bytes, expected {expected}")
            }
            ConvertError::Corrupt(m) => write!(f, "corrupt frame: {m}"),
        }
    }
}

/// Geometry of an uncompressed buffer: `stride` is bytes per row (≥ width × bytes per pixel;
/// drivers pad rows to alignment).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Geometry {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Bytes per row in the buffer, padding included.
    pub stride: usize,
}

impl Geometry {
    /// Tightly packed rows of `bytes_per_pixel`.
    pub(crate) fn packed(width: u32, height: u32, bytes_per_pixel: usize) -> Geometry {
        Geometry {
            width,
            height,
            stride: width as usize * bytes_per_pixel,
        }
    }

    /// The same geometry with `pad` extra bytes after each row.
    pub(crate) fn padded(self, pad: usize) -> Geometry {
        Geometry {
            stride: self.stride + pad,
            ..self
        }
    }

    /// Check the buffer holds every row; the last row needs only its pixels, not its padding.
    fn check(&self, buf: &[u8], bytes_per_pixel: usize) -> Result<(), ConvertError> {
        let row = self.width as usize * bytes_per_pixel;
        if self.stride < row {
            return Err(ConvertError::Corrupt(format!(
                "stride {} < {} bytes per row",
                self.stride, row
            )));
        }
        let expected = match self.height as usize {
            0 => 0,
            h => (h - 1) * self.stride + row,
        };
        if buf.len() < expected {
            return Err(ConvertError::Short {
                expected,
                got: buf.len(),
            });
        }
        Ok(())
    }

    /// The pixel bytes of row `y`.
    fn row<'a>(&self, buf: &'a [u8], y: usize, bytes_per_pixel: usize) -> &'a [u8] {
        let start = y * self.stride;
        &buf[start..start + self.width as usize * bytes_per_pixel]
    }
}

/// Apply `f` to each (source row, destination row) pair after the size check.
fn convert_rows(
    g: Geometry,
    buf: &[u8],
    bytes_per_pixel: usize,
    f: impl Fn(&[u8], &mut [u8]),
) -> Result<GrayImage, ConvertError> {
    g.check(buf, bytes_per_pixel)?;
    let mut out = GrayImage::new(g.width, g.height);
    let w = g.width as usize;
    if w > 0 {
        for (y, dst) in out.chunks_exact_mut(w).enumerate() {
            f(g.row(buf, y, bytes_per_pixel), dst);
        }
    }
    Ok(out)
}

/// 8-bit gray (V4L2 `GREY`, GenICam `Mono8`): copy, dropping row padding.
pub(crate) fn gray8(g: Geometry, buf: &[u8]) -> Result<GrayImage, ConvertError> {
    convert_rows(g, buf, 1, |src, dst| dst.copy_from_slice(src))
}

/// 16-bit gray, little-endian (V4L2 `Y16`, GenICam `Mono16`) → the high byte. Both standards
/// define the full 16-bit range, so the most significant byte is the 8-bit value.
pub(crate) fn gray16le(g: Geometry, buf: &[u8]) -> Result<GrayImage, ConvertError> {
    convert_rows(g, buf, 2, |src, dst| {
        for (d, px) in dst.iter_mut().zip(src.chunks_exact(2)) {
            *d = px[1];
        }
    })
}

/// Packed YUV 4:2:2 `Y0 U Y1 V` (V4L2 `YUYV`) → the luma bytes. `width` must be even (a
/// macropixel holds two pixels); the stride is in bytes (2 per pixel).
pub(crate) fn yuyv(g: Geometry, buf: &[u8]) -> Result<GrayImage, ConvertError> {
    if g.width % 2 != 0 {
        return Err(ConvertError::Corrupt(format!(
            "YUYV width {} is odd",
            g.width
        )));
    }
    convert_rows(g, buf, 2, |src, dst| {
        for (d, px) in dst.iter_mut().zip(src.chunks_exact(2)) {
            *d = px[0];
        }
    })
}

/// Motion-JPEG frame → gray (the decoder's luma for colour JPEGs). `expect` is the size the
/// stream was negotiated at: a frame of another size is corrupt, not silently accepted.
pub(crate) fn mjpeg(buf: &[u8], expect: Option<(u32, u32)>) -> Result<GrayImage, ConvertError> {
    if buf.is_empty() {
        return Err(ConvertError::Short {
            expected: 1,
            got: 0,
        });
    }
    let decoded = image::load_from_memory_with_format(buf, image::ImageFormat::Jpeg)
        .map_err(|e| ConvertError::Corrupt(format!("MJPEG: {e}")))?;
    // A colour JPEG's own Y is BT.601 luma; the decoder hands back RGB, so recompute it with
    // the BT.601 weights (image's `into_luma8` uses Rec.709 weights and would disagree with the
    // YUYV and Bayer paths by several grey levels on saturated colours).
    let img = to_gray(decoded);
    if let Some((w, h)) = expect {
        if img.dimensions() != (w, h) {
            return Err(ConvertError::Corrupt(format!(
                "MJPEG frame is {}x{}, stream is {w}x{h}",
                img.width(),
                img.height()
            )));
        }
    }
    Ok(img)
}

/// Any decoded image → 8-bit gray, the way every path into the pipeline converts: 8-bit gray
/// as it is, colour as BT.601 luma in OpenCV's fixed point (`cv::cvtColor(…, COLOR_RGB2GRAY)`,
/// what the camera's YUYV, Bayer and MJPEG paths give), other gray formats scaled to 8 bits.
pub(crate) fn to_gray(img: image::DynamicImage) -> GrayImage {
    match img {
        image::DynamicImage::ImageLuma8(g) => g,
        other if other.color().has_color() => {
            let rgb = other.into_rgb8();
            GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
                let [r, g, b] = rgb.get_pixel(x, y).0;
                image::Luma([luma601(r, g, b)])
            })
        }
        other => other.into_luma8(),
    }
}

/// Colour filter layout of a Bayer sensor, named by its top-left 2×2 cell read row by row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum BayerPattern {
    /// R G / G B
    Rggb,
    /// B G / G R
    Bggr,
    /// G R / B G
    Grbg,
    /// G B / R G
    Gbrg,
}

/// BT.601 luma weights ×2¹⁴ (R, G, B), the same weights OpenCV's `COLOR_RGB2GRAY` uses; they
/// sum to 2¹⁴ so a gray surface keeps its value exactly.
const LUMA_R: u32 = 4899;
const LUMA_G: u32 = 9617;
const LUMA_B: u32 = 1868;
const LUMA_SHIFT: u32 = 14;

/// BT.601 luma of an RGB triple, rounded.
fn luma601(r: u8, g: u8, b: u8) -> u8 {
    let sum = LUMA_R * r as u32 + LUMA_G * g as u32 + LUMA_B * b as u32;
    ((sum + (1 << (LUMA_SHIFT - 1))) >> LUMA_SHIFT) as u8
}

impl BayerPattern {
    /// Colour of pixel (x, y): 0 = R, 1 = G, 2 = B.
    fn colour(self, x: usize, y: usize) -> usize {
        let (r_x, r_y) = match self {
            BayerPattern::Rggb => (0, 0),
            BayerPattern::Grbg => (1, 0),
            BayerPattern::Gbrg => (0, 1),
            BayerPattern::Bggr => (1, 1),
        };
        match ((x & 1) == r_x, (y & 1) == r_y) {
            (true, true) => 0,
            (false, false) => 2,
            _ => 1,
        }
    }
}

/// 8-bit Bayer mosaic → gray at full resolution, without a colour demosaic.
///
/// Every 2×2 window of a Bayer mosaic holds exactly one R, two G and one B sample, whatever
/// its position, so its BT.601 luma is `wR·R + wG·(G₁+G₂)/2 + wB·B`. A pixel's gray value is
/// the mean luma of the four windows that contain it (a 3×3 footprint centred on the pixel,
/// so there is no half-pixel shift that would bias the calibrated principal point). On a
/// uniformly coloured surface the result is that colour's exact luma. Border pixels use the
/// windows that exist. Needs at least 2×2 pixels.
pub(crate) fn bayer8(
    g: Geometry,
    buf: &[u8],
    pattern: BayerPattern,
) -> Result<GrayImage, ConvertError> {
    g.check(buf, 1)?;
    let (w, h) = (g.width as usize, g.height as usize);
    if w < 2 || h < 2 {
        return Err(ConvertError::Corrupt(format!(
            "Bayer frame {w}x{h} is smaller than one 2x2 cell"
        )));
    }
    let weight = [LUMA_R * 2, LUMA_G, LUMA_B * 2];
    // Window luma ×2^15 (G is summed twice, so R and B carry double weight) for windows whose
    // top-left corner is (x, y), x < w-1, y < h-1; computed one row of windows at a time.
    let window_row = |y: usize, out: &mut [u32]| {
        let r0 = g.row(buf, y, 1);
        let r1 = g.row(buf, y + 1, 1);
        for (x, o) in out.iter_mut().enumerate() {
            *o = weight[pattern.colour(x, y)] * r0[x] as u32
                + weight[pattern.colour(x + 1, y)] * r0[x + 1] as u32
                + weight[pattern.colour(x, y + 1)] * r1[x] as u32
                + weight[pattern.colour(x + 1, y + 1)] * r1[x + 1] as u32;
        }
    };
    let mut out = GrayImage::new(g.width, g.height);
    let mut prev = vec![0u32; w - 1];
    let mut cur = vec![0u32; w - 1];
    for y in 0..h {
        // Windows covering row y start at rows y-1 and y (those that exist).
        std::mem::swap(&mut prev, &mut cur);
        if y < h - 1 {
            window_row(y, &mut cur);
        }
        let rows: &[&[u32]] = match (y, y == h - 1) {
            (0, _) => &[&cur],
            (_, true) => &[&prev],
            _ => &[&prev, &cur],
        };
        let dst = &mut out.as_mut()[y * w..(y + 1) * w];
        for (x, d) in dst.iter_mut().enumerate() {
            let (x0, x1) = (x.saturating_sub(1), x.min(w - 2));
            let mut sum = 0u64;
            let mut n = 0u64;
            for r in rows {
                sum += r[x0] as u64;
                n += 1;
                if x1 != x0 {
                    sum += r[x1] as u64;
                    n += 1;
                }
            }
            let scale = n << (LUMA_SHIFT + 1);
            *d = ((sum + scale / 2) / scale).min(u8::MAX as u64) as u8;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn gray_weights_are_opencvs() {
        assert_eq!(LUMA_R + LUMA_G + LUMA_B, 1 << LUMA_SHIFT);
        assert_eq!(luma601(255, 255, 255), 255);
        assert_eq!(luma601(255, 0, 0), 76); // 0.299·255 = 76.2
        assert_eq!(luma601(0, 255, 0), 150); // 0.587·255 = 149.7
        assert_eq!(luma601(0, 0, 255), 29); // 0.114·255 = 29.1
    }

    /// A gray test image with structure in both axes (and not symmetric), so a transposed,
    /// shifted or byte-swapped conversion cannot pass.
    fn known_gray(w: u32, h: u32) -> GrayImage {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        GrayImage::from_fn(w, h, |x, y| {
            image::Luma([((x * 7 + y * 13) as u8).wrapping_add(rng.random_range(0..4))])
        })
    }

    /// Rows of `row_bytes` followed by `pad` junk bytes each: how drivers align strides.
    fn with_padding(rows: impl Iterator<Item = Vec<u8>>, pad: usize) -> Vec<u8> {
        let mut out = Vec::new();
        for r in rows {
            out.extend_from_slice(&r);
            out.extend(std::iter::repeat_n(0xAB, pad));
        }
        out
    }

    #[test]
    fn grey_with_row_padding() {
        let img = known_gray(37, 11);
        let pad = 27; // 37 → stride 64
        let buf = with_padding(img.rows().map(|r| r.map(|p| p[0]).collect()), pad);
        let out = gray8(
            Geometry {
                width: 37,
                height: 11,
                stride: 64,
            },
            &buf,
        )
        .unwrap();
        assert_eq!(out, img);
    }

    #[test]
    fn y16_little_endian_takes_high_byte() {
        let img = known_gray(16, 9);
        // Full-range 16-bit value v*257 + noise in the low byte: gray must be v exactly.
        let buf: Vec<u8> = img
            .pixels()
            .enumerate()
            .flat_map(|(i, p)| ((p[0] as u16) << 8 | (i as u16 % 251)).to_le_bytes())
            .collect();
        let out = gray16le(Geometry::packed(16, 9, 2), &buf).unwrap();
        assert_eq!(out, img);
        // A big-endian misreading would give the low (noise) bytes; make sure they differ.
        let low: Vec<u8> = buf.iter().step_by(2).copied().collect();
        assert_ne!(&low, img.as_raw());
    }

    #[test]
    fn yuyv_takes_luma() {
        let img = known_gray(20, 7);
        // Chroma bytes are deliberately far from the luma so taking the wrong byte fails.
        let buf = with_padding(
            img.rows().map(|r| {
                r.enumerate()
                    .flat_map(|(x, p)| [p[0], if x % 2 == 0 { 16 } else { 240 }])
                    .collect()
            }),
            8,
        );
        let out = yuyv(
            Geometry {
                width: 20,
                height: 7,
                stride: 48,
            },
            &buf,
        )
        .unwrap();
        assert_eq!(out, img);
        assert!(matches!(
            yuyv(Geometry::packed(3, 1, 2), &[0; 6]),
            Err(ConvertError::Corrupt(_))
        ));
    }

    #[test]
    fn short_buffers_are_reported_with_sizes() {
        let e = gray8(Geometry::packed(10, 10, 1), &[0; 99]).unwrap_err();
        assert_eq!(
            e,
            ConvertError::Short {
                expected: 100,
                got: 99
            }
        );
        assert!(e.to_string().contains("99 bytes, expected 100"));
        // The last row needs no padding.
        let g = Geometry {
            width: 10,
            height: 2,
            stride: 16,
        };
        assert!(gray8(g, &[0; 26]).is_ok());
        assert!(matches!(
            gray16le(g, &[0; 26]),
            Err(ConvertError::Corrupt(_))
        ));
    }

    #[test]
    fn mjpeg_real_jpeg_round_trip() {
        // A smooth image (JPEG is lossy; smooth content keeps the error small and bounded).
        let img = GrayImage::from_fn(64, 48, |x, y| image::Luma([(x * 2 + y * 2) as u8]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&img)
            .unwrap();
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8], "a real JPEG stream (SOI)");
        let out = mjpeg(&jpeg, Some((64, 48))).unwrap();
        let max_err = out
            .pixels()
            .zip(img.pixels())
            .map(|(a, b)| (a[0] as i32 - b[0] as i32).abs())
            .max()
            .unwrap();
        assert!(max_err <= 3, "JPEG round trip error {max_err}");

        // A colour JPEG (as UVC cameras send) decodes to its luma.
        let rgb = image::RgbImage::from_fn(32, 32, |_, _| image::Rgb([200, 100, 0]));
        let mut jpeg_rgb = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg_rgb, 95)
            .encode_image(&rgb)
            .unwrap();
        let out = mjpeg(&jpeg_rgb, None).unwrap();
        // BT.601 luma of (200, 100, 0) = 118.5 (JPEG's own YCbCr uses these weights; Rec.709
        // weights would give 114).
        let centre = out.get_pixel(16, 16)[0] as i32;
        assert!((centre - 118).abs() <= 2, "luma {centre}");

        // Wrong size, truncated and garbage frames are errors, not images.
        assert!(matches!(
            mjpeg(&jpeg, Some((640, 480))),
            Err(ConvertError::Corrupt(_))
        ));
        assert!(mjpeg(&jpeg[..jpeg.len() / 3], None).is_err());
        assert!(matches!(
            mjpeg(b"not a jpeg at all", None),
            Err(ConvertError::Corrupt(_))
        ));
        assert!(matches!(mjpeg(&[], None), Err(ConvertError::Short { .. })));
    }

    /// Mosaic an RGB image with `pattern` (each pixel keeps the one channel its filter passes).
    fn mosaic(rgb: &image::RgbImage, pattern: BayerPattern) -> Vec<u8> {
        rgb.enumerate_pixels()
            .map(|(x, y, p)| p[pattern.colour(x as usize, y as usize)])
            .collect()
    }

    const PATTERNS: [BayerPattern; 4] = [
        BayerPattern::Rggb,
        BayerPattern::Bggr,
        BayerPattern::Grbg,
        BayerPattern::Gbrg,
    ];

    #[test]
    fn bayer_pattern_layouts_match_their_names() {
        let names = ["RGGB", "BGGR", "GRBG", "GBRG"];
        for (p, name) in PATTERNS.iter().zip(names) {
            let cell: String = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(x, y)| ['R', 'G', 'B'][p.colour(x, y)])
                .collect();
            assert_eq!(cell, name);
            // The pattern repeats with period 2.
            assert_eq!(p.colour(5, 7), p.colour(1, 1));
        }
    }

    #[test]
    fn bayer_uniform_colour_gives_its_bt601_luma() {
        // Orange: BT.601 luma = 0.299·200 + 0.587·100 + 0.114·0 = 118.5 → 118 or 119.
        // A pattern mix-up (R↔B) would give 0.299·0 + 0.587·100 + 0.114·200 = 81.5.
        let rgb = image::RgbImage::from_pixel(10, 8, image::Rgb([200, 100, 0]));
        for p in PATTERNS {
            let out = bayer8(Geometry::packed(10, 8, 1), &mosaic(&rgb, p), p).unwrap();
            for v in out.pixels() {
                assert!((118..=119).contains(&v[0]), "{p:?}: {}", v[0]);
            }
            // Decoding with the R/B-swapped pattern must visibly differ (the test can fail).
            let swapped = match p {
                BayerPattern::Rggb => BayerPattern::Bggr,
                BayerPattern::Bggr => BayerPattern::Rggb,
                BayerPattern::Grbg => BayerPattern::Gbrg,
                BayerPattern::Gbrg => BayerPattern::Grbg,
            };
            let wrong = bayer8(Geometry::packed(10, 8, 1), &mosaic(&rgb, p), swapped).unwrap();
            assert!((wrong.get_pixel(4, 4)[0] as i32 - 82).abs() <= 1);
        }
    }

    #[test]
    fn bayer_gray_scene_is_reproduced_and_centred() {
        // A gray scene (R = G = B) must come back as itself, smoothed by the 3×3 footprint:
        // on a linear ramp the centred footprint is exact, a shifted one would be off by ½ step.
        let img = GrayImage::from_fn(40, 30, |x, y| image::Luma([(x * 4 + y * 2) as u8]));
        let rgb = image::DynamicImage::ImageLuma8(img.clone()).into_rgb8();
        for p in PATTERNS {
            let out = bayer8(Geometry::packed(40, 30, 1), &mosaic(&rgb, p), p).unwrap();
            for y in 1..29 {
                for x in 1..39 {
                    assert_eq!(out.get_pixel(x, y), img.get_pixel(x, y), "{p:?} ({x},{y})");
                }
            }
        }
    }

    #[test]
    fn bayer_matches_opencv_reference_on_smooth_colour_scene() {
        // Reference: tests/reference/bayer_gray.py renders a smooth colour scene, mosaics it
        // and stores the scene's cv2.cvtColor(RGB2GRAY) luma. Our demosaic-free gray must agree
        // with the true luma of the scene to within the smoothing of a 3×3 footprint.
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/bayer");
        let raw = std::fs::read(format!("{dir}/scene_rggb_64x48.raw")).unwrap();
        let luma = image::open(format!("{dir}/scene_luma_64x48.png"))
            .unwrap()
            .into_luma8();
        let out = bayer8(Geometry::packed(64, 48, 1), &raw, BayerPattern::Rggb).unwrap();
        let mut max_err = 0;
        for y in 1..47 {
            for x in 1..63 {
                let e = (out.get_pixel(x, y)[0] as i32 - luma.get_pixel(x, y)[0] as i32).abs();
                max_err = max_err.max(e);
            }
        }
        assert!(max_err <= 2, "max |gray - OpenCV luma| = {max_err}");
        // With the wrong pattern the error is large: the test discriminates.
        let wrong = bayer8(Geometry::packed(64, 48, 1), &raw, BayerPattern::Bggr).unwrap();
        let wrong_err = (1..47)
            .flat_map(|y| (1..63).map(move |x| (x, y)))
            .map(|(x, y)| (wrong.get_pixel(x, y)[0] as i32 - luma.get_pixel(x, y)[0] as i32).abs())
            .max()
            .unwrap();
        assert!(wrong_err > 20, "wrong pattern error only {wrong_err}");
    }

    #[test]
    fn bayer_rejects_tiny_and_short() {
        assert!(matches!(
            bayer8(Geometry::packed(1, 5, 1), &[0; 5], BayerPattern::Rggb),
            Err(ConvertError::Corrupt(_))
        ));
        assert!(matches!(
            bayer8(Geometry::packed(4, 4, 1), &[0; 15], BayerPattern::Rggb),
            Err(ConvertError::Short { .. })
        ));
    }
}
