//! One-call MI refinement (pure): prepare, search, assess. The CLI (`infraloc refine`) and the
//! pipeline call this; they only do the file I/O around it.

use super::points::GroundPoint;
use super::quality::{assess, Quality, QualityConfig};
use super::search::{search, Evaluator, Mode, SearchConfig, SearchStats, MAX_LEVEL};
use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::pose::CamFromMap;
use serde::Serialize;

/// The refinement's answer.
#[derive(Debug, Clone)]
pub struct Refinement {
    /// The refined pose (roll and pitch kept from the initial pose unless 6-DoF is on).
    pub pose: CamFromMap,
    /// Offsets from the initial pose: x, y, z (m), yaw, pitch, roll (deg).
    pub offsets: [f64; 6],
    /// Search counters.
    pub stats: SearchStats,
    /// Quality statistics and the gate's verdict.
    pub quality: Quality,
    /// Points given, and points in the fixed set.
    pub points: (usize, usize),
}

/// Machine-readable summary (`--report`).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Search mode.
    pub mode: Mode,
    /// Offsets from the initial pose: x, y, z (m), yaw, pitch, roll (deg).
    pub offsets: [f64; 6],
    /// Points given.
    pub points_input: usize,
    /// Points in the fixed set.
    pub points_used: usize,
    /// Search counters.
    pub stats: SearchStats,
    /// exhaustive / actual point-pose evaluations.
    pub evaluation_ratio: f64,
    /// Quality.
    pub quality: Quality,
}

impl Refinement {
    /// The `--report` summary.
    pub fn report(&self, mode: Mode) -> Report {
        Report {
            mode,
            offsets: self.offsets,
            points_input: self.points.0,
            points_used: self.points.1,
            stats: self.stats,
            evaluation_ratio: self.stats.exhaustive_point_evaluations as f64
                / self.stats.point_evaluations.max(1) as f64,
            quality: self.quality.clone(),
        }
    }
}

/// Refine `init` against `gray` (row-major, camera size). The validity mask is the camera's image
/// circle. Errors (one line) on empty/invisible/non-finite points, image size ≠ camera size, bad
/// search spec. A result that fails the quality gate is returned with `quality.accepted = false`;
/// the caller decides whether to write it.
pub fn refine(
    cam: &Camera,
    gray: &[u8],
    points: &[GroundPoint],
    init: &CamFromMap,
    cfg: &SearchConfig,
    qcfg: &QualityConfig,
) -> Result<Refinement> {
    // A frame of the wrong size is refused by `Evaluator::new` (one line, both sizes).
    refine_masked(cam, gray, &cam.valid_mask(), points, init, cfg, qcfg)
}

/// [`refine`] with the camera's validity mask ([`CameraModel::valid_mask`]) computed by the
/// caller: callers that refine one camera many times (the pipeline's search + polish, a study's
/// trials) compute it once — on a 5 MP frame it costs about as much as a small search.
pub fn refine_masked(
    cam: &Camera,
    gray: &[u8],
    mask: &[u8],
    points: &[GroundPoint],
    init: &CamFromMap,
    cfg: &SearchConfig,
    qcfg: &QualityConfig,
) -> Result<Refinement> {
    // `Evaluator::new` checks the image and mask sizes.
    let levels = if cfg.mode == Mode::Exhaustive {
        0
    } else {
        MAX_LEVEL
    };
    let ev = Evaluator::new(cam, gray, mask, points, init, cfg, levels)?;
    let res = search(&ev, cfg);
    let quality = assess(&ev, &res, qcfg);
    if !res.pose.translation.iter().all(|v| v.is_finite()) {
        return Err(Error::stage("mi", "refined pose is not finite"));
    }
    Ok(Refinement {
        pose: res.pose,
        offsets: res.offsets,
        stats: res.stats,
        quality,
        points: (ev.n_input, ev.n_points),
    })
}
