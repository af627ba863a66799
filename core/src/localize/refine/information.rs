//! The covariance of the smooth estimator's answer from its observed information.
//!
//! [`information`]: the Cramér–Rao covariance of Pandey et al.: MI estimates the expected
//! log-likelihood ratio per point, so the observed information of N points is −N·∇²MI and its
//! inverse bounds the estimate's covariance. ∇²MI is the central difference of the analytic
//! gradient. Beside it, the cluster-robust ("sandwich") covariances over patches of ground and
//! over frames. A Hessian that is not negative definite over the free axes (no basin) or any
//! non-finite entry is a one-line refusal, never a number. [`information_covariance`] turns them
//! into the answer's reported covariance.

// Small fixed-size matrices (6×6) indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use crate::localize::error::InformationError;
use crate::localize::mi::smooth::Smooth;
use crate::pose::CamFromMap;
use nalgebra::{DMatrix, DVector, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

/// Central-difference steps of the Hessian: 2 cm and 0.1° (m, rad). PV's value is continuous
/// but its gradient changes in steps as points cross pixels, and real images add texture bumps
/// of a few centimetres; the curvature that bounds the answer is the basin's, a step of about a
/// fifth of its width (±10 cm / ±0.5° on the KITTI frames) measures it.
pub const HESSIAN_STEP: [f64; 6] = [0.02, 0.02, 0.02, 1.745e-3, 1.745e-3, 1.745e-3];

/// The observed-information covariance ([`information`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Information {
    /// Axis names (x, y, z, yaw, then pitch, roll when free).
    pub axes: Vec<String>,
    /// Units (m or deg).
    pub units: Vec<String>,
    /// Marginal σ per axis.
    pub sigma: Vec<f64>,
    /// Covariance (m, deg), row-major.
    pub matrix: Vec<Vec<f64>>,
    /// Points N (the fixed sets, all views).
    pub points: usize,
    /// Objective evaluations spent on the Hessian.
    pub evaluations: usize,
    /// The cluster-robust ("sandwich") σ per axis, same axes and units: see [`information`].
    pub sandwich_sigma: Vec<f64>,
    /// The cluster-robust covariance (m, deg), row-major.
    pub sandwich_matrix: Vec<Vec<f64>>,
    /// Clusters (compact patches of ground) the sandwich's score scatter is taken over.
    pub clusters: usize,
    /// The sandwich over regions of [`REGION_PATCHES`] neighbouring patches (σ per axis, same
    /// axes and units), which sees errors that neighbouring patches share: a shadow or a
    /// reflectance change longer than a patch moves them alike, and the patch sandwich, taking
    /// them as independent, would count them as evidence.
    #[serde(default)]
    pub region_sigma: Vec<f64>,
    /// The region-clustered covariance (m, deg), row-major.
    #[serde(default)]
    pub region_matrix: Vec<Vec<f64>>,
    /// Regions of the region sandwich.
    #[serde(default)]
    pub regions: usize,
    /// With [`FRAME_CLUSTERS_MIN`] or more pairs: the sandwich with each pair as one cluster
    /// (σ per axis, same axes and units), which sees what a frame's own systematic errors (its
    /// sweep's skew, its light) do to the answer; patches of one frame share those.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_sigma: Option<Vec<f64>>,
    /// The frame-clustered covariance (m, deg), row-major.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_matrix: Option<Vec<Vec<f64>>>,
    /// Pairs (clusters) of the frame sandwich, 0 without one.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub frames: usize,
    /// The objective's Hessian in θ ([`Smooth::hessian`]) the bound was taken from: the
    /// curvature the competing optima's climbs start from.
    #[serde(skip)]
    pub hessian: [[f64; 6]; 6],
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// Pairs needed for [`Information::frame_sigma`]: the scatter of fewer frames' scores is too
/// noisy to stand for a covariance over four axes.
pub const FRAME_CLUSTERS_MIN: usize = 5;

/// Clusters of [`information`]'s sandwich: enough patches for a stable 6 × 6 scatter (≫ 6),
/// few enough that each patch spans more ground than a texture's correlation length on the
/// frames measured (docs/refine.md "Sampling").
pub const SANDWICH_CLUSTERS: usize = 32;

/// Neighbouring patches per region of [`Information::region_sigma`]: 8 regions of the 32
/// patches. A patch is a contiguous run of the points' Morton order, so consecutive patches are
/// neighbours on the ground and a run of them is a compact region too. Fewer, larger clusters
/// see longer-range correlation at the price of fewer degrees of freedom, which the reported
/// covariance's Student-t widening pays ([`information_covariance`]).
pub const REGION_PATCHES: usize = 4;

/// N²·B of the sandwich: the scatter of the clusters' scores `scores` over the θ indices `idx`,
/// about their mean, ×K/(K − 1) for K clusters, times the squared count `n` of points (the
/// scores are sums over points of gradients of a mean).
fn score_scatter(scores: &[[f64; 6]], idx: &[usize], n: usize) -> DMatrix<f64> {
    let d = idx.len();
    let k = scores.len() as f64;
    let mean: Vec<f64> = (0..d)
        .map(|i| scores.iter().map(|g| g[idx[i]]).sum::<f64>() / k)
        .collect();
    let nn = (n as f64).powi(2);
    DMatrix::from_fn(d, d, |i, j| {
        nn * k / (k - 1.0).max(1.0)
            * scores
                .iter()
                .map(|g| (g[idx[i]] - mean[i]) * (g[idx[j]] - mean[j]))
                .sum::<f64>()
    })
}

/// Patch scores summed over runs of `per` consecutive patches: the scores of the regions those
/// runs cover (a patch's score is the sum of its points').
fn merged_scores(scores: &[[f64; 6]], per: usize) -> Vec<[f64; 6]> {
    scores
        .chunks(per.max(1))
        .map(|c| {
            let mut s = [0.0; 6];
            for g in c {
                for (a, b) in s.iter_mut().zip(g) {
                    *a += b;
                }
            }
            s
        })
        .collect()
}

/// The Cramér–Rao covariance at `pose` over the free axes of `free` (θ of [`step`]): inverse of
/// −N·∇²(objective), and beside it the cluster-robust ("sandwich", Huber–White) covariance
/// A⁻¹·B·A⁻¹ with A = −∇²(objective) and B the scatter of the score over
/// [`SANDWICH_CLUSTERS`] patches of ground ([`Smooth::cluster_gradients`], scaled by K/(K−1)).
/// The Cramér–Rao bound holds when every point is an independent sample of a correct model;
/// neighbouring points share pixels and a real frame's gray–reflectivity relation varies over
/// the ground, and the sandwich counts that: it equals the bound when points are independent
/// and grows with the correlation within a patch. Both are expressed over the axes the covariance
/// reports (x, y, z in m, yaw about the
/// map's up axis in degrees, and pitch and roll as [`crate::localize::mi::space::pose_at`] adds them, in
/// degrees). Errors (one line) when the Hessian or the covariance is not finite or the Hessian
/// is not negative definite over the free axes.
pub fn information(
    est: &Smooth<'_>,
    pose: &CamFromMap,
    free: &[bool; 6],
) -> Result<Information, InformationError> {
    information_with_step(est, pose, free, &HESSIAN_STEP)
}

/// [`information`] with the Hessian's central-difference steps `step` (m, rad) instead of
/// [`HESSIAN_STEP`], for measuring the choice.
pub fn information_with_step(
    est: &Smooth<'_>,
    pose: &CamFromMap,
    free: &[bool; 6],
    step: &[f64; 6],
) -> Result<Information, InformationError> {
    let h = est.hessian(pose, free, step);
    let idx: Vec<usize> = (0..6).filter(|&k| free[k]).collect();
    let n = est.n();
    let d = idx.len();
    let info = DMatrix::from_fn(d, d, |i, j| -(n as f64) * h[idx[i]][idx[j]]);
    if !info.iter().all(|v| v.is_finite()) {
        return Err(InformationError::NotFinite { what: "MI Hessian" });
    }
    let (axes, minv) = reported_axes(pose, free)?;
    let Some(chol) = info.clone().cholesky() else {
        let min_eig = info.clone().symmetric_eigenvalues().min();
        // The direction is sought in steps of the Hessian (metres and radians made comparable):
        // in θ's own units a radian of yaw would outweigh a metre.
        let scale = DMatrix::from_diagonal(&DVector::from_fn(d, |i, _| step[idx[i]]));
        let eig = (&scale * &info * &scale).symmetric_eigen();
        let k = eig.eigenvalues.imin();
        let theta = &scale * eig.eigenvectors.column(k);
        let along = upward_direction(&(&minv * theta), &axes, step);
        return Err(InformationError::NoBasin {
            along,
            curvature: -min_eig,
        });
    };
    let cov_theta = chol.inverse();
    // The sandwich over θ: A⁻¹·B·A⁻¹ = (N·A)⁻¹ (N²·B) (N·A)⁻¹ with N·A the information above.
    let sandwich = |scores: &[[f64; 6]]| -> DMatrix<f64> {
        &cov_theta * score_scatter(scores, &idx, n) * &cov_theta
    };
    let scores = est.cluster_gradients(pose, SANDWICH_CLUSTERS);
    let sandwich_theta = sandwich(&scores);
    let regions = merged_scores(&scores, REGION_PATCHES);
    let region_theta = sandwich(&regions);
    let frame_theta =
        (est.views() >= FRAME_CLUSTERS_MIN).then(|| sandwich(&est.view_gradients(pose)));
    let cov = &minv * cov_theta * minv.transpose();
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(InformationError::NotFinite { what: "covariance" });
    }
    let sw = &minv * sandwich_theta * minv.transpose();
    if !sw.iter().all(|v| v.is_finite()) {
        return Err(InformationError::NotFinite {
            what: "sandwich covariance",
        });
    }
    let region = &minv * region_theta * minv.transpose();
    if !region.iter().all(|v| v.is_finite()) {
        return Err(InformationError::NotFinite {
            what: "region-clustered covariance",
        });
    }
    let frame = frame_theta.map(|f| &minv * f * minv.transpose());
    if frame
        .as_ref()
        .is_some_and(|f| !f.iter().all(|v| v.is_finite()))
    {
        return Err(InformationError::NotFinite {
            what: "frame-clustered covariance",
        });
    }
    let sigma_of = |m: &DMatrix<f64>| -> Vec<f64> {
        (0..axes.len()).map(|i| m[(i, i)].max(0.0).sqrt()).collect()
    };
    let rows_of = |m: &DMatrix<f64>| -> Vec<Vec<f64>> {
        (0..axes.len())
            .map(|i| (0..axes.len()).map(|j| m[(i, j)]).collect())
            .collect()
    };
    let units: Vec<String> = axes
        .iter()
        .map(|a| {
            if ["x", "y", "z"].contains(a) {
                "m"
            } else {
                "deg"
            }
            .to_string()
        })
        .collect();
    Ok(Information {
        axes: axes.iter().map(|s| s.to_string()).collect(),
        units,
        sigma: sigma_of(&cov),
        matrix: rows_of(&cov),
        points: n,
        evaluations: Smooth::hessian_evaluations(free) + 1,
        sandwich_sigma: sigma_of(&sw),
        sandwich_matrix: rows_of(&sw),
        clusters: scores.len(),
        region_sigma: sigma_of(&region),
        region_matrix: rows_of(&region),
        regions: regions.len(),
        frame_sigma: frame.as_ref().map(sigma_of),
        frame_matrix: frame.as_ref().map(rows_of),
        frames: if frame.is_some() { est.views() } else { 0 },
        hessian: h,
    })
}

