//! The uncertainty of a refined pose: the marginal covariance of [x, y, z, yaw].
//!
//! Two things make a single MI optimum less certain than its peak's sharpness suggests, and both
//! are measured here instead of assumed:
//! - **Coupling.** Axes trade against each other along valleys of the objective (a forward
//!   camera's lateral shift against its yaw, a nadir camera's height against its focal length).
//!   Per-axis 1-D curvatures cannot see a valley; re-optimising all free axes together can.
//! - **Estimator noise.** MI is estimated from a finite, spatially correlated sample: neighbouring
//!   points share pixels, texture and blur, so `N` points are worth far fewer independent ones,
//!   and how many is unknown. A *delete-a-group jackknife* measures it: each view's fixed point
//!   set (in Morton order) is cut into `folds` contiguous runs — compact patches of ground — and
//!   group k is run k of every view. Leaving one group out at a time, the answer is polished
//!   again (Nelder–Mead over x, y, z and yaw from the answer) on the remaining points; the spread
//!   of those `folds` optima, scaled by (K − 1)/K, is the covariance of the answer. Whole patches
//!   go out together, so correlation within a patch is kept, and a patch that drags the peak (a
//!   parked car, a shadow, a repainted marking) shows up as spread; along a valley the optima
//!   scatter along its floor, so the coupling appears in the off-diagonal terms.
//!
//! The MI peak is a cusp rather than a parabola at the pixel scale (nearest-pixel sampling), so
//! the optima are found by re-optimising, not by Newton steps on a fitted quadratic: a quadratic
//! fitted over a cusp's stencil invents curvature in the coupled directions (tried: on a forward
//! camera it found no peak on results 1–2 cm from the truth).
//!
//! A leave-one-out histogram is the sum of the other groups' histograms at the pose, one pass of
//! the kernel over (K − 1)/K of the points per evaluation.

use super::kernel::Scratch;
use super::mi::{mutual_information, JointHist};
use super::pnp::{refine_lm, Correspondence};
use super::polish::{box_config, nelder_mead, PolishParams};
use super::search::{pose_at_pivot, Evaluator, SearchConfig, View, AXES};
use crate::camera::import::IntrinsicsSigma;
use crate::camera::{Camera, CameraModel};
use crate::error::Result;
use crate::pose::angle_difference;
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of the estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct UncertaintyConfig {
    /// Jackknife groups (contiguous patches of each view's points).
    pub folds: usize,
}

impl Default for UncertaintyConfig {
    fn default() -> Self {
        UncertaintyConfig { folds: 8 }
    }
}

/// The estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// Axis names, in the order of `sigma` and `covariance` (x, y, z, yaw, then pitch, roll
    /// when free).
    pub axes: Vec<String>,
    /// Units of the axes (m or deg).
    pub units: Vec<String>,
    /// Marginal standard deviation per axis (√ of the covariance's diagonal); ∞ where the
    /// objective has no peak.
    pub sigma: Vec<f64>,
    /// Marginal covariance in the map frame (m, deg), row-major.
    pub matrix: Vec<Vec<f64>>,
    /// Each group's optimum without it: the change of the camera centre (m) and angles (deg)
    /// from the reported pose, per axis.
    pub group_optima: Vec<Vec<f64>>,
    /// Whether every group's re-optimisation found a peak inside its box (else σ is ∞).
    pub peak: bool,
    /// Jackknife groups used.
    pub folds: usize,
    /// Per 1σ intrinsics mode (focal scale, cx, cy) stated by the camera file, the change of the
    /// answer it makes (same axes and units); empty when the file states no uncertainty.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics: Vec<Vec<f64>>,
    /// Points in the re-optimisation box's fixed set, all views.
    pub points: usize,
    /// Poses scored (every group's re-optimisation).
    pub poses: usize,
}

impl Uncertainty {
    /// σ of a named axis, if it was estimated.
    pub(crate) fn sigma_of(&self, axis: &str) -> Option<f64> {
        self.axes
            .iter()
            .position(|a| a == axis)
            .map(|i| self.sigma[i])
    }

    /// Whether every entry is finite.
    pub fn is_finite(&self) -> bool {
        self.sigma.iter().all(|v| v.is_finite())
            && self.matrix.iter().flatten().all(|v| v.is_finite())
    }
}

