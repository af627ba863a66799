//! The MI evaluation kernel: project every point with one pose, sample the binned image, and
//! accumulate the joint histogram. This is the hot loop of the search.
//!
//! Speed design (measured in `benches/mi.rs`, figures in `docs/benchmarks.md` "MI kernel"):
//! - points are origin-shifted f32 in structure-of-arrays form ([`PreparedPoints`]), ordered along
//!   a Morton curve so that neighbouring points hit neighbouring pixels;
//! - the projection is the camera's exact formula specialised to f32 ([`FastCamera`]), written
//!   without branches (invalid points are *selected* onto a sentinel pixel), in chunks, so the
//!   compiler vectorises it, with fused multiply-adds where the CPU has them ([`BASELINE_FMA`]);
//! - the image is pre-binned ([`BinnedImage`], one u8 per pixel holding the gray bin, invalid
//!   pixels and the sentinel hold the histogram's invalid column), so a sample is one load;
//! - the histogram is u32 counts in four interleaved copies (breaking the store→load dependency of
//!   consecutive equal bins), 32×33×4×4 B = 17 KiB, so it stays in L1;
//! - on x86-64 a copy compiled for AVX2 + FMA is chosen at run time (8 lanes instead of SSE2's 4),
//!   on aarch64 the Mei projection is an explicit NEON copy; both bit-identical to the plain loop.
//!
//! [`accumulate_scalar`] is the straightforward f64 version through [`CameraModel`], kept as the
//! reference the fast kernel is tested against and as the benchmark's baseline.

// The chunk loops index several parallel SoA slices by the same i; that is what vectorises.
#![allow(clippy::needless_range_loop)]

use crate::camera::{Camera, CameraModel};
use crate::localize::mi::points::{GroundPoint, PreparedPoints};
use crate::localize::mi::JointHist;
use crate::pose::CamFromMap;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "aarch64")]
mod neon;
pub mod selftest;

#[cfg(target_arch = "x86_64")]
pub(crate) use avx2::has_avx2_fma;
#[cfg(target_arch = "x86_64")]
use avx2::*;
#[cfg(target_arch = "aarch64")]
use neon::project_chunk_mei_neon;

/// Points per chunk: the index buffer (1 KiB) stays in L1 between the two passes.
const CHUNK: usize = 256;
/// Interleaved histogram copies.
const SUB_HISTS: usize = 4;
/// Pixels beyond this column or row are treated as outside the image: it keeps every accepted
/// coordinate exactly representable in f32 and in range of the i32 conversion ([`pixel_index`]).
/// No real camera comes near it.
const MAX_SIDE: usize = 1 << 24;

/// A camera model specialised for the hot loop (f32, precomputed validity limits), optionally for
/// a 2^level downsampled image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FastCamera {
    /// OpenCV omnidir (Mei) model.
    Mei(MeiConsts),
    /// OpenCV fisheye (equidistant) model with atan2 (rays beyond 90°).
    Equidistant(EquidistantConsts),
}

/// The constants of a [`FastCamera::Mei`], as the projection loops take them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeiConsts {
    /// fx, fy, skew, cx, cy (scaled to the pyramid level).
    pub k: [f32; 5],
    /// ξ.
    pub xi: f32,
    /// k1, k2, p1, p2.
    pub d: [f32; 4],
    /// Smallest admissible sphere z: max of the model's one-to-one limit and cos(max θ).
    pub zmin: f32,
    /// Largest undistorted r² where the radial polynomial is monotonic.
    pub r2max: f32,
}

/// The constants of a [`FastCamera::Equidistant`], as the projection loops take them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EquidistantConsts {
    /// fx, fy, alpha, cx, cy (scaled to the pyramid level; alpha is dimensionless).
    pub k: [f32; 5],
    /// k1..k4.
    pub d: [f32; 4],
    /// Largest admissible θ.
    pub theta_max: f32,
}

impl FastCamera {
    /// Specialise `cam` for an image downsampled by 2^`level` (pixel centres: u_l = (u+½)/2^l − ½).
    pub fn new(cam: &Camera, level: u32) -> Self {
        let s = 1.0 / (1u64 << level) as f64;
        let c = |v: f64| ((v + 0.5) * s - 0.5) as f32;
        match cam {
            Camera::Mei(m) => {
                let one_to_one = if m.xi <= 1.0 { -m.xi } else { -1.0 / m.xi };
                let zmin = one_to_one.max(cam.max_theta().cos());
                let r2max = mei_max_r2_monotonic(m.k1, m.k2);
                FastCamera::Mei(MeiConsts {
                    k: [
                        (m.fx * s) as f32,
                        (m.fy * s) as f32,
                        (m.skew * s) as f32,
                        c(m.cx),
                        c(m.cy),
                    ],
                    xi: m.xi as f32,
                    d: [m.k1 as f32, m.k2 as f32, m.p1 as f32, m.p2 as f32],
                    zmin: zmin as f32,
                    r2max: r2max.min(f32::MAX as f64) as f32,
                })
            }
            Camera::Equidistant(e) => FastCamera::Equidistant(EquidistantConsts {
                k: [
                    (e.fx * s) as f32,
                    (e.fy * s) as f32,
                    e.alpha as f32,
                    c(e.cx),
                    c(e.cy),
                ],
                d: [e.k1 as f32, e.k2 as f32, e.k3 as f32, e.k4 as f32],
                theta_max: cam.max_theta() as f32,
            }),
        }
    }
}

