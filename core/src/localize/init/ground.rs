//! Ground and image geometry shared by initialization ([`crate::localize::init`], [`crate::localize::init::coarse`]) and
//! its LiDAR-MI judge ([`crate::localize::init::verify`]): the LiDAR ground under a camera and the disc of it the
//! camera sees, the image scale of a nadir ray, and bilinear sampling of the frame and of its mip
//! pyramid. Kept apart so that neither of those imports the other for them.

use crate::camera::CameraModel;
use crate::map::Raster;
use nalgebra::Vector3;
use rayon::prelude::*;

/// A 2×2-box mip pyramid of a gray frame, so that resampling the fisheye onto coarse ground cells
/// averages the pixels a cell covers instead of aliasing (a nadir pixel of a pole camera covers
/// ~1–2 cm; ground cells here are 5–20 cm).
pub(crate) struct Mip {
    levels: Vec<(Vec<f32>, usize, usize)>,
}

/// Deepest pyramid level.
const MIP_LEVELS: usize = 6;

impl Mip {
    /// Build from a row-major gray image. Rows in parallel (a 5 MP frame is 20 MB of level 0):
    /// every value is computed as a serial loop would.
    pub(crate) fn new(img: &[u8], w: usize, h: usize) -> Self {
        let level0: Vec<f32> = img.par_iter().map(|&v| v as f32).collect();
        let mut levels = vec![(level0, w, h)];
        while levels.len() < MIP_LEVELS {
            let (prev, pw, ph) = &levels[levels.len() - 1];
            let (pw, nw, nh) = (*pw, pw / 2, ph / 2);
            if nw < 2 || nh < 2 {
                break;
            }
            let mut next = vec![0.0; nw * nh];
            next.par_chunks_mut(nw).enumerate().for_each(|(y, row)| {
                for (x, v) in row.iter_mut().enumerate() {
                    let i = 2 * y * pw + 2 * x;
                    *v = 0.25 * (prev[i] + prev[i + 1] + prev[i + pw] + prev[i + pw + 1]);
                }
            });
            levels.push((next, nw, nh));
        }
        Mip { levels }
    }

    /// Bilinear sample at level-0 pixel coordinates (u, v), at the level whose pixel is about
    /// `footprint` level-0 pixels wide.
    pub(crate) fn sample(&self, u: f64, v: f64, footprint: f64) -> Option<f32> {
        self.sample_level(self.level(footprint), u, v)
    }

    /// The level [`Mip::sample`] reads for `footprint`: a loop whose footprint is fixed asks
    /// once (a `log2` per sample otherwise) and samples with [`Mip::sample_level`].
    pub(crate) fn level(&self, footprint: f64) -> usize {
        (footprint.max(1.0).log2().floor() as usize).min(self.levels.len() - 1)
    }

    /// [`Mip::sample`] at level `l` (from [`Mip::level`]).
    #[inline(always)]
    pub(crate) fn sample_level(&self, l: usize, u: f64, v: f64) -> Option<f32> {
        // 2^−l: multiplying by it is exactly dividing by 2^l, without a division's latency.
        let inv_s = 1.0 / (1usize << l) as f64;
        let (data, w, h) = &self.levels[l];
        let (x, y) = ((u + 0.5) * inv_s - 0.5, (v + 0.5) * inv_s - 0.5);
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= *w || y0 + 1 >= *h {
            return None;
        }
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let i = y0 * w + x0;
        let top = data[i] * (1.0 - fx) + data[i + 1] * fx;
        let bot = data[i + w] * (1.0 - fx) + data[i + w + 1] * fx;
        Some(top * (1.0 - fy) + bot * fy)
    }
}

/// Bilinear height of the LiDAR height layer at (x, y); `None` on no-data.
pub fn height_at(hl: &Raster<f32>, x: f64, y: f64) -> Option<f64> {
    let (px, py) = hl.grid.to_pixel(x, y);
    if !(px >= 0.0 && py >= 0.0) {
        return None;
    }
    let (c0, r0) = (px as usize, py as usize);
    let (fx, fy) = (px - c0 as f64, py - r0 as f64);
    let mut acc = 0.0;
    for (dc, dr, w) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        let v = hl.get(c0 + dc, r0 + dr)?;
        if !v.is_finite() || hl.nodata.is_some_and(|nd| v == nd) {
            return None;
        }
        acc += w * v as f64;
    }
    Some(acc)
}

/// Assumed camera height above ground where the height layer has no data under the camera, m.
pub(crate) const FALLBACK_HEIGHT_M: f64 = 8.0;

/// The camera centre `c`'s height above the LiDAR ground under it (at least 1 m;
/// [`FALLBACK_HEIGHT_M`] on no-data) and the radius of the ground disc it sees within
/// `max_off_nadir_deg` of nadir, capped at `max_radius_m`.
pub fn ground_disc(
    heights: &Raster<f32>,
    c: &nalgebra::Point3<f64>,
    max_off_nadir_deg: f64,
    max_radius_m: f64,
) -> (f64, f64) {
    let ground = height_at(heights, c.x, c.y).unwrap_or(c.z - FALLBACK_HEIGHT_M);
    let cam_h = (c.z - ground).max(1.0);
    (
        cam_h,
        (cam_h * max_off_nadir_deg.to_radians().tan()).min(max_radius_m),
    )
}

/// Focal length near the optical axis in pixels (the image scale of a nadir ray), from the model.
pub(crate) fn focal_px(cam: &dyn CameraModel) -> f64 {
    const D: f64 = 1e-3;
    match (
        cam.project(&Vector3::new(0.0, 0.0, 1.0)),
        cam.project(&Vector3::new(D, 0.0, 1.0)),
    ) {
        (Ok(a), Ok(b)) => (b - a).norm() / D,
        _ => cam.width() as f64 / 2.0,
    }
}
