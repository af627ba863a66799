//! Rectification: perspective maps with `cv::omnidir::initUndistortRectifyMap(…, RECTIFY_PERSPECTIVE)`
//! semantics over any [`CameraModel`], a fast fixed-point bilinear remap of gray images, and
//! ground-plane (BEV) orthorectification.
//!
//! * **Perspective maps.** Output pixel (u, v) looks along the ray `(P·R)⁻¹·[u, v, 1]ᵀ` (camera frame),
//!   which is projected through the camera model. For [`crate::camera::Mei`] this is OpenCV's formula
//!   exactly: normalise the ray to the unit sphere, divide by `z + ξ`, radtan distortion, then
//!   `u = fx·xd + s·yd + cx`, `v = fy·yd + cy`. Rays the model rejects (behind the mirror, beyond the
//!   distortion fold) get `INVALID_COORD`; OpenCV writes a meaningless coordinate there instead.
//! * **Remap.** [`RemapTable`] quantises a float map the way `cv::remap` does internally (coordinate
//!   rounded to 1/32 px, 5-bit fractions, weights summing to 1024) so the result equals
//!   `cv2.remap(…, INTER_LINEAR, BORDER_CONSTANT, 0)`; [`remap_bilinear_f32`] is the plain float
//!   version kept as the benchmark baseline.
//! * **Orthorectification.** [`orthorectify`] renders the camera image onto a map grid, with the
//!   ground height taken from a height raster.

use super::{CameraError, CameraModel};
use crate::error::Result;
use crate::map::{GeoGrid, Raster};
use crate::pose::CamFromMap;
use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;

/// Map value for output pixels whose ray the camera model cannot project. It is far outside any
/// image, so `cv2.remap` and [`RemapTable`] both treat it as border (value 0).
pub(crate) const INVALID_COORD: f32 = -1.0e5;

/// Fractional bits of the remap's fixed-point coordinates (OpenCV `INTER_BITS`).
const FRAC_BITS: u32 = 5;
/// Sub-pixel positions per pixel (OpenCV `INTER_TAB_SIZE`).
const FRAC_ONE: u32 = 1 << FRAC_BITS;
/// Mask of the fractional part of a fixed-point coordinate.
const FRAC_MASK: i32 = FRAC_ONE as i32 - 1;
/// Bits of the product of two fractional weights: the bilinear weights sum to `1 << WEIGHT_BITS`.
const WEIGHT_BITS: u32 = 2 * FRAC_BITS;
/// Rounding term added before the final shift.
const WEIGHT_HALF: u32 = 1 << (WEIGHT_BITS - 1);

/// A per-pixel source-coordinate map (OpenCV `CV_32FC1` map pair), row-major `width × height`.
#[derive(Debug, Clone, PartialEq)]
pub struct RectifyMap {
    /// Output width.
    pub width: usize,
    /// Output height.
    pub height: usize,
    /// Source x of each output pixel (pixel centres at integers), or `INVALID_COORD`.
    pub map_x: Vec<f32>,
    /// Source y of each output pixel, or `INVALID_COORD`.
    pub map_y: Vec<f32>,
}

/// Build the perspective rectification map of `cam` for a virtual pinhole camera with intrinsics `p`
/// rotated by `r` (`cv::omnidir::initUndistortRectifyMap(K, D, ξ, R, P, size, CV_32FC1, …,
/// RECTIFY_PERSPECTIVE)`; for [`crate::camera::Equidistant`] it equals `cv::fisheye`'s map wherever
/// the ray is in front of the camera).
///
/// `r` is used as given (like OpenCV, it need not be orthonormal); `P·R` must be invertible.
pub fn perspective_map(
    cam: &dyn CameraModel,
    p: &Matrix3<f64>,
    r: &Matrix3<f64>,
    width: usize,
    height: usize,
) -> Result<RectifyMap> {
    if width == 0 || height == 0 {
        return Err(CameraError::RectifyEmpty { width, height }.into());
    }
    let ikr = (p * r).try_inverse().ok_or(CameraError::RectifySingular)?;
    let n = width * height;
    let mut map_x = vec![0f32; n];
    let mut map_y = vec![0f32; n];
    map_x
        .par_chunks_mut(width)
        .zip(map_y.par_chunks_mut(width))
        .enumerate()
        .for_each(|(v, (mx, my))| {
            for (u, (x, y)) in mx.iter_mut().zip(my.iter_mut()).enumerate() {
                let ray = ikr * Vector3::new(u as f64, v as f64, 1.0);
                match cam.project(&ray) {
                    Ok(px) => {
                        *x = px.x as f32;
                        *y = px.y as f32;
                    }
                    Err(_) => {
                        *x = INVALID_COORD;
                        *y = INVALID_COORD;
                    }
                }
            }
        });
    Ok(RectifyMap {
        width,
        height,
        map_x,
        map_y,
    })
}