/// Largest undistorted r² where the Mei radial term r(1 + k1 r² + k2 r⁴) still increases, i.e. the
/// smallest positive root s of 1 + 3 k1 s + 5 k2 s² (∞ if none) — the same limit
/// [`crate::camera::Mei`] applies.
fn mei_max_r2_monotonic(k1: f64, k2: f64) -> f64 {
    let (a, b, c) = (5.0 * k2, 3.0 * k1, 1.0);
    if a.abs() < 1e-300 {
        return if b < 0.0 { -c / b } else { f64::INFINITY };
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return f64::INFINITY;
    }
    let sq = disc.sqrt();
    let (r1, r2) = ((-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a));
    [r1.min(r2), r1.max(r2)]
        .into_iter()
        .find(|r| *r > 0.0)
        .unwrap_or(f64::INFINITY)
}

/// A pose in hot-loop form: `X_c = R·p + t` for origin-shifted points `p = X_w − origin`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseF32 {
    /// Row-major `R_cam_from_map`.
    pub r: [f32; 9],
    /// `R·(origin − c)`, computed in f64.
    pub t: [f32; 3],
}

impl PoseF32 {
    /// From a pose and the origin its points were shifted by.
    pub fn new(pose: &CamFromMap, origin: [f64; 3]) -> Self {
        let m = pose.rotation.matrix();
        let o = Point3::new(origin[0], origin[1], origin[2]);
        let t = pose.transform(&o);
        PoseF32 {
            r: [
                m[(0, 0)] as f32,
                m[(0, 1)] as f32,
                m[(0, 2)] as f32,
                m[(1, 0)] as f32,
                m[(1, 1)] as f32,
                m[(1, 2)] as f32,
                m[(2, 0)] as f32,
                m[(2, 1)] as f32,
                m[(2, 2)] as f32,
            ],
            t: [t.x as f32, t.y as f32, t.z as f32],
        }
    }
}

/// An image reduced to gray bins: `data[v·width + u]` is the bin of pixel (u, v), or `invalid`
/// outside the valid image circle; one extra trailing element (the sentinel) is `invalid` too and
/// receives every point that misses the image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BinnedImage {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// Bins, `width·height + 1` values.
    pub data: Vec<u8>,
}

impl BinnedImage {
    /// Bin `gray` (row-major, `width·height`) through `lut`; pixels whose `mask` is 0 get
    /// `invalid`.
    pub fn new(
        width: usize,
        height: usize,
        gray: &[u8],
        mask: &[u8],
        lut: &[u8; 256],
        invalid: u8,
    ) -> Self {
        // In parallel (each pixel on its own): 5 MP of serial work in every refinement's set-up.
        let mut data: Vec<u8> = Vec::with_capacity(gray.len().min(mask.len()) + 1);
        data.par_extend(gray.par_iter().zip(mask).map(|(&g, &m)| {
            if m != 0 {
                lut[g as usize]
            } else {
                invalid
            }
        }));
        data.push(invalid);
        BinnedImage {
            width,
            height,
            data,
        }
    }

    /// Index of the sentinel element.
    #[inline]
    pub(crate) fn sentinel(&self) -> usize {
        self.width * self.height
    }
}

/// One level of a gray image pyramid with its validity mask.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct GrayLevel {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// Gray values, row-major.
    pub gray: Vec<u8>,
    /// Validity (non-zero = valid).
    pub mask: Vec<u8>,
}

impl GrayLevel {
    /// Halve the resolution: each output pixel is the rounded mean of its valid 2×2 children and is
    /// valid if any child is (so a point valid at level 0 stays valid at coarse levels).
    pub(crate) fn downsample(&self) -> GrayLevel {
        let (w, h) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut gray = vec![0u8; w * h];
        let mut mask = vec![0u8; w * h];
        // Output rows in parallel (each reads only the input level).
        gray.par_chunks_mut(w.max(1))
            .zip(mask.par_chunks_mut(w.max(1)))
            .enumerate()
            .for_each(|(v, (grow, mrow))| {
                for u in 0..w {
                    let (mut sum, mut n) = (0u32, 0u32);
                    for (du, dv) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (x, y) = (2 * u + du, 2 * v + dv);
                        if x < self.width && y < self.height && self.mask[y * self.width + x] != 0 {
                            sum += self.gray[y * self.width + x] as u32;
                            n += 1;
                        }
                    }
                    if let Some(mean) = (sum + n / 2).checked_div(n) {
                        grow[u] = mean as u8;
                        mrow[u] = 255;
                    }
                }
            });
        GrayLevel {
            width: w,
            height: h,
            gray,
            mask,
        }
    }
}

/// Where a chunk's projections land: the image's size and its sentinel index.
#[derive(Debug, Clone, Copy)]
struct Raster {
    w: usize,
    h: usize,
    sentinel: u32,
}

