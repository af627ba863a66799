//! The drift check: a narrow MI search around the served pose on fresh frames, asking whether
//! the camera has moved (a knocked or turned pole). The service runs it on its schedule and
//! before it lets a new result replace a served pose ([`drift_search_with`] on every LiDAR cell);
//! the search and the grid's quality gate are a localization's own, on a thinned point set and
//! without the smooth stage's σ.

use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::localize::mi::objective::{Evaluator, View};
use crate::localize::mi::space::{AxisRange, SearchConfig, SearchSpec, MAX_LEVEL};
use crate::localize::pipeline::{mi_points, Params};
use crate::localize::refine::quality::{assess, GateCheck, QualityConfig};
use crate::localize::refine::search::search;
use crate::map::Tile;
use crate::pose::CamFromMap;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// The drift check's thresholds: the camera counts as moved when the optimum is this far from
/// the served pose (the service's `drift-threshold-m` and `drift-threshold-deg`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftThresholds {
    /// Horizontal shift, metres.
    pub shift_m: f64,
    /// Yaw change, degrees.
    pub yaw_deg: f64,
}

/// The drift check's search box around the served pose: wide enough to see a knocked camera
/// (the thresholds are 0.1 m / 0.3° by default), narrow enough to cost a fraction of a
/// localization.
pub const DRIFT_SPEC: SearchSpec = SearchSpec {
    x: AxisRange {
        half: 0.5,
        step: 0.02,
    },
    y: AxisRange {
        half: 0.5,
        step: 0.02,
    },
    z: AxisRange {
        half: 0.2,
        step: 0.02,
    },
    yaw: AxisRange {
        half: 1.5,
        step: 0.05,
    },
    pitch: None,
    roll: None,
    tilt_pivot_m: None,
};

/// A drift search's judgement of the served pose against fresh frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftVerdict {
    /// Whether the camera counts as moved.
    pub moved: bool,
    /// Why it counts as moved (`None` when it does not).
    pub reason: Option<String>,
    /// Horizontal distance of the optimum from the served pose, metres.
    pub shift_m: f64,
    /// Height offset of the optimum, metres.
    pub dz_m: f64,
    /// Yaw offset of the optimum, degrees.
    pub yaw_deg: f64,
}

/// The optimum a drift search found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Optimum {
    /// Camera centre, map CRS, metres.
    pub camera_center: [f64; 3],
    /// Yaw, pitch, roll, degrees.
    pub yaw_pitch_roll_deg: [f64; 3],
    /// Its NMI on the fresh frames.
    pub nmi: f64,
}

/// A drift search's answer: the verdict and the optimum it is based on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftSearch {
    /// The judgement.
    #[serde(flatten)]
    pub verdict: DriftVerdict,
    /// The optimum.
    pub optimum: Optimum,
}

/// How the drift check thins its search ([`drift_search_with`]). The check's thresholds (0.1 m,
/// 0.3°) are five times the search step, so it needs where the peak is and whether it is clear,
/// not the full point set's precision; and it runs on the node's schedule for its whole life
/// (issue 18: ≤ 0.5 CPU-s; docs/benchmarks.md "Drift check").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriftParams {
    /// Keep every `thin`-th LiDAR cell along both map axes (3: a 0.3 m grid from the 0.1 m
    /// tiles, a ninth of the points).
    pub thin: i64,
    /// The coarse levels' smallest point subsample ([`SearchConfig::coarse_min_points`]).
    pub coarse_min_points: usize,
}

impl Default for DriftParams {
    fn default() -> Self {
        DriftParams {
            thin: DRIFT_THIN,
            coarse_min_points: DRIFT_COARSE_MIN_POINTS,
        }
    }
}

/// [`DriftParams::thin`] of the service's drift check. Measured against 2 (and 1) on 24 seeded
/// scenes × 6 knocks (`examples/drift_verdicts.rs`, docs/benchmarks.md "Drift check"): as many
/// right verdicts, a third less CPU; its optimum is noisier (median 1.2–2.0 cm from the full
/// refinement's against 0.9–1.1), which the 0.1 m threshold leaves room for.
pub const DRIFT_THIN: i64 = 3;

