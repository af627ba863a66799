//! Scoring a pose against a simulated scene's truth the way the detection pipeline feels it.
//!
//! The detection pipeline maps image pixels onto the ground with infraloc's pose *and the same
//! intrinsics infraloc was given*. When those intrinsics are wrong (the `hard` preset), no pose
//! reaches the truth, so three figures are judged against the **oracle** — the 6-DoF
//! least-squares pose of the truth's control points under the given intrinsics, the best any
//! localizer can do with them:
//! - the pose's offset from the oracle (horizontal, height, yaw);
//! - the **ground error**: each control point's true pixel cast through the given intrinsics and
//!   the pose onto the horizontal plane at the point's true height, against its true map
//!   position — overall and by distance from the pole, since a vehicle 25 m out lives in the far
//!   field;
//! - the control points' reprojection error (the seed paper's metric).
//!
//! Signed per-axis errors are kept too, so a reported σ can be checked against the real error
//! (coverage).

use crate::camera::{Camera, CameraModel};
use crate::error::Result;
use crate::eval::truth::Truth;
use crate::localize::pipeline::{Stage, StageDetail};
use crate::localize::pnp::{refine_lm, Correspondence};
use crate::pose::CamFromMap;
use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

/// Distance bands from the pole (horizontal, metres) the ground error is reported in.
pub(crate) const BANDS_M: [(f64, f64); 3] = [(0.0, 10.0), (10.0, 20.0), (20.0, 30.0)];

/// Fewest control points the oracle is fitted from (6 DoF, each point gives two residuals; a
/// margin against a degenerate spread).
const MIN_ORACLE_POINTS: usize = 6;

/// The oracle: the least-squares pose of the truth's control points (map point ↔ true pixel)
/// under `camera`, started from the true pose. `None` with fewer than six control points.
pub fn oracle_pose(camera: &Camera, truth: &Truth) -> Option<CamFromMap> {
    let corr: Vec<Correspondence> = truth
        .control_points
        .iter()
        .map(|c| Correspondence {
            pixel: Point2::new(c.pixel[0], c.pixel[1]),
            world: Point3::new(c.map[0], c.map[1], c.map[2]),
        })
        .collect();
    (corr.len() >= MIN_ORACLE_POINTS).then(|| refine_lm(camera, &truth.pose, &corr, 50))
}

/// One control point's ground error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GroundHit {
    /// Horizontal distance of the point from the true camera centre (the pole), metres.
    pub range_m: f64,
    /// Distance between where the pixel lands and where the point is, metres.
    pub error_m: f64,
}

/// Every control point's ground error under `camera` and `pose`; points whose pixel does not
/// unproject, or whose ray does not descend to the point's height, are left out.
pub fn ground_hits(camera: &Camera, truth: &Truth, pose: &CamFromMap) -> Vec<GroundHit> {
    let c = pose.center();
    let tc = truth.pose.center();
    let map_from_cam = pose.rotation.inverse();
    truth
        .control_points
        .iter()
        .filter_map(|cp| {
            let b = camera
                .unproject(&Point2::new(cp.pixel[0], cp.pixel[1]))
                .ok()?;
            let d = map_from_cam * b.into_inner();
            let s = (cp.map[2] - c.z) / d.z;
            if !(s.is_finite() && s > 0.0) {
                return None;
            }
            let (gx, gy) = (c.x + s * d.x, c.y + s * d.y);
            Some(GroundHit {
                range_m: (cp.map[0] - tc.x).hypot(cp.map[1] - tc.y),
                error_m: (gx - cp.map[0]).hypot(gy - cp.map[1]),
            })
        })
        .collect()
}

/// Median, 95th percentile (nearest rank) and count of `xs`; `None` when empty.
pub fn median_p95(xs: &[f64]) -> Option<Percentiles> {
    let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    let p95 = v[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1];
    Some(Percentiles { median, p95, n })
}

