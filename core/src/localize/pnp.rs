//! Pose from 2D–3D correspondences on *bearing vectors*: works over the whole fisheye field (rays
//! beyond 90° included) because nothing is undistorted to a pinhole plane.
//!
//! Minimal solver: Grunert's P3P (as reviewed by Haralick et al. 1991, the seed's reference), real
//! roots by isolation; RANSAC with an injected seeded RNG scores hypotheses by pixel reprojection
//! error; Levenberg–Marquardt then polishes the inliers' reprojection error.

use super::poly::real_roots;
use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::pose::CamFromMap;
use crate::stage::StageName;
use nalgebra::{DMatrix, DVector, Matrix3, Point2, Point3, Rotation3, Vector3};
use rand::Rng;

/// One correspondence: a fisheye pixel and the map point it shows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// Observed pixel.
    pub pixel: Point2<f64>,
    /// Map point (map frame; the solver re-centres internally for conditioning).
    pub world: Point3<f64>,
}

/// RANSAC and refinement settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpParams {
    /// Inlier threshold on reprojection error, pixels.
    pub threshold_px: f64,
    /// Upper bound on RANSAC iterations.
    pub max_iterations: usize,
    /// Stop when the probability of having drawn an all-inlier sample reaches this.
    pub confidence: f64,
    /// Fewer inliers than this is a failure.
    pub min_inliers: usize,
    /// Levenberg–Marquardt iterations on the inliers.
    pub lm_iterations: usize,
}

impl Default for PnpParams {
    fn default() -> Self {
        PnpParams {
            threshold_px: 4.0,
            max_iterations: 5000,
            confidence: 0.9999,
            min_inliers: 12,
            lm_iterations: 50,
        }
    }
}

/// Result of [`solve_pnp_ransac`].
#[derive(Debug, Clone)]
pub(crate) struct PnpResult {
    /// World→camera pose.
    pub pose: CamFromMap,
    /// Indices of the inlier correspondences.
    pub inliers: Vec<usize>,
    /// RMS reprojection error over the inliers after refinement, pixels.
    pub rms_px: f64,
    /// The pose's tilt σ, degrees ([`tilt_sigma_deg`]); NaN when it cannot be had.
    pub tilt_sigma_deg: f64,
    /// The pose's covariance over its offsets ([`pose_covariance`]); `None` when it cannot be
    /// had.
    pub covariance: Option<PoseCovariance>,
}

/// Grunert's P3P: up to four poses mapping the three world points onto the three bearings.
pub(crate) fn p3p(f: [Vector3<f64>; 3], x: [Point3<f64>; 3]) -> Vec<CamFromMap> {
    let f = f.map(|v| v.normalize());
    let a2 = (x[1] - x[2]).norm_squared();
    let b2 = (x[0] - x[2]).norm_squared();
    let c2 = (x[0] - x[1]).norm_squared();
    if a2 < 1e-12 || b2 < 1e-12 || c2 < 1e-12 {
        return Vec::new();
    }
    let ca = f[1].dot(&f[2]);
    let cb = f[0].dot(&f[2]);
    let cg = f[0].dot(&f[1]);
    let k1 = (a2 - c2) / b2;
    let k2 = (a2 + c2) / b2;
    let a4 = (k1 - 1.0).powi(2) - 4.0 * c2 / b2 * ca * ca;
    let a3 = 4.0 * (k1 * (1.0 - k1) * cb - (1.0 - k2) * ca * cg + 2.0 * c2 / b2 * ca * ca * cb);
    let a2c = 2.0
        * (k1 * k1 - 1.0 + 2.0 * k1 * k1 * cb * cb + 2.0 * (b2 - c2) / b2 * ca * ca
            - 4.0 * k2 * ca * cb * cg
            + 2.0 * (b2 - a2) / b2 * cg * cg);
    let a1 = 4.0 * (-k1 * (1.0 + k1) * cb + 2.0 * a2 / b2 * cg * cg * cb - (1.0 - k2) * ca * cg);
    let a0 = (1.0 + k1).powi(2) - 4.0 * a2 / b2 * cg * cg;
    let mut out = Vec::new();
    for v in real_roots(&[a0, a1, a2c, a3, a4]) {
        let den = 2.0 * (cg - v * ca);
        if den.abs() < 1e-12 {
            continue;
        }
        let u = ((k1 - 1.0) * v * v - 2.0 * k1 * cb * v + 1.0 + k1) / den;
        let q = 1.0 + v * v - 2.0 * v * cb;
        if q <= 0.0 || u <= 0.0 || v <= 0.0 {
            continue;
        }
        let s1 = (b2 / q).sqrt();
        let p = [f[0] * s1, f[1] * (u * s1), f[2] * (v * s1)];
        if let Some(pose) = align(&x, &p) {
            out.push(pose);
        }
    }
    out
}