/// The axes `information` reports for the free parameters `free` (x, y, z, yaw, and pitch and
/// roll when the tilt is free) and the inverse of M = dθ/d(reported offsets) over them: θ's x, y,
/// z are the offsets', yaw is rz (rad → deg), pitch and roll go through the Jacobian of
/// [`crate::localize::mi::space::pose_at`]'s Euler increments.
pub(crate) fn reported_axes(
    pose: &CamFromMap,
    free: &[bool; 6],
) -> Result<(Vec<&'static str>, DMatrix<f64>), InformationError> {
    let idx: Vec<usize> = (0..6).filter(|&k| free[k]).collect();
    let tilt = free[3] || free[4];
    let axes: Vec<&str> = if tilt {
        vec!["x", "y", "z", "yaw", "pitch", "roll"]
    } else {
        vec!["x", "y", "z", "yaw"]
    };
    // M: d θ / d(reported offsets), columns per reported axis, rows per θ index (all six).
    let mut m = DMatrix::<f64>::zeros(6, axes.len());
    for (c, _) in axes.iter().enumerate() {
        // Reported offsets: x, y, z (m), yaw, pitch, roll (deg) of pose_at.
        let mut off = [0.0; 6];
        let h = 1e-6;
        off[c] = h;
        let plus = theta_between(pose, &crate::localize::mi::space::pose_at(pose, &off));
        off[c] = -h;
        let minus = theta_between(pose, &crate::localize::mi::space::pose_at(pose, &off));
        for r in 0..6 {
            m[(r, c)] = (plus[r] - minus[r]) / (2.0 * h);
        }
    }
    let m_free = DMatrix::from_fn(idx.len(), axes.len(), |i, j| m[(idx[i], j)]);
    if m_free.nrows() != m_free.ncols() {
        return Err(InformationError::Axes {
            free: idx.len(),
            axes: axes.len(),
        });
    }
    let Some(minv) = m_free.try_inverse() else {
        return Err(InformationError::SingularAxes);
    };
    Ok((axes, minv))
}