/// Fast Mei projection of one point: its ½-shifted pixel position (truncation rounds it to the
/// nearest pixel centre) and whether it is in view and on the `wf`×`hf` raster.
#[inline(always)]
fn mei_uv<const FMA: bool>(
    x: f32,
    y: f32,
    z: f32,
    p: &PoseF32,
    m: MeiConsts,
    wf: f32,
    hf: f32,
) -> (f32, f32, bool) {
    let MeiConsts {
        k,
        xi,
        d,
        zmin,
        r2max,
    } = m;
    let r = p.r;
    // a·b + c, fused (one rounding) where the CPU has FMA; see [`BASELINE_FMA`]. With the
    // polynomials in Horner form that is 32 floating-point operations per point (61 term by
    // term, unfused). Fused, they are exact IEEE operations that the AVX2 and NEON copies
    // reproduce bit for bit by fusing the same pairs.
    let fma = |a: f32, b: f32, c: f32| if FMA { a.mul_add(b, c) } else { a * b + c };
    let cx = fma(r[0], x, fma(r[1], y, fma(r[2], z, p.t[0])));
    let cy = fma(r[3], x, fma(r[4], y, fma(r[5], z, p.t[1])));
    let cz = fma(r[6], x, fma(r[7], y, fma(r[8], z, p.t[2])));
    // Unit sphere then normalised plane, x_u = x_s / (z_s + ξ), with the sphere's 1/‖X‖ folded
    // into the plane's denominator: x_u = X / (Z + ξ‖X‖). One sqrt and one division per point
    // instead of a sqrt and two divisions (the projection's dominant cost); the sphere test
    // z_s > zmin becomes Z > zmin·‖X‖ (same set: ‖X‖ = 0 fails both).
    let n = fma(cx, cx, fma(cy, cy, cz * cz)).sqrt();
    let f = 1.0 / fma(xi, n, cz);
    let (xu, yu) = (cx * f, cy * f);
    let (xx, yy, xy) = (xu * xu, yu * yu, xu * yu);
    let r2 = xx + yy;
    // 1 + k1·r² + k2·r⁴, then the tangential terms 2p1·xy + p2·(r² + 2x²) and
    // p1·(r² + 2y²) + 2p2·xy.
    let radial = fma(fma(d[1], r2, d[0]), r2, 1.0);
    let xd = fma(xu, radial, fma(2.0 * d[2], xy, d[3] * fma(2.0, xx, r2)));
    let yd = fma(yu, radial, fma(2.0 * d[3], xy, d[2] * fma(2.0, yy, r2)));
    // Shifted by ½ so that truncation is rounding to the nearest pixel centre.
    let u = fma(k[0], xd, fma(k[2], yd, k[3] + 0.5));
    let v = fma(k[1], yd, k[4] + 0.5);
    let ok = cz > zmin * n && r2 < r2max && u >= 0.0 && u < wf && v >= 0.0 && v < hf;
    (u, v, ok)
}

/// Fast Mei projection of one chunk into pixel indices (sentinel when not visible).
#[inline(always)]
fn project_chunk_mei<const FMA: bool>(
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    p: &PoseF32,
    m: MeiConsts,
    t: Raster,
    out: &mut [u32],
) {
    let Raster { w, h, sentinel } = t;
    let (wf, hf) = (w.min(MAX_SIDE) as f32, h.min(MAX_SIDE) as f32);
    for i in 0..out.len().min(xs.len()).min(ys.len()).min(zs.len()) {
        let (u, v, ok) = mei_uv::<FMA>(xs[i], ys[i], zs[i], p, m, wf, hf);
        out[i] = pixel_index(ok, u, v, w, sentinel);
    }
}

/// Pixel index of the (½-shifted) position (u, v), or `sentinel` when `!ok`. `ok` must imply
/// 0 ≤ u < w and 0 ≤ v < h (the callers' range tests), so the truncating conversions are in range.
#[inline(always)]
fn pixel_index(ok: bool, u: f32, v: f32, w: usize, sentinel: u32) -> u32 {
    // Not-ok lanes (which may hold NaN or ±∞) are replaced by 0 first, so both conversions below
    // see values in [0, 2^24): the plain (non-saturating) i32 truncation is exact and vectorises
    // to one instruction, where `as u32` needs a saturation and NaN fix-up sequence per lane.
    let uc = if ok { u } else { 0.0 };
    let vc = if ok { v } else { 0.0 };
    // SAFETY: uc and vc are finite and in [0, 2^24) (see above; the callers clamp the side
    // lengths to MAX_SIDE), so they truncate to i32 without overflow.
    let (ui, vi) = unsafe { (uc.to_int_unchecked::<i32>(), vc.to_int_unchecked::<i32>()) };
    let idx = vi as u32 * w as u32 + ui as u32;
    if ok {
        idx
    } else {
        sentinel
    }
}

/// Fast branch-free atan on [0, 1] (odd minimax polynomial, |error| < 1e-5 rad ≈ 0.005 px at
/// f = 500 px — far below the nearest-pixel rounding of the sampler).
#[inline(always)]
fn atan01(a: f32) -> f32 {
    let s = a * a;
    a * (0.999_977_26
        + s * (-0.332_623_47
            + s * (0.193_543_46 + s * (-0.116_432_87 + s * (0.052_653_32 + s * -0.011_721_2)))))
}

/// Fast equidistant projection of one point, as [`mei_uv`].
#[inline(always)]
fn equidistant_uv(
    x: f32,
    y: f32,
    z: f32,
    p: &PoseF32,
    e: EquidistantConsts,
    wf: f32,
    hf: f32,
) -> (f32, f32, bool) {
    let EquidistantConsts { k, d, theta_max } = e;
    let r = p.r;
    const HALF_PI: f32 = std::f32::consts::FRAC_PI_2;
    const PI: f32 = std::f32::consts::PI;
    let cx = r[0] * x + r[1] * y + r[2] * z + p.t[0];
    let cy = r[3] * x + r[4] * y + r[5] * z + p.t[1];
    let cz = r[6] * x + r[7] * y + r[8] * z + p.t[2];
    let rho = (cx * cx + cy * cy).sqrt();
    let az = cz.abs();
    let (lo, hi) = if rho < az { (rho, az) } else { (az, rho) };
    let a = atan01(lo / hi.max(f32::MIN_POSITIVE));
    let a = if rho > az { HALF_PI - a } else { a };
    let theta = if cz < 0.0 { PI - a } else { a };
    let t2 = theta * theta;
    let thd = theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))));
    // θ_d/ρ → 1/z on the axis.
    let scale = if rho > 1e-7 * az { thd / rho } else { 1.0 / cz };
    let (xd, yd) = (cx * scale, cy * scale);
    let u = k[0] * (xd + k[2] * yd) + k[3] + 0.5;
    let v = k[1] * yd + k[4] + 0.5;
    let ok = theta <= theta_max && u >= 0.0 && u < wf && v >= 0.0 && v < hf;
    (u, v, ok)
}