/// Rigid transform with `p_i = R·x_i + t` (Kabsch/Horn by SVD).
fn align(x: &[Point3<f64>], p: &[Vector3<f64>]) -> Option<CamFromMap> {
    let n = x.len() as f64;
    let cx = x.iter().fold(Vector3::zeros(), |a, v| a + v.coords) / n;
    let cp = p.iter().fold(Vector3::zeros(), |a, v| a + v) / n;
    let mut h = Matrix3::zeros();
    for (xi, pi) in x.iter().zip(p) {
        h += (pi - cp) * (xi.coords - cx).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * vt;
    if !r.iter().all(|v| v.is_finite()) {
        return None;
    }
    let rot = Rotation3::from_matrix_unchecked(r);
    Some(CamFromMap::new(rot, cp - rot * cx))
}

/// Squared reprojection error of one correspondence, `None` if it does not project.
fn reproj2(cam: &dyn CameraModel, pose: &CamFromMap, c: &Correspondence) -> Option<f64> {
    let pc = pose.transform(&c.world).coords;
    cam.project(&pc)
        .ok()
        .map(|px| (px - c.pixel).norm_squared())
}

/// RANSAC P3P on bearings + LM refinement. World points are re-centred internally.
pub(crate) fn solve_pnp_ransac<R: Rng>(
    cam: &dyn CameraModel,
    corr: &[Correspondence],
    params: &PnpParams,
    rng: &mut R,
) -> Result<PnpResult> {
    if corr.len() < params.min_inliers.max(4) {
        return Err(Error::stage(
            StageName::Pnp,
            format!(
                "{} correspondences < {} required",
                corr.len(),
                params.min_inliers.max(4)
            ),
        ));
    }
    // Re-centre: UTM-sized coordinates would cost P3P and LM most of their precision.
    let origin = corr
        .iter()
        .fold(Vector3::zeros(), |a, c| a + c.world.coords)
        / corr.len() as f64;
    let local: Vec<Correspondence> = corr
        .iter()
        .map(|c| Correspondence {
            pixel: c.pixel,
            world: c.world - origin,
        })
        .collect();
    let bearings: Vec<Option<Vector3<f64>>> = local
        .iter()
        .map(|c| cam.unproject(&c.pixel).ok().map(|b| b.into_inner()))
        .collect();
    let usable: Vec<usize> = (0..local.len())
        .filter(|&i| bearings[i].is_some())
        .collect();
    if usable.len() < 4 {
        return Err(Error::stage(
            StageName::Pnp,
            format!("{} unprojectable-free correspondences < 4", usable.len()),
        ));
    }
    let thr2 = params.threshold_px * params.threshold_px;
    let mut best: Option<(usize, f64, CamFromMap)> = None;
    let mut needed = params.max_iterations;
    let mut it = 0;
    while it < needed.min(params.max_iterations) {
        it += 1;
        let mut idx = [0usize; 3];
        for k in 0..3 {
            loop {
                let c = usable[rng.random_range(0..usable.len())];
                if !idx[..k].contains(&c) {
                    idx[k] = c;
                    break;
                }
            }
        }
        let f = idx.map(|i| bearings[i].unwrap_or_else(Vector3::z));
        let x = idx.map(|i| local[i].world);
        for pose in p3p(f, x) {
            let mut count = 0;
            let mut cost = 0.0;
            for c in &local {
                match reproj2(cam, &pose, c) {
                    Some(e) if e < thr2 => {
                        count += 1;
                        cost += e;
                    }
                    _ => cost += thr2,
                }
            }
            // MSAC-style tie-break: more inliers first, then lower truncated cost.
            let better = match &best {
                None => true,
                Some((n, bc, _)) => count > *n || (count == *n && cost < *bc),
            };
            if better {
                best = Some((count, cost, pose));
                let w = count as f64 / local.len() as f64;
                let p_fail = 1.0 - w.powi(3);
                if p_fail <= 1e-12 {
                    needed = it;
                } else {
                    let n = ((1.0 - params.confidence).ln() / p_fail.ln()).ceil();
                    needed = if n.is_finite() {
                        n as usize
                    } else {
                        params.max_iterations
                    };
                }
            }
        }
    }
    let (_, _, mut pose) = best.ok_or_else(|| Error::stage(StageName::Pnp, "no P3P hypothesis"))?;
    // Refine, re-select inliers, refine again: the first LM often recruits more inliers.
    for _ in 0..3 {
        let inliers: Vec<usize> = (0..local.len())
            .filter(|&i| reproj2(cam, &pose, &local[i]).is_some_and(|e| e < thr2))
            .collect();
        if inliers.len() < 4 {
            break;
        }
        let sel: Vec<Correspondence> = inliers.iter().map(|&i| local[i]).collect();
        pose = refine_lm(cam, &pose, &sel, params.lm_iterations);
    }
    let inliers: Vec<usize> = (0..local.len())
        .filter(|&i| reproj2(cam, &pose, &local[i]).is_some_and(|e| e < thr2))
        .collect();
    if inliers.len() < params.min_inliers {
        return Err(Error::stage(
            StageName::Pnp,
            format!(
                "{} inliers < {} required",
                inliers.len(),
                params.min_inliers
            ),
        ));
    }
    let sse: f64 = inliers
        .iter()
        .filter_map(|&i| reproj2(cam, &pose, &local[i]))
        .sum();
    let rms_px = (sse / inliers.len() as f64).sqrt();
    let sel: Vec<Correspondence> = inliers.iter().map(|&i| local[i]).collect();
    // The rotation does not depend on the re-centring.
    let tilt_sigma_deg = tilt_sigma_deg(cam, &pose, &sel, rms_px);
    // Offsets do not depend on the re-centring either.
    let covariance = pose_covariance(cam, &pose, &sel, rms_px, params.lm_iterations);
    // Undo the re-centring: X_c = R(X − o) + t = R X + (t − R o).
    let pose = CamFromMap::new(pose.rotation, pose.translation - pose.rotation * origin);
    Ok(PnpResult {
        pose,
        inliers,
        rms_px,
        tilt_sigma_deg,
        covariance,
    })
}

/// The tilt σ of a PnP pose, degrees: the larger σ of a rotation about the map's two horizontal
/// axes, from the Gauss–Newton covariance σ²·(JᵀJ)⁻¹ of the reprojection residuals over the
/// inliers `corr`, with σ from `rms_px` (the RMS reprojection distance) corrected for the six
/// fitted parameters.
/// It counts the matches' scatter, not a bias they share, so it is a lower bound on the tilt's
/// real error; NaN when the fit has no more residuals than parameters or JᵀJ is singular.
pub(crate) fn tilt_sigma_deg(
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    corr: &[Correspondence],
    rms_px: f64,
) -> f64 {
    let m = 2 * corr.len();
    if m <= 6 || !rms_px.is_finite() {
        return f64::NAN;
    }
    let residuals = |p: &CamFromMap| reprojection_residuals(cam, p, corr);
    let mut j = DMatrix::zeros(m, 6);
    for k in 0..6 {
        let h = if k < 3 { 1e-6 } else { 1e-5 };
        let mut d = [0.0; 6];
        d[k] = h;
        let plus = left_increment(pose, &d);
        d[k] = -h;
        let minus = left_increment(pose, &d);
        let (Some(rp), Some(rm)) = (residuals(&plus), residuals(&minus)) else {
            return f64::NAN;
        };
        j.set_column(k, &((rp - rm) / (2.0 * h)));
    }
    // `rms_px` is the RMS of the 2-D reprojection distance: each of the 2n residuals has half
    // its square, and six parameters were fitted to them.
    let sigma2 = 0.5 * rms_px * rms_px * m as f64 / (m - 6) as f64;
    let Some(cov) = (j.transpose() * &j).try_inverse() else {
        return f64::NAN;
    };
    // The increment rotates on the camera side (R' = exp(δ)·R = R·exp(Rᵀδ)): in the map frame
    // the rotation's covariance is Rᵀ Σ R, whose x and y rows are the tilt.
    let r = *pose.rotation.matrix();
    let sr = cov.fixed_view::<3, 3>(0, 0).into_owned() * sigma2;
    let map = r.transpose() * sr * r;
    let tilt = nalgebra::Matrix2::new(map[(0, 0)], map[(0, 1)], map[(1, 0)], map[(1, 1)]);
    let largest = tilt.symmetric_eigenvalues().max();
    if largest.is_finite() && largest >= 0.0 {
        largest.sqrt().to_degrees()
    } else {
        f64::NAN
    }
}

/// The parts of a PnP pose's covariance over the pose chart's offsets
/// ([`crate::pose::offsets_between`]: x, y, z of the camera centre in m, then yaw, pitch and
/// roll in degrees), row-major, as [`pose_covariance`] measures them; composed into the
/// initializer's σ by [`crate::localize::refine::uncertainty::initializer`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCovariance {
    /// The residuals' Gauss–Newton bound σ²·(JᵀJ)⁻¹.
    pub bound: [[f64; 6]; 6],
    /// The delete-one-sector jackknife's covariance.
    pub jackknife: [[f64; 6]; 6],
    /// Sectors that held matches (the jackknife's K).
    pub sectors: usize,
}