/// Estimate the uncertainty of `pose` on `views` (the same views and estimator the search used)
/// over x, y, z and yaw, and over pitch and roll too when `polish` frees them (tilting about the
/// ground `pivot` metres below the camera, as the pipeline's polish does). A nadir camera's tilt
/// trades against its position (a pitch of δ at height h moves the image like a shift of h·δ),
/// so a position σ with the tilt held would miss that valley. `polish` bounds and stops each
/// group's re-optimisation; the covariance is of the camera centre (map frame) and the angles.
pub fn estimate(
    cam: &Camera,
    views: &[View<'_>],
    pose: &CamFromMap,
    search: &SearchConfig,
    polish: &PolishParams,
    pivot: Option<f64>,
    ucfg: &UncertaintyConfig,
) -> Result<Uncertainty> {
    let p = PolishParams {
        tilt_starts_deg: 0.0,
        ..*polish
    };
    let tilt = p.is_free(4) || p.is_free(5);
    let ev = Evaluator::pooled(cam, views, pose, &box_config(search, &p, pivot), 0)?;
    let k = ucfg.folds.max(2);
    let folds = ev.folds(k);
    let objective = ev.objective();
    let parzen = search.mi.parzen;
    // The tilt pivot the evaluator applies (none for a near-horizontal optical axis).
    let pivot = ev.grid().pivot;
    let (ev, folds) = (&ev, &folds);
    // Group by group, each polish on the other groups' points (deterministic: no randomness,
    // results collected in group order).
    let ends: Vec<([f64; 6], usize, bool)> = (0..k)
        .into_par_iter()
        .map(|left_out| {
            let mut scratch = Scratch::default();
            let mut f = |o: &[f64; 6]| {
                let hists = ev.fold_histograms(folds, o, &mut scratch);
                let mut h = JointHist::new(hists[0].rows, hists[0].cols);
                for (j, hk) in hists.iter().enumerate() {
                    if j != left_out {
                        h.counts
                            .iter_mut()
                            .zip(&hk.counts)
                            .for_each(|(a, b)| *a += b);
                    }
                }
                mutual_information(&h, parzen).get(objective)
            };
            let end = nelder_mead(&mut f, &p);
            let on_edge = (0..6).any(|i| p.is_free(i) && end.offsets[i].abs() >= 0.95 * p.bound[i]);
            (end.offsets, end.evaluations, on_edge)
        })
        .collect();
    let d = if tilt { 6 } else { 4 };
    // Each group's optimum as the change of the camera centre and of the angles it makes (a tilt
    // about a ground pivot also moves the centre).
    let (c0, a0) = (pose.center(), pose.yaw_pitch_roll());
    let deltas: Vec<[f64; 6]> = ends
        .iter()
        .map(|e| {
            let q = pose_at_pivot(pose, &e.0, pivot);
            let (c, a) = (q.center(), q.yaw_pitch_roll());
            let da = |x: f64, y: f64| angle_difference(x, y).to_degrees();
            [
                c.x - c0.x,
                c.y - c0.y,
                c.z - c0.z,
                da(a.0, a0.0),
                da(a.1, a0.1),
                da(a.2, a0.2),
            ]
        })
        .collect();
    let mean: Vec<f64> = (0..d)
        .map(|i| deltas.iter().map(|e| e[i]).sum::<f64>() / k as f64)
        .collect();
    let scale = (k as f64 - 1.0) / k as f64;
    let mut matrix = vec![vec![0.0; d]; d];
    for (a, row) in matrix.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            *v = scale
                * deltas
                    .iter()
                    .map(|e| (e[a] - mean[a]) * (e[b] - mean[b]))
                    .sum::<f64>();
        }
    }
    // A group that walked to its box's edge found no peak within reach: the spread is at least
    // that far, and the answer unbounded in truth.
    let peak = !ends.iter().any(|e| e.2);
    if !peak {
        for (a, row) in matrix.iter_mut().enumerate() {
            row[a] = f64::INFINITY;
        }
    }
    let sigma = (0..d).map(|a| matrix[a][a].max(0.0).sqrt()).collect();
    Ok(Uncertainty {
        axes: AXES[..d].iter().map(|a| a.to_string()).collect(),
        units: ["m", "m", "m", "deg", "deg", "deg"][..d]
            .iter()
            .map(|u| u.to_string())
            .collect(),
        sigma,
        matrix,
        group_optima: deltas.iter().map(|e| e[..d].to_vec()).collect(),
        peak,
        folds: k,
        intrinsics: Vec::new(),
        points: ev.n_points,
        poses: ends.iter().map(|e| e.1).sum(),
    })
}

/// Most points the intrinsics propagation fits the pose to (every view's fixed set thinned
/// evenly): plenty for a 6-parameter fit, cheap next to one MI evaluation.
const MAX_PROPAGATION_POINTS: usize = 4000;