/// A direction `o` of the reported offsets (m, deg) for people: each axis in units of the
/// Hessian's step on it (`step`: m, rad), so that metres and degrees compare, as a unit vector
/// whose components of 0.2 or more are named, e.g. "x +0.88, yaw −0.29 (steps of 2 cm / 0.10°)".
fn upward_direction(o: &DVector<f64>, axes: &[&str], step: &[f64; 6]) -> String {
    let unit = |i: usize| if i < 3 { step[i] } else { step[i].to_degrees() };
    let v: Vec<f64> = (0..axes.len()).map(|i| o[i] / unit(i)).collect();
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !(norm > 0.0 && norm.is_finite()) {
        return "an undetermined direction".into();
    }
    // The sign of an eigenvector is arbitrary: the largest component is shown positive.
    let big = v
        .iter()
        .copied()
        .max_by(|a, b| a.abs().total_cmp(&b.abs()))
        .unwrap_or(1.0);
    let s = big.signum() / norm;
    let parts: Vec<String> = axes
        .iter()
        .zip(&v)
        .filter(|(_, x)| (**x * s).abs() >= 0.2)
        .map(|(a, x)| format!("{a} {:+.2}", x * s))
        .collect();
    format!(
        "{} (steps of {:.0} cm / {:.2}°)",
        parts.join(", "),
        100.0 * step[0],
        step[3].to_degrees()
    )
}