/// A distribution's median, 95th percentile and size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Percentiles {
    /// Median.
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Number of values.
    pub n: usize,
}

/// Ground error of one pose: over all control points and per distance band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundError {
    /// All control points, metres.
    pub all: Option<Percentiles>,
    /// Per band of `BANDS_M`, metres (`None` for a band without points).
    pub bands: Vec<BandError>,
}

/// Ground error within one distance band.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BandError {
    /// Band start, metres from the pole.
    pub from_m: f64,
    /// Band end (exclusive), metres.
    pub to_m: f64,
    /// Error statistics in the band, metres.
    pub error: Option<Percentiles>,
}

/// Summarise ground hits overall and per band.
pub fn ground_error(hits: &[GroundHit]) -> GroundError {
    let all: Vec<f64> = hits.iter().map(|h| h.error_m).collect();
    GroundError {
        all: median_p95(&all),
        bands: BANDS_M
            .iter()
            .map(|&(from_m, to_m)| {
                let xs: Vec<f64> = hits
                    .iter()
                    .filter(|h| h.range_m >= from_m && h.range_m < to_m)
                    .map(|h| h.error_m)
                    .collect();
                BandError {
                    from_m,
                    to_m,
                    error: median_p95(&xs),
                }
            })
            .collect(),
    }
}

/// Signed error of a pose against a reference: camera centre (map x, y, z, metres) and yaw
/// (degrees, wrapped to ±180), the axes the refinement's σ describes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SignedError {
    /// Map x, metres.
    pub x: f64,
    /// Map y, metres.
    pub y: f64,
    /// Height, metres.
    pub z: f64,
    /// Yaw, degrees.
    pub yaw: f64,
}

impl SignedError {
    /// `pose` minus `reference`.
    pub fn between(pose: &CamFromMap, reference: &CamFromMap) -> Self {
        let [x, y, z, yaw, _, _] = crate::pose::offsets_between(reference, pose);
        SignedError { x, y, z, yaw }
    }

    /// Horizontal distance, metres.
    pub fn horizontal_m(&self) -> f64 {
        self.x.hypot(self.y)
    }

    /// Whether every axis lies within `k` σ (+ `slack`, in the axis' unit: half a search step).
    /// An axis whose σ is not finite covers anything (the gate refuses such results).
    pub fn within(
        &self,
        sigma: &crate::localize::refine::quality::Sigma,
        k: f64,
        slack: [f64; 4],
    ) -> [bool; 4] {
        let e = [self.x, self.y, self.z, self.yaw];
        let s = [sigma.x, sigma.y, sigma.z, sigma.yaw];
        std::array::from_fn(|i| !s[i].is_finite() || e[i].abs() <= k * s[i] + slack[i])
    }
}

/// Errors of each stage against a simulator `truth.json` (its text; `origin` names it in errors):
/// for `prior` the horizontal distance of the GPS prior, for each stage with a pose (`pnp`, `mi`)
/// [`pose_errors`] plus its signed error (`signed`), its ground error (`ground`) and its offset
/// from the oracle (`vs_oracle`), the oracle's own errors (`oracle`; see
/// this module), and the number of control points. The report of
/// `infraloc localize --truth`, `infraloc demo` and `examples/pipeline_accuracy.rs` use this.
pub fn truth_errors(
    text: &str,
    origin: &std::path::Path,
    camera: &Camera,
    stages: &[Stage],
) -> Result<Value> {
    let truth = crate::eval::truth::parse_truth(text, origin)?;
    let tc = truth.pose.center();
    let mut out = json!({ "control_points": truth.control_points.len() });
    let oracle = oracle_pose(camera, &truth);
    if let Some(o) = &oracle {
        out["oracle"] = pose_errors(&truth, camera, o);
        out["oracle"]["ground"] = json!(ground_error(&ground_hits(camera, &truth, o)));
    }
    for s in stages {
        if let Some(p) = &s.pose {
            let mut e = pose_errors(&truth, camera, p);
            e["signed"] = json!(SignedError::between(p, &truth.pose));
            e["ground"] = json!(ground_error(&ground_hits(camera, &truth, p)));
            if let Some(o) = &oracle {
                let d = SignedError::between(p, o);
                e["vs_oracle"] = json!({
                    "horizontal_m": d.horizontal_m(),
                    "height_m": d.z.abs(),
                    "yaw_deg": d.yaw.abs(),
                    "signed": d,
                });
            }
            out[s.name.name()] = e;
        } else if let StageDetail::Prior(d) = &s.detail {
            // The prior is a position only: no height, no heading.
            out[s.name.name()] =
                json!({ "horizontal_m": ((d.x - tc.x).powi(2) + (d.y - tc.y).powi(2)).sqrt() });
        }
    }
    Ok(out)
}

