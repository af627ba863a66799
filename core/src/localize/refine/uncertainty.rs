//! The reported uncertainty of a refined pose: the marginal covariance of [x, y, z, yaw(, pitch,
//! roll)] in the map frame that the pose file carries ([`Uncertainty`]), composed in one place
//! ([`compose`]) from the local stage's [`Evidence`]; docs/refine.md "Uncertainty" names each
//! part. The grade is judged from it ([`crate::localize::refine::verdict::judge`]).

use crate::camera::import::IntrinsicsSigma;
use crate::camera::{Camera, CameraModel};
use crate::localize::error::InformationError;
use crate::localize::mi::objective::View;
use crate::localize::mi::space::Axis;
use crate::localize::mi::space::{SearchConfig, AXES};
use crate::localize::pnp::{refine_lm, Correspondence};
use crate::localize::refine::information::{Information, FRAME_CLUSTERS_MIN};
use crate::localize::refine::optima::Optima;
use crate::localize::refine::region::Region;
use crate::pose::angle_difference;
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The uncertainty of the initializer's own pose (x, y, z, yaw, pitch, roll; m, deg), for
/// serving it when the refinement is refused. Three parts, each named once:
/// - the PnP residuals' Gauss–Newton bound (`pnp.bound`): independent pixel noise;
/// - the sectors' jackknife (`pnp.jackknife`), widened by the Student-t factor of its K − 1
///   degrees of freedom so that its 3σ holds with so few groups: an error the matches of one
///   part of the view share;
/// - the orthophoto's registration σ on x and y (`orthophoto_sigma_m`): an error every
///   satellite match shares, which neither of the others can see.
///
/// `inliers`: the matches fitted.
pub fn initializer(
    pnp: &crate::localize::pnp::PoseCovariance,
    orthophoto_sigma_m: f64,
    inliers: usize,
) -> Uncertainty {
    let widen = (student_t_3sigma(pnp.sectors.saturating_sub(1).max(1)) / 3.0).powi(2);
    let mut matrix: Vec<Vec<f64>> = (0..6)
        .map(|r| {
            (0..6)
                .map(|c| pnp.bound[r][c] + widen * pnp.jackknife[r][c])
                .collect()
        })
        .collect();
    for (k, row) in matrix.iter_mut().enumerate().take(2) {
        row[k] += orthophoto_sigma_m * orthophoto_sigma_m;
    }
    Uncertainty {
        axes: ["x", "y", "z", "yaw", "pitch", "roll"]
            .iter()
            .map(|a| a.to_string())
            .collect(),
        units: ["m", "m", "m", "deg", "deg", "deg"]
            .iter()
            .map(|u| u.to_string())
            .collect(),
        sigma: (0..6).map(|k| matrix[k][k].max(0.0).sqrt()).collect(),
        matrix,
        intrinsics: Vec::new(),
        points: inliers,
        poses: 0,
        gate_sigma: Vec::new(),
        unbounded: None,
    }
}

/// The reported covariance of an answer.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
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
    /// The σ the grade is judged by (same axes): the data's, the local σ or the indifference
    /// set's with the competing optima's spread, before the Student-t widening that makes the
    /// reported `sigma`'s 3σ bounds cover and without the intrinsics' part
    /// ([`crate::localize::refine::verdict::judge`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gate_sigma: Vec<f64>,
    /// The axis along which the poses the data cannot tell from the answer reach the search
    /// box, and how far they were followed (m or deg): σ is unbounded there
    /// ([`crate::localize::refine::region`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unbounded: Option<(Axis, f64)>,
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

/// What the local stage measured at the answer, from which [`compose`] makes its covariance.
#[derive(Debug, Clone, Copy)]
pub struct Evidence<'a> {
    /// The observed information and its sandwiches, or why there is none.
    pub information: &'a std::result::Result<Information, InformationError>,
    /// The poses the data cannot tell from the answer, followed where the Hessian has no basin.
    pub region: Option<&'a Region>,
    /// The optima that compete with the answer.
    pub optima: Option<&'a Optima>,
    /// The search whose finest step sets the floor ([`sigma_floor`]).
    pub search: &'a SearchConfig,
    /// The answer's change per 1σ intrinsics mode the camera file states ([`intrinsics_deltas`]).
    pub intrinsics: Option<&'a [[f64; 6]]>,
}

