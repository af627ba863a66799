//! Pixel → map: where a pixel's ray meets the ground, with the pose's uncertainty carried to it.
//! Pure computation, no I/O: the camera, the pose (with its covariance) and the height layer come
//! in as values; `infraloc georef`, the service's `georef` request and its lookup table are shells
//! over [`georef`] / [`georef_batch`] (docs/georef.md).
//!
//! The ground is either the tile's LiDAR height layer — the bilinear surface through its cell
//! centres — or a horizontal plane. On the height layer the ray is walked from where it descends
//! below the layer's highest height, first over blocks of [`BLOCK`] × [`BLOCK`] bilinear patches
//! (a block is skipped while the ray stays above its highest height), then patch by patch. Along
//! a straight line a bilinear patch is a quadratic in the ray parameter, so the crossing inside a
//! patch is the smallest root of that quadratic in the patch: exact up to rounding (far below a
//! millimetre), with no step size to tune.
//!
//! The covariance is first-order: the Jacobian of the ground point with respect to the pose's
//! parameters (camera centre x, y, z in metres; yaw, pitch, roll in degrees, exactly the
//! parametrisation of [`CamFromMap::from_center_ypr`] that the pose file's
//! `quality.covariance` uses), by the implicit function theorem on the ray–surface equation,
//! including the surface's slope at the hit. An optional isotropic pixel noise `σ_px` adds the
//! Jacobian with respect to the pixel (the bearing's derivative by central differences of the
//! unprojection).

use crate::camera::CameraModel;
use crate::map::{Crs, GeoGrid, Raster};
use crate::pose::CamFromMap;
use nalgebra::{Matrix3, Point2, Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Side of the blocks of bilinear patches whose height range lets a ray skip them, in patches.
pub const BLOCK: usize = 8;

/// Default largest angle of a ray from nadir, degrees: beyond it a ray is [`Status::Grazing`].
/// At 85° the ground point moves by 1/cos²(85°) ≈ 130 times the ray's angular error per metre of
/// camera height, so a 0.01° pose error is already ~1.5 cm per metre of pole.
pub const DEFAULT_MAX_OFF_NADIR_DEG: f64 = 85.0;

/// Why a pixel has (or has no) map point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// The ray meets the ground: the point and its covariance are valid.
    Ok,
    /// The pixel is outside the sensor.
    OutsideImage,
    /// The pixel is on the sensor but outside the lens's image circle (or the model's invertible
    /// range).
    OutsideCircle,
    /// The ray does not descend (at or above the horizon).
    AboveHorizon,
    /// The ray descends more than the largest off-nadir angle from the vertical.
    Grazing,
    /// The ray leaves the height layer, or crosses cells without height, before meeting the
    /// ground.
    NoHeight,
    /// The pixel is not finite.
    NonFinite,
}

impl Status {
    /// The status as written in CSV/JSON (`ok`, `outside_image`, …).
    pub fn name(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::OutsideImage => "outside_image",
            Status::OutsideCircle => "outside_circle",
            Status::AboveHorizon => "above_horizon",
            Status::Grazing => "grazing",
            Status::NoHeight => "no_height",
            Status::NonFinite => "non_finite",
        }
    }

    /// Every status, in the order docs/georef.md lists them.
    pub const ALL: [Status; 7] = [
        Status::Ok,
        Status::OutsideImage,
        Status::OutsideCircle,
        Status::AboveHorizon,
        Status::Grazing,
        Status::NoHeight,
        Status::NonFinite,
    ];

    /// The status of a [`Status::name`], `None` for any other text.
    pub fn from_name(name: &str) -> Option<Status> {
        Status::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// The pose's covariance over the axes of the pose file's `quality.covariance`: camera centre
/// x, y, z (map frame, m), yaw (deg), and pitch, roll (deg) when estimated. Axes it does not
/// cover (pitch and roll of a 4-axis estimate) count as exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCovariance {
    /// Covariance over x, y, z, yaw, pitch, roll (m², m·deg, deg²); zero rows and columns for
    /// axes not covered.
    pub matrix: [[f64; 6]; 6],
}

/// Why axes and a matrix are not a pose covariance ([`PoseCovariance::from_axes`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CovarianceError {
    /// A covariance matrix whose shape does not match its axes.
    #[error("covariance matrix is not {n}×{n} (its axes: {axes:?})")]
    Shape {
        /// The number of axes.
        n: usize,
        /// The axes.
        axes: Vec<String>,
    },
    /// A covariance axis that is not a pose axis.
    #[error("covariance axis {axis:?} is not one of {:?}", POSE_AXES)]
    Axis {
        /// The axis as given.
        axis: String,
    },
    /// A covariance axis named twice.
    #[error("covariance axis {axis:?} appears twice")]
    AxisTwice {
        /// The axis.
        axis: String,
    },
    /// A covariance entry that is not finite.
    #[error("covariance entry ({row}, {col}) is not finite")]
    Entry {
        /// Its row's axis.
        row: String,
        /// Its column's axis.
        col: String,
    },
}

/// The pose covariance's axis names, in [`PoseCovariance::matrix`] order.
pub const POSE_AXES: [&str; 6] = ["x", "y", "z", "yaw", "pitch", "roll"];