/// A borrowed gray u8 image, row-major without padding.
#[derive(Debug, Clone, Copy)]
pub struct GrayView<'a> {
    /// `width × height` samples.
    pub data: &'a [u8],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl<'a> GrayView<'a> {
    /// Wrap a buffer, checking its length.
    pub fn new(data: &'a [u8], width: usize, height: usize) -> Result<Self> {
        if width.checked_mul(height) != Some(data.len()) {
            return Err(CameraError::GraySize {
                bytes: data.len(),
                width,
                height,
            }
            .into());
        }
        Ok(GrayView {
            data,
            width,
            height,
        })
    }

    /// Pixel with constant-0 border.
    #[inline]
    fn at_or_zero(&self, x: i64, y: i64) -> u32 {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.data[y as usize * self.width + x as usize] as u32
        } else {
            0
        }
    }

    /// Bilinear sample at a continuous position with edge replication (callers ensure the
    /// position is on the sensor; replication only matters in the last half pixel).
    #[inline]
    fn bilinear_clamped(&self, x: f64, y: f64) -> u8 {
        let xc = x.clamp(0.0, (self.width - 1) as f64);
        let yc = y.clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (xc.floor() as usize, yc.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (ax, ay) = (xc - x0 as f64, yc - y0 as f64);
        let px = |c: usize, r: usize| self.data[r * self.width + c] as f64;
        let top = px(x0, y0) + ax * (px(x1, y0) - px(x0, y0));
        let bot = px(x0, y1) + ax * (px(x1, y1) - px(x0, y1));
        (top + ay * (bot - top)).round().clamp(0.0, 255.0) as u8
    }
}

/// Check that a map and an image go together.
fn check_map(map: &RectifyMap) -> Result<()> {
    let n = map.width.checked_mul(map.height);
    if n != Some(map.map_x.len()) || n != Some(map.map_y.len()) {
        return Err(CameraError::MapPlanes {
            map_x: map.map_x.len(),
            map_y: map.map_y.len(),
            width: map.width,
            height: map.height,
        }
        .into());
    }
    Ok(())
}

/// Straightforward float bilinear remap with constant-0 border (the benchmark baseline).
///
/// Differs from `cv2.remap` only by OpenCV's 1/32-px coordinate quantisation (at most a few grey
/// levels on hard edges).
pub fn remap_bilinear_f32(src: &GrayView<'_>, map: &RectifyMap) -> Result<Vec<u8>> {
    check_map(map)?;
    let mut out = vec![0u8; map.width * map.height];
    out.par_chunks_mut(map.width)
        .zip(map.map_x.par_chunks(map.width))
        .zip(map.map_y.par_chunks(map.width))
        .for_each(|((row, mx), my)| {
            for ((d, &x), &y) in row.iter_mut().zip(mx).zip(my) {
                if !(x.is_finite() && y.is_finite()) {
                    *d = 0;
                    continue;
                }
                let (xf, yf) = (x.floor(), y.floor());
                let (ax, ay) = (x - xf, y - yf);
                let (x0, y0) = (xf as i64, yf as i64);
                let p00 = src.at_or_zero(x0, y0) as f32;
                let p01 = src.at_or_zero(x0 + 1, y0) as f32;
                let p10 = src.at_or_zero(x0, y0 + 1) as f32;
                let p11 = src.at_or_zero(x0 + 1, y0 + 1) as f32;
                let top = p00 + ax * (p01 - p00);
                let bot = p10 + ax * (p11 - p10);
                *d = (top + ay * (bot - top)).round() as u8;
            }
        });
    Ok(out)
}

/// An output pixel whose 2×2 source neighbourhood is not entirely inside the image.
#[derive(Debug, Clone, Copy)]
struct EdgePixel {
    /// Column in the output row.
    col: u32,
    /// Integer source position of the top-left tap.
    x0: i32,
    /// Integer source row of the top-left tap.
    y0: i32,
    /// Packed 5-bit fractions, `fx | fy << FRAC_BITS`.
    frac: u16,
}

/// A float map compiled for one source size into the form the fast remap streams through:
/// per output pixel a `u32` offset of the top-left tap and packed 5-bit fractions (6 bytes instead
/// of the 8 of two f32 planes), with the few pixels touching the border kept in a side list.
///
/// Quantisation follows `cv::remap` (`INTER_LINEAR`): the source coordinate is rounded
/// (ties to even) to 1/32 px; the weights are products of the fractions and sum to exactly 1024,
/// which is OpenCV's 15-bit table divided by 32. So the output equals OpenCV's bit for bit given
/// the same float map (constant border 0).
#[derive(Debug, Clone)]
pub struct RemapTable {
    src_width: usize,
    src_height: usize,
    width: usize,
    height: usize,
    /// Offset of the top-left tap (0 for edge pixels, fixed up afterwards).
    offsets: Vec<u32>,
    /// Packed fractions `fx | fy << FRAC_BITS`.
    fracs: Vec<u16>,
    /// Border-touching pixels, sorted by row.
    edges: Vec<EdgePixel>,
    /// `edges[row_edges[r]..row_edges[r + 1]]` belong to output row `r`.
    row_edges: Vec<u32>,
}