/// The answer's covariance from its evidence, each part named once:
/// - **local σ**, per axis the largest of the Cramér–Rao bound, the patch, region and frame
///   sandwiches and the floor ([`local_sigma`]), in the patch sandwich's shape, each widened by
///   its clusters' Student-t ([`information_covariance`]);
/// - or, where the Hessian has no basin, **the indifference set**: the extent of the poses the
///   data cannot tell from the answer ([`crate::localize::refine::region`]), raised to the floor;
/// - **the optima's spread**: the optima the data cannot tell apart, as a mixture about the
///   answer ([`crate::localize::refine::optima`]);
/// - **the intrinsics**: the camera file's stated uncertainty ([`intrinsics_deltas`]).
///
/// Why there is no covariance, when there is none: the information failed otherwise than for
/// want of a basin, or had none and no set was followed.
pub fn compose(e: &Evidence<'_>) -> std::result::Result<Uncertainty, InformationError> {
    let (mut u, data) = match (e.information, e.region) {
        (Ok(info), _) => {
            let local = local_sigma(info, e.search);
            (information_covariance(info, &local), local)
        }
        (Err(InformationError::NoBasin { .. }), Some(r)) => {
            let u = region_covariance(r, e.search);
            let s = u.sigma.clone();
            (u, s)
        }
        (Err(err), _) => return Err(err.clone()),
    };
    let spread = |a: &String| e.optima.map_or(0.0, |o| o.sigma(a));
    u.gate_sigma = u
        .axes
        .iter()
        .zip(&data)
        .map(|(a, s)| s.hypot(spread(a)))
        .collect();
    if let Some(o) = e.optima {
        add_spread(&mut u, o);
    }
    if let Some(d) = e.intrinsics {
        add_intrinsics(&mut u, d);
    }
    u.unbounded = e.region.and_then(|r| r.unbounded);
    Ok(u)
}

/// The local σ per axis of `info`: the largest of the Cramér–Rao bound, the patch sandwich, the
/// region sandwich, the frame sandwich (when there is one) and the floor ([`sigma_floor`]).
/// Each sandwich sees error shared over a wider scale than the one before: a point's with its
/// neighbours in the same pixels, a patch's with its neighbours over a region of ground (a long
/// shadow, a reflectance change), a frame's over its whole view (its light, its sweep). The
/// floor stands for what every frame shares; pooled frames do not shrink it.
pub(crate) fn local_sigma(info: &Information, cfg: &SearchConfig) -> Vec<f64> {
    let frame = |i: usize| info.frame_sigma.as_ref().map_or(0.0, |f| f[i]);
    let region = |i: usize| info.region_sigma.get(i).copied().unwrap_or(0.0);
    info.axes
        .iter()
        .zip(info.sigma.iter().zip(&info.sandwich_sigma))
        .enumerate()
        .map(|(i, (a, (s, w)))| {
            s.max(*w)
                .max(region(i))
                .max(frame(i))
                .max(sigma_floor(cfg, a))
        })
        .collect()
}