impl PoseCovariance {
    /// From axis names and a square row-major matrix over them (the pose file's
    /// `quality.covariance.axes` and `.matrix`). Every axis must be one of [`POSE_AXES`], named
    /// once, and every entry finite; the matrix is symmetrised.
    pub fn from_axes(axes: &[String], matrix: &[Vec<f64>]) -> Result<Self, CovarianceError> {
        let n = axes.len();
        if matrix.len() != n || matrix.iter().any(|r| r.len() != n) {
            return Err(CovarianceError::Shape {
                n,
                axes: axes.to_vec(),
            });
        }
        let mut idx = Vec::with_capacity(n);
        for a in axes {
            let i = POSE_AXES
                .iter()
                .position(|p| p == a)
                .ok_or_else(|| CovarianceError::Axis { axis: a.clone() })?;
            if idx.contains(&i) {
                return Err(CovarianceError::AxisTwice { axis: a.clone() });
            }
            idx.push(i);
        }
        let mut m = [[0.0; 6]; 6];
        for (r, &i) in idx.iter().enumerate() {
            for (c, &j) in idx.iter().enumerate() {
                let v = 0.5 * (matrix[r][c] + matrix[c][r]);
                if !v.is_finite() {
                    return Err(CovarianceError::Entry {
                        row: axes[r].clone(),
                        col: axes[c].clone(),
                    });
                }
                m[i][j] = v;
            }
        }
        Ok(PoseCovariance { matrix: m })
    }

    /// A diagonal covariance from σ per axis (m, deg; x, y, z, yaw, pitch, roll).
    pub fn from_sigma(sigma: [f64; 6]) -> Self {
        let mut m = [[0.0; 6]; 6];
        for (i, s) in sigma.iter().enumerate() {
            m[i][i] = s * s;
        }
        PoseCovariance { matrix: m }
    }
}

/// The pose a pixel is georeferenced through, with its covariance (`None`: taken as exact).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseWithCovariance {
    /// World(map) → camera.
    pub pose: CamFromMap,
    /// The pose's covariance.
    pub covariance: Option<PoseCovariance>,
}

/// Settings of a georeferencing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    /// Largest angle of a ray from nadir, degrees ([`DEFAULT_MAX_OFF_NADIR_DEG`]).
    pub max_off_nadir_deg: f64,
    /// Isotropic pixel noise σ (px) added to the covariance (0: none).
    pub sigma_px: f64,
    /// Also compute WGS84 latitude and longitude (EPSG tiles only).
    pub wgs84: bool,
    /// σ of the surface's height (m), propagated along the ray into the covariance. `None`: the
    /// height layer's own noise ([`HeightSurface::noise_sigma_m`]); 0 for [`Surface::Plane`].
    pub height_sigma_m: Option<f64>,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            max_off_nadir_deg: DEFAULT_MAX_OFF_NADIR_DEG,
            sigma_px: 0.0,
            wgs84: true,
            height_sigma_m: None,
        }
    }
}

/// σ (m) of the Gaussian a height layer is smoothed with before rays meet it (see
/// [`HeightIndex::with_smoothing`]).
pub const DEFAULT_SMOOTHING_M: f64 = 0.15;

/// Largest smoothing σ accepted (m): beyond it a kerb or a ramp's start is no longer where the
/// layer puts it.
pub const MAX_SMOOTHING_M: f64 = 1.0;

/// What ray walking needs: the surface's samples (the layer smoothed, see
/// [`HeightIndex::with_smoothing`]), the highest and lowest height of the surface and of each
/// block of [`BLOCK`] × [`BLOCK`] bilinear patches, and the layer's noise. Built once per layer;
/// owned, so a service keeps it beside the layer it was built from and serves every request
/// without rebuilding it.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightIndex {
    /// The surface's samples on the layer's grid (NaN: no height).
    heights: Vec<f32>,
    /// σ of the smoothing (m; 0: the layer's own samples).
    smoothing_m: f64,
    /// Sum of the squared weights one smoothed sample gives the layer's samples (1 unsmoothed):
    /// the factor on the layer's noise variance.
    smoothing_weights_sq: f64,
    /// Highest valid height of each block (row-major over blocks); a block with no valid height
    /// gets the layer's highest, so a ray never skips it.
    block_max: Vec<f32>,
    blocks_w: usize,
    /// Lowest and highest valid height of the layer.
    h_min: f64,
    h_max: f64,
    /// The layer's per-sample height noise σ (m), see [`HeightSurface::noise_sigma_m`].
    noise_sigma: f64,
    /// The grid the index was built on (a check that it is used with its own layer).
    grid: GeoGrid,
}

impl HeightIndex {
    /// σ (m) of the smoothing the surface's samples had (0: none).
    pub fn smoothing_m(&self) -> f64 {
        self.smoothing_m
    }

    /// Index `raster` (NaN and its no-data value are cells without height) smoothed by
    /// [`DEFAULT_SMOOTHING_M`]. `None` when the layer has fewer than 2 × 2 cells or no valid
    /// height at all.
    pub fn new(raster: &Raster<f32>) -> Option<Self> {
        Self::with_smoothing(raster, DEFAULT_SMOOTHING_M)
    }

