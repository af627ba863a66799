//! The seed's robustness study and MI plots (pure; the shells are `infraloc study` and
//! `infraloc plot mi-surface`).
//!
//! Study: from seeded random initial poses (truth perturbed uniformly in x, y, z and yaw) run the
//! MI refinement exactly as the pipeline does (same search configuration, same ground-point
//! selection around the initial camera centre) and measure the final pose against the truth.
//! Surface: the same estimator the search uses ([`Evaluator`], fixed point set, level 0) evaluated
//! along each axis and over an x–y grid around a pose.

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::localize::mi::objective::Evaluator;
use crate::localize::mi::objective::View;
use crate::localize::mi::space::{pose_at, SearchConfig, AXES};
use crate::localize::refine::quality::QualityConfig;
use crate::localize::refine::{refine_polished, PolishedSearch};
use crate::map::{ground_points, Tile};
use crate::pose::CamFromMap;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A trial counts as a success within these bounds (the demo's thresholds, the refinement's
/// 99th-percentile goal): horizontal error, metres.
pub(crate) const SUCCESS_HORIZONTAL_M: f64 = 0.10;
/// Success bound on the height error, metres.
pub(crate) const SUCCESS_HEIGHT_M: f64 = 0.10;
/// Success bound on the yaw error, degrees.
pub(crate) const SUCCESS_YAW_DEG: f64 = 0.2;

/// Largest perturbation of the initial pose on each axis (uniform in ±value).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct Perturbation {
    /// x and y, metres.
    pub xy_m: f64,
    /// z, metres.
    pub z_m: f64,
    /// Yaw, degrees.
    pub yaw_deg: f64,
}

impl Default for Perturbation {
    /// ±0.8 m x/y, ±0.4 m z, ±2.5° yaw: inside the default search box (±1 m, ±0.5 m, ±3°) with a
    /// margin, like a PnP initialization that went moderately wrong.
    fn default() -> Self {
        Perturbation {
            xy_m: 0.8,
            z_m: 0.4,
            yaw_deg: 2.5,
        }
    }
}

impl Perturbation {
    /// Reject negative or non-finite bounds, naming the flag.
    pub(crate) fn validate(&self) -> Result<()> {
        for (flag, v) in [
            ("--perturb-xy", self.xy_m),
            ("--perturb-z", self.z_m),
            ("--perturb-yaw", self.yaw_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::arg(flag, v, "must be a finite number ≥ 0"));
            }
        }
        Ok(())
    }

    /// `n` start offsets [dx, dy, dz (m), dyaw (deg)] from `seed`: the same seed gives the same
    /// starts whatever else changes (the RNG is used for nothing else).
    pub(crate) fn starts(&self, n: usize, seed: u64) -> Vec<[f64; 4]> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut u = |a: f64| {
            if a > 0.0 {
                rng.random_range(-a..=a)
            } else {
                0.0
            }
        };
        (0..n)
            .map(|_| [u(self.xy_m), u(self.xy_m), u(self.z_m), u(self.yaw_deg)])
            .collect()
    }
}

/// Offsets of `pose` from `truth`: camera centre difference (map frame, m) and yaw difference
/// wrapped to [−180°, 180°).
pub(crate) fn offsets_from(truth: &CamFromMap, pose: &CamFromMap) -> [f64; 4] {
    let o = crate::pose::offsets_between(truth, pose);
    [o[0], o[1], o[2], o[3]]
}

/// How the refinement picks its LiDAR points around the initial camera centre (the pipeline's
/// rule: within `max_off_nadir_deg` of nadir at the camera's height above the ground, at most
/// `radius_m`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PointSelection {
    /// Largest radius, metres.
    pub radius_m: f64,
    /// Largest off-nadir angle, degrees.
    pub max_off_nadir_deg: f64,
}