/// Fast equidistant projection of one chunk into pixel indices (sentinel when not visible).
#[inline(always)]
fn project_chunk_equidistant(
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    p: &PoseF32,
    e: EquidistantConsts,
    t: Raster,
    out: &mut [u32],
) {
    let Raster { w, h, sentinel } = t;
    let (wf, hf) = (w.min(MAX_SIDE) as f32, h.min(MAX_SIDE) as f32);
    for i in 0..out.len().min(xs.len()).min(ys.len()).min(zs.len()) {
        let (u, v, ok) = equidistant_uv(xs[i], ys[i], zs[i], p, e, wf, hf);
        out[i] = pixel_index(ok, u, v, w, sentinel);
    }
}

/// Project a chunk of points with `cam` into pixel indices of `img` (sentinel when not visible).
/// `NEON`: on aarch64 the Mei projection runs the explicit NEON copy
/// ([`project_chunk_mei_neon`]; the equidistant model keeps the plain loop); elsewhere, and with
/// `false` (the reference), the plain loop, which the compiler vectorises for the target.
#[inline(always)]
fn project_chunk<const NEON: bool, const FMA: bool>(
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    out: &mut [u32],
) {
    let t = Raster {
        w: img.width,
        h: img.height,
        sentinel: img.sentinel() as u32,
    };
    match *cam {
        FastCamera::Mei(m) => {
            #[cfg(target_arch = "aarch64")]
            if NEON {
                project_chunk_mei_neon(xs, ys, zs, pose, m, t, out);
                return;
            }
            project_chunk_mei::<FMA>(xs, ys, zs, pose, m, t, out)
        }
        FastCamera::Equidistant(e) => project_chunk_equidistant(xs, ys, zs, pose, e, t, out),
    }
}

/// [`project_chunk`] of the points `a..b` of `pts` into `out` (length `b − a`).
#[inline(always)]
fn project_range<const NEON: bool, const FMA: bool>(
    pts: &PreparedPoints,
    a: usize,
    b: usize,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    out: &mut [u32],
) {
    project_chunk::<NEON, FMA>(
        &pts.x[a..b],
        &pts.y[a..b],
        &pts.z[a..b],
        pose,
        cam,
        img,
        out,
    );
}

/// Scratch memory of the kernel (reuse it across poses; one per thread).
#[derive(Debug, Clone)]
pub struct Scratch {
    idx: Vec<u32>,
    sub: Vec<u32>,
}

impl Default for Scratch {
    fn default() -> Self {
        Scratch {
            idx: vec![0; CHUNK],
            sub: Vec::new(),
        }
    }
}

/// The fast kernel: add the joint histogram of `pts` seen from `pose` to `hist` (which must have
/// as many rows as reflectivity bins and `cols` = the image's invalid value).
///
/// On x86-64 CPUs with AVX2 and FMA (detected at run time) a copy of the kernel compiled for them
/// runs (8-wide projection instead of SSE2's 4-wide). It performs the same IEEE operations in the
/// same order as [`accumulate_reference`] — the fused multiply-adds are explicit `mul_add`s, and
/// Rust never contracts `a·b + c` on its own — so the histogram is bit-identical to it (tested).
/// On aarch64 the Mei projection is the explicit NEON copy ([`project_chunk_mei_neon`]),
/// bit-identical too (`infraloc self-test` under qemu in CI). An x86-64 CPU without AVX2 and
/// FMA runs the baseline copy, which rounds the multiply-adds separately ([`BASELINE_FMA`]).
pub fn accumulate(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    hist: &mut JointHist,
    scratch: &mut Scratch,
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU supports the features the function is compiled for (checked above).
        unsafe { accumulate_avx2(pts, pose, cam, img, hist, scratch) };
        return;
    }
    // The target's baseline features (SSE2 on x86-64; NEON on aarch64, with the explicit copy).
    accumulate_impl::<true, BASELINE_FMA>(pts, pose, cam, img, hist, scratch);
}

/// [`accumulate`] without hand-picked SIMD: the plain loop for the target's baseline features
/// (SSE2 on x86-64; on aarch64 whatever NEON code the compiler makes of it), fusing the
/// multiply-adds exactly when the copy [`accumulate`] runs does (on x86-64 with FMA through libm's
/// `fmaf`, slowly: a check, not a path). The reference the fast copies must equal bit for bit
/// (tests, `infraloc self-test`).
pub(crate) fn accumulate_reference(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    hist: &mut JointHist,
    scratch: &mut Scratch,
) {
    if fused() {
        accumulate_impl::<false, true>(pts, pose, cam, img, hist, scratch);
    } else {
        accumulate_impl::<false, false>(pts, pose, cam, img, hist, scratch);
    }
}

/// Whether the baseline copies (no run-time selected features) fuse the projection's
/// multiply-adds. Every aarch64 CPU has FMA. An x86-64 CPU without FMA (before Haswell and
/// Piledriver; Atom-class cores up to Tremont) would have to emulate each fused operation, ~9×
/// slower (measured: an exact emulation through f64 with round-to-odd), so there the baseline
/// copies round the product and the sum separately: the same formula, fast, but its poses agree
/// with an FMA machine's to the projection's rounding, not bit for bit (docs/benchmarks.md).
const BASELINE_FMA: bool = cfg!(target_arch = "aarch64");