    /// Index `raster` smoothed by a Gaussian of σ `smoothing_m` (metres; 0: the layer's own
    /// samples, bilinear), normalised over the valid cells (a cell without height stays without).
    ///
    /// Why smooth: a LiDAR height layer is the road plus each cell's noise. Far from nadir a height
    /// error δh moves the point by δh·tan θ along the ground (× 5.7 at 80°), and the first
    /// crossing of a noisy surface leans upwards (the ray meets the first bump that reaches it).
    /// Smoothing estimates the road instead of interpolating its noise: the default σ of 0.15 m
    /// on a 0.1 m layer keeps about a fifth of the noise's σ; a camber or a ramp, smooth over the
    /// kernel, is kept, and a kerb's step spreads over ±2σ of the kernel.
    /// `None` also when `smoothing_m` is not in [0, [`MAX_SMOOTHING_M`]].
    pub fn with_smoothing(raster: &Raster<f32>, smoothing_m: f64) -> Option<Self> {
        let g = raster.grid;
        if g.width < 2 || g.height < 2 || raster.data.len() != g.len() {
            return None;
        }
        if !(0.0..=MAX_SMOOTHING_M).contains(&smoothing_m) {
            return None;
        }
        let valid = |v: f32| v.is_finite() && raster.nodata != Some(v);
        let (heights, smoothing_weights_sq) = smoothed(raster, smoothing_m / g.res);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &v in &heights {
            if valid(v) {
                lo = lo.min(v as f64);
                hi = hi.max(v as f64);
            }
        }
        if !(lo <= hi) {
            return None;
        }
        // Patches: (width − 1) × (height − 1); block (bi, bj) holds patches bi·B .. (bi+1)·B,
        // i.e. the samples bi·B ..= (bi+1)·B (clamped).
        let (pw, ph) = (g.width - 1, g.height - 1);
        let (bw, bh) = (pw.div_ceil(BLOCK), ph.div_ceil(BLOCK));
        let mut block_max = vec![f32::NEG_INFINITY; bw * bh];
        for bj in 0..bh {
            for bi in 0..bw {
                let (c0, c1) = (bi * BLOCK, ((bi + 1) * BLOCK).min(pw));
                let (r0, r1) = (bj * BLOCK, ((bj + 1) * BLOCK).min(ph));
                let k = bj * bw + bi;
                for r in r0..=r1 {
                    for &v in &heights[r * g.width + c0..=r * g.width + c1] {
                        if valid(v) {
                            block_max[k] = block_max[k].max(v);
                        }
                    }
                }
                if block_max[k] == f32::NEG_INFINITY {
                    block_max[k] = hi as f32;
                }
            }
        }
        Some(HeightIndex {
            heights,
            smoothing_m,
            smoothing_weights_sq,
            block_max,
            blocks_w: bw,
            h_min: lo,
            h_max: hi,
            noise_sigma: noise_sigma(raster),
            grid: g,
        })
    }
}

/// A height layer prepared for ray walking: the layer and its [`HeightIndex`] (owned, or
/// borrowed from whoever keeps it). Read-only, so threads share it.
#[derive(Debug, Clone)]
pub struct HeightSurface<'a> {
    raster: &'a Raster<f32>,
    index: std::borrow::Cow<'a, HeightIndex>,
}

impl std::ops::Deref for HeightSurface<'_> {
    type Target = HeightIndex;
    fn deref(&self) -> &HeightIndex {
        &self.index
    }
}

impl<'a> HeightSurface<'a> {
    /// Prepare `raster` (NaN and its no-data value are cells without height). `None` when the
    /// layer has fewer than 2 × 2 cells or no valid height at all.
    pub fn new(raster: &'a Raster<f32>) -> Option<Self> {
        Some(HeightSurface {
            raster,
            index: std::borrow::Cow::Owned(HeightIndex::new(raster)?),
        })
    }

    /// Prepare `raster` smoothed by σ `smoothing_m` (see [`HeightIndex::with_smoothing`]).
    pub fn with_smoothing(raster: &'a Raster<f32>, smoothing_m: f64) -> Option<Self> {
        Some(HeightSurface {
            raster,
            index: std::borrow::Cow::Owned(HeightIndex::with_smoothing(raster, smoothing_m)?),
        })
    }

    /// `raster` with the index built from it earlier; `None` when `index` was built on another
    /// grid.
    pub fn with_index(raster: &'a Raster<f32>, index: &'a HeightIndex) -> Option<Self> {
        (index.grid == raster.grid && raster.data.len() == raster.grid.len()).then_some(
            HeightSurface {
                raster,
                index: std::borrow::Cow::Borrowed(index),
            },
        )
    }

    /// The layer's per-sample height noise σ (m), estimated from the layer itself: the robust
    /// spread (1.4826 × the median absolute deviation) of its second differences along rows and
    /// columns, over √6. For independent noise of σ on a surface whose curvature is small over
    /// three samples, a second difference h₋ − 2h₀ + h₊ has the spread √6·σ; kerbs and walls are
    /// a minority of the differences and move the median little. 0 when the layer has fewer than
    /// 16 such triples.
    pub fn noise_sigma_m(&self) -> f64 {
        self.noise_sigma
    }

    /// The layer this surface was prepared from.
    pub fn raster(&self) -> &Raster<f32> {
        self.raster
    }

    /// The sample at (col, row) if it is a valid height.
    #[inline]
    fn sample(&self, col: usize, row: usize) -> Option<f64> {
        let v = self.index.heights[row * self.raster.grid.width + col];
        v.is_finite().then_some(v as f64)
    }