/// [`DriftParams::coarse_min_points`] of the service's drift check: the coarse levels' survey
/// needs the peak's neighbourhood, not its place (the finest level keeps every thinned point).
pub const DRIFT_COARSE_MIN_POINTS: usize = 10_000;

/// The camera's validity mask, computed once per camera for the process (the drift check runs on
/// a schedule with the same camera; the mask depends on nothing else).
fn cached_mask(camera: &Camera) -> Arc<Vec<u8>> {
    static CACHE: Mutex<Option<(Camera, Arc<Vec<u8>>)>> = Mutex::new(None);
    let mut c = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    match &*c {
        Some((cam, mask)) if cam == camera => mask.clone(),
        _ => {
            let mask = Arc::new(camera.valid_mask());
            *c = Some((camera.clone(), mask.clone()));
            mask
        }
    }
}

/// A narrow MI search ([`DRIFT_SPEC`]) around `pose` on `image`. The camera counts as moved when
/// the optimum is [`DriftThresholds::shift_m`] or more away horizontally, [`DriftThresholds::yaw_deg`] or more in
/// yaw (the [`DriftThresholds`]), or there is no clear MI peak in the box at all. The answer also carries the
/// optimum's pose and NMI.
///
/// A gate refusal for ambiguity alone (a second peak near the optimum's height, often the same
/// flat valley: docs/refine.md) is judged by where the optimum is, like an accepted one: the
/// optimum passed every other check, so it is a clear peak; when it lies within the thresholds the
/// served pose is the frames' best explanation and a near-tie elsewhere is no evidence that the
/// camera moved. Counting it as moved made a steady camera re-localize (examples/drift_verdicts.rs).
///
/// The search and its quality gate are those of a localization's MI stage, on the thinned point
/// set ([`DRIFT_THIN`]) and without the smooth stage's σ: the verdict asks where the peak is
/// and whether it is clear, not how precise the served pose is.
pub fn drift_search(
    camera: &Camera,
    gray: &[u8],
    tile: &Tile,
    pose: &CamFromMap,
    thresholds: &DriftThresholds,
) -> Result<DriftSearch> {
    drift_search_with(
        camera,
        gray,
        tile,
        pose,
        thresholds,
        &DriftParams::default(),
    )
}

/// [`drift_search`] with its thinning given (for measuring the check's cost against its
/// verdicts: `examples/drift_verdicts.rs`).
pub fn drift_search_with(
    camera: &Camera,
    gray: &[u8],
    tile: &Tile,
    pose: &CamFromMap,
    thresholds: &DriftThresholds,
    params: &DriftParams,
) -> Result<DriftSearch> {
    let g = tile.reflectivity.grid;
    let thin = params.thin.max(1);
    let on_grid = |v: f64| (v.round() as i64).rem_euclid(thin) == 0;
    let points: Vec<_> = mi_points(tile, pose, &Params::default())
        .into_iter()
        .filter(|p| {
            let (c, r) = g.to_pixel(p.x, p.y);
            on_grid(c) && on_grid(r)
        })
        .collect();
    let search_cfg = SearchConfig {
        spec: DRIFT_SPEC,
        coarse_min_points: params.coarse_min_points,
        ..SearchConfig::default()
    };
    let mask = cached_mask(camera);
    let views = [View {
        gray,
        mask: &mask,
        points: &points,
    }];
    let ev = Evaluator::pooled(camera, &views, pose, &search_cfg, MAX_LEVEL)?;
    let res = search(&ev, &search_cfg);
    let quality = assess(&ev, &res, &QualityConfig::default());
    if !res.pose.translation.iter().all(|v| v.is_finite()) {
        return Err(Error::stage(
            crate::stage::StageName::Mi,
            "refined pose is not finite",
        ));
    }
    let verdict = drift_verdict(
        &res.offsets,
        quality
            .grid_refusal()
            .map(|r| (Some(r.check()), r.to_string()))
            .as_ref()
            .map(|(c, w)| (*c, w.as_str())),
        thresholds.shift_m,
        thresholds.yaw_deg,
    );
    let (y, p, ro) = res.pose.yaw_pitch_roll();
    Ok(DriftSearch {
        verdict,
        optimum: Optimum {
            camera_center: <[f64; 3]>::from(res.pose.center().coords),
            yaw_pitch_roll_deg: [y.to_degrees(), p.to_degrees(), ro.to_degrees()],
            nmi: quality.nmi,
        },
    })
}