/// The local part of the reported covariance: the patch sandwich's, each axis scaled up to its
/// local σ (`judged`, [`local_sigma`]; correlations kept)
/// and widened to a Student-t 3σ quantile. Each estimate is widened by its own degrees of
/// freedom: the patch sandwich's (and the bound's with it) by its clusters − 1, the region
/// sandwich's by its regions − 1, the frame sandwich's by its frames − 1, and an axis takes the
/// widest.
pub(crate) fn information_covariance(info: &Information, judged: &[f64]) -> Uncertainty {
    let d = info.axes.len();
    let base = &info.sandwich_matrix;
    let have: Vec<f64> = (0..d).map(|i| base[i][i].max(0.0).sqrt()).collect();
    let f: Vec<f64> = (0..d)
        .map(|i| {
            if have[i] > 0.0 && judged[i] > have[i] {
                judged[i] / have[i]
            } else {
                1.0
            }
        })
        .collect();
    let t = |dof: usize| student_t_3sigma(dof.max(1)) / 3.0;
    let patches = t(info.clusters.saturating_sub(1));
    let regions = t(info.regions.saturating_sub(1));
    let frames = t(info.frames.max(FRAME_CLUSTERS_MIN).saturating_sub(1));
    // Per axis, the widening that takes the judged σ to the widest of the widened estimates.
    let tau: Vec<f64> = (0..d)
        .map(|i| {
            let by_regions = info.region_sigma.get(i).map_or(0.0, |s| s * regions);
            let by_frames = info.frame_sigma.as_ref().map_or(0.0, |f| f[i] * frames);
            let widest = (judged[i] * patches).max(by_regions).max(by_frames);
            if judged[i] > 0.0 && widest > judged[i] * patches {
                widest / judged[i]
            } else {
                patches
            }
        })
        .collect();
    let matrix: Vec<Vec<f64>> = (0..d)
        .map(|i| {
            (0..d)
                .map(|j| match (have[i] > 0.0, have[j] > 0.0) {
                    (true, true) => base[i][j] * f[i] * f[j] * (tau[i] * tau[j]),
                    // An axis the patches left without scatter still carries its judged σ.
                    _ if i == j => judged[i] * judged[i] * (tau[i] * tau[i]),
                    _ => 0.0,
                })
                .collect()
        })
        .collect();
    Uncertainty {
        axes: info.axes.clone(),
        units: info.units.clone(),
        sigma: (0..d).map(|i| matrix[i][i].max(0.0).sqrt()).collect(),
        matrix,
        points: info.points,
        poses: info.evaluations,
        ..Default::default()
    }
}

/// The indifference set's covariance, each axis raised to at least its floor (correlations
/// kept).
fn region_covariance(r: &Region, cfg: &SearchConfig) -> Uncertainty {
    let d = r.axes.len();
    let floor: Vec<f64> = r.axes.iter().map(|a| sigma_floor(cfg, a)).collect();
    let f: Vec<f64> = (0..d)
        .map(|i| {
            if r.sigma[i] > 0.0 {
                (floor[i] / r.sigma[i]).max(1.0)
            } else {
                1.0
            }
        })
        .collect();
    let matrix: Vec<Vec<f64>> = (0..d)
        .map(|i| {
            (0..d)
                .map(|j| match (r.sigma[i] > 0.0, i == j) {
                    (false, true) => floor[i] * floor[i],
                    _ => r.matrix[i][j] * f[i] * f[j],
                })
                .collect()
        })
        .collect();
    Uncertainty {
        axes: r.axes.clone(),
        units: r
            .axes
            .iter()
            .map(|a| Axis::from_name(a).map_or("m", Axis::unit).to_string())
            .collect(),
        sigma: (0..d).map(|i| matrix[i][i].max(0.0).sqrt()).collect(),
        matrix,
        points: r.points,
        poses: r.evaluations,
        ..Uncertainty::default()
    }
}