    /// Where the ray `c + t·d` (map frame, `d` unit and descending) first meets the surface, with
    /// the surface's slope there; `None` when it leaves the layer or crosses a cell without height
    /// first.
    fn intersect(&self, c: &Point3<f64>, d: &Vector3<f64>) -> Option<RayHit> {
        let g = self.raster.grid;
        // Continuous sample coordinates: sample centres at integers.
        let (pc, pr) = g.to_pixel(c.x, c.y);
        let (dc, dr) = (d.x / g.res, -d.y / g.res);
        // The stretch of the ray between the layer's highest and lowest height.
        let slack = 1e-6;
        let ta = ((self.h_max + slack - c.z) / d.z).max(0.0);
        let tb = (self.h_min - slack - c.z) / d.z;
        if !(tb >= ta) {
            // The camera is below the lowest ground: no crossing from above.
            return None;
        }
        // Clip to the patch domain [0, W−1] × [0, H−1].
        let (w1, h1) = ((g.width - 1) as f64, (g.height - 1) as f64);
        let (ta, tb) =
            clip_1d(pc, dc, 0.0, w1, ta, tb).and_then(|(a, b)| clip_1d(pr, dr, 0.0, h1, a, b))?;
        let bsize = BLOCK as f64;
        let (pw, ph) = (g.width - 1, g.height - 1);
        let (bw, bh) = (self.blocks_w, ph.div_ceil(BLOCK));
        walk_cells(
            (pc / bsize, pr / bsize),
            (dc / bsize, dr / bsize),
            ta,
            tb,
            (bw, bh),
            |bi, bj, t0, t1| {
                let k = bj * bw + bi;
                // Lowest point of the ray in the block is where it leaves it.
                if c.z + t1 * d.z > self.block_max[k] as f64 + slack {
                    return Walk::Next;
                }
                let top = self.block_max[k] as f64;
                let found = walk_cells((pc, pr), (dc, dr), t0, t1, (pw, ph), |i, j, s0, s1| {
                    self.patch_hit(c, d, (pc, pr), (dc, dr), (i, j), (s0, s1), top)
                });
                match found {
                    Some(r) => Walk::Stop(r),
                    None => Walk::Next,
                }
            },
        )
        .flatten()
    }

    /// The ray's first crossing of patch (i, j) between `t0` and `t1`; [`Walk::Stop`]`(None)` when
    /// the patch has a corner without height and the ray leaves it below `top`, the highest
    /// height of the patch's block.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn patch_hit(
        &self,
        c: &Point3<f64>,
        d: &Vector3<f64>,
        p: (f64, f64),
        dp: (f64, f64),
        (i, j): (usize, usize),
        (t0, t1): (f64, f64),
        top: f64,
    ) -> Walk<Option<RayHit>> {
        let corners = [
            self.sample(i, j),
            self.sample(i + 1, j),
            self.sample(i, j + 1),
            self.sample(i + 1, j + 1),
        ];
        let [Some(h00), Some(h10), Some(h01), Some(h11)] = corners else {
            // Unknown ground under this stretch of the ray: a ray that stays above the block's
            // highest height passes, any other has no height to meet.
            return if c.z + t1 * d.z > top {
                Walk::Next
            } else {
                Walk::Stop(None)
            };
        };
        if c.z + t1 * d.z > h00.max(h10).max(h01).max(h11) {
            return Walk::Next;
        }
        // Patch-local coordinates at t0, s = t − t0.
        let (u0, v0) = (p.0 + t0 * dp.0 - i as f64, p.1 + t0 * dp.1 - j as f64);
        let (a, b, cc, e) = (h00, h10 - h00, h01 - h00, h00 - h10 - h01 + h11);
        let hgt = a + b * u0 + cc * v0 + e * u0 * v0;
        let h1 = b * dp.0 + cc * dp.1 + e * (u0 * dp.1 + v0 * dp.0);
        let h2 = e * dp.0 * dp.1;
        // f(s) = ray z − surface = f0 + f1·s + f2·s².
        let f0 = c.z + t0 * d.z - hgt;
        let (f1, f2) = (d.z - h1, -h2);
        let len = t1 - t0;
        let s = if f0 <= 0.0 {
            Some(0.0)
        } else {
            smallest_root_in(f0, f1, f2, len)
        };
        match s {
            None => Walk::Next,
            Some(s) => {
                let (u, v) = (
                    (u0 + s * dp.0).clamp(0.0, 1.0),
                    (v0 + s * dp.1).clamp(0.0, 1.0),
                );
                // Slope of the bilinear patch in map units (rows run south).
                let dhdu = b + e * v;
                let dhdv = cc + e * u;
                let res = self.raster.grid.res;
                Walk::Stop(Some(RayHit {
                    t: t0 + s,
                    slope: (dhdu / res, -dhdv / res),
                    weights_sq: if self.smoothing_m > 0.0 {
                        // Neighbouring smoothed samples share most of their weights: the
                        // kernel's own sum is the (slightly high) variance factor.
                        self.smoothing_weights_sq
                    } else {
                        ((1.0 - u).powi(2) + u * u) * ((1.0 - v).powi(2) + v * v)
                    },
                }))
            }
        }
    }
}

/// A ray's crossing of the ground surface.
#[derive(Debug, Clone, Copy)]
struct RayHit {
    /// Distance along the unit ray (m).
    t: f64,
    /// The surface's slope at the hit, (∂h/∂x, ∂h/∂y).
    slope: (f64, f64),
    /// Sum of the squared interpolation weights of the heights the hit's height is made of (1 for
    /// a plane): the hit's height variance is σ_h² times this for independent sample noise.
    weights_sq: f64,
}