/// Fixed-point coordinate as `cv::remap` computes it: `round_ties_even(c · 32)`, saturated.
#[inline]
fn fixed_coord(c: f32) -> Option<i32> {
    if !c.is_finite() {
        return None;
    }
    let s = (c * FRAC_ONE as f32).round_ties_even();
    // Saturate far-away (sentinel) coordinates; they are outside either way.
    Some(s.clamp(i32::MIN as f32, i32::MAX as f32) as i32)
}

impl RemapTable {
    /// Compile `map` for a source image of `src_width × src_height` (at least 2×2).
    pub fn new(map: &RectifyMap, src_width: usize, src_height: usize) -> Result<Self> {
        check_map(map)?;
        if src_width < 2 || src_height < 2 {
            return Err(CameraError::SourceTooSmall {
                width: src_width,
                height: src_height,
            }
            .into());
        }
        if src_width
            .checked_mul(src_height)
            .is_none_or(|n| n > u32::MAX as usize)
        {
            return Err(CameraError::SourceTooLarge {
                width: src_width,
                height: src_height,
            }
            .into());
        }
        let (w, h) = (map.width, map.height);
        let mut offsets = vec![0u32; w * h];
        let mut fracs = vec![0u16; w * h];
        let row_lists: Vec<Vec<EdgePixel>> = offsets
            .par_chunks_mut(w)
            .zip(fracs.par_chunks_mut(w))
            .zip(map.map_x.par_chunks(w))
            .zip(map.map_y.par_chunks(w))
            .map(|(((offs, frs), mx), my)| {
                let mut edges = Vec::new();
                for (col, (((o, f), &x), &y)) in offs
                    .iter_mut()
                    .zip(frs.iter_mut())
                    .zip(mx)
                    .zip(my)
                    .enumerate()
                {
                    let (Some(fx), Some(fy)) = (fixed_coord(x), fixed_coord(y)) else {
                        // Non-finite: a fully outside edge pixel.
                        edges.push(EdgePixel {
                            col: col as u32,
                            x0: i32::MIN,
                            y0: i32::MIN,
                            frac: 0,
                        });
                        continue;
                    };
                    let (x0, y0) = (fx >> FRAC_BITS, fy >> FRAC_BITS);
                    let frac = ((fx & FRAC_MASK) | (fy & FRAC_MASK) << FRAC_BITS) as u16;
                    let inside = x0 >= 0
                        && y0 >= 0
                        && (x0 as usize) + 1 < src_width
                        && (y0 as usize) + 1 < src_height;
                    if inside {
                        *o = (y0 as usize * src_width + x0 as usize) as u32;
                        *f = frac;
                    } else {
                        edges.push(EdgePixel {
                            col: col as u32,
                            x0,
                            y0,
                            frac,
                        });
                    }
                }
                edges
            })
            .collect();
        let mut row_edges = Vec::with_capacity(h + 1);
        let mut edges = Vec::with_capacity(row_lists.iter().map(Vec::len).sum());
        row_edges.push(0u32);
        for list in row_lists {
            edges.extend(list);
            row_edges.push(edges.len() as u32);
        }
        Ok(RemapTable {
            src_width,
            src_height,
            width: w,
            height: h,
            offsets,
            fracs,
            edges,
            row_edges,
        })
    }

    /// Remap `src` (which must have the size the table was built for) into a new image.
    pub fn remap(&self, src: &GrayView<'_>) -> Result<Vec<u8>> {
        let mut out = vec![0u8; self.width * self.height];
        self.remap_into(src, &mut out)?;
        Ok(out)
    }

    /// Remap `src` into `dst` (`width × height`), rows in parallel on the current rayon pool.
    pub fn remap_into(&self, src: &GrayView<'_>, dst: &mut [u8]) -> Result<()> {
        if src.width != self.src_width || src.height != self.src_height {
            return Err(CameraError::RemapSource {
                width: src.width,
                height: src.height,
                table_width: self.src_width,
                table_height: self.src_height,
            }
            .into());
        }
        if dst.len() != self.width * self.height {
            return Err(CameraError::RemapOutput {
                bytes: dst.len(),
                width: self.width,
                height: self.height,
            }
            .into());
        }
        let w = self.width;
        dst.par_chunks_mut(w)
            .zip(self.offsets.par_chunks(w))
            .zip(self.fracs.par_chunks(w))
            .enumerate()
            .for_each(|(row, ((d, offs), frs))| {
                // SAFETY: the table's offsets satisfy `o + stride + 1 < src.len()` for a source of
                // the size it was built for (`RemapTable::new`), and the size was checked above.
                unsafe { remap_row(src.data, self.src_width, d, offs, frs) };
                let edges =
                    &self.edges[self.row_edges[row] as usize..self.row_edges[row + 1] as usize];
                for e in edges {
                    d[e.col as usize] = edge_sample(src, e);
                }
            });
        Ok(())
    }
}

/// Pixels per block of the inner loop: gathered first, then interpolated in one vectorisable pass.
const BLOCK: usize = 16;