/// Whether the kernel that [`accumulate`] dispatches to on this CPU fuses the multiply-adds: the
/// reference loop must do the same to be its bit-for-bit check.
fn fused() -> bool {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        return true;
    }
    BASELINE_FMA
}

/// The kernel's body, inlined into each feature-specific copy (and into [`accumulate`] itself for
/// the baseline features).
#[inline(always)]
fn accumulate_impl<const NEON: bool, const FMA: bool>(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    hist: &mut JointHist,
    scratch: &mut Scratch,
) {
    let size = hist.counts.len();
    let stride = hist.stride();
    scratch.sub.clear();
    scratch.sub.resize(SUB_HISTS * size, 0);
    let (sub, idx) = (&mut scratch.sub, &mut scratch.idx);
    let data = &img.data;
    let n = pts.len();
    let mut start = 0;
    while start < n {
        let end = (start + CHUNK).min(n);
        let len = end - start;
        project_range::<NEON, FMA>(pts, start, end, pose, cam, img, &mut idx[..len]);
        let bins = &pts.bin[start..end];
        let mut quads = idx[..len].chunks_exact(SUB_HISTS);
        let mut bquads = bins.chunks_exact(SUB_HISTS);
        for (q, b) in (&mut quads).zip(&mut bquads) {
            for j in 0..SUB_HISTS {
                let g = data[q[j] as usize] as usize;
                sub[j * size + b[j] as usize * stride + g] += 1;
            }
        }
        for (&i, &b) in quads.remainder().iter().zip(bquads.remainder()) {
            let g = data[i as usize] as usize;
            sub[b as usize * stride + g] += 1;
        }
        start = end;
    }
    for (c, out) in hist.counts.iter_mut().enumerate() {
        *out += (0..SUB_HISTS).map(|j| sub[j * size + c]).sum::<u32>();
    }
}

/// Visibility of each point from `pose` (lands on a valid pixel of `img`).
///
/// Dispatched like [`accumulate`] (AVX2 + FMA copy where the CPU has them; same results).
pub(crate) fn visible(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    invalid: u8,
    out: &mut [bool],
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU supports the features the function is compiled for (checked above).
        unsafe { visible_avx2(pts, pose, cam, img, invalid, out) };
        return;
    }
    visible_impl::<true, BASELINE_FMA>(pts, pose, cam, img, invalid, out);
}

/// The body of [`visible`].
#[inline(always)]
fn visible_impl<const NEON: bool, const FMA: bool>(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    invalid: u8,
    out: &mut [bool],
) {
    let mut idx = vec![0u32; CHUNK];
    let n = pts.len().min(out.len());
    let mut start = 0;
    while start < n {
        let end = (start + CHUNK).min(n);
        let len = end - start;
        project_range::<NEON, FMA>(pts, start, end, pose, cam, img, &mut idx[..len]);
        for (o, &i) in out[start..end].iter_mut().zip(&idx[..len]) {
            *o = img.data[i as usize] != invalid;
        }
        start = end;
    }
}

/// Visibility from *every* pose of `poses`: `keep[i]` is AND-ed with "point `first + i` lands on
/// a valid pixel of `img`" for each pose (so a point stays `true` only when all poses see it).
///
/// The same test as [`visible`], pose by pose, but chunk-major: each chunk of points is projected
/// with all the poses while it sits in L1, and the poses of a small box project it into one small
/// image area, so the image reads hit the cache too; a chunk whose points are all out stops early.
/// AND is order-free, so the flags equal those of [`visible`] AND-ed over the poses.
pub(crate) fn visible_from_all(
    pts: &PreparedPoints,
    first: usize,
    poses: &[PoseF32],
    cam: &FastCamera,
    img: &BinnedImage,
    invalid: u8,
    keep: &mut [bool],
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU supports the features the function is compiled for (checked above).
        unsafe { visible_from_all_avx2(pts, first, poses, cam, img, invalid, keep) };
        return;
    }
    visible_from_all_impl::<true, BASELINE_FMA>(pts, first, poses, cam, img, invalid, keep);
}

/// The body of [`visible_from_all`].
#[inline(always)]
fn visible_from_all_impl<const NEON: bool, const FMA: bool>(
    pts: &PreparedPoints,
    first: usize,
    poses: &[PoseF32],
    cam: &FastCamera,
    img: &BinnedImage,
    invalid: u8,
    keep: &mut [bool],
) {
    let mut idx = [0u32; CHUNK];
    let n = pts.len().saturating_sub(first).min(keep.len());
    let mut start = 0;
    while start < n {
        let end = (start + CHUNK).min(n);
        let len = end - start;
        let (a, b) = (first + start, first + end);
        let k = &mut keep[start..end];
        for pose in poses {
            project_range::<NEON, FMA>(pts, a, b, pose, cam, img, &mut idx[..len]);
            let mut any = false;
            for (o, &i) in k.iter_mut().zip(&idx[..len]) {
                *o &= img.data[i as usize] != invalid;
                any |= *o;
            }
            if !any {
                break;
            }
        }
        start = end;
    }
}

/// A search box as the sure-visibility test sees it ([`surely_visible_block`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct BoxView<'a> {
    /// The box's centre pose.
    pub center: PoseF32,
    /// Its axis extremes, in pairs: − and + of one axis.
    pub extremes: &'a [PoseF32],
    /// The camera.
    pub cam: FastCamera,
    /// Chessboard distance map of the valid pixels (0 on an invalid one), `width` wide.
    pub dist: &'a [u16],
    /// The image width.
    pub width: usize,
}

