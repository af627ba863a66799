//! A smooth MI estimator: partial-volume (PV) joint histogram with the analytic gradient of MI
//! with respect to the 6-DoF pose, and the observed information (the Hessian of the total
//! log-likelihood) for the Cramér–Rao covariance.
//!
//! The nearest-pixel kernel ([`super::kernel`]) puts each point's whole unit of mass in one
//! histogram cell, so the histogram, and MI, jumps whenever a projection crosses a pixel
//! boundary. Here a point projected to the sub-pixel position (u, v) spreads its unit of mass
//! over the four surrounding pixel centres with the bilinear weights (Maes et al. 1997,
//! partial-volume interpolation): cell (reflectivity bin of the point, gray bin of pixel k)
//! receives w_k. The histogram is then continuous in the pose and piecewise differentiable:
//!
//! dMI/dθ = Σ_cells ∂MI/∂h_ij · dh_ij/dθ, dh_ij/dθ = Σ_points Σ_k [cell] ∇_uv w_k · J_proj · dX_c/dθ
//!
//! with ∂MI/∂h_ij = (ln(h_ij·T / (h_i·h_j)) − MI) / T for un-normalised masses h (T their sum),
//! chained through the binomial Parzen smoothing (a symmetric convolution, its own adjoint).
//! J_proj is the camera's analytic 2×3 Jacobian (Mei/omnidir with radial and tangential
//! distortion and skew, or equidistant with atan2 and α), checked against central differences in
//! the tests.
//!
//! Pose parameters θ = (dx, dy, dz, rx, ry, rz): the camera centre moves by (dx, dy, dz) in the
//! map frame and the camera body rotates by Exp(r) about the map axes through its centre
//! ([`step`]); rz is exactly the yaw of [`super::space::pose_at`].
//!
//! Pooling: one joint histogram over every view ([`Pooling::Joint`], what the nearest-pixel
//! search does), or one histogram per view and the objective Σ_v (n_v/n)·MI_v, each frame's MI
//! weighted by its share of the points ([`Pooling::PerPair`]): frames under different light then
//! need not share one gray–reflectivity relation. Either way n · objective is the total
//! log-likelihood whose negative Hessian is the observed information.
//!
//! Sums are deterministic: points are cut into fixed blocks, each block's partial sums are made on
//! the pool and added up in block order, so the thread count cannot change a bit.

// Small fixed-size matrices (2×3, 6×6) indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use super::kernel::BinnedImage;
use super::points::PreparedPoints;
pub use super::Pooling;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::pose::CamFromMap;
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

mod lanes;
mod proj;
pub use lanes::{lanes_path, self_test as lanes_self_test, workload as pv_workload, LanesTest};
use proj::Proj;

/// Points per parallel block (fixed, so the sums do not depend on the thread count).
const BLOCK: usize = 4096;

/// Points projected before any of them is sampled (see [`Smooth::histogram`]).
const CHUNK: usize = 64;

/// ⌊x⌋ without a library call (the baseline x86-64 target has no rounding instruction): exact
/// for finite |x| < 2⁶³, which bounds every pixel coordinate the models return.
#[inline]
fn floor(x: f64) -> f64 {
    let f = x as i64 as f64;
    if f > x {
        f - 1.0
    } else {
        f
    }
}

/// How a projected point samples the image, for surface plots of either objective the
/// refinement uses: the grid search's nearest pixel, or the smooth stage's partial volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Sampling {
    /// Nearest-pixel joint histogram (the grid search's kernel).
    Nearest,
    /// Partial-volume joint histogram ([`Smooth`]), the local stage's.
    #[default]
    Pv,
}

impl Sampling {
    /// The command-line name (`nearest`, `pv`).
    pub fn name(self) -> &'static str {
        match self {
            Sampling::Nearest => "nearest",
            Sampling::Pv => "pv",
        }
    }
}

impl std::fmt::Display for Sampling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Sampling {
    type Err = Error;
    /// `nearest` or `pv`; anything else is a one-line error naming `--sampling`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "nearest" => Ok(Sampling::Nearest),
            "pv" => Ok(Sampling::Pv),
            _ => Err(super::choice("sampling", s, "nearest or pv")),
        }
    }
}

/// The pose at local parameters θ = (dx, dy, dz, rx, ry, rz) from `pose`: centre + (dx, dy, dz)
/// (map frame, m), body rotated by Exp(rx, ry, rz) (rad) about the map axes through the centre.
pub fn step(pose: &CamFromMap, theta: &[f64; 6]) -> CamFromMap {
    let c = pose.center() + Vector3::new(theta[0], theta[1], theta[2]);
    let q = Rotation3::new(Vector3::new(theta[3], theta[4], theta[5]));
    let map_from_cam = q * pose.rotation.inverse();
    CamFromMap::from_center(map_from_cam.inverse(), &c)
}

/// One view: its binned level-0 image and its fixed point set.
#[derive(Debug, Clone, Copy)]
pub struct SmoothView<'a> {
    /// Gray bins per pixel (invalid pixels hold the invalid bin, `cols`).
    pub img: &'a BinnedImage,
    /// Origin-shifted points with their reflectivity bins.
    pub pts: &'a PreparedPoints,
}

/// The PV estimator over a set of views sharing one pose.
#[derive(Debug, Clone)]
pub struct Smooth<'a> {
    proj: Proj,
    origin: [f64; 3],
    rows: usize,
    cols: usize,
    parzen: bool,
    pooling: Pooling,
    views: Vec<SmoothView<'a>>,
    /// Both passes project point by point through the scalar reference instead of
    /// [`lanes::project_chunk`] (the self-test and its workload).
    reference: bool,
}

/// The objective at one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothValue {
    /// The objective: MI of the joint histogram, or Σ_v (n_v/n)·MI_v.
    pub value: f64,
    /// MI per histogram (one, or one per view).
    pub mi: Vec<f64>,
    /// Points in the fixed sets, all views.
    pub n: usize,
    /// Mass that landed on valid pixels, all views (≤ n).
    pub valid: f64,
    /// d(value)/dθ at the pose, θ as in [`step`]; `None` when not asked for.
    pub grad: Option<[f64; 6]>,
}