/// Judge a drift search's offsets (x, y, z m; yaw deg; …) and the gate's refusal, if any (the
/// check that refused and its words), against the thresholds. An ambiguity refusal is judged by
/// where the optimum is (see [`drift_search`]); any other refusal means there is no clear peak.
pub fn drift_verdict(
    offsets: &[f64; 6],
    refused: Option<(Option<GateCheck>, &str)>,
    threshold_m: f64,
    threshold_deg: f64,
) -> DriftVerdict {
    let shift = offsets[0].hypot(offsets[1]);
    let yaw = offsets[3];
    let beyond = if shift >= threshold_m {
        Some(format!("shifted {shift:.3} m ≥ {threshold_m} m"))
    } else if yaw.abs() >= threshold_deg {
        Some(format!("yaw changed {yaw:.3}° (|·| ≥ {threshold_deg}°)"))
    } else {
        None
    };
    let reason = match refused {
        None => beyond,
        Some((Some(GateCheck::Ambiguous), why)) => beyond.map(|b| format!("{b}; {why}")),
        Some((_, why)) => Some(format!(
            "no clear MI peak within ±{} m / ±{}° of the served pose: {why}",
            DRIFT_SPEC.x.half, DRIFT_SPEC.yaw.half,
        )),
    };
    DriftVerdict {
        moved: reason.is_some(),
        reason,
        shift_m: shift,
        dz_m: offsets[2],
        yaw_deg: yaw,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_verdict_flags_shift_yaw_and_missing_peak() {
        let v = drift_verdict(&[0.02, -0.03, 0.01, 0.1, 0.0, 0.0], None, 0.1, 0.3);
        assert!(!v.moved);
        let v = drift_verdict(&[0.12, 0.0, 0.0, 0.0, 0.0, 0.0], None, 0.1, 0.3);
        assert!(v.moved);
        assert!(v.reason.as_deref().unwrap().contains("shifted 0.120 m"));
        let v = drift_verdict(&[0.0, 0.0, 0.0, -0.5, 0.0, 0.0], None, 0.1, 0.3);
        assert!(v.reason.as_deref().unwrap().contains("yaw changed -0.500°"));
        let edge = Some((Some(GateCheck::OnEdge), "optimum on the box edge"));
        let v = drift_verdict(&[0.0; 6], edge, 0.1, 0.3);
        assert!(v.moved);
        assert!(v.reason.as_deref().unwrap().contains(
            "no clear MI peak within ±0.5 m / ±1.5° of the served pose: optimum on the box edge"
        ));
    }

    #[test]
    fn drift_verdict_judges_an_ambiguous_peak_by_where_the_optimum_is() {
        let ambiguous = Some((Some(GateCheck::Ambiguous), "ambiguous: two separate peaks"));
        // The optimum at the served pose, a near-tie 12 cm away: the served pose is still the
        // frames' best explanation.
        let v = drift_verdict(&[-0.02, 0.0, 0.0, -0.05, 0.0, 0.0], ambiguous, 0.1, 0.3);
        assert!(!v.moved, "{v:?}");
        assert_eq!(v.reason, None);
        // The optimum away from it: moved, and the reason keeps the ambiguity.
        let v = drift_verdict(&[0.25, 0.0, 0.0, 0.0, 0.0, 0.0], ambiguous, 0.1, 0.3);
        assert!(v.moved);
        assert_eq!(
            v.reason.as_deref(),
            Some("shifted 0.250 m ≥ 0.1 m; ambiguous: two separate peaks")
        );
        let v = drift_verdict(&[0.0, 0.0, 0.0, 0.4, 0.0, 0.0], ambiguous, 0.1, 0.3);
        assert!(v.moved);
        // Any other refusal is no clear peak, wherever the optimum is.
        let flat = Some((Some(GateCheck::NoPeak), "no peak along x"));
        assert!(drift_verdict(&[0.0; 6], flat, 0.1, 0.3).moved);
        assert!(drift_verdict(&[0.0; 6], Some((None, "quality gate")), 0.1, 0.3).moved);
    }
}