impl Default for PointSelection {
    /// The pipeline's defaults.
    fn default() -> Self {
        let p = crate::localize::pipeline::Params::default();
        PointSelection {
            radius_m: p.mi_radius_m,
            max_off_nadir_deg: p.mi_max_off_nadir_deg,
        }
    }
}

impl PointSelection {
    /// Ground points of `tile` for a camera at `pose`.
    pub(crate) fn points(&self, tile: &Tile, pose: &CamFromMap) -> Vec<crate::map::GroundPoint> {
        let c = pose.center();
        let (_, r) = crate::localize::init::ground::ground_disc(
            &tile.height,
            &c,
            self.max_off_nadir_deg,
            self.radius_m,
        );
        ground_points(tile, (c.x, c.y), r)
    }
}

/// One trial of the study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Trial {
    /// Trial number (0-based).
    pub index: usize,
    /// Start offsets from the truth: dx, dy, dz (m, map frame), dyaw (deg).
    pub start: [f64; 4],
    /// Final offsets from the truth, same layout.
    pub result: [f64; 4],
    /// Final horizontal error, metres.
    pub horizontal_m: f64,
    /// Final height error (absolute), metres.
    pub height_m: f64,
    /// Final yaw error (absolute), degrees.
    pub yaw_deg: f64,
    /// Within the success bounds ([`SUCCESS_HORIZONTAL_M`], …).
    pub success: bool,
    /// The result was served: graded precise or coarse.
    pub accepted: bool,
    /// Its grade: `precise`, `coarse` or `refused`.
    #[serde(default)]
    pub grade: String,
    /// Why it is not precise, when it is not.
    pub reason: Option<String>,
    /// MI at the optimum, nats.
    pub mi: f64,
    /// Points in the fixed set.
    pub points: usize,
    /// The σ the refinement reported (the covariance the pose file would carry, competing
    /// optima included), accepted or not; absent when it made none. Read against `result`
    /// for coverage.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<crate::pose::Sigma>,
    /// Ground error of each control point under the final pose, metres (as the pipeline's
    /// `ground` error: the true pixel cast through the given intrinsics onto the plane at the
    /// point's true height); empty without control points.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ground_m: Vec<f64>,
    /// Wall time of the refinement, seconds (the only field that varies between identical runs).
    pub seconds: f64,
}

/// Median, 95th percentile and maximum of a sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct Spread {
    /// Median.
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Maximum.
    pub max: f64,
}

impl Spread {
    /// Of `v` (NaN for an empty sample; NaNs sort last, so they show up as the maximum).
    pub(crate) fn of(v: &[f64]) -> Spread {
        let mut s = v.to_vec();
        s.sort_by(|a, b| a.total_cmp(b));
        let rank = |q: f64| -> f64 {
            if s.is_empty() {
                return f64::NAN;
            }
            // Nearest rank: the smallest value with at least q of the sample at or below it.
            let k = ((q * s.len() as f64).ceil() as usize).clamp(1, s.len());
            s[k - 1]
        };
        let median = if s.is_empty() {
            f64::NAN
        } else if s.len() % 2 == 1 {
            s[s.len() / 2]
        } else {
            0.5 * (s[s.len() / 2 - 1] + s[s.len() / 2])
        };
        Spread {
            median,
            p95: rank(0.95),
            max: s.last().copied().unwrap_or(f64::NAN),
        }
    }
}

/// Summary of a study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Summary {
    /// Number of trials.
    pub trials: usize,
    /// Horizontal error, metres (all trials, gate-rejected ones included).
    pub horizontal_m: Spread,
    /// Height error, metres.
    pub height_m: Spread,
    /// Yaw error, degrees.
    pub yaw_deg: Spread,
    /// Fraction of trials within 10 cm horizontal, 10 cm height and 0.2° yaw.
    pub success_fraction: f64,
    /// Trials refused.
    pub gate_rejections: usize,
    /// Trials served graded coarse.
    #[serde(default)]
    pub coarse: usize,
    /// Total refinement wall time, seconds.
    pub seconds_total: f64,
    /// Median refinement wall time per trial, seconds.
    pub seconds_median: f64,
}