/// Add the spread of the optima the data cannot tell apart ([`Optima::spread`]) to `u`, on the
/// axes the two share.
fn add_spread(u: &mut Uncertainty, o: &Optima) {
    let at = |a: &String| u.axes.iter().position(|b| b == a);
    for (i, ai) in o.axes.iter().enumerate() {
        for (j, aj) in o.axes.iter().enumerate() {
            if let (Some(p), Some(q)) = (at(ai), at(aj)) {
                u.matrix[p][q] += o.spread[i][j];
            }
        }
    }
    for (k, s) in u.sigma.iter_mut().enumerate() {
        *s = u.matrix[k][k].max(0.0).sqrt();
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
fn add_intrinsics(u: &mut Uncertainty, deltas: &[[f64; 6]]) {
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
// Per-axis checks over parallel arrays read clearer with the index.
#[allow(clippy::needless_range_loop)]
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
            points: points.len(),
            ..Uncertainty::default()
        };
        add_intrinsics(&mut u, &d);
        assert!(
            (u.sigma[2] - (1e-4 + d.iter().map(|e| e[2] * e[2]).sum::<f64>()).sqrt()).abs() < 1e-12
        );
        assert_eq!(u.intrinsics.len(), 3);
    }

    /// The reported covariance is the sandwich's shape at the judged σ:
    /// every axis at least its judged σ (the search's floor included), correlations kept, widened
    /// by the sandwich's Student-t factor, and the intrinsics' part added on top.
    #[test]
    fn the_reported_covariance_is_the_sandwich_s_shape_at_the_judged_sigma() {
        use crate::pose::Sigma;
        let axes: Vec<String> = ["x", "y", "z", "yaw", "pitch", "roll"]
            .map(String::from)
            .to_vec();
        let sd = [0.004, 0.02, 0.003, 0.01, 0.05, 0.03];
        let sandwich: Vec<Vec<f64>> = (0..6)
            .map(|i| {
                (0..6)
                    .map(|j| match (i, j) {
                        _ if i == j => sd[i] * sd[i],
                        (0, 4) | (4, 0) => -0.9 * sd[0] * sd[4],
                        _ => 0.0,
                    })
                    .collect()
            })
            .collect();
        let info = Information {
            axes,
            units: ["m", "m", "m", "deg", "deg", "deg"]
                .map(String::from)
                .to_vec(),
            sigma: vec![0.001; 6],
            matrix: sandwich.clone(),
            points: 1000,
            evaluations: 13,
            sandwich_sigma: sd.to_vec(),
            sandwich_matrix: sandwich,
            clusters: 32,
            region_sigma: Vec::new(),
            region_matrix: Vec::new(),
            regions: 0,
            frame_sigma: None,
            frame_matrix: None,
            frames: 0,
            hessian: [[0.0; 6]; 6],
        };
        let search = SearchConfig::default();
        let judged = local_sigma(&info, &search);
        // The default search's floor: half of 2 cm on x, y and z, none on the angles.
        assert_eq!(judged, vec![0.01, 0.02, 0.01, 0.01, 0.05, 0.03]);
        let t = (student_t_3sigma(31) / 3.0).powi(2);
        let information = Ok(info.clone());
        let evidence = Evidence {
            information: &information,
            region: None,
            optima: None,
            search: &search,
            intrinsics: None,
        };
        let u = compose(&evidence).expect("a covariance");
        assert_eq!(u.gate_sigma, judged);
        for i in 0..6 {
            assert!(
                (u.matrix[i][i] - judged[i] * judged[i] * t).abs() < 1e-15,
                "{i}"
            );
        }
        let rho = u.matrix[0][4] / (u.sigma[0] * u.sigma[4]);
        assert!((rho + 0.9).abs() < 1e-12, "{rho}");
        let d = [[0.0, 0.0, 0.02, 0.0, 0.0, 0.0]; 1];
        let w = compose(&Evidence {
            intrinsics: Some(&d),
            ..evidence
        })
        .expect("a covariance");
        assert!((w.matrix[2][2] - (u.matrix[2][2] + 4e-4)).abs() < 1e-15);
        assert_eq!(Sigma::of(&w).x, u.sigma[0]);
    }

    /// With region and frame sandwiches each estimate is widened by its own degrees of freedom:
    /// the frames' (K − 1) or the regions' (7) where they decide the axis, the patches' (31, the
    /// floor's too) elsewhere; the floor stays.
    #[test]
    fn each_sandwich_widens_by_its_own_clusters_above_the_floor() {
        let axes: Vec<String> = ["x", "y", "z", "yaw"].map(String::from).to_vec();
        let diag = |sd: &[f64]| -> Vec<Vec<f64>> {
            (0..4)
                .map(|i| {
                    (0..4)
                        .map(|j| if i == j { sd[i] * sd[i] } else { 0.0 })
                        .collect()
                })
                .collect()
        };
        let patch = [0.003, 0.004, 0.006, 0.007];
        let frame = [0.008, 0.001, 0.001, 0.004];
        let region = [0.002, 0.009, 0.001, 0.012];
        let info = |frames: usize| Information {
            axes: axes.clone(),
            units: ["m", "m", "m", "deg"].map(String::from).to_vec(),
            sigma: vec![0.0005; 4],
            matrix: diag(&[0.0005; 4]),
            points: 100_000,
            evaluations: 9,
            sandwich_sigma: patch.to_vec(),
            sandwich_matrix: diag(&patch),
            clusters: 32,
            region_sigma: region.to_vec(),
            region_matrix: diag(&region),
            regions: 8,
            frame_sigma: Some(frame.to_vec()),
            frame_matrix: Some(diag(&frame)),
            frames,
            hessian: [[0.0; 6]; 6],
        };
        let cfg = SearchConfig::default();
        let judged = local_sigma(&info(6), &cfg);
        // x, y and z at the default floor (1 cm); yaw, which has none, at its region σ.
        assert_eq!(judged, vec![0.01, 0.01, 0.01, 0.012]);
        let t = |dof: usize| student_t_3sigma(dof) / 3.0;
        // Six frames: x's frame σ widened by t₅ (1.46 cm) passes the floor widened by t₃₁
        // (1.09 cm). Twelve: by t₁₁ (1.03 cm) it does not. y's and yaw's region σ widened by
        // t₇ pass their judged σ widened by t₃₁.
        for (frames, x) in [(6, 0.008 * t(5)), (12, 0.01 * t(31))] {
            let u = information_covariance(&info(frames), &judged);
            let want = [x, 0.009 * t(7), 0.01 * t(31), 0.012 * t(7)];
            for i in 0..4 {
                assert!(
                    (u.sigma[i] - want[i]).abs() < 1e-12,
                    "{frames} {i}: {:?}",
                    u.sigma
                );
            }
        }
    }

    /// Without a basin the indifference set is the local part, raised to the floor where it
    /// is narrower, and its open axis travels with it; an information failure other than the
    /// basin's, or no basin and no set, is the stop.
    #[test]
    fn without_a_basin_the_indifference_set_is_the_covariance() {
        let search = SearchConfig::default();
        let no_basin = Err(InformationError::NoBasin {
            along: "x".into(),
            curvature: 1.0,
        });
        let region = Region {
            axes: ["x", "y", "z", "yaw"].map(String::from).to_vec(),
            rays: Vec::new(),
            sigma: vec![0.2, 0.004, 0.0, 0.3],
            matrix: vec![
                vec![0.04, 0.0, 0.0, 0.054],
                vec![0.0, 0.004f64.powi(2), 0.0, 0.0],
                vec![0.0; 4],
                vec![0.054, 0.0, 0.0, 0.09],
            ],
            unbounded: None,
            points: 5000,
            evaluations: 40,
        };
        let e = Evidence {
            information: &no_basin,
            region: Some(&region),
            optima: None,
            search: &search,
            intrinsics: None,
        };
        let u = compose(&e).expect("a covariance");
        // x and yaw as the set gives them (correlation 0.9 kept); y and z at the 1 cm floor.
        assert_eq!(u.sigma[0], 0.2);
        assert!((u.sigma[3] - 0.3).abs() < 1e-12);
        assert!((u.matrix[0][3] / (u.sigma[0] * u.sigma[3]) - 0.9).abs() < 1e-12);
        assert!((u.sigma[1] - 0.01).abs() < 1e-12 && (u.sigma[2] - 0.01).abs() < 1e-12);
        assert_eq!(u.units, vec!["m", "m", "m", "deg"]);
        let open = Region {
            unbounded: Some((Axis::Yaw, 3.0)),
            ..region.clone()
        };
        let u = compose(&Evidence {
            region: Some(&open),
            ..e
        })
        .expect("a covariance");
        assert_eq!(u.unbounded, Some((Axis::Yaw, 3.0)));
        assert_eq!(
            compose(&Evidence { region: None, ..e }),
            Err(no_basin.clone().unwrap_err())
        );
        let edge = Err(InformationError::OnEdge { rounds: 3 });
        assert!(matches!(
            compose(&Evidence {
                information: &edge,
                ..e
            }),
            Err(InformationError::OnEdge { .. })
        ));
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
