//! The reported uncertainty of a refined pose: the marginal covariance of [x, y, z, yaw(, pitch,
//! roll)] in the map frame that the pose file carries ([`Uncertainty`]). The smooth estimator's
//! stage fills it from its observed information
//! ([`crate::localize::refine::information::information_covariance`]) and adds the spread of the
//! optima the data cannot tell apart ([`crate::localize::refine::optima`]); this module adds the
//! part no resampling of the points can see, the camera file's stated intrinsics uncertainty
//! ([`intrinsics_deltas`]), and holds the small pieces of statistics they share.

use crate::camera::import::IntrinsicsSigma;
use crate::camera::{Camera, CameraModel};
use crate::localize::mi::objective::View;
use crate::localize::mi::space::{SearchConfig, AXES};
use crate::localize::pnp::{refine_lm, Correspondence};
use crate::pose::angle_difference;
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The reported covariance of an answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// Axis names, in the order of `sigma` and `matrix` (x, y, z, yaw, then pitch, roll when
    /// free).
    pub axes: Vec<String>,
    /// Units of the axes (m or deg).
    pub units: Vec<String>,
    /// Marginal standard deviation per axis (√ of the covariance's diagonal).
    pub sigma: Vec<f64>,
    /// Marginal covariance in the map frame (m, deg), row-major.
    pub matrix: Vec<Vec<f64>>,
    /// Per 1σ intrinsics mode (focal scale, cx, cy) stated by the camera file, the change of the
    /// answer it makes (same axes and units); empty when the file states no uncertainty.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics: Vec<Vec<f64>>,
    /// Points in the smooth stage's fixed set, all views.
    pub points: usize,
    /// Poses scored for the estimate (the information's Hessian and cluster scores).
    pub poses: usize,
    /// The σ the gate judges (same axes): the largest of the information's bound, its
    /// sandwiches and the translation floor, with the competing optima's spread; without the Student-t
    /// widening that makes the reported `sigma`'s 3σ bounds cover and without the intrinsics'
    /// part.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gate_sigma: Vec<f64>,
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
    pub(crate) fn is_finite(&self) -> bool {
        self.sigma.iter().all(|v| v.is_finite())
            && self.matrix.iter().flatten().all(|v| v.is_finite())
    }
}

/// The Student-t quantile with `dof` degrees of freedom at the normal's 3σ probability
/// (0.99865, one-sided), by the Cornish–Fisher expansion (within 0.5 % of the exact quantile from
/// 5 degrees of freedom up; 4.53 at 7).
pub(crate) fn student_t_3sigma(dof: usize) -> f64 {
    let (z, v) = (3.0f64, dof.max(1) as f64);
    let (z3, z5, z7, z9) = (z.powi(3), z.powi(5), z.powi(7), z.powi(9));
    z + (z3 + z) / (4.0 * v)
        + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * v * v)
        + (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * z) / (384.0 * v.powi(3))
        + (79.0 * z9 + 776.0 * z7 + 1482.0 * z5 - 1920.0 * z3 - 945.0 * z) / (92160.0 * v.powi(4))
}

/// The σ floor of a named axis: half the search's finest step on x, y and z (1 cm by default),
/// none on the angles (0, as for an unknown name). It stands for an error every frame shares,
/// which no clustering of patches or frames can see: a low sun casts its shadows to the same side
/// all day and so shifts every frame's answer alike (on `simulate --low-sun`, +0.8 cm north
/// pooled or not). A shift, not a turn: a shared rotation has not been measured, and the
/// angles' longer-range errors are what the region sandwich sees.
pub(crate) fn sigma_floor(search: &SearchConfig, axis: &str) -> f64 {
    let axes = search.spec.axes();
    AXES.iter()
        .position(|a| *a == axis)
        .filter(|&i| i < 3)
        .map_or(0.0, |i| 0.5 * axes[i].step)
}

/// The change of the camera centre (map metres) and of the yaw, pitch and roll (degrees) from
/// `pose` to `q`.
fn pose_delta(pose: &CamFromMap, q: &CamFromMap) -> [f64; 6] {
    let (c0, a0) = (pose.center(), pose.yaw_pitch_roll());
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
pub(crate) fn intrinsics_deltas(
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
    // Each perturbed camera's refit on its own (results collected in order): a serial stretch
    // at the end of every localization otherwise.
    sigma
        .perturbed(cam)
        .par_iter()
        .map(|pc| pose_delta(pose, &refine_lm(pc, pose, &corr, 30)))
        .collect()
}

/// Add the intrinsics' part ([`intrinsics_deltas`]) to an estimate's covariance and σ.
pub(crate) fn add_intrinsics(u: &mut Uncertainty, deltas: &[[f64; 6]]) {
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
            intrinsics: Vec::new(),
            points: points.len(),
            poses: 0,
            gate_sigma: Vec::new(),
        };
        add_intrinsics(&mut u, &d);
        assert!(
            (u.sigma[2] - (1e-4 + d.iter().map(|e| e[2] * e[2]).sum::<f64>()).sqrt()).abs() < 1e-12
        );
        assert_eq!(u.intrinsics.len(), 3);
    }

    #[test]
    fn student_t_quantile_at_three_sigma() {
        // The 0.99865 quantiles by numerical integration of the t density: 5 dof 5.507, 7 dof
        // 4.530, 31 dof 3.261; ∞: 3.
        for (dof, want) in [(5, 5.507), (7, 4.530), (31, 3.261)] {
            let got = student_t_3sigma(dof);
            assert!((got / want - 1.0).abs() < 0.005, "{dof}: {got} vs {want}");
        }
        assert!((student_t_3sigma(100_000) - 3.0).abs() < 1e-3);
        assert!(student_t_3sigma(5) > student_t_3sigma(6));
    }
}