impl Summary {
    /// Summarise trials.
    pub(crate) fn of(trials: &[Trial]) -> Summary {
        let col = |f: fn(&Trial) -> f64| trials.iter().map(f).collect::<Vec<_>>();
        let n = trials.len();
        Summary {
            trials: n,
            horizontal_m: Spread::of(&col(|t| t.horizontal_m)),
            height_m: Spread::of(&col(|t| t.height_m)),
            yaw_deg: Spread::of(&col(|t| t.yaw_deg)),
            success_fraction: trials.iter().filter(|t| t.success).count() as f64 / n.max(1) as f64,
            gate_rejections: trials.iter().filter(|t| !t.accepted).count(),
            coarse: trials.iter().filter(|t| t.grade == "coarse").count(),
            seconds_total: trials.iter().map(|t| t.seconds).sum(),
            seconds_median: Spread::of(&col(|t| t.seconds)).median,
        }
    }
}

/// The LiDAR points of a study's trials.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Ground<'a> {
    /// The map tile: each trial selects its points around its start, as the pipeline does.
    Tile(&'a Tile),
    /// Fixed point sets in the pose's frame, one per image of the scene (a LiDAR sweep from the
    /// camera's own mast, taken with the image).
    Points(&'a [Vec<crate::map::GroundPoint>]),
}

/// What a study needs: the scene in memory.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Scene<'a> {
    /// Intrinsics given to the localizer.
    pub camera: &'a Camera,
    /// Gray frames (camera size, row-major), pooled with one histogram each when there are
    /// several: a burst's temporal median, as the pipeline uses, or one per time of day.
    pub grays: &'a [&'a [u8]],
    /// The camera's validity mask ([`crate::camera::CameraModel::valid_mask`]), computed once for
    /// all trials.
    pub mask: &'a [u8],
    /// Where each trial's LiDAR points come from.
    pub ground: Ground<'a>,
    /// True pose: errors are measured against it.
    pub truth: &'a CamFromMap,
    /// The pose the start offsets are applied to: the truth, or the truth with another roll and
    /// pitch (see [`attitude_from_control_points`]).
    pub base: &'a CamFromMap,
    /// The control points the ground error is measured on (none: no ground error).
    pub control: Option<&'a crate::eval::truth::Truth>,
}

/// The truth's centre and yaw with the roll and pitch of the 6-DoF least-squares fit of
/// `control` (map point, true pixel) under the intrinsics `camera`. With exact intrinsics this is
/// the truth; with wrong ones (simulator `hard`) it is the attitude a perfect PnP would hand the
/// refinement: a principal-point error is indistinguishable from a tilt, and the 4-DoF search
/// cannot tilt, so starting from the true roll/pitch under wrong intrinsics forces the error into
/// x and y. Errors when fewer than 6 control points are given.
pub(crate) fn attitude_from_control_points(
    camera: &Camera,
    truth: &CamFromMap,
    control: &[([f64; 3], [f64; 2])],
) -> Result<CamFromMap> {
    if control.len() < 6 {
        return Err(Error::Invalid(format!(
            "control points: {} given, the attitude fit needs at least 6",
            control.len()
        )));
    }
    let corr: Vec<crate::localize::pnp::Correspondence> = control
        .iter()
        .map(|(m, p)| crate::localize::pnp::Correspondence {
            pixel: nalgebra::Point2::new(p[0], p[1]),
            world: nalgebra::Point3::new(m[0], m[1], m[2]),
        })
        .collect();
    let fit = crate::localize::pnp::refine_lm(camera, truth, &corr, 50);
    let (yaw, _, _) = truth.yaw_pitch_roll();
    let (_, pitch, roll) = fit.yaw_pitch_roll();
    Ok(CamFromMap::from_center_ypr(
        &truth.center(),
        yaw,
        pitch,
        roll,
    ))
}