/// For the points `first..first + sure.len()` of `pts`: whether every pose of the box `b` surely
/// sees the point on a valid pixel: its pixel at the centre must lie farther from any invalid
/// pixel than 1.5 × the sum over the axes of the farther of its two extremes' pixel moves, plus
/// 4 px (the margin is the caller's to justify: `search::surely_visible`). A point an extreme
/// loses is never sure. The kernel's own projection, so the test sees the pixels the lattice
/// test will.
///
/// Dispatched like [`accumulate`].
pub(crate) fn surely_visible_block(
    pts: &PreparedPoints,
    first: usize,
    b: &BoxView<'_>,
    sure: &mut [bool],
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU supports the features the function is compiled for (checked above).
        unsafe { surely_visible_block_avx2(pts, first, b, sure) };
        return;
    }
    surely_visible_block_impl::<BASELINE_FMA>(pts, first, b, sure);
}

/// Project the points (`xs`, `ys`, `zs`: origin-shifted as [`PoseF32`] expects) with the kernel's
/// own projection onto a `width` × `height` raster: each point's pixel position (pixel centres
/// at integers, as [`CameraModel::project`] gives them) and whether it is in view and on the
/// raster (`u, v ∈ [−½, size − ½)`). For loops that sample the image themselves (the
/// initializer's LiDAR verifier).
///
/// Dispatched like [`accumulate`].
pub(crate) fn project_points(
    (xs, ys, zs): (&[f32], &[f32], &[f32]),
    pose: &PoseF32,
    cam: &FastCamera,
    (width, height): (usize, usize),
    (us, vs, oks): (&mut [f32], &mut [f32], &mut [bool]),
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU supports the features the function is compiled for (checked above).
        unsafe { project_points_avx2((xs, ys, zs), pose, cam, (width, height), (us, vs, oks)) };
        return;
    }
    project_points_impl::<BASELINE_FMA>((xs, ys, zs), pose, cam, (width, height), (us, vs, oks));
}

/// The body of [`project_points`].
#[inline(always)]
fn project_points_impl<const FMA: bool>(
    (xs, ys, zs): (&[f32], &[f32], &[f32]),
    pose: &PoseF32,
    cam: &FastCamera,
    (width, height): (usize, usize),
    (us, vs, oks): (&mut [f32], &mut [f32], &mut [bool]),
) {
    let raster = (width.min(MAX_SIDE) as f32, height.min(MAX_SIDE) as f32);
    uv_chunk::<FMA>(
        xs,
        ys,
        zs,
        pose,
        cam,
        raster,
        (&mut *us, &mut *vs, &mut *oks),
    );
    // The projection's ½ shift (truncation = rounding to the nearest centre) taken back.
    for (u, v) in us.iter_mut().zip(vs.iter_mut()) {
        *u -= 0.5;
        *v -= 0.5;
    }
}

/// Pixel positions and in-view flags of a chunk of points (see [`mei_uv`]).
#[inline(always)]
fn uv_chunk<const FMA: bool>(
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    pose: &PoseF32,
    cam: &FastCamera,
    (wf, hf): (f32, f32),
    (us, vs, oks): (&mut [f32], &mut [f32], &mut [bool]),
) {
    let n = xs
        .len()
        .min(ys.len())
        .min(zs.len())
        .min(us.len())
        .min(vs.len())
        .min(oks.len());
    match *cam {
        FastCamera::Mei(m) => {
            for i in 0..n {
                (us[i], vs[i], oks[i]) = mei_uv::<FMA>(xs[i], ys[i], zs[i], pose, m, wf, hf);
            }
        }
        FastCamera::Equidistant(e) => {
            for i in 0..n {
                (us[i], vs[i], oks[i]) = equidistant_uv(xs[i], ys[i], zs[i], pose, e, wf, hf);
            }
        }
    }
}

/// The body of [`surely_visible_block`].
#[inline(always)]
fn surely_visible_block_impl<const FMA: bool>(
    pts: &PreparedPoints,
    first: usize,
    b: &BoxView<'_>,
    sure: &mut [bool],
) {
    let BoxView {
        ref center,
        extremes,
        ref cam,
        dist,
        width,
    } = *b;
    let height = dist.len() / width.max(1);
    let raster = (width.min(MAX_SIDE) as f32, height.min(MAX_SIDE) as f32);
    let (mut u0, mut v0, mut ok0) = ([0f32; CHUNK], [0f32; CHUNK], [false; CHUNK]);
    let (mut u1, mut v1, mut ok1) = ([0f32; CHUNK], [0f32; CHUNK], [false; CHUNK]);
    let (mut moved, mut far) = ([0f32; CHUNK], [0f32; CHUNK]);
    let n = pts.len().saturating_sub(first).min(sure.len());
    let mut start = 0;
    while start < n {
        let end = (start + CHUNK).min(n);
        let len = end - start;
        let (a, b) = (first + start, first + end);
        let (xs, ys, zs) = (&pts.x[a..b], &pts.y[a..b], &pts.z[a..b]);
        uv_chunk::<FMA>(
            xs,
            ys,
            zs,
            center,
            cam,
            raster,
            (&mut u0[..len], &mut v0[..len], &mut ok0[..len]),
        );
        moved[..len].fill(0.0);
        for pair in extremes.chunks(2) {
            far[..len].fill(0.0);
            for e in pair {
                uv_chunk::<FMA>(
                    xs,
                    ys,
                    zs,
                    e,
                    cam,
                    raster,
                    (&mut u1[..len], &mut v1[..len], &mut ok1[..len]),
                );
                for i in 0..len {
                    let (du, dv) = (u1[i] - u0[i], v1[i] - v0[i]);
                    let d = (du * du + dv * dv).sqrt();
                    far[i] = if ok1[i] { far[i].max(d) } else { f32::INFINITY };
                }
            }
            for i in 0..len {
                moved[i] += far[i];
            }
        }
        for i in 0..len {
            // In-raster when ok, so the index is in `dist`; elsewhere index 0, discarded below.
            let at = pixel_index(ok0[i], u0[i], v0[i], width, 0) as usize;
            let d = dist.get(at).copied().unwrap_or(0) as f32;
            sure[start + i] = ok0[i] && d > 1.5 * moved[i] + 4.0;
        }
        start = end;
    }
}