/// `raster`'s heights smoothed by a Gaussian of σ `sigma_cells`, normalised over the valid cells
/// (separable: rows, then columns, on the weighted heights and on the weights), NaN where the
/// layer has no height; and the sum of the kernel's squared normalised weights. `sigma_cells` 0
/// (or under 0.05 cells) returns the valid samples as they are.
fn smoothed(raster: &Raster<f32>, sigma_cells: f64) -> (Vec<f32>, f64) {
    let g = raster.grid;
    let valid = |v: f32| v.is_finite() && raster.nodata != Some(v);
    let raw: Vec<f32> = raster
        .data
        .iter()
        .map(|&v| if valid(v) { v } else { f32::NAN })
        .collect();
    if sigma_cells < 0.05 {
        return (raw, 1.0);
    }
    let radius = (3.0 * sigma_cells).ceil() as usize;
    let kernel: Vec<f64> = (0..=2 * radius)
        .map(|k| {
            let d = k as f64 - radius as f64;
            (-0.5 * d * d / (sigma_cells * sigma_cells)).exp()
        })
        .collect();
    let total: f64 = kernel.iter().sum();
    let sq_1d: f64 = kernel.iter().map(|w| (w / total).powi(2)).sum();
    // Heights relative to a reference, so f64 sums of large map heights keep their millimetres.
    let reference = raw
        .iter()
        .find(|v| v.is_finite())
        .map_or(0.0, |&v| v as f64);
    let (w, h) = (g.width, g.height);
    let mut num = vec![0.0f64; w * h];
    let mut den = vec![0.0f64; w * h];
    // Rows.
    num.par_chunks_mut(w)
        .zip(den.par_chunks_mut(w))
        .enumerate()
        .for_each(|(r, (nr, dr))| {
            let row = &raw[r * w..(r + 1) * w];
            for c in 0..w {
                let (lo, hi) = (c.saturating_sub(radius), (c + radius).min(w - 1));
                let (mut n, mut d) = (0.0, 0.0);
                for (k, &v) in row[lo..=hi].iter().enumerate() {
                    if v.is_finite() {
                        let wk = kernel[lo + k + radius - c];
                        n += wk * (v as f64 - reference);
                        d += wk;
                    }
                }
                nr[c] = n;
                dr[c] = d;
            }
        });
    // Columns.
    let out: Vec<f32> = (0..w * h)
        .into_par_iter()
        .with_min_len(1024)
        .map(|k| {
            let (c, r) = (k % w, k / w);
            if !raw[k].is_finite() {
                return f32::NAN;
            }
            let (lo, hi) = (r.saturating_sub(radius), (r + radius).min(h - 1));
            let (mut n, mut d) = (0.0, 0.0);
            for rr in lo..=hi {
                let wk = kernel[rr + radius - r];
                n += wk * num[rr * w + c];
                d += wk * den[rr * w + c];
            }
            (reference + n / d) as f32
        })
        .collect();
    (out, sq_1d * sq_1d)
}