/// Run one trial from `start` (offsets from the truth): the grid search, then, with `finish`,
/// the smooth estimator's local stage (as `infraloc refine`: 4-DoF, or 6-DoF when `finish`'s
/// polish frees the tilt); `None` answers the grid's cell.
/// `now` returns seconds from any origin (injected so that this module reads no clock of its
/// own).
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_trial(
    scene: &Scene,
    index: usize,
    start: [f64; 4],
    sel: &PointSelection,
    cfg: &SearchConfig,
    qcfg: &QualityConfig,
    finish: Option<&PolishedSearch>,
    now: &dyn Fn() -> f64,
) -> Result<Trial> {
    let init = pose_at(
        scene.base,
        &[start[0], start[1], start[2], start[3], 0.0, 0.0],
    );
    let t0 = now();
    let tile_points = match scene.ground {
        Ground::Tile(tile) => vec![sel.points(tile, &init)],
        Ground::Points(p) => p.to_vec(),
    };
    if tile_points.len() != 1 && tile_points.len() != scene.grays.len() {
        return Err(Error::command(
            "study",
            format!(
                "{} images but {} point sets",
                scene.grays.len(),
                tile_points.len()
            ),
        ));
    }
    let views: Vec<View> = scene
        .grays
        .iter()
        .enumerate()
        .map(|(i, gray)| View {
            gray,
            mask: scene.mask,
            points: &tile_points[i.min(tile_points.len() - 1)],
        })
        .collect();
    // As `infraloc refine`: the smooth estimator's local stage after the grid search, or the
    // grid's cell alone.
    let r = match finish {
        Some(f) => crate::localize::refine::local::refine_smooth(
            scene.camera,
            &views,
            &init,
            cfg,
            qcfg,
            f.polish.frees_tilt(),
        )
        .map(|(r, _)| r),
        None => {
            refine_polished(scene.camera, &views, &init, cfg, qcfg, None, &|_| None).map(|(r, _)| r)
        }
    }
    .map_err(|e| Error::command("study", format!("trial {index}: {e}")))?;
    let seconds = now() - t0;
    let result = offsets_from(scene.truth, &r.pose);
    let horizontal_m = result[0].hypot(result[1]);
    let (height_m, yaw_deg) = (result[2].abs(), result[3].abs());
    Ok(Trial {
        index,
        start,
        result,
        horizontal_m,
        height_m,
        yaw_deg,
        success: horizontal_m <= SUCCESS_HORIZONTAL_M
            && height_m <= SUCCESS_HEIGHT_M
            && yaw_deg <= SUCCESS_YAW_DEG,
        accepted: r.quality.served(),
        grade: r.quality.grade.name().to_string(),
        reason: (!r.quality.precise()).then(|| r.quality.grade.to_string()),
        mi: r.quality.mi,
        points: r.points.1,
        sigma: r.quality.sigma,
        ground_m: scene
            .control
            .map(|t| {
                crate::eval::truth_eval::ground_hits(scene.camera, t, &r.pose)
                    .iter()
                    .map(|h| h.error_m)
                    .collect()
            })
            .unwrap_or_default(),
        seconds,
    })
}

/// MI along each axis and over x–y around a pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Surface {
    /// Per enabled axis (x, y, z, yaw): (axis name, offsets, MI values).
    pub profiles: Vec<(String, Vec<f64>, Vec<f64>)>,
    /// x offsets of the 2-D grid, metres.
    pub grid_x: Vec<f64>,
    /// y offsets of the 2-D grid, metres.
    pub grid_y: Vec<f64>,
    /// MI over the grid, row-major with y slowest: `mi[j * grid_x.len() + i]`.
    pub grid_mi: Vec<f64>,
    /// Map x, y of the unit lateral direction (left of the view, [`lateral_direction`]).
    pub lateral_direction: [f64; 2],
    /// Lateral offsets of the yaw–lateral grid, metres.
    pub grid_lateral: Vec<f64>,
    /// Yaw offsets of the yaw–lateral grid, degrees.
    pub grid_yaw: Vec<f64>,
    /// MI over the yaw–lateral grid, yaw slowest: `mi[j * grid_lateral.len() + i]`.
    pub grid_lateral_yaw_mi: Vec<f64>,
    /// Points in the fixed set.
    pub points: usize,
}