/// Azimuth sectors of the matches around the camera for [`pose_covariance`]'s jackknife.
const SECTORS: usize = 8;

/// The covariance parts of a PnP pose fitted to the inliers `corr` with RMS reprojection
/// distance `rms_px`: the residuals' scatter through the Gauss–Newton bound σ²·(JᵀJ)⁻¹ (σ from
/// `rms_px`, corrected for the six fitted parameters), and a delete-one-sector jackknife: the
/// pose refitted ([`refine_lm`], `iterations`) without the matches of each of [`SECTORS`]
/// azimuth sectors around the camera. The bound sees only independent pixel noise; the
/// jackknife also sees an error the matches of one part of the view share (a template matched
/// a pixel off over a whole patch of road, a building's lean in the orthophoto), which is what
/// a satellite match's error mostly is. An error every match shares alike (the orthophoto's
/// own registration) neither sees. `None` when the fit has no more residuals than parameters,
/// JᵀJ is singular, fewer than four sectors hold matches, or a value is not finite.
pub(crate) fn pose_covariance(
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    corr: &[Correspondence],
    rms_px: f64,
    iterations: usize,
) -> Option<PoseCovariance> {
    let bound = residual_bound(cam, pose, corr, rms_px)?;
    let (jackknife, sectors) = sector_jackknife(cam, pose, corr, iterations)?;
    let rows = |m: &DMatrix<f64>| std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
    (bound.iter().chain(jackknife.iter()).all(|v| v.is_finite())).then(|| PoseCovariance {
        bound: rows(&bound),
        jackknife: rows(&jackknife),
        sectors,
    })
}