/// The robust noise σ of a height layer (see [`HeightSurface::noise_sigma_m`]). At most about
/// 2¹⁶ triples are used, taken on a regular stride, so the cost does not grow with the tile.
fn noise_sigma(raster: &Raster<f32>) -> f64 {
    let g = raster.grid;
    let valid = |v: f32| v.is_finite() && raster.nodata != Some(v);
    let at = |c: usize, r: usize| {
        let v = raster.data[r * g.width + c];
        valid(v).then_some(v as f64)
    };
    // A stride prime to the width, so the samples do not fall on the same few columns.
    let mut stride = (g.len() / 32_768).max(1);
    while stride > 1 && gcd(stride, g.width) != 1 {
        stride += 1;
    }
    let mut second = Vec::with_capacity(2 * (g.len() / stride + 1));
    let mut k = 0;
    while k < g.len() {
        let (c, r) = (k % g.width, k / g.width);
        if c >= 1 && c + 1 < g.width {
            if let (Some(a), Some(b), Some(e)) = (at(c - 1, r), at(c, r), at(c + 1, r)) {
                second.push(a - 2.0 * b + e);
            }
        }
        if r >= 1 && r + 1 < g.height {
            if let (Some(a), Some(b), Some(e)) = (at(c, r - 1), at(c, r), at(c, r + 1)) {
                second.push(a - 2.0 * b + e);
            }
        }
        k += stride;
    }
    if second.len() < 16 {
        return 0.0;
    }
    let median = |xs: &mut Vec<f64>| {
        let m = xs.len() / 2;
        *xs.select_nth_unstable_by(m, f64::total_cmp).1
    };
    let mid = median(&mut second);
    let mut dev: Vec<f64> = second.iter().map(|x| (x - mid).abs()).collect();
    1.4826 * median(&mut dev) / 6f64.sqrt()
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// Smallest root in `[0, len]` of `f0 + f1·s + f2·s²` with `f0 > 0`, if any.
#[inline]
fn smallest_root_in(f0: f64, f1: f64, f2: f64, len: f64) -> Option<f64> {
    let tol = 1e-12 * (1.0 + len);
    let in_range = |s: f64| (s >= -tol && s <= len + tol).then(|| s.clamp(0.0, len));
    if f2.abs() <= 1e-12 * f1.abs().max(1e-300) {
        return in_range(-f0 / f1);
    }
    let disc = f1 * f1 - 4.0 * f2 * f0;
    if disc < 0.0 {
        return None;
    }
    // Numerically stable pair of roots.
    let q = -0.5 * (f1 + f1.signum() * disc.sqrt());
    let (r1, r2) = (q / f2, if q != 0.0 { f0 / q } else { f64::NAN });
    let (lo, hi) = if r1 <= r2 { (r1, r2) } else { (r2, r1) };
    in_range(lo).or_else(|| in_range(hi))
}

/// The part `[a, b]` of `[ta, tb]` where `p + t·dp` lies in `[lo, hi]`; `None` if empty.
fn clip_1d(p: f64, dp: f64, lo: f64, hi: f64, ta: f64, tb: f64) -> Option<(f64, f64)> {
    let (mut a, mut b) = (ta, tb);
    if dp == 0.0 {
        if p < lo || p > hi {
            return None;
        }
    } else {
        let (t_lo, t_hi) = ((lo - p) / dp, (hi - p) / dp);
        let (t0, t1) = if t_lo <= t_hi {
            (t_lo, t_hi)
        } else {
            (t_hi, t_lo)
        };
        a = a.max(t0);
        b = b.min(t1);
    }
    (a <= b).then_some((a, b))
}

/// What a cell visitor of [`walk_cells`] asks for.
enum Walk<R> {
    Next,
    Stop(R),
}

/// Visit the unit cells `(i, j)` of an `n.0 × n.1` grid that the line `p + t·dp` crosses for `t`
/// in `[ta, tb]`, in order, with the stretch `(t0, t1)` inside each (a 2-D DDA); the first
/// [`Walk::Stop`] ends the walk. The line is assumed clipped to the grid.
#[inline]
fn walk_cells<R>(
    p: (f64, f64),
    dp: (f64, f64),
    ta: f64,
    tb: f64,
    n: (usize, usize),
    mut visit: impl FnMut(usize, usize, f64, f64) -> Walk<R>,
) -> Option<R> {
    if n.0 == 0 || n.1 == 0 {
        return None;
    }
    // The cell of the stretch's start, nudged along the ray so that a start on a cell edge picks
    // the cell the ray enters.
    let tm = ta + 1e-9 * (1.0 + (tb - ta));
    let start =
        |x: f64, dx: f64, n: usize| ((x + tm.min(tb) * dx).floor().max(0.0) as usize).min(n - 1);
    let (mut i, mut j) = (start(p.0, dp.0, n.0), start(p.1, dp.1, n.1));
    let axis = |x: f64, dx: f64, k: usize| -> (f64, f64, isize) {
        if dx > 0.0 {
            (((k + 1) as f64 - x) / dx, 1.0 / dx, 1)
        } else if dx < 0.0 {
            ((k as f64 - x) / dx, -1.0 / dx, -1)
        } else {
            (f64::INFINITY, f64::INFINITY, 0)
        }
    };
    let (mut next_i, step_ti, di) = axis(p.0, dp.0, i);
    let (mut next_j, step_tj, dj) = axis(p.1, dp.1, j);
    let mut t0 = ta;
    loop {
        let t1 = next_i.min(next_j).min(tb);
        if let Walk::Stop(r) = visit(i, j, t0, t1.max(t0)) {
            return Some(r);
        }
        if t1 >= tb {
            return None;
        }
        t0 = t1;
        if next_i <= next_j {
            let ni = i as isize + di;
            if ni < 0 || ni as usize >= n.0 {
                return None;
            }
            i = ni as usize;
            next_i += step_ti;
        } else {
            let nj = j as isize + dj;
            if nj < 0 || nj as usize >= n.1 {
                return None;
            }
            j = nj as usize;
            next_j += step_tj;
        }
    }
}

/// The ground a pixel's ray is intersected with.
#[derive(Debug, Clone)]
pub enum Surface<'a> {
    /// The tile's LiDAR height layer, bilinear.
    Heights(HeightSurface<'a>),
    /// A horizontal plane at this height (map frame, m).
    Plane(f64),
}

impl Surface<'_> {
    /// The ray's first crossing (see [`HeightSurface::intersect`]).
    fn intersect(&self, c: &Point3<f64>, d: &Vector3<f64>) -> Option<RayHit> {
        match self {
            Surface::Heights(s) => s.intersect(c, d),
            Surface::Plane(h) => {
                let t = (h - c.z) / d.z;
                (t.is_finite() && t >= 0.0).then_some(RayHit {
                    t,
                    slope: (0.0, 0.0),
                    weights_sq: 1.0,
                })
            }
        }
    }

    /// The height σ (m) a georeference on this surface carries with `params`: the given one, or
    /// the layer's own estimate (0 for a plane).
    pub fn height_sigma_m(&self, params: &Params) -> f64 {
        match (params.height_sigma_m, self) {
            (Some(s), _) => s,
            (None, Surface::Heights(h)) => h.noise_sigma,
            (None, Surface::Plane(_)) => 0.0,
        }
    }
}

/// The ground-plane error ellipse of a covariance: σ along its major and minor axes (m) and the
/// major axis's direction, degrees counter-clockwise from map east (x), in (−90°, 90°].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Ellipse {
    /// σ along the major axis, m.
    pub sigma_major_m: f64,
    /// σ along the minor axis, m.
    pub sigma_minor_m: f64,
    /// Direction of the major axis, degrees counter-clockwise from east.
    pub angle_deg: f64,
}

impl Ellipse {
    /// The 1σ ellipse of the horizontal (E, N) block of `cov`.
    pub fn of(cov: &[[f64; 3]; 3]) -> Self {
        let (a, b, c) = (cov[0][0], cov[0][1], cov[1][1]);
        let mean = 0.5 * (a + c);
        let r = (0.25 * (a - c) * (a - c) + b * b).sqrt();
        let (l1, l2) = (mean + r, (mean - r).max(0.0));
        let mut angle = 0.5 * (2.0 * b).atan2(a - c);
        if angle <= -std::f64::consts::FRAC_PI_2 {
            angle += std::f64::consts::PI;
        }
        Ellipse {
            sigma_major_m: l1.max(0.0).sqrt(),
            sigma_minor_m: l2.sqrt(),
            angle_deg: angle.to_degrees(),
        }
    }