/// Evaluate MI around `pose` with the search's estimator: the box of `cfg.spec` (its fixed point
/// set, full resolution), 1-D profiles at the finest step along x, y, z and yaw, the x–y plane
/// and the yaw–lateral plane every `xy_stride` finest cells (see [`surface_of`]).
pub(crate) fn mi_surface(
    camera: &Camera,
    gray: &[u8],
    points: &[crate::map::GroundPoint],
    pose: &CamFromMap,
    cfg: &SearchConfig,
    xy_stride: i64,
    pv: Option<crate::localize::mi::smooth::Pooling>,
) -> Result<Surface> {
    let mask = crate::camera::CameraModel::valid_mask(camera);
    let ev = Evaluator::new(camera, gray, &mask, points, pose, cfg, 0)?;
    surface_of(&ev, pose, xy_stride, pv.map(|p| (camera, p)))
}

/// [`mi_surface`] on several image/point-set pairs that share the pose, pooled into one joint
/// histogram per pose as `refine` pools them.
pub(crate) fn mi_surface_pooled(
    camera: &Camera,
    pairs: &[(&[u8], &[crate::map::GroundPoint])],
    pose: &CamFromMap,
    cfg: &SearchConfig,
    xy_stride: i64,
    pv: Option<crate::localize::mi::smooth::Pooling>,
) -> Result<Surface> {
    let mask = crate::camera::CameraModel::valid_mask(camera);
    let views: Vec<crate::localize::mi::objective::View> = pairs
        .iter()
        .map(|(gray, points)| crate::localize::mi::objective::View {
            gray,
            mask: &mask,
            points,
        })
        .collect();
    let ev = Evaluator::pooled(camera, &views, pose, cfg, 0)?;
    surface_of(&ev, pose, xy_stride, pv.map(|p| (camera, p)))
}

/// The horizontal unit vector (map x, y) to the *left* of the camera's view: perpendicular to
/// the horizontal part of the optical axis, or, for a camera looking (nearly) straight down, of
/// the image's up direction. The yaw–lateral plane moves the camera along it.
pub(crate) fn lateral_direction(pose: &CamFromMap) -> [f64; 2] {
    let inv = pose.rotation.inverse();
    let axis = inv * nalgebra::Vector3::z();
    // Below ~17° from the nadir the optical axis' horizontal part is short and unstable; the
    // image's up direction (−y of the camera) is where a nadir camera "looks".
    let view = if axis.xy().norm() > 0.3 {
        axis.xy()
    } else {
        (inv * -nalgebra::Vector3::y()).xy()
    };
    let v = view.normalize();
    [-v.y, v.x]
}