impl Information {
    /// One line for people: σ per axis in cm and degrees.
    pub fn describe(&self) -> String {
        let line = |sigma: &[f64]| -> String {
            self.axes
                .iter()
                .zip(sigma)
                .zip(&self.units)
                .map(|((a, s), u)| {
                    if u == "m" {
                        format!("{a} {:.1} cm", 100.0 * s)
                    } else {
                        format!("{a} {s:.3}°")
                    }
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        let frames = self.frame_sigma.as_ref().map_or(String::new(), |f| {
            format!("; frame σ {} (one cluster per pair)", line(f))
        });
        let regions = if self.region_sigma.is_empty() {
            String::new()
        } else {
            format!(
                "; region σ {} ({} regions)",
                line(&self.region_sigma),
                self.regions
            )
        };
        format!(
            "σ {} (Cramér–Rao, N = {}); sandwich σ {} ({} patches){regions}{frames}",
            line(&self.sigma),
            self.points,
            line(&self.sandwich_sigma),
            self.clusters
        )
    }
}

/// θ (of [`step`]) that takes `from` to `to`.
pub fn theta_between(from: &CamFromMap, to: &CamFromMap) -> [f64; 6] {
    let d = to.center() - from.center();
    let q: Rotation3<f64> = to.rotation.inverse() * from.rotation;
    // Angle from the skew part and the trace together (atan2): exact for tiny rotations, where
    // the acos of the trace alone rounds to 0 (the axes' Jacobian takes 1e-6 steps).
    let m = q.matrix();
    let v = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    ) * 0.5;
    let s = v.norm();
    let angle = s.atan2(0.5 * (m.trace() - 1.0));
    let r = if s > 0.0 { v * (angle / s) } else { v };
    [d.x, d.y, d.z, r.x, r.y, r.z]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::localize::mi::smooth::step;
    use nalgebra::Point3;

    /// A "no basin" refusal names its direction in steps of the Hessian (metres and degrees
    /// compared), with the sign of its largest component, and leaves out the small ones.
    #[test]
    fn the_upward_direction_is_named_in_steps() {
        let axes = ["x", "y", "z", "yaw"];
        // 2 cm along x and 0.1° of yaw: one step each.
        let o = DVector::from_vec(vec![0.02, 0.0, 0.001, 0.1]);
        let want = "x +0.71, yaw +0.71 (steps of 2 cm / 0.10°)";
        assert_eq!(upward_direction(&o, &axes, &HESSIAN_STEP), want);
        assert_eq!(upward_direction(&(-o), &axes, &HESSIAN_STEP), want);
        let o = DVector::from_vec(vec![0.0, -0.04, 0.0, 0.1]);
        assert_eq!(
            upward_direction(&o, &axes, &HESSIAN_STEP),
            "y +0.89, yaw -0.45 (steps of 2 cm / 0.10°)"
        );
        let zero = DVector::from_vec(vec![0.0; 4]);
        assert_eq!(
            upward_direction(&zero, &axes, &HESSIAN_STEP),
            "an undetermined direction"
        );
    }

    #[test]
    fn theta_between_inverts_step_down_to_tiny_rotations() {
        let p = CamFromMap::from_center_ypr(&Point3::new(1.0, -2.0, 6.0), 0.7, 0.05, -0.1);
        for th in [
            [0.1, -0.2, 0.05, 0.01, -0.02, 0.03],
            [0.0, 0.0, 0.0, 1e-8, 0.0, -2e-8],
            [1e-7, 0.0, 0.0, 0.0, 3e-9, 0.0],
        ] {
            let back = theta_between(&p, &step(&p, &th));
            for k in 0..6 {
                assert!(
                    (back[k] - th[k]).abs() < 1e-12 + 1e-9 * th[k].abs(),
                    "{th:?} -> {back:?}"
                );
            }
        }
    }

    /// The reported yaw is θ's rz in degrees (the covariance's axis mapping).
    #[test]
    fn reported_yaw_is_rz_in_degrees() {
        let p = CamFromMap::from_center_ypr(&Point3::new(0.0, 0.0, 5.0), 0.3, 0.0, 0.0);
        let mut off = [0.0; 6];
        off[3] = 1e-6;
        let th = theta_between(&p, &crate::localize::mi::space::pose_at(&p, &off));
        assert!((th[5] - 1e-6f64.to_radians()).abs() < 1e-15, "{th:?}");
        assert!(th[..5].iter().all(|v| v.abs() < 1e-15), "{th:?}");
    }

    /// A region's score is the sum of its patches' (runs of consecutive patches, one region per
    /// run). The patch scatter takes patches that move alike as independent evidence; the
    /// regions' sees the shared motion: patches alike in runs of four give the regions
    /// 4·(8/7)/(32/31) ≈ 4.4 times the patches' scatter (σ about twice), and patches that cancel
    /// within each run give the regions none.
    #[test]
    fn the_region_sandwich_sees_what_neighbouring_patches_share() {
        let idx = [0usize, 3];
        let at = |x: f64, yaw: f64| [x, 0.0, 0.0, yaw, 0.0, 0.0];
        let merged = merged_scores(&[at(1.0, 2.0), at(3.0, -1.0), at(0.5, 0.5)], 2);
        assert_eq!(merged, vec![at(4.0, 1.0), at(0.5, 0.5)]);
        // Eight regions of four identical patches each.
        let shared: Vec<[f64; 6]> = (0..32)
            .map(|j| {
                let g = (j / 4) as f64;
                at(g - 3.5, 0.5 * (g - 3.5))
            })
            .collect();
        let patches = score_scatter(&shared, &idx, 100);
        let regions = score_scatter(&merged_scores(&shared, REGION_PATCHES), &idx, 100);
        let want = 4.0 * (8.0 / 7.0) / (32.0 / 31.0);
        for (r, p) in regions.iter().zip(patches.iter()) {
            assert!((r / p - want).abs() < 1e-12, "{r} {p}");
        }
        // Patches that cancel within each region: the regions see no scatter at all.
        let cancel: Vec<[f64; 6]> = (0..32)
            .map(|j| {
                let s = [1.0, -1.0, 2.0, -2.0][j % 4];
                at(s, -s)
            })
            .collect();
        assert!(score_scatter(&cancel, &idx, 100)[(0, 0)] > 0.0);
        let none = score_scatter(&merged_scores(&cancel, REGION_PATCHES), &idx, 100);
        assert!(none.iter().all(|v| *v == 0.0), "{none}");
    }
}