/// Interpolate one output row (all pixels; edge pixels are overwritten afterwards). Uses AVX2 for
/// the arithmetic when the CPU has it (runtime detection; the same code compiled twice).
///
/// # Safety
/// As [`remap_row_kernel`]: every offset `o` in `offs` satisfies `o + stride + 1 < src.len()`.
#[inline]
unsafe fn remap_row(src: &[u8], stride: usize, dst: &mut [u8], offs: &[u32], fracs: &[u16]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above); the offsets contract is this
        // function's own, passed on.
        unsafe { remap_row_avx2(src, stride, dst, offs, fracs) };
        return;
    }
    // SAFETY: the offsets contract is this function's own, passed on.
    unsafe { remap_row_kernel(src, stride, dst, offs, fracs) };
}

/// [`remap_row_kernel`] compiled with AVX2 enabled.
///
/// # Safety
/// The CPU supports AVX2, and the offsets satisfy [`remap_row_kernel`]'s contract.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn remap_row_avx2(src: &[u8], stride: usize, dst: &mut [u8], offs: &[u32], fracs: &[u16]) {
    // SAFETY: the offsets contract is this function's own, passed on.
    unsafe { remap_row_kernel(src, stride, dst, offs, fracs) }
}

/// The branch-free inner loop. Per block: gather the two 2-byte pairs of each pixel (unaligned,
/// unchecked loads), then interpolate in the form `t = 32·p00 + (p01 − p00)·fx`,
/// `r = (32·t + (b − t)·fy + 512) >> 10`, which equals OpenCV's weighted sum exactly with three
/// multiplies instead of eight.
///
/// # Safety
/// Every offset `o` in `offs` satisfies `o + stride + 1 < src.len()` ([`RemapTable::new`] only
/// stores offsets of pixels whose 2×2 neighbourhood is inside the source, and
/// [`RemapTable::remap_into`] checks the source size); the reads are unchecked because checked
/// loads would cost a compare and a branch per tap in the hottest loop of the frame pipeline.
#[inline(always)]
unsafe fn remap_row_kernel(src: &[u8], stride: usize, dst: &mut [u8], offs: &[u32], fracs: &[u16]) {
    let base = src.as_ptr();
    let gather = |o: u32| -> ([u8; 2], [u8; 2]) {
        debug_assert!(o as usize + stride + 1 < src.len());
        // SAFETY: by the function's contract both 2-byte reads at o and o + stride lie inside `src`;
        // read_unaligned has no alignment requirement.
        unsafe {
            let p = base.add(o as usize);
            (
                p.cast::<[u8; 2]>().read_unaligned(),
                p.add(stride).cast::<[u8; 2]>().read_unaligned(),
            )
        }
    };
    let one = FRAC_ONE as i32;
    let interp = |t: [u8; 2], b: [u8; 2], f: u16| -> u8 {
        let fx = (f as i32) & FRAC_MASK;
        let fy = (f as i32) >> FRAC_BITS;
        let top = t[0] as i32 * one + (t[1] as i32 - t[0] as i32) * fx;
        let bot = b[0] as i32 * one + (b[1] as i32 - b[0] as i32) * fx;
        ((top * one + (bot - top) * fy + WEIGHT_HALF as i32) >> WEIGHT_BITS) as u8
    };
    let mut d_blocks = dst.chunks_exact_mut(BLOCK);
    let mut o_blocks = offs.chunks_exact(BLOCK);
    let mut f_blocks = fracs.chunks_exact(BLOCK);
    for ((d, o), f) in (&mut d_blocks).zip(&mut o_blocks).zip(&mut f_blocks) {
        let mut top = [[0u8; 2]; BLOCK];
        let mut bot = [[0u8; 2]; BLOCK];
        for i in 0..BLOCK {
            (top[i], bot[i]) = gather(o[i]);
        }
        for i in 0..BLOCK {
            d[i] = interp(top[i], bot[i], f[i]);
        }
    }
    let rest = d_blocks
        .into_remainder()
        .iter_mut()
        .zip(o_blocks.remainder())
        .zip(f_blocks.remainder());
    for ((d, &o), &f) in rest {
        let (t, b) = gather(o);
        *d = interp(t, b, f);
    }
}

/// A border-touching pixel: outside taps read 0 (OpenCV `BORDER_CONSTANT`, value 0).
#[inline]
fn edge_sample(src: &GrayView<'_>, e: &EdgePixel) -> u8 {
    if e.x0 == i32::MIN {
        return 0;
    }
    let (x0, y0) = (e.x0 as i64, e.y0 as i64);
    let fx = e.frac as u32 & FRAC_MASK as u32;
    let fy = e.frac as u32 >> FRAC_BITS;
    let top = src.at_or_zero(x0, y0) * (FRAC_ONE - fx) + src.at_or_zero(x0 + 1, y0) * fx;
    let bot = src.at_or_zero(x0, y0 + 1) * (FRAC_ONE - fx) + src.at_or_zero(x0 + 1, y0 + 1) * fx;
    ((top * (FRAC_ONE - fy) + bot * fy + WEIGHT_HALF) >> WEIGHT_BITS) as u8
}