    /// Mahalanobis distance of a horizontal offset (dE, dN) under the horizontal block of `cov`
    /// (∞ when the block is singular and the offset leaves its range).
    pub fn mahalanobis(cov: &[[f64; 3]; 3], de: f64, dn: f64) -> f64 {
        let (a, b, c) = (cov[0][0], cov[0][1], cov[1][1]);
        let det = a * c - b * b;
        if !(det > 0.0) {
            return f64::INFINITY;
        }
        ((c * de * de - 2.0 * b * de * dn + a * dn * dn) / det)
            .max(0.0)
            .sqrt()
    }
}

/// One pixel's map point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Whether (and why not) the point is valid; the other fields are NaN unless [`Status::Ok`].
    pub status: Status,
    /// Easting, northing, height in the tile's CRS (m).
    pub enh: [f64; 3],
    /// WGS84 latitude and longitude (degrees) when asked for and the CRS is an EPSG one.
    pub lat_lon: Option<[f64; 2]>,
    /// Covariance of (E, N, h), m².
    pub covariance: [[f64; 3]; 3],
    /// Distance along the ray from the camera centre, m.
    pub range_m: f64,
    /// Angle of the ray from nadir, degrees.
    pub off_nadir_deg: f64,
}

impl MapPoint {
    /// A pixel without a map point: `status`, every number NaN.
    pub fn invalid(status: Status) -> Self {
        MapPoint {
            status,
            enh: [f64::NAN; 3],
            lat_lon: None,
            covariance: [[f64::NAN; 3]; 3],
            range_m: f64::NAN,
            off_nadir_deg: f64::NAN,
        }
    }

    /// The ground-plane error ellipse of [`MapPoint::covariance`].
    pub fn ellipse(&self) -> Ellipse {
        Ellipse::of(&self.covariance)
    }
}

/// The map point of pixel (u, v) (OpenCV convention, the top-left pixel's centre at (0, 0)).
pub fn georef(
    camera: &dyn CameraModel,
    pose: &PoseWithCovariance,
    surface: &Surface<'_>,
    crs: Crs,
    px: [f64; 2],
    params: &Params,
) -> MapPoint {
    let pre = Prepared::new(camera, pose, params);
    pre.point(camera, pose, surface, crs, px, params)
}

/// [`georef`] of every pixel, in order (on the rayon pool); one pixel's status never affects
/// another's.
pub fn georef_batch(
    camera: &dyn CameraModel,
    pose: &PoseWithCovariance,
    surface: &Surface<'_>,
    crs: Crs,
    pixels: &[[f64; 2]],
    params: &Params,
) -> Vec<MapPoint> {
    let pre = Prepared::new(camera, pose, params);
    pixels
        .par_iter()
        .with_min_len(256)
        .map(|&px| pre.point(camera, pose, surface, crs, px, params))
        .collect()
}

/// Channels of a [`LookupTable`] cell, in order.
pub const LUT_CHANNELS: [&str; 4] = ["e", "n", "h", "sigma_major_m"];

/// A per-pixel map of one pose: cell (row, col) holds the georeference of pixel
/// (col·step, row·step), so the cells cover the image from its top-left pixel to within one step
/// of its right and bottom edges.
#[derive(Debug, Clone, PartialEq)]
pub struct LookupTable {
    /// Pixel step between neighbouring cells.
    pub step: u32,
    /// Rows: `⌈image height / step⌉`.
    pub rows: usize,
    /// Columns: `⌈image width / step⌉`.
    pub cols: usize,
    /// Row-major cells, [`LUT_CHANNELS`] each: E, N, h (map frame, m) and the 1σ error ellipse's
    /// major semi-axis (m); all four NaN where the pixel's status is not [`Status::Ok`].
    pub cells: Vec<[f64; 4]>,
}

/// The [`LookupTable`] of `pose` at every `step`-th pixel of the camera's image (`step` ≥ 1; 0 is
/// taken as 1), with `params` (its `wgs84` is not used: the table holds map coordinates).
pub fn lookup_table(
    camera: &dyn CameraModel,
    pose: &PoseWithCovariance,
    surface: &Surface<'_>,
    step: u32,
    params: &Params,
) -> LookupTable {
    let step = step.max(1);
    let (w, h) = (camera.width(), camera.height());
    let (cols, rows) = (w.div_ceil(step) as usize, h.div_ceil(step) as usize);
    let params = Params {
        wgs84: false,
        ..*params
    };
    let pre = Prepared::new(camera, pose, &params);
    let cells = (0..rows * cols)
        .into_par_iter()
        .with_min_len(256)
        .map(|k| {
            let px = [
                ((k % cols) as u32 * step) as f64,
                ((k / cols) as u32 * step) as f64,
            ];
            let m = pre.point(camera, pose, surface, Crs::Local, px, &params);
            if m.status == Status::Ok {
                [m.enh[0], m.enh[1], m.enh[2], m.ellipse().sigma_major_m]
            } else {
                [f64::NAN; 4]
            }
        })
        .collect();
    LookupTable {
        step,
        rows,
        cols,
        cells,
    }
}