/// Errors of pose `p` against the truth: horizontal, height, yaw and full-rotation errors and the
/// mean reprojection error of the truth's control points under `camera` (the seed paper's
/// accuracy figure; NaN without control points).
pub(crate) fn pose_errors(truth: &Truth, camera: &Camera, p: &CamFromMap) -> Value {
    let t = &truth.pose;
    let (c, tc) = (p.center(), t.center());
    let dyaw = crate::pose::angle_difference(p.yaw_pitch_roll().0, t.yaw_pitch_roll().0);
    let reproj: Vec<f64> = truth
        .control_points
        .iter()
        .filter_map(|cp| {
            let q = camera
                .project(&p.transform(&nalgebra::Point3::from(cp.map)).coords)
                .ok()?;
            Some(((q.x - cp.pixel[0]).powi(2) + (q.y - cp.pixel[1]).powi(2)).sqrt())
        })
        .collect();
    let mean = if reproj.is_empty() {
        f64::NAN
    } else {
        reproj.iter().sum::<f64>() / reproj.len() as f64
    };
    json!({
        "horizontal_m": ((c.x - tc.x).powi(2) + (c.y - tc.y).powi(2)).sqrt(),
        "height_m": (c.z - tc.z).abs(),
        "yaw_deg": dyaw.abs().to_degrees(),
        "rotation_deg": crate::pose::rotation_angle_between(&p.rotation, &t.rotation).to_degrees(),
        "control_points_mean_px": mean,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Mei;
    use crate::sim::TruthPoint;

    fn camera() -> Camera {
        Camera::Mei(Mei {
            fx: 400.0,
            fy: 400.0,
            cx: 640.0,
            cy: 480.0,
            skew: 0.0,
            xi: 1.2,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            width: 1280,
            height: 960,
            fov_deg: None,
        })
    }

    /// A nadir camera 8 m up and control points on a ring grid out to 28 m.
    fn truth(cam: &Camera) -> Truth {
        let pose = CamFromMap::from_center_ypr(&Point3::new(100.0, 200.0, 8.0), 0.3, 0.0, 0.0);
        let mut control_points = Vec::new();
        for r in [3.0, 7.0, 12.0, 17.0, 22.0, 28.0] {
            for k in 0..8 {
                let a = k as f64 * std::f64::consts::FRAC_PI_4 + 0.1;
                let m = Point3::new(100.0 + r * a.cos(), 200.0 + r * a.sin(), 0.2);
                if let Ok(px) = cam.project(&pose.transform(&m).coords) {
                    control_points.push(TruthPoint {
                        id: String::new(),
                        map: [m.x, m.y, m.z],
                        pixel: [px.x, px.y],
                    });
                }
            }
        }
        Truth {
            pose,
            crs: None,
            control_points,
        }
    }

    #[test]
    fn the_true_pose_under_true_intrinsics_has_no_ground_error_and_is_its_own_oracle() {
        let cam = camera();
        let t = truth(&cam);
        assert!(t.control_points.len() > 30, "{}", t.control_points.len());
        let hits = ground_hits(&cam, &t, &t.pose);
        assert_eq!(hits.len(), t.control_points.len());
        assert!(hits.iter().all(|h| h.error_m < 1e-6), "{hits:?}");
        let o = oracle_pose(&cam, &t).expect("oracle");
        let e = SignedError::between(&o, &t.pose);
        assert!(
            e.horizontal_m() < 1e-6 && e.z.abs() < 1e-6 && e.yaw.abs() < 1e-6,
            "{e:?}"
        );
        let g = ground_error(&hits);
        assert_eq!(g.bands.len(), 3);
        assert!(g.bands.iter().all(|b| b.error.is_some()), "{g:?}");
    }

    #[test]
    fn a_shifted_pose_moves_every_ground_point_by_the_shift() {
        let cam = camera();
        let t = truth(&cam);
        let c = t.pose.center();
        let shifted =
            CamFromMap::from_center(t.pose.rotation, &Point3::new(c.x + 0.05, c.y - 0.02, c.z));
        let hits = ground_hits(&cam, &t, &shifted);
        let want = 0.05f64.hypot(0.02);
        assert!(
            hits.iter().all(|h| (h.error_m - want).abs() < 1e-9),
            "{hits:?}"
        );
        let e = SignedError::between(&shifted, &t.pose);
        assert!(
            (e.x - 0.05).abs() < 1e-12 && (e.y + 0.02).abs() < 1e-12,
            "{e:?}"
        );
    }

    #[test]
    fn a_yaw_error_grows_with_range_and_wrong_intrinsics_leave_a_floor() {
        let cam = camera();
        let t = truth(&cam);
        let c = t.pose.center();
        let (y, p, r) = t.pose.yaw_pitch_roll();
        let turned = CamFromMap::from_center_ypr(&c, y + 0.2f64.to_radians(), p, r);
        let g = ground_error(&ground_hits(&cam, &t, &turned));
        let near = g.bands[0].error.expect("near").median;
        let far = g.bands[2].error.expect("far").median;
        assert!(far > 3.0 * near, "near {near} far {far}");
        // A 3 % focal error: the oracle cannot reach zero ground error, and the truth pose does
        // worse than the oracle under those intrinsics.
        let Camera::Mei(mut m) = cam else {
            unreachable!()
        };
        m.fx *= 1.03;
        m.fy *= 1.03;
        let given = Camera::Mei(m);
        let o = oracle_pose(&given, &t).expect("oracle");
        let go = ground_error(&ground_hits(&given, &t, &o))
            .all
            .expect("oracle")
            .median;
        let gt = ground_error(&ground_hits(&given, &t, &t.pose))
            .all
            .expect("truth")
            .median;
        assert!(go > 1e-4 && go < gt, "oracle {go} truth {gt}");
    }

    #[test]
    fn coverage_uses_k_sigma_plus_slack_and_treats_infinite_sigma_as_covering() {
        let e = SignedError {
            x: 0.03,
            y: -0.031,
            z: 0.0,
            yaw: 0.5,
        };
        let s = crate::localize::refine::quality::Sigma {
            x: 0.01,
            y: 0.01,
            z: 0.01,
            yaw: f64::INFINITY,
            pitch: None,
            roll: None,
        };
        assert_eq!(e.within(&s, 3.0, [0.0; 4]), [true, false, true, true]);
        assert_eq!(e.within(&s, 3.0, [0.002; 4]), [true, true, true, true]);
    }

    #[test]
    fn percentiles_are_nearest_rank_and_skip_non_finite_values() {
        let p = median_p95(&[4.0, 1.0, f64::NAN, 3.0, 2.0]).expect("some");
        assert_eq!((p.median, p.p95, p.n), (2.5, 4.0, 4));
        assert!(median_p95(&[f64::NAN]).is_none());
    }
}