/// How each 1σ intrinsics mode ([`IntrinsicsSigma::perturbed`]) moves the answer: the pose that
/// keeps the answer's ground points (the MI points of every view) on the pixels the given
/// intrinsics put them on, refitted 6-DoF under the perturbed intrinsics, as the change of the
/// camera centre (m) and of yaw, pitch, roll (deg). Their outer products add up to the part of
/// the covariance the intrinsics' own uncertainty makes: a bias every ground patch shares, which
/// no resampling of the points can see.
pub fn intrinsics_deltas(
    cam: &Camera,
    views: &[View<'_>],
    pose: &CamFromMap,
    sigma: &IntrinsicsSigma,
) -> Vec<[f64; 6]> {
    let total: usize = views.iter().map(|v| v.points.len()).sum();
    let stride = total.div_ceil(MAX_PROPAGATION_POINTS).max(1);
    let corr: Vec<Correspondence> = views
        .iter()
        .flat_map(|v| v.points.iter())
        .step_by(stride)
        .filter_map(|g| {
            let w = nalgebra::Point3::new(g.x, g.y, g.z);
            let px = cam.project_visible(&pose.transform(&w).coords).ok()?;
            Some(Correspondence {
                pixel: px,
                world: w,
            })
        })
        .collect();
    if corr.len() < 6 {
        return Vec::new();
    }
    let (c0, a0) = (pose.center(), pose.yaw_pitch_roll());
    sigma
        .perturbed(cam)
        .iter()
        .map(|pc| {
            let q = refine_lm(pc, pose, &corr, 30);
            let (c, a) = (q.center(), q.yaw_pitch_roll());
            let da = |x: f64, y: f64| angle_difference(x, y).to_degrees();
            [
                c.x - c0.x,
                c.y - c0.y,
                c.z - c0.z,
                da(a.0, a0.0),
                da(a.1, a0.1),
                da(a.2, a0.2),
            ]
        })
        .collect()
}

/// Add the intrinsics' part ([`intrinsics_deltas`]) to an estimate's covariance and σ.
pub fn add_intrinsics(u: &mut Uncertainty, deltas: &[[f64; 6]]) {
    let d = u.sigma.len();
    for (a, row) in u.matrix.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            *v += deltas.iter().map(|e| e[a] * e[b]).sum::<f64>();
        }
    }
    for a in 0..d {
        u.sigma[a] = u.matrix[a][a].max(0.0).sqrt();
    }
    u.intrinsics = deltas.iter().map(|e| e[..d].to_vec()).collect();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_focal_scale_moves_a_nadir_camera_s_height_and_a_principal_point_its_tilt() {
        use crate::camera::Mei;
        use crate::map::GroundPoint;
        let cam = Camera::Mei(Mei::pinhole(800, 800, 200.0, 200.0, 400.0, 400.0));
        let pose =
            CamFromMap::from_center_ypr(&nalgebra::Point3::new(0.0, 0.0, 10.0), 0.4, 0.0, 0.0);
        let points: Vec<GroundPoint> = (-12..=12)
            .flat_map(|i| (-12..=12).map(move |j| (i, j)))
            .map(|(i, j)| GroundPoint {
                x: i as f64,
                y: j as f64,
                z: 0.0,
                reflectivity: 0,
            })
            .collect();
        let (gray, mask) = (vec![0u8; 800 * 800], vec![1u8; 800 * 800]);
        let views = [View {
            gray: &gray,
            mask: &mask,
            points: &points,
        }];
        let s = IntrinsicsSigma {
            focal_rel: 0.01,
            principal_point_px: 2.0,
        };
        let d = intrinsics_deltas(&cam, &views, &pose, &s);
        assert_eq!(d.len(), 3);
        // A pinhole 1 % longer sees the ground as from 1 % higher: +10 cm, no shift, no turn.
        assert!((d[0][2] - 0.1).abs() < 0.005, "{:?}", d[0]);
        assert!(
            d[0][0].abs() < 1e-3 && d[0][1].abs() < 1e-3 && d[0][3].abs() < 1e-3,
            "{:?}",
            d[0]
        );
        // 2 px of principal point is a tilt of atan(2/200) ≈ 0.57°, or the equivalent shift.
        let tilt = (d[1][4].powi(2) + d[1][5].powi(2)).sqrt();
        let shift = d[1][0].hypot(d[1][1]);
        assert!(tilt > 0.3 || shift > 0.05, "{:?}", d[1]);
        let mut u = Uncertainty {
            axes: AXES.iter().map(|a| a.to_string()).collect(),
            units: vec!["m".into(); 6],
            sigma: vec![0.01; 6],
            matrix: (0..6)
                .map(|a| (0..6).map(|b| if a == b { 1e-4 } else { 0.0 }).collect())
                .collect(),
            group_optima: Vec::new(),
            peak: true,
            folds: 8,
            intrinsics: Vec::new(),
            points: points.len(),
            poses: 0,
        };
        add_intrinsics(&mut u, &d);
        assert!(
            (u.sigma[2] - (1e-4 + d.iter().map(|e| e[2] * e[2]).sum::<f64>()).sqrt()).abs() < 1e-12
        );
        assert_eq!(u.intrinsics.len(), 3);
    }

    #[test]
    fn groups_cover_the_fixed_set_once() {
        // Covered by tests/refine_pooled.rs end to end; here: the config's defaults are sane.
        let c = UncertaintyConfig::default();
        assert!(c.folds >= 2);
    }
}