/// [`mi_surface`] on a prepared evaluator (its box and fixed point set; one view or several
/// pooled): profiles at the finest step, the x–y plane (z and yaw fixed) and the yaw–lateral
/// plane (z fixed; lateral along [`lateral_direction`], over the smaller of the x and y half
/// ranges) every `xy_stride` finest cells. With `pv`, the values are the partial-volume
/// estimator's ([`crate::localize::mi::smooth`]) on the same images and point sets, pooled as it says.
pub(crate) fn surface_of(
    ev: &Evaluator,
    pose: &CamFromMap,
    xy_stride: i64,
    pv: Option<(&Camera, crate::localize::mi::smooth::Pooling)>,
) -> Result<Surface> {
    if xy_stride < 1 {
        return Err(Error::Invalid(format!(
            "surface stride {xy_stride}: must be ≥ 1"
        )));
    }
    let g = *ev.grid();
    let objective = ev.objective();
    let smooth = pv.map(|(cam, p)| crate::localize::mi::smooth::Smooth::of_evaluator(cam, ev, p));
    let score = |offsets: &[[f64; 6]]| -> Vec<f64> {
        if let Some(est) = &smooth {
            return offsets
                .par_iter()
                .map(|o| {
                    est.evaluate(&crate::localize::mi::space::pose_at(pose, o), false)
                        .value
                })
                .collect();
        }
        // Chunks keep one scratch buffer per task; collect keeps the input order.
        offsets
            .par_chunks(16)
            .flat_map_iter(|chunk| {
                let mut s = crate::localize::mi::kernel::Scratch::default();
                chunk
                    .iter()
                    .map(|o| ev.value_at(0, o, &mut s).get(objective))
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let mut profiles = Vec::new();
    for axis in 0..4 {
        let offs: Vec<f64> = (-g.m[axis]..=g.m[axis])
            .map(|k| k as f64 * g.step[axis])
            .collect();
        let cells: Vec<[f64; 6]> = offs
            .iter()
            .map(|&v| {
                let mut c = [0.0; 6];
                c[axis] = v;
                c
            })
            .collect();
        profiles.push((AXES[axis].to_string(), offs, score(&cells)));
    }
    let ks = |m: i64| -> Vec<i64> {
        let k = m / xy_stride;
        (-k..=k).map(|j| j * xy_stride).collect()
    };
    let grid_x: Vec<f64> = ks(g.m[0]).iter().map(|&i| i as f64 * g.step[0]).collect();
    let grid_y: Vec<f64> = ks(g.m[1]).iter().map(|&j| j as f64 * g.step[1]).collect();
    let cells: Vec<[f64; 6]> = grid_y
        .iter()
        .flat_map(|&y| grid_x.iter().map(move |&x| [x, y, 0.0, 0.0, 0.0, 0.0]))
        .collect();
    let grid_mi = score(&cells);
    // Lateral: the finer of the x and y steps, within both half ranges, so every pose lies
    // inside the box whose fixed point set the evaluator holds.
    let lat_step = g.step[0].min(g.step[1]);
    let lat_m =
        ((g.m[0] as f64 * g.step[0]).min(g.m[1] as f64 * g.step[1]) / lat_step).floor() as i64;
    let dir = lateral_direction(pose);
    let grid_lateral: Vec<f64> = ks(lat_m).iter().map(|&i| i as f64 * lat_step).collect();
    let grid_yaw: Vec<f64> = ks(g.m[3]).iter().map(|&j| j as f64 * g.step[3]).collect();
    let cells: Vec<[f64; 6]> = grid_yaw
        .iter()
        .flat_map(|&yaw| {
            grid_lateral
                .iter()
                .map(move |&l| [l * dir[0], l * dir[1], 0.0, yaw, 0.0, 0.0])
        })
        .collect();
    let grid_lateral_yaw_mi = score(&cells);
    Ok(Surface {
        profiles,
        grid_x,
        grid_y,
        grid_mi,
        lateral_direction: dir,
        grid_lateral,
        grid_yaw,
        grid_lateral_yaw_mi,
        points: ev.n_points,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn starts_are_seeded_and_bounded() {
        let p = Perturbation::default();
        let a = p.starts(50, 7);
        assert_eq!(a, p.starts(50, 7));
        assert_ne!(a, p.starts(50, 8));
        assert!(a.iter().all(|s| s[0].abs() <= 0.8
            && s[1].abs() <= 0.8
            && s[2].abs() <= 0.4
            && s[3].abs() <= 2.5));
    }

    #[test]
    fn spread_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = Spread::of(&v);
        assert_eq!((s.median, s.p95, s.max), (50.5, 95.0, 100.0));
        assert!(Spread::of(&[]).median.is_nan());
    }
}