/// Height raster with holes filled, ready for bilinear lookups.
struct FilledHeight {
    grid: GeoGrid,
    z: Vec<f64>,
}

impl FilledHeight {
    /// Fill NaN / no-data cells with the value of the nearest valid cell (multi-source
    /// breadth-first search, 4-neighbourhood, so "nearest" is in city-block distance, ties broken
    /// by scan order). Holes in LiDAR ground height are small (cars, poles), where this is a
    /// reasonable local fill and, unlike interpolation, never invents heights outside the data.
    fn new(h: &Raster<f32>) -> Result<Self> {
        let g = h.grid;
        if h.data.len() != g.len() {
            return Err(CameraError::HeightSize {
                samples: h.data.len(),
                width: g.width,
                height: g.height,
            }
            .into());
        }
        let valid = |v: f32| v.is_finite() && h.nodata.is_none_or(|nd| v != nd);
        let mut z: Vec<f64> = h.data.iter().map(|&v| v as f64).collect();
        let mut done: Vec<bool> = h.data.iter().map(|&v| valid(v)).collect();
        let mut queue: std::collections::VecDeque<usize> =
            (0..g.len()).filter(|&i| done[i]).collect();
        if queue.is_empty() {
            return Err(CameraError::HeightEmpty.into());
        }
        while let Some(i) = queue.pop_front() {
            let (c, r) = (i % g.width, i / g.width);
            let mut visit = |j: usize| {
                if !done[j] {
                    done[j] = true;
                    z[j] = z[i];
                    queue.push_back(j);
                }
            };
            if c > 0 {
                visit(i - 1);
            }
            if c + 1 < g.width {
                visit(i + 1);
            }
            if r > 0 {
                visit(i - g.width);
            }
            if r + 1 < g.height {
                visit(i + g.width);
            }
        }
        Ok(FilledHeight { grid: g, z })
    }

    /// Bilinear height at map (x, y); outside the grid the edge cells are extended.
    fn at(&self, x: f64, y: f64) -> f64 {
        let g = &self.grid;
        let (c, r) = g.to_pixel(x, y);
        let c = c.clamp(0.0, (g.width - 1) as f64);
        let r = r.clamp(0.0, (g.height - 1) as f64);
        let (c0, r0) = (c.floor() as usize, r.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(g.width - 1), (r0 + 1).min(g.height - 1));
        let (ax, ay) = (c - c0 as f64, r - r0 as f64);
        let z = |cc: usize, rr: usize| self.z[rr * g.width + cc];
        let top = z(c0, r0) + ax * (z(c1, r0) - z(c0, r0));
        let bot = z(c0, r1) + ax * (z(c1, r1) - z(c0, r1));
        top + ay * (bot - top)
    }
}

/// Mask value of an orthorectified cell the camera sees.
pub const MASK_SEEN: u8 = 255;