/// The Gauss–Newton bound σ²·(JᵀJ)⁻¹ of [`pose_covariance`], over the pose chart's offsets;
/// `None` with no more residuals than parameters, a match that does not project, or JᵀJ
/// singular.
fn residual_bound(
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    corr: &[Correspondence],
    rms_px: f64,
) -> Option<DMatrix<f64>> {
    let m = 2 * corr.len();
    if m <= 6 || !rms_px.is_finite() {
        return None;
    }
    let c0 = pose.center();
    let (y0, p0, r0) = pose.yaw_pitch_roll();
    let at = |o: &[f64; 6]| {
        CamFromMap::from_center_ypr(
            &(c0 + Vector3::new(o[0], o[1], o[2])),
            y0 + o[3].to_radians(),
            p0 + o[4].to_radians(),
            r0 + o[5].to_radians(),
        )
    };
    let residuals = |p: &CamFromMap| reprojection_residuals(cam, p, corr);
    let mut j = DMatrix::zeros(m, 6);
    for k in 0..6 {
        let h = if k < 3 { 1e-5 } else { 1e-4 };
        let mut o = [0.0; 6];
        o[k] = h;
        let rp = residuals(&at(&o))?;
        o[k] = -h;
        let rm = residuals(&at(&o))?;
        j.set_column(k, &((rp - rm) / (2.0 * h)));
    }
    // As in `tilt_sigma_deg`: each of the 2n residuals has half the squared distance.
    let sigma2 = 0.5 * rms_px * rms_px * m as f64 / (m - 6) as f64;
    Some((j.transpose() * &j).try_inverse()? * sigma2)
}