/// What every pixel of one pose shares.
struct Prepared {
    map_from_cam: Matrix3<f64>,
    center: Point3<f64>,
    cos_max: f64,
    max_theta: f64,
    /// Axes of the pose's yaw, pitch and roll rotations in the map frame.
    rot_axes: [Vector3<f64>; 3],
}

impl Prepared {
    fn new(camera: &dyn CameraModel, pose: &PoseWithCovariance, params: &Params) -> Self {
        let (yaw, pitch, _) = pose.pose.yaw_pitch_roll();
        let rz = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
        let ry = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), pitch);
        Prepared {
            map_from_cam: *pose.pose.rotation.inverse().matrix(),
            center: pose.pose.center(),
            cos_max: params.max_off_nadir_deg.to_radians().cos(),
            max_theta: camera.max_theta(),
            rot_axes: [Vector3::z(), rz * Vector3::y(), rz * ry * Vector3::x()],
        }
    }

    #[inline]
    fn point(
        &self,
        camera: &dyn CameraModel,
        pose: &PoseWithCovariance,
        surface: &Surface<'_>,
        crs: Crs,
        px: [f64; 2],
        params: &Params,
    ) -> MapPoint {
        if !(px[0].is_finite() && px[1].is_finite()) {
            return MapPoint::invalid(Status::NonFinite);
        }
        let p = Point2::new(px[0], px[1]);
        if !camera.in_image(&p) {
            return MapPoint::invalid(Status::OutsideImage);
        }
        let b = match camera.unproject(&p) {
            Ok(b) if b.z.clamp(-1.0, 1.0).acos() <= self.max_theta => b.into_inner(),
            _ => return MapPoint::invalid(Status::OutsideCircle),
        };
        let d = self.map_from_cam * b;
        if !(d.z < 0.0) {
            return MapPoint::invalid(Status::AboveHorizon);
        }
        if -d.z < self.cos_max {
            return MapPoint::invalid(Status::Grazing);
        }
        let c = self.center;
        let Some(hit) = surface.intersect(&c, &d) else {
            return MapPoint::invalid(Status::NoHeight);
        };
        let (t, (hx, hy)) = (hit.t, hit.slope);
        let g = c + t * d;
        // F(t, θ) = c_z + t·d_z − H(c_xy + t·d_xy) = 0; F_t < 0 for a ray meeting the ground
        // from above.
        let f_t = d.z - hx * d.x - hy * d.y;
        // The ground point's change for a change of the ray's direction (δd) or origin (δc).
        let by_dir = |dd: Vector3<f64>| -> Vector3<f64> {
            let df = t * (dd.z - hx * dd.x - hy * dd.y);
            t * dd - d * (df / f_t)
        };
        let mut cov = Matrix3::zeros();
        if let Some(pc) = &pose.covariance {
            let deg = std::f64::consts::PI / 180.0;
            let mut jac = [Vector3::zeros(); 6];
            let unit: [Vector3<f64>; 3] = [Vector3::x(), Vector3::y(), Vector3::z()];
            for (k, e) in unit.iter().enumerate() {
                let df = e.z - hx * e.x - hy * e.y;
                jac[k] = e - d * (df / f_t);
            }
            for (k, axis) in self.rot_axes.iter().enumerate() {
                jac[3 + k] = by_dir(axis.cross(&d) * deg);
            }
            for (a, ja) in jac.iter().enumerate() {
                for (bi, jb) in jac.iter().enumerate() {
                    let s = pc.matrix[a][bi];
                    if s != 0.0 {
                        cov += s * ja * jb.transpose();
                    }
                }
            }
        }
        // A height error δh of the surface moves the hit along the ray: F_δh = −1, so
        // δt = δh / F_t and δg = d·δh / F_t (|δg_xy| = δh·tan θ on flat ground).
        let sigma_h = surface.height_sigma_m(params);
        if sigma_h > 0.0 {
            let j = d / f_t;
            cov += (sigma_h * sigma_h * hit.weights_sq) * j * j.transpose();
        }
        if params.sigma_px > 0.0 {
            const H: f64 = 1e-2;
            let bearing = |du: f64, dv: f64| {
                camera
                    .unproject(&Point2::new(px[0] + du, px[1] + dv))
                    .map(|b| b.into_inner())
            };
            if let (Ok(a), Ok(b), Ok(c2), Ok(d2)) = (
                bearing(H, 0.0),
                bearing(-H, 0.0),
                bearing(0.0, H),
                bearing(0.0, -H),
            ) {
                let s2 = params.sigma_px * params.sigma_px;
                for db in [(a - b) / (2.0 * H), (c2 - d2) / (2.0 * H)] {
                    let j = by_dir(self.map_from_cam * db);
                    cov += s2 * j * j.transpose();
                }
            }
        }
        let covariance = [
            [cov[(0, 0)], cov[(0, 1)], cov[(0, 2)]],
            [cov[(1, 0)], cov[(1, 1)], cov[(1, 2)]],
            [cov[(2, 0)], cov[(2, 1)], cov[(2, 2)]],
        ];
        let lat_lon = match crs {
            Crs::Epsg(_) if params.wgs84 => super::map_to_wgs84(crs, g.x, g.y)
                .ok()
                .map(|(la, lo)| [la, lo]),
            _ => None,
        };
        MapPoint {
            status: Status::Ok,
            enh: [g.x, g.y, g.z],
            lat_lon,
            covariance,
            range_m: t,
            off_nadir_deg: (-d.z).clamp(-1.0, 1.0).acos().to_degrees(),
        }
    }
}

#[cfg(test)]
mod tests;