/// Ask the cache for the 2 × 2 pixel blocks that a chunk's samples (pixel positions `u`, `v`,
/// in view where `ok`) are about to read. The samples are spread over an image of megabytes,
/// and their loads were most of a pass's time waiting (`perf annotate`); asked for together,
/// they arrive side by side. A prefetch reads nothing, so no result changes.
#[inline(always)]
fn prefetch_blocks(img: &BinnedImage, u: &[f64], v: &[f64], ok: &[bool]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let (w, h) = (img.width as i64, img.height as i64);
        let base = img.data.as_ptr();
        for ((&u, &v), &ok) in u.iter().zip(v).zip(ok) {
            let (x, y) = (u as i64, v as i64);
            if ok && x >= 0 && y >= 0 && x + 1 < w && y + 1 < h {
                let i = (y * w + x) as usize;
                // SAFETY: `i` and `i + w` index `img.data` (checked above); a prefetch is a hint
                // that reads and writes nothing.
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(base.add(i) as *const i8);
                    _mm_prefetch::<_MM_HINT_T0>(base.add(i + w as usize) as *const i8);
                }
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (img, u, v, ok);
}

/// The objective at one pose with what its gradient needs ([`Smooth::evaluate_value`]).
#[derive(Debug, Clone)]
pub struct Valued {
    /// The value (no gradient).
    pub value: SmoothValue,
    /// The pose's rotation and translation as the passes over the points take them.
    r: Matrix3<f64>,
    t: Vector3<f64>,
    /// Per view, the cell weights ∂objective/∂h and the view's weight.
    cells: Vec<(Vec<f64>, f64)>,
}

/// [`Smooth::pool`]'s answer.
struct Pooled {
    value: f64,
    mi: Vec<f64>,
    cells: Vec<(Vec<f64>, f64)>,
}

/// A joint histogram of f64 masses, `rows × cols` (invalid mass is counted apart).
#[derive(Debug, Clone)]
struct Hist {
    h: Vec<f64>,
    invalid: f64,
}

impl<'a> Smooth<'a> {
    /// The estimator on `views` (points shifted by `origin`), `rows × cols` bins.
    pub fn new(
        cam: &Camera,
        views: Vec<SmoothView<'a>>,
        origin: [f64; 3],
        rows: usize,
        cols: usize,
        parzen: bool,
        pooling: Pooling,
    ) -> Self {
        Smooth {
            proj: Proj::new(cam),
            origin,
            rows,
            cols,
            parzen,
            pooling,
            views,
            reference: false,
        }
    }

    /// This estimator with its value and gradient passes on the scalar reference projection
    /// (same values bit for bit; the self-test compares them, the workload times them).
    pub fn with_reference_projection(mut self) -> Self {
        self.reference = true;
        self
    }

    /// The estimator on `ev`'s level 0: the same binned (blurred) images, fixed point sets,
    /// bins and Parzen setting as the nearest-pixel search scores.
    pub fn of_evaluator(
        cam: &Camera,
        ev: &'a super::objective::Evaluator,
        pooling: Pooling,
    ) -> Self {
        let (parts, origin, mi) = ev.level0();
        let views = parts
            .into_iter()
            .map(|(img, pts)| SmoothView { img, pts })
            .collect();
        Self::new(
            cam,
            views,
            origin,
            mi.bins_reflectivity,
            mi.bins_gray,
            mi.parzen,
            pooling,
        )
    }

    /// Views (image/point-set pairs).
    pub fn views(&self) -> usize {
        self.views.len()
    }

    /// Points in all views.
    pub fn n(&self) -> usize {
        self.views.iter().map(|v| v.pts.len()).sum()
    }

    /// The pooling rule.
    pub fn pooling(&self) -> Pooling {
        self.pooling
    }

    /// R (row-major) and t of `X_c = R·p + t` for origin-shifted points p.
    fn rt(&self, pose: &CamFromMap) -> (Matrix3<f64>, Vector3<f64>) {
        let o = Point3::new(self.origin[0], self.origin[1], self.origin[2]);
        (*pose.rotation.matrix(), pose.transform(&o).coords)
    }

    /// The four PV samples of a projection: (pixel bin or `None` when off the image or invalid,
    /// weight, ∂weight/∂(u, v)).
    #[inline]
    fn samples(
        img: &BinnedImage,
        cols: usize,
        uv: [f64; 2],
    ) -> [(Option<usize>, f64, [f64; 2]); 4] {
        let (u0, v0) = (floor(uv[0]), floor(uv[1]));
        let (fu, fv) = (uv[0] - u0, uv[1] - v0);
        let valid = |b: u8| -> Option<usize> { ((b as usize) < cols).then_some(b as usize) };
        let bins = if u0 >= 0.0
            && v0 >= 0.0
            && u0 + 1.0 < img.width as f64
            && v0 + 1.0 < img.height as f64
        {
            // The whole 2 × 2 block is on the image (almost every sample): one bounds check.
            let i = v0 as usize * img.width + u0 as usize;
            let (top, bottom) = (
                &img.data[i..i + 2],
                &img.data[i + img.width..i + img.width + 2],
            );
            [
                valid(top[0]),
                valid(top[1]),
                valid(bottom[0]),
                valid(bottom[1]),
            ]
        } else {
            let bin = |du: f64, dv: f64| -> Option<usize> {
                let (x, y) = (u0 + du, v0 + dv);
                if x < 0.0 || y < 0.0 || x >= img.width as f64 || y >= img.height as f64 {
                    return None;
                }
                valid(img.data[y as usize * img.width + x as usize])
            };
            [bin(0.0, 0.0), bin(1.0, 0.0), bin(0.0, 1.0), bin(1.0, 1.0)]
        };
        [
            (bins[0], (1.0 - fu) * (1.0 - fv), [-(1.0 - fv), -(1.0 - fu)]),
            (bins[1], fu * (1.0 - fv), [1.0 - fv, -fu]),
            (bins[2], (1.0 - fu) * fv, [-fv, 1.0 - fu]),
            (bins[3], fu * fv, [fv, fu]),
        ]
    }

    /// Project a chunk of points ([`lanes::project_chunk`], or point by point through the
    /// reference when the estimator was built [`Self::with_reference_projection`]).
    #[inline]
    fn project_chunk<O: lanes::ChunkOut>(
        &self,
        rt: &lanes::Rt,
        xs: &[f32],
        ys: &[f32],
        zs: &[f32],
        out: &mut O,
    ) {
        if self.reference {
            lanes::project_reference(&self.proj, rt, xs, ys, zs, out);
        } else {
            lanes::project_chunk(&self.proj, rt, xs, ys, zs, out);
        }
    }

    /// The PV histogram of one view at `pose`.
    fn histogram(&self, v: &SmoothView<'_>, r: &Matrix3<f64>, t: &Vector3<f64>) -> Hist {
        let (rows, cols) = (self.rows, self.cols);
        let n = v.pts.len();
        let rt = &lanes::Rt::of(r, t);
        let blocks: Vec<Hist> = (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|b| self.histogram_range(v, rt, b * BLOCK..((b + 1) * BLOCK).min(n)))
            .collect();
        let mut out = Hist {
            h: vec![0.0; rows * cols],
            invalid: 0.0,
        };
        for b in blocks {
            out.h.iter_mut().zip(&b.h).for_each(|(a, x)| *a += x);
            out.invalid += b.invalid;
        }
        out
    }

    /// The PV histogram of the points `range` of `v` at the pose `rt`.
    fn histogram_range(
        &self,
        v: &SmoothView<'_>,
        rt: &lanes::Rt,
        range: std::ops::Range<usize>,
    ) -> Hist {
        let cols = self.cols;
        let mut h = Hist {
            h: vec![0.0; self.rows * cols],
            invalid: 0.0,
        };
        // A chunk's projections first, then its samples: the pixel loads of a chunk are
        // independent, so they overlap instead of each waiting behind a projection.
        let mut uv = lanes::UvChunk::default();
        for c0 in range.clone().step_by(CHUNK) {
            let c1 = (c0 + CHUNK).min(range.end);
            let p = v.pts;
            let (xs, ys, zs) = (&p.x[c0..c1], &p.y[c0..c1], &p.z[c0..c1]);
            self.project_chunk(rt, xs, ys, zs, &mut uv);
            let n = c1 - c0;
            prefetch_blocks(v.img, &uv.u[..n], &uv.v[..n], &uv.ok[..n]);
            for c in 0..n {
                if !uv.ok[c] {
                    h.invalid += 1.0;
                    continue;
                }
                let row = v.pts.bin[c0 + c] as usize;
                for (bin, w, _) in Self::samples(v.img, cols, [uv.u[c], uv.v[c]]) {
                    match bin {
                        Some(j) => h.h[row * cols + j] += w,
                        None => h.invalid += w,
                    }
                }
            }
        }
        h
    }

    /// Σ over `view`'s points of the pose gradient of Σ_cells g_ij·h_ij (g: `rows × cols`).
    fn pull_back(
        &self,
        v: &SmoothView<'_>,
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
        g: &[f64],
    ) -> [f64; 6] {
        let n = v.pts.len();
        let blocks: Vec<[f64; 6]> = (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|blk| self.pull_back_range(v, r, t, g, blk * BLOCK..((blk + 1) * BLOCK).min(n)))
            .collect();
        let mut s = [0.0; 6];
        for b in blocks {
            for k in 0..6 {
                s[k] += b[k];
            }
        }
        Self::to_theta(r, &s)
    }

    /// The camera-frame sums B = Σ b and C = Σ b × X_c over the points `range` of `v`, with b
    /// = ∂/∂X_c of a point's contribution to Σ_cells g_ij·h_ij; [`Self::to_theta`] turns them
    /// into the gradient over θ.
    fn pull_back_range(
        &self,
        v: &SmoothView<'_>,
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
        g: &[f64],
        range: std::ops::Range<usize>,
    ) -> [f64; 6] {
        let cols = self.cols;
        let mut acc = [0.0; 6];
        let rt = &lanes::Rt::of(r, t);
        let mut ch = lanes::JacChunk::default();
        for c0 in range.clone().step_by(CHUNK) {
            let c1 = (c0 + CHUNK).min(range.end);
            let p = v.pts;
            let (xs, ys, zs) = (&p.x[c0..c1], &p.y[c0..c1], &p.z[c0..c1]);
            self.project_chunk(rt, xs, ys, zs, &mut ch);
            let n = c1 - c0;
            prefetch_blocks(v.img, &ch.uv.u[..n], &ch.uv.v[..n], &ch.uv.ok[..n]);
            for c in 0..n {
                if !ch.uv.ok[c] {
                    continue;
                }
                let q = &ch.parts;
                let xc = [q.xc[0][c], q.xc[1][c], q.xc[2][c]];
                let j = [
                    [q.ju[0][c], q.ju[1][c], q.ju[2][c]],
                    [q.jv[0][c], q.jv[1][c], q.jv[2][c]],
                ];
                let row = v.pts.bin[c0 + c] as usize;
                let mut a = [0.0; 2];
                for (bin, _, dw) in Self::samples(v.img, cols, [ch.uv.u[c], ch.uv.v[c]]) {
                    if let Some(col) = bin {
                        let gij = g[row * cols + col];
                        a[0] += gij * dw[0];
                        a[1] += gij * dw[1];
                    }
                }
                if a == [0.0, 0.0] {
                    continue;
                }
                let b = [
                    a[0] * j[0][0] + a[1] * j[1][0],
                    a[0] * j[0][1] + a[1] * j[1][1],
                    a[0] * j[0][2] + a[1] * j[1][2],
                ];
                acc[0] += b[0];
                acc[1] += b[1];
                acc[2] += b[2];
                acc[3] += b[1] * xc[2] - b[2] * xc[1];
                acc[4] += b[2] * xc[0] - b[0] * xc[2];
                acc[5] += b[0] * xc[1] - b[1] * xc[0];
            }
        }
        acc
    }

    /// The gradient over θ of camera-frame sums `s` = (B, C) of [`Self::pull_back_range`].
    fn to_theta(r: &Matrix3<f64>, s: &[f64; 6]) -> [f64; 6] {
        // dX_c/dd = −R, dX_c/dr = [X_c]× R: ∂/∂d = −Rᵀ B, ∂/∂r = Rᵀ (B × X_c summed) = Rᵀ C.
        let rt = r.transpose();
        let gd = -(rt * Vector3::new(s[0], s[1], s[2]));
        let gr = rt * Vector3::new(s[3], s[4], s[5]);
        [gd.x, gd.y, gd.z, gr.x, gr.y, gr.z]
    }

    /// Every view's PV histogram at the pose (R, t).
    fn histograms(&self, r: &Matrix3<f64>, t: &Vector3<f64>) -> Vec<Hist> {
        self.views.iter().map(|v| self.histogram(v, r, t)).collect()
    }

    /// The objective of the views' histograms under the pooling rule: its value, MI per
    /// histogram, and per view the cell weights ∂objective/∂h with the view's weight in the
    /// objective (1 for the joint histogram, n_v/n per pair), which pull the gradient back.
    fn pool(&self, hists: &[Hist]) -> Pooled {
        let n = self.n();
        match self.pooling {
            Pooling::Joint => {
                let mut h = vec![0.0; self.rows * self.cols];
                for x in hists {
                    h.iter_mut().zip(&x.h).for_each(|(a, b)| *a += b);
                }
                let (mi, g) = mi_gradient(&h, self.rows, self.cols, self.parzen);
                Pooled {
                    value: mi,
                    mi: vec![mi],
                    cells: self.views.iter().map(|_| (g.clone(), 1.0)).collect(),
                }
            }
            Pooling::PerPair => {
                let mut out = Pooled {
                    value: 0.0,
                    mi: Vec::new(),
                    cells: Vec::new(),
                };
                for (v, h) in self.views.iter().zip(hists) {
                    let wv = v.pts.len() as f64 / n.max(1) as f64;
                    let (mi, g) = mi_gradient(&h.h, self.rows, self.cols, self.parzen);
                    out.value += wv * mi;
                    out.mi.push(mi);
                    out.cells.push((g, wv));
                }
                out
            }
        }
    }

    /// The objective at `pose`, with its gradient when `grad`.
    pub fn evaluate(&self, pose: &CamFromMap, grad: bool) -> SmoothValue {
        let valued = self.evaluate_value(pose);
        let g = grad.then(|| self.gradient_of(&valued));
        SmoothValue {
            grad: g,
            ..valued.value
        }
    }

    /// The objective at `pose` without its gradient, keeping what the gradient needs: a caller
    /// that only wants the gradient at some of the poses it tries (a line search's accepted step)
    /// asks [`Self::gradient_of`] for it and skips the second pass over the points elsewhere.
    /// The two together are [`Self::evaluate`] with `grad`, to the bit.
    pub fn evaluate_value(&self, pose: &CamFromMap) -> Valued {
        let (r, t) = self.rt(pose);
        let hists = self.histograms(&r, &t);
        let valid = hists.iter().map(|h| h.h.iter().sum::<f64>()).sum::<f64>();
        let pooled = self.pool(&hists);
        Valued {
            value: SmoothValue {
                value: pooled.value,
                mi: pooled.mi,
                n: self.n(),
                valid,
                grad: None,
            },
            r,
            t,
            cells: pooled.cells,
        }
    }

    /// The gradient over θ at the pose of `valued` ([`Self::evaluate_value`] of this estimator).
    pub fn gradient_of(&self, valued: &Valued) -> [f64; 6] {
        let mut gsum = [0.0; 6];
        for (v, (g, w)) in self.views.iter().zip(&valued.cells) {
            let d = self.pull_back(v, &valued.r, &valued.t, g);
            gsum.iter_mut().zip(d).for_each(|(a, b)| *a += w * b);
        }
        gsum
    }

    /// The gradient of the objective at `pose` cut into `k` clusters of points: cluster j holds
    /// the j-th of `k` contiguous runs of every view's fixed set (Morton order, so a run is a
    /// compact patch of ground). ∂MI/∂h is taken at the whole
    /// histogram, so the clusters' gradients sum to [`Self::evaluate`]'s: each is a patch's
    /// share of the score, whose scatter across patches measures how much the answer depends on
    /// which ground it saw ([`crate::localize::refine::information::information`]'s sandwich).
    pub fn cluster_gradients(&self, pose: &CamFromMap, k: usize) -> Vec<[f64; 6]> {
        let k = k.max(1);
        let (r, t) = self.rt(pose);
        let weights = self.pool(&self.histograms(&r, &t)).cells;
        (0..k)
            .into_par_iter()
            .map(|j| {
                let mut s = [0.0; 6];
                for (v, (g, w)) in self.views.iter().zip(&weights) {
                    let m = v.pts.len();
                    let part = self.pull_back_range(v, &r, &t, g, j * m / k..(j + 1) * m / k);
                    for (a, b) in s.iter_mut().zip(part) {
                        *a += w * b;
                    }
                }
                Self::to_theta(&r, &s)
            })
            .collect()
    }

    /// The PV histograms at `pose` cut into `k` clusters of points, as
    /// [`Self::cluster_gradients`] cuts them (cluster j: the j-th of `k` contiguous Morton runs of
    /// every view's fixed set): `[cluster][view]` joint masses, `rows × cols` row-major. Their
    /// sum over the clusters is each view's histogram, so an objective without one cluster is
    /// [`Self::value_of`] of the others' sum: what a delete-a-patch jackknife of a difference of
    /// values needs (the confidence region's test in
    /// [`crate::localize::refine::uncertainty`]).
    pub fn cluster_histograms(&self, pose: &CamFromMap, k: usize) -> Vec<Vec<Vec<f64>>> {
        let k = k.max(1);
        let (r, t) = self.rt(pose);
        let rt = &lanes::Rt::of(&r, &t);
        (0..k)
            .into_par_iter()
            .map(|j| {
                self.views
                    .iter()
                    .map(|v| {
                        let m = v.pts.len();
                        self.histogram_range(v, rt, j * m / k..(j + 1) * m / k).h
                    })
                    .collect()
            })
            .collect()
    }

    /// The objective of per-view joint masses `hists` (`[view]`, as [`Self::cluster_histograms`]
    /// gives them, summed over any clusters), pooled as this estimator pools.
    pub fn value_of(&self, hists: &[Vec<f64>]) -> f64 {
        let hs: Vec<Hist> = hists
            .iter()
            .map(|h| Hist {
                h: h.clone(),
                invalid: 0.0,
            })
            .collect();
        self.pool(&hs).value
    }

    /// The gradient of the objective at `pose` cut by view: entry v is view v's points' share
    /// (∂MI/∂h at the whole histogram, so the entries sum to [`Self::evaluate`]'s gradient). With
    /// frames of one rig, each its own sweep and light, the frames are the independent units
    /// whose scatter measures what a frame's systematic errors do to the answer.
    pub fn view_gradients(&self, pose: &CamFromMap) -> Vec<[f64; 6]> {
        let (r, t) = self.rt(pose);
        let weights = self.pool(&self.histograms(&r, &t)).cells;
        self.views
            .par_iter()
            .zip(&weights)
            .map(|(v, (g, w))| {
                let part = self.pull_back_range(v, &r, &t, g, 0..v.pts.len());
                let s = part.map(|b| w * b);
                Self::to_theta(&r, &s)
            })
            .collect()
    }

    /// Evaluations (value + gradient) that [`Smooth::hessian`] makes: two per free parameter.
    pub fn hessian_evaluations(free: &[bool; 6]) -> usize {
        2 * free.iter().filter(|f| **f).count()
    }

    /// The objective's Hessian at `pose` over the free parameters (θ of [`step`]), by central
    /// differences of the analytic gradient with steps `h` (m, rad); rows and columns of fixed
    /// parameters are 0. Symmetrised.
    pub fn hessian(&self, pose: &CamFromMap, free: &[bool; 6], h: &[f64; 6]) -> [[f64; 6]; 6] {
        let mut m = [[0.0; 6]; 6];
        for j in (0..6).filter(|&j| free[j]) {
            let mut th = [0.0; 6];
            th[j] = h[j];
            let gp = self
                .evaluate(&step(pose, &th), true)
                .grad
                .unwrap_or([0.0; 6]);
            th[j] = -h[j];
            let gm = self
                .evaluate(&step(pose, &th), true)
                .grad
                .unwrap_or([0.0; 6]);
            for i in (0..6).filter(|&i| free[i]) {
                m[i][j] = (gp[i] - gm[i]) / (2.0 * h[j]);
            }
        }
        for i in 0..6 {
            for j in 0..i {
                let s = 0.5 * (m[i][j] + m[j][i]);
                m[i][j] = s;
                m[j][i] = s;
            }
        }
        m
    }
}

/// MI of the `rows × cols` masses `h` (after the binomial Parzen smoothing when `parzen`) and
/// ∂MI/∂h (chained back through the smoothing). Empty: MI 0, zero gradient.
pub(crate) fn mi_gradient(h: &[f64], rows: usize, cols: usize, parzen: bool) -> (f64, Vec<f64>) {
    let p = if parzen {
        binomial3(h, rows, cols)
    } else {
        h.to_vec()
    };
    let total: f64 = p.iter().sum();
    if total <= 0.0 {
        return (0.0, vec![0.0; rows * cols]);
    }
    let mut px = vec![0.0; rows];
    let mut py = vec![0.0; cols];
    for i in 0..rows {
        for j in 0..cols {
            px[i] += p[i * cols + j];
            py[j] += p[i * cols + j];
        }
    }
    let xlx = |v: f64| if v > 0.0 { v * v.ln() } else { 0.0 };
    let sxy: f64 = p.iter().map(|&v| xlx(v)).sum();
    let sx: f64 = px.iter().map(|&v| xlx(v)).sum();
    let sy: f64 = py.iter().map(|&v| xlx(v)).sum();
    let mi = (sxy - sx - sy) / total + total.ln();
    let mut g = vec![0.0; rows * cols];
    for i in 0..rows {
        for j in 0..cols {
            let v = p[i * cols + j];
            if v > 0.0 {
                g[i * cols + j] = ((v * total / (px[i] * py[j])).ln() - mi) / total;
            }
        }
    }
    let g = if parzen { binomial3(&g, rows, cols) } else { g };
    (mi, g)
}

/// The separable [1 2 1] ⊗ [1 2 1] convolution with zero padding (the nearest-pixel estimator's
/// Parzen smoothing, [`super::mutual_information`]); symmetric, so it is its own adjoint.
fn binomial3(h: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut tmp = vec![0.0; rows * cols];
    for i in 0..rows {
        for j in 0..cols {
            let l = if j > 0 { h[i * cols + j - 1] } else { 0.0 };
            let r = if j + 1 < cols {
                h[i * cols + j + 1]
            } else {
                0.0
            };
            tmp[i * cols + j] = l + 2.0 * h[i * cols + j] + r;
        }
    }
    let mut out = vec![0.0; rows * cols];
    for i in 0..rows {
        for j in 0..cols {
            let u = if i > 0 { tmp[(i - 1) * cols + j] } else { 0.0 };
            let d = if i + 1 < rows {
                tmp[(i + 1) * cols + j]
            } else {
                0.0
            };
            out[i * cols + j] = u + 2.0 * tmp[i * cols + j] + d;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraModel, Equidistant, Mei};
    use crate::localize::mi::{mutual_information, JointHist};

    fn mei() -> Camera {
        Camera::Mei(Mei {
            width: 320,
            height: 240,
            fx: 180.0,
            fy: 175.0,
            cx: 161.3,
            cy: 118.7,
            skew: 0.4,
            xi: 1.2,
            k1: -0.12,
            k2: 0.03,
            p1: 0.002,
            p2: -0.001,
            fov_deg: None,
        })
    }

    fn equidistant() -> Camera {
        Camera::Equidistant(Equidistant {
            width: 320,
            height: 240,
            fx: 90.0,
            fy: 91.0,
            cx: 160.2,
            cy: 119.5,
            alpha: 0.001,
            k1: 0.02,
            k2: -0.01,
            k3: 0.003,
            k4: -0.0005,
            fov_deg: None,
            cache: Default::default(),
        })
    }

    #[test]
    fn floor_is_the_library_s_on_pixel_coordinates() {
        for x in [
            -2049.5, -1.0, -0.75, -1e-12, 0.0, 1e-12, 0.5, 1.0, 2047.9999, 3.0e9, -4.5e15,
        ] {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "{x}");
        }
    }

    #[test]
    fn projection_matches_the_camera_and_its_jacobian_central_differences() {
        for cam in [mei(), equidistant()] {
            let proj = Proj::new(&cam);
            for p in [
                [0.3, -0.2, 1.0],
                [-1.5, 0.7, 0.4],
                [2.0, 1.0, -0.3],
                [0.01, 0.02, 3.0],
            ] {
                let pv = Vector3::new(p[0], p[1], p[2]);
                let Ok(want) = cam.model().project(&pv) else {
                    assert!(proj.project(p).is_none(), "{p:?}");
                    assert!(proj.project_uv(p).is_none(), "{p:?}");
                    continue;
                };
                let (uv, j) = proj.project(p).expect("visible");
                assert!((uv[0] - want.x).abs() < 1e-9 && (uv[1] - want.y).abs() < 1e-9);
                // The value passes' projection is the same pixel to the last bit.
                assert_eq!(proj.project_uv(p), Some(uv), "{p:?}");
                let h = 1e-6;
                for c in 0..3 {
                    let (mut a, mut b) = (p, p);
                    a[c] += h;
                    b[c] -= h;
                    let (ua, _) = proj.project(a).unwrap();
                    let (ub, _) = proj.project(b).unwrap();
                    for r in 0..2 {
                        let fd = (ua[r] - ub[r]) / (2.0 * h);
                        assert!(
                            (fd - j[r][c]).abs() < 1e-5 * (1.0 + fd.abs()),
                            "{p:?} ∂{r}/∂{c}: {fd} vs {}",
                            j[r][c]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn names_round_trip_and_unknown_names_the_flag() {
        for e in [Sampling::Nearest, Sampling::Pv] {
            assert_eq!(e.to_string().parse::<Sampling>().unwrap(), e);
        }
        for p in [Pooling::Joint, Pooling::PerPair] {
            assert_eq!(p.to_string().parse::<Pooling>().unwrap(), p);
            assert_eq!(serde_json::to_value(p).unwrap(), p.name());
        }
        let e = "bspline".parse::<Sampling>().unwrap_err().to_string();
        assert!(e.starts_with("--sampling \"bspline\"") && !e.contains('\n'));
        assert!("joint-hist"
            .parse::<Pooling>()
            .unwrap_err()
            .to_string()
            .starts_with("--pooling"));
    }

    #[test]
    fn mi_of_integer_masses_is_the_nearest_pixel_estimator_s() {
        let (rows, cols) = (5, 6);
        let mut jh = JointHist::new(rows, cols);
        let mut h = vec![0.0; rows * cols];
        for i in 0..997usize {
            let (x, y) = ((i * 7) % 5, (i * i + 3 * i) % 6);
            let s = jh.stride();
            jh.counts[x * s + y] += 1;
            h[x * cols + y] += 1.0;
        }
        for parzen in [false, true] {
            let want = mutual_information(&jh, parzen).mi;
            let (mi, _) = mi_gradient(&h, rows, cols, parzen);
            assert!((mi - want).abs() < 1e-12, "{parzen}: {mi} vs {want}");
        }
    }

    #[test]
    fn mi_gradient_matches_central_differences() {
        let (rows, cols) = (4, 5);
        let h: Vec<f64> = (0..rows * cols)
            .map(|k| 1.0 + ((k * 37) % 11) as f64 + 0.25 * (k % 3) as f64)
            .collect();
        for parzen in [false, true] {
            let (_, g) = mi_gradient(&h, rows, cols, parzen);
            for k in 0..rows * cols {
                let (mut a, mut b) = (h.clone(), h.clone());
                a[k] += 1e-6;
                b[k] -= 1e-6;
                let fd = (mi_gradient(&a, rows, cols, parzen).0
                    - mi_gradient(&b, rows, cols, parzen).0)
                    / 2e-6;
                assert!(
                    (fd - g[k]).abs() < 1e-7,
                    "{parzen} cell {k}: {fd} vs {}",
                    g[k]
                );
            }
        }
    }

    /// A textured plane in front of the camera (points on z = 0 of the map, the camera 5 m above
    /// looking down), its image rendered from a smooth pattern of the same reflectivity.
    struct Scene {
        img: BinnedImage,
        pts: PreparedPoints,
        pose: CamFromMap,
        origin: [f64; 3],
    }

    fn pattern(x: f64, y: f64) -> f64 {
        0.5 + 0.25 * (1.3 * x).sin() * (0.9 * y + 0.4).cos() + 0.2 * (0.37 * x * y).sin()
    }

    fn scene(cam: &Camera, bins: usize) -> Scene {
        let c = Point3::new(0.3, -0.2, 5.0);
        // Zero pitch and roll: looking straight down.
        let pose = CamFromMap::from_center_ypr(&c, 0.3, 0.0, 0.0);
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let mut data = vec![bins as u8; w * h + 1];
        for v in 0..h {
            for u in 0..w {
                let Ok(ray) = cam
                    .model()
                    .unproject(&nalgebra::Point2::new(u as f64, v as f64))
                else {
                    continue;
                };
                let d = pose.rotation.inverse() * ray.into_inner();
                if d.z >= -0.05 {
                    continue;
                }
                let s = -c.z / d.z;
                let val = pattern(c.x + s * d.x, c.y + s * d.y);
                data[v * w + u] = ((val * bins as f64) as usize).min(bins - 1) as u8;
            }
        }
        let img = BinnedImage {
            width: w,
            height: h,
            data,
        };
        let origin = [c.x, c.y, c.z];
        let mut pts = PreparedPoints::default();
        for i in 0..80 {
            for j in 0..80 {
                let (x, y) = (
                    -4.0 + 0.1 * i as f64 + 0.013 * j as f64,
                    -4.0 + 0.1 * j as f64,
                );
                pts.x.push((x - origin[0]) as f32);
                pts.y.push((y - origin[1]) as f32);
                pts.z.push((0.0 - origin[2]) as f32);
                let val = pattern(x, y);
                pts.bin
                    .push(((val * bins as f64) as usize).min(bins - 1) as u8);
            }
        }
        Scene {
            img,
            pts,
            pose,
            origin,
        }
    }

    /// The scene's points cut in two halves, as two views' point sets.
    fn halves(pts: &PreparedPoints) -> [PreparedPoints; 2] {
        [
            pts.range(0, pts.len() / 2),
            pts.range(pts.len() / 2, pts.len()),
        ]
    }

    /// Two views of one image, one per half.
    fn two_views<'a>(img: &'a BinnedImage, halves: &'a [PreparedPoints; 2]) -> Vec<SmoothView<'a>> {
        halves.iter().map(|pts| SmoothView { img, pts }).collect()
    }

    #[test]
    fn pose_gradient_matches_central_differences_for_both_models_and_poolings() {
        for cam in [mei(), equidistant()] {
            let s = scene(&cam, 16);
            let halves = halves(&s.pts);
            for pooling in [Pooling::Joint, Pooling::PerPair] {
                let views = two_views(&s.img, &halves);
                let est = Smooth::new(&cam, views, s.origin, 16, 16, true, pooling);
                // Off the optimum, so the gradient is not ~0.
                let at = step(&s.pose, &[0.03, -0.02, 0.01, 0.004, -0.003, 0.01]);
                let g = est.evaluate(&at, true).grad.unwrap();
                let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
                assert!(norm > 1e-3, "{g:?}");
                // PV's gradient is piecewise constant per point between pixel crossings; steps
                // far below a pixel keep most points inside their cells.
                for k in 0..6 {
                    let h = if k < 3 { 1e-5 } else { 2e-6 };
                    let mut th = [0.0; 6];
                    th[k] = h;
                    let a = est.evaluate(&step(&at, &th), false).value;
                    th[k] = -h;
                    let b = est.evaluate(&step(&at, &th), false).value;
                    let fd = (a - b) / (2.0 * h);
                    assert!(
                        (fd - g[k]).abs() < 0.02 * norm,
                        "{pooling} θ{k}: fd {fd} vs analytic {} (|g| {norm})",
                        g[k]
                    );
                }
            }
        }
    }

    /// The value first and the gradient after ([`Smooth::evaluate_value`], [`Smooth::gradient_of`])
    /// are one evaluation with its gradient, to the bit: the ascent's line search relies on it.
    #[test]
    fn a_deferred_gradient_is_the_evaluation_s_own() {
        let cam = mei();
        let s = scene(&cam, 16);
        let halves = halves(&s.pts);
        for pooling in [Pooling::Joint, Pooling::PerPair] {
            let est = Smooth::new(
                &cam,
                two_views(&s.img, &halves),
                s.origin,
                16,
                16,
                true,
                pooling,
            );
            let at = step(&s.pose, &[0.03, -0.02, 0.01, 0.004, -0.003, 0.01]);
            let whole = est.evaluate(&at, true);
            let valued = est.evaluate_value(&at);
            assert_eq!(
                valued.value,
                SmoothValue {
                    grad: None,
                    ..whole.clone()
                }
            );
            let g = est.gradient_of(&valued);
            assert_eq!(whole.grad, Some(g), "{pooling}");
            assert!(g.iter().any(|v| *v != 0.0));
        }
    }

    #[test]
    fn clusters_sum_to_the_gradient_and_the_objective() {
        let cam = mei();
        let s = scene(&cam, 16);
        let halves = halves(&s.pts);
        for pooling in [Pooling::Joint, Pooling::PerPair] {
            let views = two_views(&s.img, &halves);
            let est = Smooth::new(&cam, views, s.origin, 16, 16, true, pooling);
            let at = step(&s.pose, &[0.03, -0.02, 0.01, 0.004, -0.003, 0.01]);
            let g = est.evaluate(&at, true).grad.unwrap();
            let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            for k in [1, 7, 32] {
                let parts = est.cluster_gradients(&at, k);
                assert_eq!(parts.len(), k);
                for a in 0..6 {
                    let sum: f64 = parts.iter().map(|p| p[a]).sum();
                    assert!(
                        (sum - g[a]).abs() <= 1e-9 * norm,
                        "{pooling} k={k} θ{a}: {sum} vs {}",
                        g[a]
                    );
                }
            }
            // The patches differ: the score is not spread evenly over the ground.
            let parts = est.cluster_gradients(&at, 8);
            assert!(parts.windows(2).any(|w| w[0] != w[1]));
            let by_view = est.view_gradients(&at);
            assert_eq!(by_view.len(), 2);
            for a in 0..6 {
                let sum = by_view[0][a] + by_view[1][a];
                assert!((sum - g[a]).abs() <= 1e-9 * norm, "{pooling} θ{a}");
            }
            // The patches' histograms sum to the views' and give the objective.
            let want = est.evaluate(&at, false);
            for k in [1, 7, 32] {
                let parts = est.cluster_histograms(&at, k);
                assert_eq!(parts.len(), k);
                assert!(parts.iter().all(|p| p.len() == 2 && p[0].len() == 16 * 16));
                let sum_of = |skip: Option<usize>| -> Vec<Vec<f64>> {
                    let mut sum = vec![vec![0.0; 16 * 16]; 2];
                    for (j, p) in parts.iter().enumerate() {
                        if Some(j) == skip {
                            continue;
                        }
                        for (a, b) in sum.iter_mut().zip(p) {
                            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                        }
                    }
                    sum
                };
                let all = sum_of(None);
                let mass: f64 = all.iter().flatten().sum();
                assert!(
                    (mass - want.valid).abs() <= 1e-9 * want.valid,
                    "{pooling} k={k}"
                );
                let v = est.value_of(&all);
                assert!(
                    (v - want.value).abs() <= 1e-12 * want.value.abs().max(1.0),
                    "{pooling} k={k}: {v} vs {}",
                    want.value
                );
                if k > 1 {
                    // Leaving a patch out changes the histogram, hence the objective.
                    assert_ne!(est.value_of(&sum_of(Some(0))), v, "{pooling} k={k}");
                }
            }
        }
    }

    /// With the start's Hessian the ascent ends where the plain one does, to a fraction of a
    /// Cramér–Rao σ, in fewer evaluations; a Hessian that is not negative definite leaves the
    /// plain ascent as it is; a tolerance on the Newton step left ends it sooner, that close.
    #[test]
    fn the_start_s_curvature_shortens_the_ascent_to_the_same_peak() {
        use crate::localize::refine::ascent::{ascend, ascend_with, AscentConfig};
        use crate::localize::refine::information::{information, HESSIAN_STEP};
        let cam = mei();
        let s = scene(&cam, 16);
        let views = vec![SmoothView {
            img: &s.img,
            pts: &s.pts,
        }];
        let est = Smooth::new(&cam, views, s.origin, 16, 16, true, Pooling::Joint);
        let cfg = AscentConfig::four_dof();
        let start = step(&s.pose, &[0.012, -0.009, 0.006, 0.0, 0.0, 0.0015]);
        let plain = ascend(&est, &start, &cfg);
        let h = est.hessian(&start, &cfg.free, &HESSIAN_STEP);
        let with = ascend_with(&est, &start, &cfg, Some(&h));
        assert!(
            ["gradient", "newton step"].contains(&with.stop),
            "{}",
            with.stop
        );
        assert!(
            with.evaluations < plain.evaluations,
            "{} vs {}",
            with.evaluations,
            plain.evaluations
        );
        // The two answers' distance in the information metric at the plain answer.
        let info = information(&est, &plain.pose, &cfg.free).expect("a basin");
        let d: Vec<f64> = [0, 1, 2, 5]
            .iter()
            .map(|&k| with.theta[k] - plain.theta[k])
            .collect();
        let cov = nalgebra::DMatrix::from_fn(4, 4, |i, j| info.matrix[i][j]);
        // θ's rz is radians, the covariance's yaw degrees.
        let v = nalgebra::DVector::from_fn(4, |i, _| if i == 3 { d[i].to_degrees() } else { d[i] });
        let m2 = (v.transpose() * cov.try_inverse().expect("invertible") * &v)[(0, 0)];
        assert!(m2 <= 1.0, "answers {m2:.3} Cramér–Rao σ² apart");
        // No basin in the given curvature: the plain ascent, bit for bit.
        let flat = [[0.0; 6]; 6];
        assert_eq!(ascend_with(&est, &start, &cfg, Some(&flat)), plain);
        // With `max_newton_step` it ends as soon as the Newton step left is within it: in
        // fewer evaluations than an ascent to the gradient's tolerance, and that close to its end.
        let far = step(&s.pose, &[0.03, -0.025, 0.012, 0.0, 0.0, 0.003]);
        let h_peak = est.hessian(&s.pose, &cfg.free, &HESSIAN_STEP);
        // The full ascent climbs on to the gradient's tolerance.
        let tight = AscentConfig {
            max_newton_decrement: 0.0,
            ..cfg
        };
        let full = ascend_with(&est, &far, &tight, Some(&h_peak));
        let tol = [0.004, 0.004, 0.004, 1e-4, 1e-4, 1e-4];
        let located = ascend_with(
            &est,
            &far,
            &AscentConfig {
                max_newton_step: tol,
                ..tight
            },
            Some(&h_peak),
        );
        assert_eq!(located.stop, "newton step");
        assert!(
            located.evaluations < full.evaluations,
            "{} vs {}",
            located.evaluations,
            full.evaluations
        );
        for k in [0, 1, 2, 5] {
            let d = (located.theta[k] - full.theta[k]).abs();
            assert!(
                d <= 2.0 * tol[k],
                "axis {k}: {d:.5} from the full ascent's end"
            );
        }
    }

    /// With five pairs or more the information carries the sandwich of one cluster per pair;
    /// with fewer, none.
    #[test]
    fn frame_clusters_need_five_pairs() {
        use crate::localize::refine::information::{information, FRAME_CLUSTERS_MIN};
        let cam = mei();
        let s = scene(&cam, 16);
        let free = [true, true, true, false, false, true];
        for k in [FRAME_CLUSTERS_MIN - 1, FRAME_CLUSTERS_MIN] {
            let m = s.pts.len();
            let parts: Vec<PreparedPoints> = (0..k)
                .map(|j| s.pts.range(j * m / k, (j + 1) * m / k))
                .collect();
            let views = parts
                .iter()
                .map(|pts| SmoothView { img: &s.img, pts })
                .collect();
            let est = Smooth::new(&cam, views, s.origin, 16, 16, true, Pooling::PerPair);
            let info = information(&est, &s.pose, &free).expect("a basin at the truth");
            match &info.frame_sigma {
                None => assert!(k < FRAME_CLUSTERS_MIN),
                Some(f) => {
                    assert!(k >= FRAME_CLUSTERS_MIN);
                    assert_eq!(f.len(), 4);
                    assert!(f.iter().all(|v| v.is_finite() && *v > 0.0), "{f:?}");
                    assert!(info.describe().contains("frame σ"));
                }
            }
        }
    }

    #[test]
    fn duplicated_points_shrink_the_bound_but_not_the_sandwich() {
        use crate::localize::refine::information::{information, SANDWICH_CLUSTERS};
        let cam = mei();
        let s = scene(&cam, 16);
        // Every point twice, side by side: the same patches, no new information.
        let mut twice = PreparedPoints::default();
        for i in 0..s.pts.len() {
            for _ in 0..2 {
                twice.x.push(s.pts.x[i]);
                twice.y.push(s.pts.y[i]);
                twice.z.push(s.pts.z[i]);
                twice.bin.push(s.pts.bin[i]);
            }
        }
        assert_eq!(s.pts.len() % SANDWICH_CLUSTERS, 0);
        let free = [true, true, true, false, false, true];
        let info_of = |pts: &PreparedPoints| {
            let views = vec![SmoothView { img: &s.img, pts }];
            let est = Smooth::new(&cam, views, s.origin, 16, 16, true, Pooling::Joint);
            information(&est, &s.pose, &free).expect("a basin at the truth")
        };
        let (one, two) = (info_of(&s.pts), info_of(&twice));
        for a in 0..one.axes.len() {
            let bound = two.sigma[a] / one.sigma[a];
            assert!(
                (bound - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-6,
                "{}: Cramér–Rao ratio {bound}",
                one.axes[a]
            );
            let sw = two.sandwich_sigma[a] / one.sandwich_sigma[a];
            assert!(
                (sw - 1.0).abs() < 1e-6,
                "{}: sandwich ratio {sw}",
                one.axes[a]
            );
            assert!(one.sandwich_sigma[a].is_finite() && one.sandwich_sigma[a] > 0.0);
        }
    }

    #[test]
    fn value_is_continuous_in_sub_pixel_shifts_and_peaks_at_the_truth() {
        let cam = mei();
        let s = scene(&cam, 16);
        let est = Smooth::new(
            &cam,
            vec![SmoothView {
                img: &s.img,
                pts: &s.pts,
            }],
            s.origin,
            16,
            16,
            true,
            Pooling::Joint,
        );
        // 1 mm steps (≈ a fifth of a pixel at the nadir, 5 m down): consecutive values differ
        // by a small fraction of the curve's range, never a jump.
        let vals: Vec<f64> = (-40..=40)
            .map(|i| {
                est.evaluate(
                    &step(&s.pose, &[0.001 * i as f64, 0.0, 0.0, 0.0, 0.0, 0.0]),
                    false,
                )
                .value
            })
            .collect();
        let range = vals.iter().cloned().fold(f64::MIN, f64::max)
            - vals.iter().cloned().fold(f64::MAX, f64::min);
        let max_jump = vals
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        assert!(range > 0.01, "{range}");
        assert!(max_jump < 0.08 * range, "{max_jump} of {range}");
        let best = vals
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, _)| i as i64 - 40)
            .unwrap();
        assert!(best.abs() <= 3, "peak {best} mm from the truth");
    }

    #[test]
    fn step_is_the_search_s_yaw_and_translation() {
        let p = CamFromMap::from_center_ypr(&Point3::new(1.0, 2.0, 6.0), 0.4, 0.1, -0.05);
        let a = step(&p, &[0.1, -0.2, 0.05, 0.0, 0.0, 0.02]);
        let b = crate::localize::mi::space::pose_at(
            &p,
            &[0.1, -0.2, 0.05, 0.02f64.to_degrees(), 0.0, 0.0],
        );
        assert!((a.translation - b.translation).norm() < 1e-12);
        assert!((a.rotation.matrix() - b.rotation.matrix()).norm() < 1e-12);
    }
}
