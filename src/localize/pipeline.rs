//! The two-step pipeline (pure): prior → initialization (satellite matching + PnP) → MI refinement →
//! quality gate. The shell (`infraloc localize`, `demo`, the daemon) gathers the inputs and writes
//! the outputs; the clock for stage timings is injected.

use super::init::{initialize, CoarseParams, FineParams, InitResult};
use super::quality::QualityConfig;
use super::refine::{refine, Refinement};
use super::search::SearchConfig;
use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::map::{ground_points, Tile};
use crate::pose::CamFromMap;
use rand::SeedableRng;
use serde_json::{json, Value};

/// Pipeline settings.
#[derive(Debug, Clone)]
pub struct Params {
    /// Coarse matching.
    pub coarse: CoarseParams,
    /// Fine matching + PnP.
    pub fine: FineParams,
    /// MI search.
    pub search: SearchConfig,
    /// MI quality gate.
    pub quality: QualityConfig,
    /// Seed of every random choice (RANSAC).
    pub seed: u64,
    /// GPS search radius = this many σ of the prior …
    pub prior_sigmas: f64,
    /// … clamped to this range, metres.
    pub search_radius_range_m: (f64, f64),
    /// LiDAR points used by MI lie within this radius of the nadir point, metres …
    pub mi_radius_m: f64,
    /// … and within this off-nadir angle, degrees.
    pub mi_max_off_nadir_deg: f64,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            coarse: CoarseParams::default(),
            fine: FineParams::default(),
            search: SearchConfig::default(),
            quality: QualityConfig::default(),
            seed: 0,
            prior_sigmas: 3.0,
            search_radius_range_m: (5.0, 40.0),
            mi_radius_m: 30.0,
            mi_max_off_nadir_deg: 70.0,
        }
    }
}

/// One stage's record for the report and the pose file.
#[derive(Debug, Clone)]
pub struct Stage {
    /// `prior`, `pnp` or `mi`.
    pub name: &'static str,
    /// The stage's pose, if it makes one.
    pub pose: Option<CamFromMap>,
    /// Wall time, seconds.
    pub seconds: f64,
    /// Stage-specific figures.
    pub detail: Value,
}

impl Stage {
    /// JSON form: name, seconds, detail, and the pose as centre + yaw/pitch/roll.
    pub fn to_json(&self) -> Value {
        let mut v = json!({ "name": self.name, "seconds": self.seconds, "detail": self.detail });
        if let Some(p) = &self.pose {
            let (y, pi, r) = p.yaw_pitch_roll();
            v["camera_center"] = json!(<[f64; 3]>::from(p.center().coords));
            v["yaw_pitch_roll_deg"] = json!([y.to_degrees(), pi.to_degrees(), r.to_degrees()]);
        }
        v
    }
}

/// What the pipeline produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The final (MI-refined) pose.
    pub pose: CamFromMap,
    /// Initialization details.
    pub init: InitResult,
    /// Refinement details (quality included).
    pub refinement: Refinement,
    /// Per-stage records, in order.
    pub stages: Vec<Stage>,
}

/// The LiDAR ground points MI uses around `pose`: within [`Params::mi_radius_m`] of the nadir
/// point and within [`Params::mi_max_off_nadir_deg`] of nadir as seen from the camera's height.
pub fn mi_points(tile: &Tile, pose: &CamFromMap, p: &Params) -> Vec<crate::map::GroundPoint> {
    let c = pose.center();
    let ground = super::init::height_at(&tile.height, c.x, c.y).unwrap_or(c.z - 8.0);
    let radius =
        ((c.z - ground).max(1.0) * p.mi_max_off_nadir_deg.to_radians().tan()).min(p.mi_radius_m);
    ground_points(tile, (c.x, c.y), radius)
}

/// Run the pipeline on a (temporally median-filtered) gray frame. `now` returns seconds from any
/// fixed origin. Errors name the stage and the numbers.
pub fn localize(
    camera: &Camera,
    image: &[u8],
    tile: &Tile,
    prior_xy: (f64, f64),
    prior_sigma_m: f64,
    p: &Params,
    now: &dyn Fn() -> f64,
) -> Result<Outcome> {
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    if image.len() != w * h {
        return Err(Error::stage(
            "capture",
            format!("frame has {} pixels, camera expects {w}×{h}", image.len()),
        ));
    }
    if !(prior_sigma_m > 0.0 && prior_xy.0.is_finite() && prior_xy.1.is_finite()) {
        return Err(Error::stage(
            "prior",
            format!("unusable prior {prior_xy:?} σ {prior_sigma_m}"),
        ));
    }
    let (lo, hi) = p.search_radius_range_m;
    let radius = (p.prior_sigmas * prior_sigma_m).clamp(lo, hi);
    let mut stages = vec![Stage {
        name: "prior",
        pose: None,
        seconds: 0.0,
        detail: json!({ "x": prior_xy.0, "y": prior_xy.1, "sigma_m": prior_sigma_m, "search_radius_m": radius }),
    }];
    if !tile.satellite.grid.contains(prior_xy.0, prior_xy.1, 0.0) {
        return Err(Error::stage(
            "prior",
            format!(
                "prior ({:.1}, {:.1}) is outside tile {:?}",
                prior_xy.0, prior_xy.1, tile.id
            ),
        ));
    }
    let t0 = now();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed);
    let init = initialize(
        camera,
        image,
        &tile.satellite,
        &tile.height,
        prior_xy,
        radius,
        &p.coarse,
        &p.fine,
        &mut rng,
    )?;
    let t1 = now();
    stages.push(Stage {
        name: "pnp",
        pose: Some(init.pose),
        seconds: t1 - t0,
        detail: json!({
            "matches": init.matches, "inliers": init.inliers, "rms_px": init.rms_px,
            "candidates": init.candidates_tried,
            "coarse": { "yaw_deg": init.candidate.yaw.to_degrees(), "height_m": init.candidate.height,
                        "offset_m": init.candidate.offset, "score": init.candidate.score },
        }),
    });
    let points = mi_points(tile, &init.pose, p);
    let refinement = refine(camera, image, &points, &init.pose, &p.search, &p.quality)?;
    let t2 = now();
    stages.push(Stage {
        name: "mi",
        pose: Some(refinement.pose),
        seconds: t2 - t1,
        detail: serde_json::to_value(refinement.report(p.search.mode)).unwrap_or(Value::Null),
    });
    if !refinement.quality.accepted {
        return Err(Error::stage(
            "mi",
            format!(
                "quality gate: {}",
                refinement.quality.reason.clone().unwrap_or_default()
            ),
        ));
    }
    Ok(Outcome {
        pose: refinement.pose,
        init,
        refinement,
        stages,
    })
}