/// The delete-one-sector jackknife covariance of [`pose_covariance`]: (K − 1)/K · Σ (o_k − ō)
/// (o_k − ō)ᵀ over the K sectors that hold matches, o_k the offsets of the pose refitted
/// without sector k's, and K. `None` below four such sectors or where a refit leaves fewer than
/// six matches.
fn sector_jackknife(
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    corr: &[Correspondence],
    iterations: usize,
) -> Option<(DMatrix<f64>, usize)> {
    let c = pose.center();
    let sector = |w: &Point3<f64>| {
        let a = (w.y - c.y).atan2(w.x - c.x) + std::f64::consts::PI;
        ((a / std::f64::consts::TAU * SECTORS as f64) as usize).min(SECTORS - 1)
    };
    let of: Vec<usize> = corr.iter().map(|m| sector(&m.world)).collect();
    let held: Vec<usize> = (0..SECTORS).filter(|k| of.contains(k)).collect();
    if held.len() < 4 {
        return None;
    }
    let mut offsets = Vec::with_capacity(held.len());
    for &k in &held {
        let rest: Vec<Correspondence> = corr
            .iter()
            .zip(&of)
            .filter(|(_, s)| **s != k)
            .map(|(m, _)| *m)
            .collect();
        if rest.len() < 6 {
            return None;
        }
        let refit = refine_lm(cam, pose, &rest, iterations);
        offsets.push(DVector::from_row_slice(&crate::pose::offsets_between(
            pose, &refit,
        )));
    }
    let n = offsets.len() as f64;
    let mean = offsets.iter().fold(DVector::zeros(6), |a, o| a + o) / n;
    let scatter = offsets.iter().fold(DMatrix::zeros(6, 6), |a, o| {
        let d = o - &mean;
        a + &d * d.transpose()
    });
    Some((scatter * ((n - 1.0) / n), offsets.len()))
}

/// The 2n reprojection residuals (pixel x, then y, per match) of `corr` under `pose`; `None`
/// where a match does not project.
fn reprojection_residuals(
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    corr: &[Correspondence],
) -> Option<DVector<f64>> {
    let mut r = DVector::zeros(2 * corr.len());
    for (i, c) in corr.iter().enumerate() {
        let px = cam.project(&pose.transform(&c.world).coords).ok()?;
        r[2 * i] = px.x - c.pixel.x;
        r[2 * i + 1] = px.y - c.pixel.y;
    }
    Some(r)
}

/// `pose` with a left rotation increment (axis-angle, `d[0..3]`) and a translation increment
/// (`d[3..6]`), as [`refine_lm`] parameterises it.
fn left_increment(pose: &CamFromMap, d: &[f64; 6]) -> CamFromMap {
    let dr = Rotation3::new(Vector3::new(d[0], d[1], d[2]));
    CamFromMap::new(
        dr * pose.rotation,
        dr * pose.translation + Vector3::new(d[3], d[4], d[5]),
    )
}