/// Reference kernel (the benchmark baseline): f64 through [`CameraModel::project_visible`],
/// nearest pixel, validity `mask`, bins through the two LUTs. Same histogram layout as
/// [`accumulate`].
#[allow(clippy::too_many_arguments)]
pub fn accumulate_scalar(
    points: &[GroundPoint],
    pose: &CamFromMap,
    cam: &dyn CameraModel,
    gray: &[u8],
    mask: &[u8],
    lut_reflectivity: &[u8; 256],
    lut_gray: &[u8; 256],
    hist: &mut JointHist,
) {
    let w = cam.width() as usize;
    let stride = hist.stride();
    let inv = hist.invalid_col();
    for p in points {
        let pc: Vector3<f64> = pose.transform(&Point3::new(p.x, p.y, p.z)).coords;
        let row = lut_reflectivity[p.reflectivity as usize] as usize;
        let col = match cam.project_visible(&pc) {
            Ok(px) => {
                let (u, v) = ((px.x + 0.5).floor() as usize, (px.y + 0.5).floor() as usize);
                let i = v * w + u;
                if i < mask.len() && mask[i] != 0 {
                    lut_gray[gray[i] as usize] as usize
                } else {
                    inv
                }
            }
            Err(_) => inv,
        };
        hist.counts[row * stride + col] += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::selftest::*;
    use super::*;
    use crate::camera::{Equidistant, Mei};
    use crate::localize::mi::{bin_lut, Binning};
    use crate::localize::synth::{ground_points, Texture};

    fn check(cam: Camera) {
        let tex = Texture::new(9);
        let c = Point3::new(10.0, 20.0, 5.0);
        let pose = CamFromMap::from_center_ypr(&c, 0.7, 0.02, -0.03);
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let mask = cam.valid_mask();
        let gray: Vec<u8> = (0..w * h).map(|i| ((i * 7919) % 251) as u8).collect();
        let lut = bin_lut(Binning::Uniform, 16, &[0; 256]);
        // Points out to 40 m: past the horizon of the 185° lens, so the FOV limit is exercised.
        let mut pts = ground_points(&tex, (10.0, 20.0), 40.0, 0.4, 0.0, 3.0, 1);
        // Every 5th point above the camera (θ > 90°): rays near and beyond the 92.5° limit.
        for p in pts.iter_mut().step_by(5) {
            p.z = 5.6;
        }
        let origin = [c.x + 0.3, c.y - 0.2, c.z];
        let prepared = PreparedPoints::new(&pts, origin, &lut);
        let img = BinnedImage::new(w, h, &gray, &mask, &lut, 16);
        type Kernel =
            fn(&PreparedPoints, &PoseF32, &FastCamera, &BinnedImage, &mut JointHist, &mut Scratch);
        let hist_of = |kernel: Kernel| {
            let mut h = JointHist::new(16, 16);
            let p = PoseF32::new(&pose, origin);
            kernel(
                &prepared,
                &p,
                &FastCamera::new(&cam, 0),
                &img,
                &mut h,
                &mut Scratch::default(),
            );
            h
        };
        let fast = hist_of(accumulate);
        // The dispatched copy (AVX2 where available) and the baseline copy agree to the bit.
        let generic = hist_of(accumulate_reference);
        assert_eq!(fast, generic);
        let mut slow = JointHist::new(16, 16);
        accumulate_scalar(&pts, &pose, &cam, &gray, &mask, &lut, &lut, &mut slow);
        let n = pts.len() as u64;
        assert_eq!(fast.valid_count() + fast.invalid_count(), n);
        eprintln!(
            "valid {} invalid {}",
            slow.valid_count(),
            slow.invalid_count()
        );
        assert!(slow.valid_count() > n / 4 && slow.invalid_count() > n / 20);
        // How many counts two histograms place differently.
        let moved = |a: &JointHist, b: &JointHist| -> u64 {
            a.counts
                .iter()
                .zip(&b.counts)
                .map(|(&x, &y)| (x as i64 - y as i64).unsigned_abs())
                .sum()
        };
        // f32 vs f64 may round a point to the neighbouring pixel at pixel borders; allow 0.5 %.
        let diff = moved(&fast, &slow);
        assert!(diff * 200 <= n, "{diff} of {n} differ");
        // The baseline copy of an x86-64 CPU without FMA rounds each product and sum separately:
        // other bits, but the same pixel for all but a few points at pixel borders.
        let unfused = hist_of(accumulate_impl::<false, false>);
        let diff = moved(&fast, &unfused);
        eprintln!("unfused: {diff} of {n} counts moved");
        assert!(diff * 2000 <= n, "unfused: {diff} of {n} differ");
        // Visibility agrees with the histogram's valid count.
        let mut vis = vec![false; prepared.len()];
        visible(
            &prepared,
            &PoseF32::new(&pose, origin),
            &FastCamera::new(&cam, 0),
            &img,
            16,
            &mut vis,
        );
        assert_eq!(
            vis.iter().filter(|&&v| v).count() as u64,
            fast.valid_count()
        );
        // All-poses visibility (the fixed set's test) = `visible` AND-ed pose by pose, whatever
        // the block split, in both copies.
        let fc = FastCamera::new(&cam, 0);
        let poses: Vec<PoseF32> = (0..7)
            .map(|j| {
                let d = j as f64 - 3.0;
                let c = Point3::new(10.0 + 0.3 * d, 20.0 - 0.2 * d, 5.0 + 0.1 * d);
                PoseF32::new(
                    &CamFromMap::from_center_ypr(&c, 0.7 + 0.01 * d, 0.02, -0.03 - 0.02 * d),
                    origin,
                )
            })
            .collect();
        let mut want = vec![true; prepared.len()];
        for p in &poses {
            visible(&prepared, p, &fc, &img, 16, &mut vis);
            want.iter_mut().zip(&vis).for_each(|(w, &v)| *w &= v);
        }
        assert!(want.iter().any(|&v| v) && want.iter().any(|&v| !v));
        type VisibleFromAll =
            fn(&PreparedPoints, usize, &[PoseF32], &FastCamera, &BinnedImage, u8, &mut [bool]);
        let reference: VisibleFromAll = if fused() {
            visible_from_all_impl::<false, true>
        } else {
            visible_from_all_impl::<false, false>
        };
        for block in [prepared.len(), 1000, 300] {
            let mut got = vec![true; prepared.len()];
            let mut generic = vec![true; prepared.len()];
            for (b, (g, q)) in got
                .chunks_mut(block)
                .zip(generic.chunks_mut(block))
                .enumerate()
            {
                visible_from_all(&prepared, b * block, &poses, &fc, &img, 16, g);
                reference(&prepared, b * block, &poses, &fc, &img, 16, q);
            }
            assert_eq!(got, want, "block {block}");
            assert_eq!(generic, want, "block {block}");
        }
    }

    #[test]
    fn fast_kernel_matches_scalar_mei() {
        check(Camera::Mei(Mei {
            width: 400,
            height: 380,
            fx: 230.0,
            fy: 231.0,
            cx: 201.0,
            cy: 188.0,
            skew: 0.3,
            xi: 1.1,
            k1: -0.05,
            k2: 0.01,
            p1: 3e-4,
            p2: -2e-4,
            fov_deg: Some(185.0),
        }));
    }

    #[test]
    fn fast_kernel_matches_scalar_equidistant() {
        check(Camera::Equidistant(Equidistant {
            width: 400,
            height: 380,
            fx: 125.0,
            fy: 125.5,
            cx: 199.0,
            cy: 190.0,
            alpha: 0.001,
            k1: 0.01,
            k2: -0.002,
            k3: 0.0003,
            k4: 0.0,
            fov_deg: Some(185.0),
            cache: Default::default(),
        }));
    }

    /// The dispatched copy of the sure-visibility test (AVX2 on most x86-64 CPUs) flags the same
    /// points as the plain loop, for both models, a chunk-unaligned block and a centre pose with
    /// each axis' extremes.
    #[test]
    fn dispatched_sure_test_matches_the_plain_loop() {
        let equidistant = test_camera_equidistant((2448, 2048), 620.0, (1219.8, 1022.1));
        for cam in [test_camera_mei(), equidistant] {
            let (pts, _, origin) = test_scene(&cam);
            let fc = FastCamera::new(&cam, 0);
            let (w, h) = (cam.width() as usize, cam.height() as usize);
            // A distance map that grows towards the centre, as the valid circle's does.
            let dist: Vec<u16> = (0..w * h)
                .map(|i| {
                    let (u, v) = ((i % w) as i64, (i / w) as i64);
                    u.min(v).min(w as i64 - 1 - u).min(h as i64 - 1 - v) as u16
                })
                .collect();
            let at = |dx: f64, dy: f64, dz: f64, dyaw: f64| {
                let c = Point3::new(10.0 + dx, 20.0 + dy, 6.0 + dz);
                PoseF32::new(
                    &CamFromMap::from_center_ypr(&c, 0.3 + dyaw, 0.02, -0.01),
                    origin,
                )
            };
            let center = at(0.0, 0.0, 0.0, 0.0);
            // Pairs (−, +) along x, y, z and yaw.
            let extremes: Vec<PoseF32> = [-1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0]
                .into_iter()
                .enumerate()
                .map(|(i, s)| {
                    let mut o = [0.0; 4];
                    o[i / 2] = s * if i < 6 { 0.05 } else { 0.005 };
                    at(o[0], o[1], o[2], o[3])
                })
                .collect();
            let first = 77;
            let n = pts.len() - first - 5;
            let mut fast = vec![false; n];
            let mut plain = vec![true; n];
            let b = BoxView {
                center,
                extremes: &extremes,
                cam: fc,
                dist: &dist,
                width: w,
            };
            surely_visible_block(&pts, first, &b, &mut fast);
            if fused() {
                surely_visible_block_impl::<true>(&pts, first, &b, &mut plain);
            } else {
                surely_visible_block_impl::<false>(&pts, first, &b, &mut plain);
            }
            let sure = fast.iter().filter(|&&s| s).count();
            assert!(sure > n / 10 && sure < n, "{sure} of {n} sure");
            assert_eq!(fast, plain, "{cam:?}");
        }
    }

    #[test]
    fn self_test_passes_on_this_cpu() {
        let r = self_test(6).unwrap();
        assert_eq!(r.path, kernel_path());
        assert!(r.points > 50_000);
    }

    #[test]
    fn pyramid_keeps_validity() {
        let g = GrayLevel {
            width: 3,
            height: 2,
            gray: vec![10, 20, 30, 40, 50, 60],
            mask: vec![255, 0, 255, 0, 0, 0],
        };
        let d = g.downsample();
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.gray, vec![10, 30]);
        assert_eq!(d.mask, vec![255, 255]);
    }
}