/// Render the camera image onto the map grid `out` (ground-plane orthorectification, "BEV").
///
/// For each output cell centre (x, y) the ground height z is interpolated bilinearly from `height`
/// (NaN / no-data cells filled from the nearest valid cell, see `FilledHeight`; outside the height
/// grid its edge is extended), the point (x, y, z) is transformed into the camera with `pose` and
/// projected with [`CameraModel::project_visible`]; the image is sampled bilinearly there.
/// Returns the gray BEV image and a mask ([`MASK_SEEN`] where seen, 0 elsewhere, gray 0 there),
/// both row-major on `out`. All geometry is f64, so large UTM coordinates lose nothing.
/// Occlusion by objects above the ground is not modelled.
pub fn orthorectify(
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    height: &Raster<f32>,
    image: &GrayView<'_>,
    out: GeoGrid,
) -> Result<(Vec<u8>, Vec<u8>)> {
    if image.width != cam.width() as usize || image.height != cam.height() as usize {
        return Err(CameraError::OrthoImage {
            width: image.width,
            height: image.height,
            camera_width: cam.width(),
            camera_height: cam.height(),
        }
        .into());
    }
    if image.width == 0 || image.height == 0 || out.is_empty() {
        return Err(CameraError::OrthoEmpty.into());
    }
    let z = FilledHeight::new(height)?;
    let mut gray = vec![0u8; out.len()];
    let mut mask = vec![0u8; out.len()];
    gray.par_chunks_mut(out.width)
        .zip(mask.par_chunks_mut(out.width))
        .enumerate()
        .for_each(|(row, (g, m))| {
            for (col, (gv, mv)) in g.iter_mut().zip(m.iter_mut()).enumerate() {
                let (x, y) = out.pixel_center(col, row);
                let p = pose.transform(&Point3::new(x, y, z.at(x, y)));
                if let Ok(px) = cam.project_visible(&p.coords) {
                    *gv = image.bilinear_clamped(px.x, px.y);
                    *mv = MASK_SEEN;
                }
            }
        });
    Ok((gray, mask))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Equidistant, Mei};
    use crate::map::Crs;
    use nalgebra::Point2;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Independent per-pixel transcription of OpenCV's remapBilinear rules (8u, constant border 0):
    /// 15-bit weights from the float table, then `(Σ w·p + 2^14) >> 15`.
    fn opencv_rule(src: &GrayView<'_>, x: f32, y: f32) -> u8 {
        let xi = (x * 32.0).round_ties_even() as i64;
        let yi = (y * 32.0).round_ties_even() as i64;
        let (x0, y0) = (xi.div_euclid(32), yi.div_euclid(32));
        let (ax, ay) = (
            xi.rem_euclid(32) as f32 / 32.0,
            yi.rem_euclid(32) as f32 / 32.0,
        );
        let w = [
            (1.0 - ax) * (1.0 - ay),
            ax * (1.0 - ay),
            (1.0 - ax) * ay,
            ax * ay,
        ];
        let taps = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
        let mut acc = 0i64;
        for (wi, (tx, ty)) in w.iter().zip(taps) {
            acc += (wi * 32768.0).round() as i64 * src.at_or_zero(tx, ty) as i64;
        }
        ((acc + (1 << 14)) >> 15) as u8
    }

    fn noise_image(w: usize, h: usize, seed: u64) -> Vec<u8> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..w * h).map(|_| rng.random::<u8>()).collect()
    }

    #[test]
    fn fixed_point_remap_matches_opencv_rules_including_borders() {
        let (sw, sh) = (37, 23);
        let img = noise_image(sw, sh, 1);
        let src = GrayView::new(&img, sw, sh).unwrap();
        let (w, h) = (50, 40);
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut map = RectifyMap {
            width: w,
            height: h,
            map_x: (0..w * h).map(|_| rng.random_range(-3.0..40.0)).collect(),
            map_y: (0..w * h).map(|_| rng.random_range(-3.0..26.0)).collect(),
        };
        // Exact ties of the 1/32 quantisation, the sentinel and NaN.
        map.map_x[0] = 1.0 + 1.5 / 32.0;
        map.map_x[1] = 2.0 + 2.5 / 32.0;
        map.map_x[2] = INVALID_COORD;
        map.map_y[3] = f32::NAN;
        map.map_x[4] = (sw - 1) as f32;
        map.map_y[4] = (sh - 1) as f32;
        let table = RemapTable::new(&map, sw, sh).unwrap();
        let out = table.remap(&src).unwrap();
        for (i, &got) in out.iter().enumerate() {
            let (x, y) = (map.map_x[i], map.map_y[i]);
            let expect = if x.is_finite() && y.is_finite() {
                opencv_rule(&src, x, y)
            } else {
                0
            };
            assert_eq!(got, expect, "pixel {i} at ({x}, {y})");
        }
        let edges = table.edges.len();
        assert!(edges > 100, "the random map must exercise the border path");
    }

    #[test]
    fn portable_and_dispatched_kernels_agree() {
        // On an AVX2 machine `remap` runs the AVX2 build; check the portable build directly.
        let (sw, sh) = (300, 200);
        let img = noise_image(sw, sh, 5);
        let src = GrayView::new(&img, sw, sh).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let (w, h) = (123, 7); // not a multiple of the block size: exercises the remainder
        let map = RectifyMap {
            width: w,
            height: h,
            map_x: (0..w * h).map(|_| rng.random_range(0.0..298.9)).collect(),
            map_y: (0..w * h).map(|_| rng.random_range(0.0..198.9)).collect(),
        };
        let table = RemapTable::new(&map, sw, sh).unwrap();
        assert!(table.edges.is_empty());
        let fast = table.remap(&src).unwrap();
        let mut portable = vec![0u8; w * h];
        for r in 0..h {
            let row = r * w..(r + 1) * w;
            // SAFETY: the table was built for an `sw`×`sh` source, which `img` is.
            unsafe {
                remap_row_kernel(
                    &img,
                    sw,
                    &mut portable[row.clone()],
                    &table.offsets[row.clone()],
                    &table.fracs[row],
                )
            };
        }
        assert_eq!(fast, portable);
    }

    #[test]
    fn float_baseline_agrees_with_fixed_point() {
        let (sw, sh) = (64, 48);
        // Smooth image, interior positions: quantisation to 1/32 px moves a sample by at most
        // 1/64 px, well under a grey level here. (At the constant border the image jumps by up to
        // 255 per pixel, where the two legitimately differ by a few levels.)
        let img: Vec<u8> = (0..sw * sh)
            .map(|i| {
                let (x, y) = ((i % sw) as f64, (i / sw) as f64);
                (128.0 + 100.0 * (x * 0.15).sin() * (y * 0.11).cos()) as u8
            })
            .collect();
        let src = GrayView::new(&img, sw, sh).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (w, h) = (40, 30);
        let map = RectifyMap {
            width: w,
            height: h,
            map_x: (0..w * h).map(|_| rng.random_range(0.0..63.0)).collect(),
            map_y: (0..w * h).map(|_| rng.random_range(0.0..47.0)).collect(),
        };
        let a = remap_bilinear_f32(&src, &map).unwrap();
        let b = RemapTable::new(&map, sw, sh).unwrap().remap(&src).unwrap();
        let max = a
            .iter()
            .zip(&b)
            .map(|(&p, &q)| (p as i32 - q as i32).abs())
            .max()
            .unwrap();
        assert!(max <= 1, "max difference {max}");
    }

    #[test]
    fn identity_map_reproduces_the_image() {
        let (w, h) = (17, 9);
        let img = noise_image(w, h, 4);
        let src = GrayView::new(&img, w, h).unwrap();
        let map = RectifyMap {
            width: w,
            height: h,
            map_x: (0..w * h).map(|i| (i % w) as f32).collect(),
            map_y: (0..w * h).map(|i| (i / w) as f32).collect(),
        };
        assert_eq!(
            RemapTable::new(&map, w, h).unwrap().remap(&src).unwrap(),
            img
        );
        assert_eq!(remap_bilinear_f32(&src, &map).unwrap(), img);
    }

    #[test]
    fn bad_sizes_are_errors() {
        let img = vec![0u8; 12];
        assert!(GrayView::new(&img, 5, 3).is_err());
        let src = GrayView::new(&img, 4, 3).unwrap();
        let map = RectifyMap {
            width: 2,
            height: 2,
            map_x: vec![0.0; 4],
            map_y: vec![0.0; 3],
        };
        assert!(RemapTable::new(&map, 4, 3).is_err());
        let map = RectifyMap {
            map_y: vec![0.0; 4],
            ..map
        };
        let t = RemapTable::new(&map, 5, 3).unwrap();
        assert!(t.remap(&src).is_err());
        let cam = Mei::pinhole(4, 3, 1.0, 1.0, 1.0, 1.0);
        assert!(perspective_map(&cam, &Matrix3::zeros(), &Matrix3::identity(), 4, 3).is_err());
    }

    #[test]
    fn pinhole_to_pinhole_map_is_the_homography() {
        // ξ = 0 and no distortion: the map must be K·R·P⁻¹ applied to (u, v, 1).
        let cam = Mei::pinhole(640, 480, 500.0, 510.0, 320.0, 240.0);
        let p = Matrix3::new(300.0, 0.0, 100.0, 0.0, 300.0, 80.0, 0.0, 0.0, 1.0);
        let r = *nalgebra::Rotation3::from_euler_angles(0.05, -0.1, 0.2).matrix();
        let m = perspective_map(&cam, &p, &r, 200, 160).unwrap();
        let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0);
        let hmat = k * (p * r).try_inverse().unwrap();
        for (u, v) in [(0usize, 0usize), (199, 0), (57, 101), (199, 159)] {
            let q = hmat * Vector3::new(u as f64, v as f64, 1.0);
            let i = v * 200 + u;
            assert!((m.map_x[i] as f64 - q.x / q.z).abs() < 1e-3);
            assert!((m.map_y[i] as f64 - q.y / q.z).abs() < 1e-3);
        }
    }

    /// Ground texture: smooth pattern plus a few sharp-edged blocks, grey 20..235.
    fn texture(x: f64, y: f64) -> f64 {
        let smooth = 60.0 * (x * 0.9).sin() * (y * 0.7).cos() + 30.0 * ((x + y) * 0.35).sin();
        let block = if ((x * 0.25).floor() + (y * 0.25).floor()) as i64 % 2 == 0 {
            30.0
        } else {
            -30.0
        };
        (128.0 + smooth + block).clamp(20.0, 235.0)
    }

    /// Render what `cam` at `pose` sees of the textured ground z = a·x + b·y + c (exact ray–plane
    /// intersection per pixel, 4×4 supersampled to avoid aliasing).
    fn render(cam: &dyn CameraModel, pose: &CamFromMap, plane: (f64, f64, f64)) -> Vec<u8> {
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let map_from_cam = pose.inverse();
        let c = pose.center();
        let n = Vector3::new(-plane.0, -plane.1, 1.0);
        let mut img = vec![0u8; w * h];
        img.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, px) in row.iter_mut().enumerate() {
                let mut acc = 0.0;
                let mut cnt = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let q = Point2::new(
                            u as f64 - 0.375 + 0.25 * sx as f64,
                            v as f64 - 0.375 + 0.25 * sy as f64,
                        );
                        let Ok(b) = cam.unproject(&q) else { continue };
                        let d = map_from_cam.rotate(&b);
                        // (c + t·d)·n = plane.2  with n·(x, y, z) = z − a·x − b·y.
                        let t = (plane.2 - c.coords.dot(&n)) / d.dot(&n);
                        if t > 0.0 {
                            let g = c + d * t;
                            acc += texture(g.x, g.y);
                            cnt += 1.0;
                        }
                    }
                }
                if cnt > 0.0 {
                    *px = (acc / cnt).round() as u8;
                }
            }
        });
        img
    }

    fn check_ortho(cam: &dyn CameraModel, pose: &CamFromMap, plane: (f64, f64, f64), x0: f64) {
        let img = render(cam, pose, plane);
        let src = GrayView::new(&img, cam.width() as usize, cam.height() as usize).unwrap();
        // Height raster on a coarser grid, with NaN holes away from the exact plane values:
        // a plane is reproduced exactly by bilinear interpolation, holes by nearest fill.
        let y0 = 5_000_000.0;
        let hgrid = GeoGrid {
            crs: Crs::Epsg(32617),
            x0: x0 - 20.0,
            y0: y0 + 20.0,
            res: 0.5,
            width: 160,
            height: 160,
        };
        let mut height = Raster::filled(hgrid, 0f32, None);
        for r in 0..hgrid.height {
            for c in 0..hgrid.width {
                let (x, y) = hgrid.pixel_center(c, r);
                height.data[r * hgrid.width + c] = (plane.0 * x + plane.1 * y + plane.2) as f32;
            }
        }
        let out = GeoGrid {
            crs: Crs::Epsg(32617),
            x0: x0 - 15.0,
            y0: y0 + 15.0,
            res: 0.1,
            width: 300,
            height: 300,
        };
        let (gray, mask) = orthorectify(cam, pose, &height, &src, out).unwrap();
        let mut diffs = Vec::new();
        for r in 0..out.height {
            for c in 0..out.width {
                let i = r * out.width + c;
                if mask[i] == MASK_SEEN {
                    let (x, y) = out.pixel_center(c, r);
                    diffs.push((gray[i] as f64 - texture(x, y)).abs());
                } else {
                    assert_eq!(gray[i], 0);
                }
            }
        }
        assert!(
            diffs.len() > out.len() / 2,
            "only {} cells seen",
            diffs.len()
        );
        diffs.sort_by(f64::total_cmp);
        let median = diffs[diffs.len() / 2];
        let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
        let p99 = diffs[diffs.len() * 99 / 100];
        // Residuals come from resampling the camera image twice (render, ortho), largest on the
        // block edges; a wrong pose/height convention gives tens of grey levels everywhere.
        assert!(
            median < 2.0 && mean < 4.0 && p99 < 40.0,
            "{median} {mean} {p99}"
        );
    }

    #[test]
    fn orthorectify_recovers_ground_texture_mei() {
        // Tilted ground (2 % slope in x) at UTM-sized coordinates.
        let cam = Mei {
            width: 640,
            height: 480,
            fx: 300.0,
            fy: 300.0,
            cx: 320.0,
            cy: 240.0,
            skew: 0.3,
            xi: 1.0,
            k1: -0.1,
            k2: 0.01,
            p1: 1e-4,
            p2: -1e-4,
            fov_deg: Some(185.0),
        };
        let x0 = 500_000.0;
        let pose = CamFromMap::from_center_ypr(
            &Point3::new(x0 + 1.0, 5_000_000.0 - 2.0, 14.0),
            0.6,
            0.05,
            -0.03,
        );
        check_ortho(&cam, &pose, (0.02, 0.0, 3.0 - 0.02 * x0), x0);
    }

    #[test]
    fn orthorectify_recovers_ground_texture_equidistant_with_holes() {
        let cam = Equidistant {
            width: 600,
            height: 600,
            fx: 190.0,
            fy: 190.0,
            cx: 300.0,
            cy: 300.0,
            alpha: 0.0,
            k1: 0.01,
            k2: -0.002,
            k3: 0.0,
            k4: 0.0,
            fov_deg: Some(185.0),
            cache: Default::default(),
        };
        let x0 = 300_000.0;
        let pose =
            CamFromMap::from_center_ypr(&Point3::new(x0, 5_000_000.0, 12.0), -1.2, 0.0, 0.08);
        // Flat ground with NaN holes: nearest fill restores the exact height.
        check_ortho(&cam, &pose, (0.0, 0.0, 1.5), x0);
        let img = render(&cam, &pose, (0.0, 0.0, 1.5));
        let src = GrayView::new(&img, 600, 600).unwrap();
        let g = GeoGrid {
            crs: Crs::Local,
            x0: x0 - 10.0,
            y0: 5_000_010.0,
            res: 1.0,
            width: 20,
            height: 20,
        };
        let mut holes = Raster::filled(g, 1.5f32, Some(-9999.0));
        for i in (0..400).step_by(3) {
            holes.data[i] = if i % 2 == 0 { f32::NAN } else { -9999.0 };
        }
        let full = Raster::filled(g, 1.5f32, None);
        let out = GeoGrid {
            res: 0.2,
            width: 100,
            height: 100,
            ..g
        };
        let a = orthorectify(&cam, &pose, &holes, &src, out).unwrap();
        let b = orthorectify(&cam, &pose, &full, &src, out).unwrap();
        assert_eq!(a, b);
        let empty = Raster::filled(g, f32::NAN, None);
        assert!(orthorectify(&cam, &pose, &empty, &src, out).is_err());
    }
}