/// Levenberg–Marquardt on pixel reprojection error; parameters are a left rotation increment
/// (axis-angle) and a translation increment. Forward-difference Jacobian: six parameters and
/// a cheap residual make analytic derivatives per lens model not worth their code.
pub fn refine_lm(
    cam: &dyn CameraModel,
    init: &CamFromMap,
    corr: &[Correspondence],
    iterations: usize,
) -> CamFromMap {
    // A correspondence that stops projecting keeps a fixed residual (and zero gradient).
    const UNPROJECTABLE_RESIDUAL: f64 = 1e3;
    let residuals = |p: &CamFromMap| -> DVector<f64> {
        let mut r = DVector::zeros(2 * corr.len());
        for (i, c) in corr.iter().enumerate() {
            match cam.project(&p.transform(&c.world).coords) {
                Ok(px) => {
                    r[2 * i] = px.x - c.pixel.x;
                    r[2 * i + 1] = px.y - c.pixel.y;
                }
                Err(_) => {
                    r[2 * i] = UNPROJECTABLE_RESIDUAL;
                    r[2 * i + 1] = UNPROJECTABLE_RESIDUAL;
                }
            }
        }
        r
    };
    let apply = |p: &CamFromMap, d: &DVector<f64>| -> CamFromMap {
        left_increment(p, &[d[0], d[1], d[2], d[3], d[4], d[5]])
    };
    let mut pose = *init;
    let mut r = residuals(&pose);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let mut j = DMatrix::zeros(r.len(), 6);
        for k in 0..6 {
            let h = if k < 3 { 1e-7 } else { 1e-6 };
            let mut d = DVector::zeros(6);
            d[k] = h;
            let rk = residuals(&apply(&pose, &d));
            j.set_column(k, &((rk - &r) / h));
        }
        let jt = j.transpose();
        let jtj = &jt * &j;
        let g = &jt * &r;
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj.clone();
            for k in 0..6 {
                a[(k, k)] += lambda * (1.0 + jtj[(k, k)]);
            }
            let Some(step) = a.lu().solve(&(-&g)) else {
                lambda *= 10.0;
                continue;
            };
            let cand = apply(&pose, &step);
            let rc = residuals(&cand);
            let c = rc.norm_squared();
            if c < cost {
                let rel = (cost - c) / cost.max(1e-300);
                pose = cand;
                r = rc;
                cost = c;
                lambda = (lambda * 0.3).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    pose
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Mei;
    use crate::pose::rotation_angle_between;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn fisheye() -> Mei {
        Mei {
            width: 1024,
            height: 1024,
            fx: 300.0,
            fy: 300.0,
            cx: 512.0,
            cy: 512.0,
            skew: 0.0,
            xi: 1.1,
            k1: -0.05,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        }
    }

    #[test]
    fn p3p_recovers_random_poses() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut worst: f64 = 0.0;
        for _ in 0..200 {
            let truth = CamFromMap::from_center_ypr(
                &Point3::new(
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    rng.random_range(3.0..12.0),
                ),
                rng.random_range(-3.1..3.1),
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
            );
            let x: [Point3<f64>; 3] = std::array::from_fn(|_| {
                Point3::new(
                    rng.random_range(-20.0..20.0),
                    rng.random_range(-20.0..20.0),
                    rng.random_range(-0.5..0.5),
                )
            });
            let f = x.map(|p| truth.transform(&p).coords.normalize());
            let sols = p3p(f, x);
            let best = sols
                .iter()
                .map(|s| {
                    (s.center() - truth.center()).norm()
                        + rotation_angle_between(&s.rotation, &truth.rotation)
                })
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(best);
        }
        assert!(worst < 1e-6, "worst P3P error {worst}");
    }

    #[test]
    fn ransac_with_outliers_and_wide_field() {
        let cam = fisheye();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let center = Point3::new(500_010.0, 4_700_020.0, 208.0);
        let truth = CamFromMap::from_center_ypr(&center, 2.1, 0.02, -0.015);
        let mut corr = Vec::new();
        let mut n_wide = 0;
        while corr.len() < 200 {
            let w = Point3::new(
                center.x + rng.random_range(-60.0..60.0),
                center.y + rng.random_range(-60.0..60.0),
                // Every 5th point on a facade above the camera: rays beyond 90° off-axis.
                if corr.len() % 5 == 1 {
                    209.0 + rng.random_range(0.0..6.0)
                } else {
                    200.0 + rng.random_range(-0.2..0.2)
                },
            );
            let Ok(px) = cam.project_visible(&truth.transform(&w).coords) else {
                continue;
            };
            let outlier = corr.len() % 3 == 0; // 33 % outliers
            let pixel = if outlier {
                Point2::new(rng.random_range(0.0..1024.0), rng.random_range(0.0..1024.0))
            } else {
                px + nalgebra::Vector2::new(
                    rng.random_range(-0.5..0.5),
                    rng.random_range(-0.5..0.5),
                )
            };
            if !outlier && truth.transform(&w).z < 0.0 {
                n_wide += 1;
            }
            corr.push(Correspondence { pixel, world: w });
        }
        assert!(n_wide > 0, "the test must include rays beyond 90°");
        let res = solve_pnp_ransac(
            &cam,
            &corr,
            &PnpParams::default(),
            &mut ChaCha8Rng::seed_from_u64(5),
        )
        .unwrap();
        assert!(
            (res.pose.center() - truth.center()).norm() < 0.05,
            "{:?}",
            res.pose.center() - truth.center()
        );
        assert!(rotation_angle_between(&res.pose.rotation, &truth.rotation) < 0.002);
        assert!(
            res.inliers.len() >= 120 && res.rms_px < 0.6,
            "{} {}",
            res.inliers.len(),
            res.rms_px
        );
        // Deterministic given the seed.
        let again = solve_pnp_ransac(
            &cam,
            &corr,
            &PnpParams::default(),
            &mut ChaCha8Rng::seed_from_u64(5),
        )
        .unwrap();
        assert_eq!(again.pose, res.pose);
        assert_eq!(again.inliers, res.inliers);
    }

    /// The tilt σ from the residuals is the scatter PnP's tilt really has under pixel noise: over
    /// 300 noisy draws of 40 ground matches the tilt errors' largest σ (map frame) and the median
    /// predicted σ agree within 25 %, and the prediction scales with the noise.
    #[test]
    fn tilt_sigma_is_the_scatter_of_the_tilt_under_pixel_noise() {
        let cam = fisheye();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let center = Point3::new(100.0, -50.0, 6.0);
        let truth = CamFromMap::from_center_ypr(&center, 0.7, 0.03, -0.02);
        let world: Vec<Point3<f64>> = (0..40)
            .map(|_| {
                Point3::new(
                    center.x + rng.random_range(-15.0..15.0),
                    center.y + rng.random_range(-15.0..15.0),
                    rng.random_range(-0.1..0.1),
                )
            })
            .collect();
        let clean: Vec<Point2<f64>> = world
            .iter()
            .map(|w| cam.project(&truth.transform(w).coords).unwrap())
            .collect();
        let mut gauss = |s: f64| -> f64 {
            let (u, v): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
            s * (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        for noise in [1.0, 3.0] {
            let (mut errs, mut predicted) = (Vec::new(), Vec::new());
            for _ in 0..300 {
                let corr: Vec<Correspondence> = world
                    .iter()
                    .zip(&clean)
                    .map(|(w, p)| Correspondence {
                        pixel: Point2::new(p.x + gauss(noise), p.y + gauss(noise)),
                        world: *w,
                    })
                    .collect();
                let est = refine_lm(&cam, &truth, &corr, 50);
                let sse: f64 = corr.iter().filter_map(|c| reproj2(&cam, &est, c)).sum();
                let rms = (sse / corr.len() as f64).sqrt();
                predicted.push(tilt_sigma_deg(&cam, &est, &corr, rms));
                let d = (truth.rotation.inverse() * est.rotation).scaled_axis();
                errs.push([d.x.to_degrees(), d.y.to_degrees()]);
            }
            let n = errs.len() as f64;
            let c = |a: usize, b: usize| errs.iter().map(|e| e[a] * e[b]).sum::<f64>() / n;
            let m = nalgebra::Matrix2::new(c(0, 0), c(0, 1), c(1, 0), c(1, 1));
            let observed = m.symmetric_eigenvalues().max().sqrt();
            predicted.sort_by(f64::total_cmp);
            let median = predicted[predicted.len() / 2];
            assert!(
                (median / observed - 1.0).abs() < 0.25,
                "noise {noise} px: predicted {median}° against observed {observed}°"
            );
            assert!(predicted.iter().all(|s| s.is_finite() && *s > 0.0));
        }
        // Too few residuals for six parameters: unknown.
        let three: Vec<Correspondence> = world[..3]
            .iter()
            .zip(&clean)
            .map(|(w, p)| Correspondence {
                pixel: *p,
                world: *w,
            })
            .collect();
        assert!(tilt_sigma_deg(&cam, &truth, &three, 1.0).is_nan());
    }

    /// The pose covariance's 3σ covers PnP's real error on every axis, both under independent
    /// pixel noise (the bound's part) and when the matches of each part of the view share an
    /// error (each 60° of azimuth shifted by its own 0.15 m on the ground: the jackknife's part,
    /// which the bound alone misses), as [`crate::localize::refine::uncertainty::initializer`]
    /// composes them (no orthophoto part: the map points are exact but for those shifts).
    #[test]
    fn pose_covariance_covers_independent_and_shared_match_errors() {
        let cam = fisheye();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let center = Point3::new(100.0, -50.0, 6.0);
        let truth = CamFromMap::from_center_ypr(&center, 0.7, 0.03, -0.02);
        let gauss = |rng: &mut ChaCha8Rng, s: f64| -> f64 {
            let (u, v): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
            s * (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        for shared_m in [0.0, 0.15] {
            let (mut covered, mut bound_only, trials) = ([0usize; 4], [0usize; 4], 200);
            for _ in 0..trials {
                // Per 60° sector of azimuth, one ground shift shared by its matches.
                let shifts: Vec<(f64, f64)> = (0..6)
                    .map(|_| (gauss(&mut rng, shared_m), gauss(&mut rng, shared_m)))
                    .collect();
                let corr: Vec<Correspondence> = (0..48)
                    .map(|_| {
                        let w = Point3::new(
                            center.x + rng.random_range(-15.0..15.0),
                            center.y + rng.random_range(-15.0..15.0),
                            rng.random_range(-0.1..0.1),
                        );
                        let a = (w.y - center.y).atan2(w.x - center.x) + std::f64::consts::PI;
                        let (dx, dy) = shifts[((a / std::f64::consts::TAU * 6.0) as usize).min(5)];
                        let p = cam.project(&truth.transform(&w).coords).unwrap();
                        Correspondence {
                            pixel: Point2::new(
                                p.x + gauss(&mut rng, 1.0),
                                p.y + gauss(&mut rng, 1.0),
                            ),
                            // The map point is off by the sector's shift: the match's error.
                            world: Point3::new(w.x + dx, w.y + dy, w.z),
                        }
                    })
                    .collect();
                let est = refine_lm(&cam, &truth, &corr, 50);
                let sse: f64 = corr.iter().filter_map(|c| reproj2(&cam, &est, c)).sum();
                let rms = (sse / corr.len() as f64).sqrt();
                let parts = pose_covariance(&cam, &est, &corr, rms, 50).expect("a covariance");
                let cov = crate::localize::refine::uncertainty::initializer(&parts, 0.0, 48).matrix;
                let bound = parts.bound;
                let err = crate::pose::offsets_between(&truth, &est);
                for k in 0..4 {
                    covered[k] += usize::from(err[k].abs() <= 3.0 * cov[k][k].sqrt());
                    bound_only[k] += usize::from(err[k].abs() <= 3.0 * bound[k][k].sqrt());
                }
            }
            for (k, c) in covered.iter().enumerate() {
                assert!(
                    *c as f64 >= 0.95 * trials as f64,
                    "shared {shared_m} m, axis {k}: 3σ covers {c} of {trials}"
                );
            }
            // With shared errors the bound alone misses them on x and y.
            if shared_m > 0.0 {
                for (k, b) in bound_only.iter().take(2).enumerate() {
                    assert!(
                        (*b as f64) < 0.8 * trials as f64,
                        "axis {k}: the bound alone covers {b} of {trials}"
                    );
                }
            }
        }
    }

    /// Matches in three sectors of azimuth only: no jackknife, no covariance.
    #[test]
    fn a_pose_covariance_needs_four_sectors() {
        let cam = fisheye();
        let center = Point3::new(100.0, -50.0, 6.0);
        let truth = CamFromMap::from_center_ypr(&center, 0.7, 0.03, -0.02);
        let corr = |sectors: usize| -> Vec<Correspondence> {
            (0..40)
                .map(|i| {
                    let a = (i % sectors) as f64 * std::f64::consts::TAU / sectors as f64 + 0.1;
                    let r = 4.0 + (i / sectors) as f64;
                    let w = Point3::new(center.x + r * a.cos(), center.y + r * a.sin(), 0.0);
                    Correspondence {
                        pixel: cam.project(&truth.transform(&w).coords).unwrap(),
                        world: w,
                    }
                })
                .collect()
        };
        assert!(pose_covariance(&cam, &truth, &corr(3), 1.0, 50).is_none());
        let c = pose_covariance(&cam, &truth, &corr(8), 1.0, 50).expect("eight sectors");
        assert_eq!(c.sectors, 8);
    }

    #[test]
    fn too_few_inliers_is_a_named_failure() {
        let cam = fisheye();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let corr: Vec<Correspondence> = (0..30)
            .map(|i| Correspondence {
                pixel: Point2::new(rng.random_range(0.0..1024.0), rng.random_range(0.0..1024.0)),
                world: Point3::new(i as f64, (i * 7 % 13) as f64, 0.0),
            })
            .collect();
        let e = solve_pnp_ransac(&cam, &corr, &PnpParams::default(), &mut rng)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("pnp: ") && e.contains("required"), "{e}");
    }
}
