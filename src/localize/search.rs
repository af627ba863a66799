//! Grid search over Θ = [x, y, z, ψ] (optionally pitch and roll) around an initial pose.
//!
//! The grid: axis i has cells at offsets k·step_i, k ∈ −m_i..=m_i, m_i = round(half_i/step_i),
//! around the initial pose (x, y, z offsets of the camera centre in the map frame; yaw about the
//! map's up axis through the camera centre, [`CamFromMap::perturbed`]). Cells are numbered
//! mixed-radix with x slowest; ties between equal scores go to the lowest number.
//!
//! Two modes:
//! - [`Mode::Exhaustive`] evaluates every cell with all points (the seed's method); exact argmax.
//! - [`Mode::Tiled`] (default) is coarse-to-fine on sub-lattices of the same grid: level L surveys
//!   the whole box at step 2^L cells — split into tiles evaluated in parallel — against a 2^L
//!   downsampled image with a point subsample; the top-k local maxima go down a level, where each is
//!   re-examined on a ±2-cell window at half the step and the top-k local maxima of all that was
//!   scored go on, down to level 0 (finest step, full image, all points); finally each candidate
//!   hill-climbs on the finest grid to a local maximum (every step's cells scored in parallel).
//!   The result is always a cell of the exhaustive grid, scored by the same estimator.
//!
//! Bias remedy: MI computed on fewer points is biased upward (≈ (bx−1)(by−1)/2N nats), so a pose
//! that pushes points out of the image would be favoured. The search therefore uses a *fixed point
//! set*: the points that land on the image, at least `visibility-margin-px` inside the valid
//! circle, from every pose of a 3^d lattice of the box (corners, edge and face centres, centre).
//! Every pose of the search then sees (nearly) the same points; the residual loss is counted and
//! reported ([`SearchStats::max_lost_fraction`]).
//!
//! Determinism: every score is a pure function of the cell (integer histogram → f64 entropies in a
//! fixed order); parallel maps are collected in input order and reductions use the total order
//! (score, −cell), so the result does not depend on thread count or scheduling.

// Axis-indexed loops over parallel fixed-size arrays ([_; 6]) read clearer with the index.
#![allow(clippy::needless_range_loop)]

use super::kernel::{
    self, accumulate, visible, visible_from_all, BinnedImage, FastCamera, GrayLevel, PoseF32,
    Scratch,
};
use super::mi::{bin_lut, mutual_information, JointHist, MiConfig, MiValue};
use super::points::{morton_order, validate, GroundPoint, PreparedPoints};
use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::pose::CamFromMap;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Axis names in grid order.
pub(crate) const AXES: [&str; 6] = ["x", "y", "z", "yaw", "pitch", "roll"];
/// Largest accepted half range for x and y (m): beyond this the prior is not a refinement start.
pub(crate) const MAX_HALF_XY: f64 = 50.0;
/// Largest accepted half range for z (m).
pub(crate) const MAX_HALF_Z: f64 = 20.0;
/// Largest accepted half range for yaw (deg).
pub(crate) const MAX_HALF_YAW: f64 = 180.0;
/// Largest accepted half range for pitch and roll (deg).
pub(crate) const MAX_HALF_TILT: f64 = 20.0;
/// Largest accepted number of grid cells (the exhaustive grid's size).
pub(crate) const MAX_CELLS: u64 = 1 << 40;
/// Deepest coarse level (step 2^6 = 64 finest cells).
pub const MAX_LEVEL: u32 = 6;

/// Half range and finest step of one axis (metres, or degrees for angles).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AxisRange {
    /// Half range: the grid spans −half..=+half around the initial value.
    pub half: f64,
    /// Finest step.
    pub step: f64,
}

impl AxisRange {
    /// Cells on each side of the centre.
    pub(crate) fn m(&self) -> i64 {
        (self.half / self.step).round() as i64
    }
}

/// The search box (`--search x=HALF:STEP,y=…,z=…,yaw=…[,pitch=…,roll=…]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SearchSpec {
    /// Map x (easting) of the camera centre, metres.
    pub x: AxisRange,
    /// Map y (northing), metres.
    pub y: AxisRange,
    /// Map z (up), metres.
    pub z: AxisRange,
    /// Yaw about the map's up axis, degrees.
    pub yaw: AxisRange,
    /// Pitch, degrees (6-DoF only; off by default).
    pub pitch: Option<AxisRange>,
    /// Roll, degrees (6-DoF only; off by default).
    pub roll: Option<AxisRange>,
    /// Pivot of the pitch/roll axes: the point on the optical axis this many metres below the
    /// camera (the ground under a downward-looking camera). `None` tilts about the camera centre.
    /// About the ground point a tilt leaves the nadir ground where it was and moves only the
    /// oblique view, so tilt and x/y stop trading against each other along a ridge of the MI
    /// surface that an axis-aligned grid follows badly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_pivot_m: Option<f64>,
}

impl Default for SearchSpec {
    /// ±1 m x/y, ±0.5 m z, ±3° yaw; finest steps 2 cm and 0.05°.
    fn default() -> Self {
        SearchSpec {
            x: AxisRange {
                half: 1.0,
                step: 0.02,
            },
            y: AxisRange {
                half: 1.0,
                step: 0.02,
            },
            z: AxisRange {
                half: 0.5,
                step: 0.02,
            },
            yaw: AxisRange {
                half: 3.0,
                step: 0.05,
            },
            pitch: None,
            roll: None,
            tilt_pivot_m: None,
        }
    }
}

impl std::str::FromStr for SearchSpec {
    type Err = Error;
    /// Parse `x=HALF:STEP,y=HALF:STEP,z=HALF:STEP,yaw=HALF:STEP` (any subset; missing axes keep
    /// their defaults; `pitch=`/`roll=` switch those axes on). The result is validated.
    fn from_str(s: &str) -> Result<Self> {
        let mut spec = SearchSpec::default();
        for item in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
            let bad = || {
                Error::Invalid(format!(
                    "--search {item:?}: expected AXIS=HALF:STEP with AXIS one of x, y, z, yaw, pitch, roll"
                ))
            };
            let (axis, val) = item.split_once('=').ok_or_else(bad)?;
            let (h, st) = val.split_once(':').ok_or_else(bad)?;
            let r = AxisRange {
                half: h.trim().parse().map_err(|_| bad())?,
                step: st.trim().parse().map_err(|_| bad())?,
            };
            if r.half == 0.0 {
                return Err(Error::Invalid(format!(
                    "--search {item}: half range and step must be positive"
                )));
            }
            match axis.trim() {
                "x" => spec.x = r,
                "y" => spec.y = r,
                "z" => spec.z = r,
                "yaw" => spec.yaw = r,
                "pitch" => spec.pitch = Some(r),
                "roll" => spec.roll = Some(r),
                _ => return Err(bad()),
            }
        }
        spec.validate()?;
        Ok(spec)
    }
}

impl SearchSpec {
    /// All six axes (pitch and roll as a single cell when off).
    pub(crate) fn axes(&self) -> [AxisRange; 6] {
        let off = AxisRange {
            half: 0.0,
            step: 1.0,
        };
        [
            self.x,
            self.y,
            self.z,
            self.yaw,
            self.pitch.unwrap_or(off),
            self.roll.unwrap_or(off),
        ]
    }

    /// Reject zero, negative, non-finite or absurd ranges and steps.
    pub(crate) fn validate(&self) -> Result<()> {
        let limits = [
            MAX_HALF_XY,
            MAX_HALF_XY,
            MAX_HALF_Z,
            MAX_HALF_YAW,
            MAX_HALF_TILT,
            MAX_HALF_TILT,
        ];
        let enabled = [
            true,
            true,
            true,
            true,
            self.pitch.is_some(),
            self.roll.is_some(),
        ];
        for (i, a) in self.axes().iter().enumerate() {
            if !enabled[i] {
                continue;
            }
            let name = AXES[i];
            // A zero half range holds the axis (used by the pipeline's tilt pass); `--search`
            // itself refuses it (see `FromStr`).
            if a.half == 0.0 && a.step.is_finite() && a.step > 0.0 {
                continue;
            }
            let positive = a.half.is_finite() && a.step.is_finite() && a.half > 0.0 && a.step > 0.0;
            if !positive {
                return Err(Error::Invalid(format!(
                    "--search {name}={}:{}: half range and step must be positive",
                    a.half, a.step
                )));
            }
            if a.half > limits[i] {
                return Err(Error::Invalid(format!(
                    "--search {name}: half range {} exceeds the limit {} (not a refinement)",
                    a.half, limits[i]
                )));
            }
            if a.step > a.half {
                return Err(Error::Invalid(format!(
                    "--search {name}: step {} larger than the half range {}",
                    a.step, a.half
                )));
            }
        }
        let cells = self.grid().cells();
        if cells <= 1 {
            return Err(Error::Invalid(
                "--search: every axis is held: nothing to search".into(),
            ));
        }
        if cells > MAX_CELLS {
            return Err(Error::Invalid(format!(
                "--search: {cells} grid cells, more than the limit {MAX_CELLS}"
            )));
        }
        Ok(())
    }

    /// The grid geometry.
    pub(crate) fn grid(&self) -> Grid {
        let axes = self.axes();
        let mut m = [0i64; 6];
        let mut step = [0f64; 6];
        for i in 0..6 {
            m[i] = if axes[i].half == 0.0 { 0 } else { axes[i].m() };
            step[i] = axes[i].step;
        }
        Grid {
            m,
            step,
            pivot: self.tilt_pivot_m,
        }
    }
}

/// Grid geometry: `m[i]` cells each side, `step[i]` per cell (m or deg).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Cells on each side of the centre, per axis.
    pub m: [i64; 6],
    /// Step per axis (m for x, y, z; degrees for angles).
    pub step: [f64; 6],
    /// Pivot depth of pitch/roll ([`SearchSpec::tilt_pivot_m`]).
    pub pivot: Option<f64>,
}

/// Integer cell offsets from the centre, per axis.
pub(crate) type Cell = [i64; 6];

impl Grid {
    /// Cells along axis i.
    pub(crate) fn n(&self, i: usize) -> u64 {
        (2 * self.m[i] + 1) as u64
    }

    /// Total number of cells.
    pub(crate) fn cells(&self) -> u64 {
        (0..6).fold(1u64, |a, i| a.saturating_mul(self.n(i)))
    }

    /// Cell number (x slowest).
    pub fn index(&self, c: &Cell) -> u64 {
        (0..6).fold(0u64, |a, i| a * self.n(i) + (c[i] + self.m[i]) as u64)
    }

    /// Cell of a number.
    pub(crate) fn cell(&self, mut idx: u64) -> Cell {
        let mut c = [0i64; 6];
        for i in (0..6).rev() {
            let n = self.n(i);
            c[i] = (idx % n) as i64 - self.m[i];
            idx /= n;
        }
        c
    }

    /// Whether a cell is inside the grid.
    pub(crate) fn contains(&self, c: &Cell) -> bool {
        (0..6).all(|i| c[i].abs() <= self.m[i])
    }

    /// Physical offsets (m, m, m, deg, deg, deg) of a cell.
    pub(crate) fn offsets(&self, c: &Cell) -> [f64; 6] {
        let mut o = [0.0; 6];
        for i in 0..6 {
            o[i] = c[i] as f64 * self.step[i];
        }
        o
    }

    /// The lattice of level l along axis i: multiples of 2^l within range.
    fn lattice_axis(&self, i: usize, level: u32) -> Vec<i64> {
        let f = 1i64 << level;
        let k = self.m[i] / f;
        (-k..=k).map(|j| j * f).collect()
    }
}

/// The pose of a cell: centre moved by (dx, dy, dz) in the map frame, yaw about the map's up axis
/// through the camera centre; pitch and roll (6-DoF) are added to the pose's own yaw/pitch/roll,
/// about the camera centre.
pub fn pose_at(init: &CamFromMap, offsets: &[f64; 6]) -> CamFromMap {
    pose_at_pivot(init, offsets, None)
}

/// Optical axes steeper than this (|z| of the unit axis in the map) have a ground pivot; a
/// near-horizontal axis (a forward-looking camera) meets the ground too far away to pivot on.
const MIN_PIVOT_AXIS_Z: f64 = 0.3;

/// [`pose_at`] with the pitch/roll pivot `pivot` metres below the camera on its optical axis
/// (see [`SearchSpec::tilt_pivot_m`]): after the tilt the centre moves horizontally so that the
/// optical axis meets the pivot's height at the same point as before; the centre's height is kept.
pub(crate) fn pose_at_pivot(
    init: &CamFromMap,
    offsets: &[f64; 6],
    pivot: Option<f64>,
) -> CamFromMap {
    let dc = Vector3::new(offsets[0], offsets[1], offsets[2]);
    let moved = init.perturbed(&dc, offsets[3].to_radians());
    if offsets[4] == 0.0 && offsets[5] == 0.0 {
        return moved;
    }
    let c = moved.center();
    let (y, p, r) = moved.yaw_pitch_roll();
    let tilted = CamFromMap::from_center_ypr(
        &c,
        y,
        p + offsets[4].to_radians(),
        r + offsets[5].to_radians(),
    );
    let Some(depth) = pivot.filter(|d| d.is_finite() && *d > 0.0) else {
        return tilted;
    };
    let axis = |q: &CamFromMap| q.rotation.inverse() * Vector3::z();
    let (d0, d1) = (axis(&moved), axis(&tilted));
    if d0.z > -MIN_PIVOT_AXIS_Z || d1.z > -MIN_PIVOT_AXIS_Z {
        return tilted;
    }
    // Ground point of the old axis, then the centre at the same height on the new axis through it.
    let g = c + d0 * (depth / -d0.z);
    let c1 = g - d1 * (depth / -d1.z);
    CamFromMap::from_center(tilted.rotation, &c1)
}

/// Search mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Coarse-to-fine over tiles in parallel (default).
    #[default]
    Tiled,
    /// Every cell (the seed's exhaustive grid search).
    Exhaustive,
}

impl std::str::FromStr for Mode {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "tiled" => Ok(Mode::Tiled),
            "exhaustive" => Ok(Mode::Exhaustive),
            _ => Err(Error::Invalid(format!(
                "--mode {s:?}: expected tiled or exhaustive"
            ))),
        }
    }
}

/// Search settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct SearchConfig {
    /// The box and steps.
    pub spec: SearchSpec,
    /// Exhaustive or tiled.
    pub mode: Mode,
    /// Estimator.
    pub mi: MiConfig,
    /// Candidates carried between levels.
    pub top_k: usize,
    /// Largest number of poses of the coarsest survey (selects the coarsest level).
    pub coarse_budget: u64,
    /// Smallest point count of a coarse level's subsample.
    pub coarse_min_points: usize,
    /// Use the fixed point set (the bias remedy). Off = the naive estimator (for comparison only).
    pub fixed_point_set: bool,
    /// The fixed set keeps points at least this far (px) inside the valid image circle.
    pub visibility_margin_px: usize,
    /// Hill-climb iteration limit at the finest level.
    pub max_climb: usize,
}

impl Default for SearchConfig {
    fn default() -> Self {
        SearchConfig {
            spec: SearchSpec::default(),
            mode: Mode::Tiled,
            mi: MiConfig::default(),
            top_k: 8,
            coarse_budget: 4096,
            coarse_min_points: 20_000,
            fixed_point_set: true,
            visibility_margin_px: 2,
            max_climb: 64,
        }
    }
}

/// One image and the points it sees, for a search whose pose all the views share: one frame and
/// its LiDAR sweep, or one of several frames of a static camera over one tile. Several views
/// feed one joint histogram per candidate pose (pooled refinement).
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// Gray image, row-major at the camera's size.
    pub gray: &'a [u8],
    /// Validity mask at the camera's size (non-zero = valid pixel).
    pub mask: &'a [u8],
    /// The points.
    pub points: &'a [GroundPoint],
}

/// Jackknife groups of an evaluator's level-0 points ([`Evaluator::folds`]).
#[derive(Debug, Clone)]
pub(crate) struct Folds {
    parts: Vec<Vec<PreparedPoints>>,
    k: usize,
}

/// One view at one level of the evaluator: its image and its points at that resolution.
#[derive(Debug, Clone)]
struct Part {
    img: Arc<BinnedImage>,
    pts: PreparedPoints,
}

/// One level of the evaluator: the camera and every view at that resolution.
#[derive(Debug, Clone)]
struct Level {
    cam: FastCamera,
    parts: Vec<Part>,
}

/// Everything needed to score a grid cell: the problem prepared at every pyramid level.
#[derive(Debug, Clone)]
pub struct Evaluator {
    init: CamFromMap,
    origin: [f64; 3],
    grid: Grid,
    mi: MiConfig,
    levels: Vec<Level>,
    /// Points in the (fixed) set at level 0, all views together.
    pub n_points: usize,
    /// Points given, all views together.
    pub n_input: usize,
    /// Per view: points given and points in its fixed set.
    pub view_points: Vec<(usize, usize)>,
}

/// A scored cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scored {
    /// Cell number.
    pub idx: u64,
    /// Objective value.
    pub score: f64,
    /// Full statistics.
    pub value: MiValue,
}

/// Total order: higher score first, then lower cell number.
fn better(a: &Scored, b: &Scored) -> bool {
    a.score > b.score || (a.score == b.score && a.idx < b.idx)
}

fn best_of<'a>(it: impl IntoIterator<Item = &'a Scored>) -> Option<Scored> {
    it.into_iter()
        .fold(None, |acc: Option<Scored>, s| match acc {
            Some(a) if !better(s, &a) => Some(a),
            _ => Some(*s),
        })
}

/// The image side of a view's preparation: everything that depends on the frame, its mask and
/// the estimator's gray binning and visibility margin, but not on the pose or the points.
struct ViewImage {
    lut_gray: [u8; 256],
    /// The mask eroded by the visibility margin (as the binned image the fixed set is tested
    /// on) and its chessboard distance map; only with the fixed point set.
    eroded: Option<(BinnedImage, Vec<u16>)>,
    /// Level l's smoothed gray and mask with its binned image, from level 0 up to the deepest
    /// level asked for so far (levels are added on demand: only the search uses coarse ones).
    levels: Mutex<Vec<(GrayLevel, Arc<BinnedImage>)>>,
}

impl ViewImage {
    /// Binned images of levels 0..=`max_level`, building the missing coarse levels.
    fn binned_levels(&self, max_level: u32, invalid: u8) -> Vec<Arc<BinnedImage>> {
        let mut levels = self.levels.lock().unwrap_or_else(|e| e.into_inner());
        while levels.len() <= max_level as usize {
            let (prev, _) = &levels[levels.len() - 1];
            let g = prev.downsample();
            let img =
                BinnedImage::new(g.width, g.height, &g.gray, &g.mask, &self.lut_gray, invalid);
            levels.push((g, Arc::new(img)));
        }
        levels[..=max_level as usize]
            .iter()
            .map(|(_, img)| Arc::clone(img))
            .collect()
    }
}

/// What a [`ViewImage`] was prepared with, besides the frame and mask themselves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ImageKey {
    binning: super::mi::Binning,
    bins_gray: usize,
    fixed_point_set: bool,
    visibility_margin_px: usize,
}

impl ImageKey {
    fn of(cfg: &SearchConfig) -> Self {
        ImageKey {
            binning: cfg.mi.binning,
            bins_gray: cfg.mi.bins_gray,
            fixed_point_set: cfg.fixed_point_set,
            visibility_margin_px: cfg.visibility_margin_px,
        }
    }
}

/// Image preparations shared by the evaluators one refinement builds on the same frames (the
/// search's, the polish's, the jackknife's and the region's): the blur, the gray binning, the
/// erosion with its distance map and the pyramid are the same for all of them, only the point
/// sets differ. Likewise the Morton order of a point set ([`morton_order`]), which
/// depends on the points alone while each evaluator's origin, bins and fixed set differ. An
/// entry is found by the very slices it was made from (same address and length, borrowed for
/// the cache's whole life so they cannot change) and the same settings; anything else is
/// prepared afresh, so the cache can only save work, never change a result.
#[derive(Default)]
pub(crate) struct ImageCache<'a> {
    entries: Mutex<Vec<CachedImage<'a>>>,
    orders: Mutex<Vec<CachedOrder<'a>>>,
}

/// A point set and its Morton order.
type CachedOrder<'a> = (&'a [GroundPoint], Arc<Vec<usize>>);

struct CachedImage<'a> {
    gray: &'a [u8],
    mask: &'a [u8],
    key: ImageKey,
    image: Arc<ViewImage>,
}

impl<'a> ImageCache<'a> {
    /// The preparation of `v`'s image under `cfg`, made now or earlier.
    fn get(
        &self,
        cam: &Camera,
        v: &View<'a>,
        cfg: &SearchConfig,
    ) -> std::result::Result<Arc<ViewImage>, String> {
        let key = ImageKey::of(cfg);
        let same = |e: &CachedImage<'a>| {
            std::ptr::eq(e.gray, v.gray) && std::ptr::eq(e.mask, v.mask) && e.key == key
        };
        if let Some(e) = self.lock().iter().find(|e| same(e)) {
            return Ok(Arc::clone(&e.image));
        }
        let image = Arc::new(prepare_image(cam, v.gray, v.mask, cfg)?);
        self.lock().push(CachedImage {
            gray: v.gray,
            mask: v.mask,
            key,
            image: Arc::clone(&image),
        });
        Ok(image)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<CachedImage<'a>>> {
        self.entries.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The Morton order of `points`, computed now or earlier.
    fn order(&self, points: &'a [GroundPoint]) -> Arc<Vec<usize>> {
        let lock = || self.orders.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, o)) = lock().iter().find(|(p, _)| std::ptr::eq(*p, points)) {
            return Arc::clone(o);
        }
        let order = Arc::new(morton_order(points));
        lock().push((points, Arc::clone(&order)));
        order
    }
}

impl Evaluator {
    /// Prepare the problem: validate inputs, bin, build the pyramid (levels 0..=`max_level`) and the
    /// fixed point set. `gray`/`mask` are row-major at the camera's size (mask non-zero = valid
    /// pixel, e.g. [`CameraModel::valid_mask`]).
    pub fn new(
        cam: &Camera,
        gray: &[u8],
        mask: &[u8],
        points: &[GroundPoint],
        init: &CamFromMap,
        cfg: &SearchConfig,
        max_level: u32,
    ) -> Result<Self> {
        Self::pooled(cam, &[View { gray, mask, points }], init, cfg, max_level)
    }

    /// [`Evaluator::new`] over several views that share the pose: each view is binned on its own
    /// (its gray and reflectivity bin edges come from its own data, so frames under different
    /// light are labelled alike) and keeps its own fixed point set; a candidate pose's joint
    /// histogram is the sum over the views. With one view this is exactly [`Evaluator::new`].
    pub fn pooled(
        cam: &Camera,
        views: &[View<'_>],
        init: &CamFromMap,
        cfg: &SearchConfig,
        max_level: u32,
    ) -> Result<Self> {
        Self::pooled_cached(cam, views, init, cfg, max_level, &ImageCache::default())
    }

    /// [`Evaluator::pooled`] taking the views' image preparations from `cache` (and leaving
    /// there the ones it makes), for a refinement that builds several evaluators on one frame.
    pub(crate) fn pooled_cached<'a>(
        cam: &Camera,
        views: &[View<'a>],
        init: &CamFromMap,
        cfg: &SearchConfig,
        max_level: u32,
        cache: &ImageCache<'a>,
    ) -> Result<Self> {
        if views.is_empty() {
            return Err(Error::Invalid(
                "no image/point-set pair to refine on".into(),
            ));
        }
        cfg.mi.validate()?;
        cfg.spec.validate()?;
        let grid = cfg.spec.grid();
        let c = init.center();
        let origin = [c.x, c.y, c.z];
        let pooled = views.len() > 1;
        // One error line per view: with several, it names the pair (1-based, as given).
        let name = |i: usize, msg: String| -> Error {
            if pooled {
                Error::Invalid(format!("pair {} of {}: {msg}", i + 1, views.len()))
            } else {
                Error::Invalid(msg)
            }
        };
        let invalid = cfg.mi.bins_gray as u8;
        // Per view: its binned image at every level, and its fixed point set.
        let mut prepared = Vec::with_capacity(views.len());
        for (i, v) in views.iter().enumerate() {
            validate(v.points, "points").map_err(|e| match e {
                Error::Invalid(m) => name(i, m),
                other => other,
            })?;
            // The image's preparation and the points' order are independent (and each serial in
            // part: the erosion's sweep, the order's sort), so they run side by side.
            let (image, order) = rayon::join(|| cache.get(cam, v, cfg), || cache.order(v.points));
            let image = image.map_err(|m| name(i, m))?;
            let pts0 = prepare_points(cam, v.points, &order, &image, init, origin, &grid, cfg)
                .map_err(|m| name(i, m))?;
            prepared.push((image.binned_levels(max_level, invalid), pts0));
        }
        let n_points = prepared.iter().map(|(_, p)| p.len()).sum::<usize>();
        let view_points = views
            .iter()
            .zip(&prepared)
            .map(|(v, (_, p))| (v.points.len(), p.len()))
            .collect();
        // The coarse levels subsample the fixed sets first; level 0 then takes them as they are.
        let coarse: Vec<Level> = (1..=max_level)
            .map(|l| {
                let stride =
                    (1usize << (2 * l)).min((n_points / cfg.coarse_min_points.max(1)).max(1));
                Level {
                    cam: FastCamera::new(cam, l),
                    parts: prepared
                        .iter()
                        .map(|(imgs, pts0)| Part {
                            img: Arc::clone(&imgs[l as usize]),
                            pts: pts0.subsample(stride),
                        })
                        .collect(),
                }
            })
            .collect();
        let mut levels = vec![Level {
            cam: FastCamera::new(cam, 0),
            parts: prepared
                .into_iter()
                .map(|(mut imgs, pts)| Part {
                    img: imgs.swap_remove(0),
                    pts,
                })
                .collect(),
        }];
        levels.extend(coarse);
        Ok(Evaluator {
            init: *init,
            origin,
            grid,
            mi: cfg.mi,
            levels,
            n_points,
            n_input: views.iter().map(|v| v.points.len()).sum(),
            view_points,
        })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Points used at a level.
    pub(crate) fn points_at(&self, level: u32) -> usize {
        self.levels[level as usize]
            .parts
            .iter()
            .map(|p| p.pts.len())
            .sum()
    }

    /// Number of views (image/point-set pairs).
    pub fn views(&self) -> usize {
        self.view_points.len()
    }

    /// The pose of a cell.
    pub(crate) fn pose(&self, cell: &Cell) -> CamFromMap {
        pose_at_pivot(&self.init, &self.grid.offsets(cell), self.grid.pivot)
    }

    /// Joint histogram of a cell at a level.
    pub fn histogram(&self, level: u32, cell: &Cell, scratch: &mut Scratch) -> JointHist {
        self.histogram_at(level, &self.pose(cell), scratch)
    }

    /// Joint histogram of any pose at a level, on the fixed point set: the sum over the views
    /// (its invalid column counts the points of the set that pose loses). For diagnostics that
    /// score poses off the grid on one point set (`examples/diag_s11.rs`).
    pub fn histogram_at(&self, level: u32, pose: &CamFromMap, scratch: &mut Scratch) -> JointHist {
        let lv = &self.levels[level as usize];
        let mut h = JointHist::new(self.mi.bins_reflectivity, self.mi.bins_gray);
        let p = PoseF32::new(pose, self.origin);
        for part in &lv.parts {
            accumulate(&part.pts, &p, &lv.cam, &part.img, &mut h, scratch);
        }
        h
    }

    /// MI and NMI at continuous offsets from the initial pose (not restricted to the grid's
    /// cells), on the fixed point set at `level`; for local continuous polishing after the grid
    /// search ([`super::polish`]).
    pub(crate) fn value_at(
        &self,
        level: u32,
        offsets: &[f64; 6],
        scratch: &mut Scratch,
    ) -> MiValue {
        let pose = pose_at_pivot(&self.init, offsets, self.grid.pivot);
        mutual_information(&self.histogram_at(level, &pose, scratch), self.mi.parzen)
    }

    /// The level-0 point sets cut into `k` jackknife groups: each view's fixed set, in Morton
    /// order, in `k` contiguous runs (compact patches of ground); group j is run j of every view.
    /// Indexed `[view][group]`.
    pub(crate) fn folds(&self, k: usize) -> Folds {
        let k = k.max(1);
        Folds {
            parts: self.levels[0]
                .parts
                .iter()
                .map(|p| {
                    let n = p.pts.len();
                    (0..k)
                        .map(|j| p.pts.range(j * n / k, (j + 1) * n / k))
                        .collect()
                })
                .collect(),
            k,
        }
    }

    /// Level-0 joint histograms of the pose at `offsets`, one per group of `folds`; their sum is
    /// the histogram [`Evaluator::value_at`] scores.
    pub(crate) fn fold_histograms(
        &self,
        folds: &Folds,
        offsets: &[f64; 6],
        scratch: &mut Scratch,
    ) -> Vec<JointHist> {
        let lv = &self.levels[0];
        let pose = PoseF32::new(
            &pose_at_pivot(&self.init, offsets, self.grid.pivot),
            self.origin,
        );
        let mut out = vec![JointHist::new(self.mi.bins_reflectivity, self.mi.bins_gray); folds.k];
        for (part, groups) in lv.parts.iter().zip(&folds.parts) {
            for (h, pts) in out.iter_mut().zip(groups) {
                accumulate(pts, &pose, &lv.cam, &part.img, h, scratch);
            }
        }
        out
    }

    /// This evaluator's level 0 on every `stride`-th point of each view's fixed set (Morton
    /// order, so the kept points spread evenly over the ground): a cheaper and noisier objective,
    /// for screening optimiser starts. The images are shared, not copied.
    pub(crate) fn thinned(&self, stride: usize) -> Evaluator {
        let lv = &self.levels[0];
        let parts: Vec<Part> = lv
            .parts
            .iter()
            .map(|p| Part {
                img: Arc::clone(&p.img),
                pts: p.pts.subsample(stride),
            })
            .collect();
        Evaluator {
            init: self.init,
            origin: self.origin,
            grid: self.grid,
            mi: self.mi,
            n_points: parts.iter().map(|p| p.pts.len()).sum(),
            n_input: self.n_input,
            view_points: self
                .view_points
                .iter()
                .zip(&parts)
                .map(|(v, p)| (v.0, p.pts.len()))
                .collect(),
            levels: vec![Level { cam: lv.cam, parts }],
        }
    }

    /// [`Evaluator::value_at`] at level 0 with the groups of `folds` scored in parallel: their
    /// histograms add up to the one `value_at` scores (integer counts), so the value is the
    /// same; for a single optimiser run that should still use every thread.
    pub(crate) fn value_at_split(&self, folds: &Folds, offsets: &[f64; 6]) -> MiValue {
        let lv = &self.levels[0];
        let pose = PoseF32::new(
            &pose_at_pivot(&self.init, offsets, self.grid.pivot),
            self.origin,
        );
        let (rows, cols) = (self.mi.bins_reflectivity, self.mi.bins_gray);
        let jobs: Vec<(usize, usize)> = (0..folds.parts.len())
            .flat_map(|v| (0..folds.k).map(move |g| (v, g)))
            .collect();
        let h = jobs
            .par_iter()
            .fold(
                || (JointHist::new(rows, cols), Scratch::default()),
                |(mut h, mut scratch), &(v, g)| {
                    let part = &lv.parts[v];
                    accumulate(
                        &folds.parts[v][g],
                        &pose,
                        &lv.cam,
                        &part.img,
                        &mut h,
                        &mut scratch,
                    );
                    (h, scratch)
                },
            )
            .map(|(h, _)| h)
            .reduce(
                || JointHist::new(rows, cols),
                |mut a, b| {
                    a.counts
                        .iter_mut()
                        .zip(&b.counts)
                        .for_each(|(x, y)| *x += y);
                    a
                },
            );
        mutual_information(&h, self.mi.parzen)
    }

    /// The level-0 joint histogram at `offsets` of every group of `folds` but `left_out`, in one
    /// pass: the sum of those groups' [`Evaluator::fold_histograms`] (counts are integers, so
    /// the order of the sum cannot change them), without scoring the group left out.
    pub(crate) fn histogram_without(
        &self,
        folds: &Folds,
        left_out: usize,
        offsets: &[f64; 6],
        scratch: &mut Scratch,
    ) -> JointHist {
        let lv = &self.levels[0];
        let pose = PoseF32::new(
            &pose_at_pivot(&self.init, offsets, self.grid.pivot),
            self.origin,
        );
        let mut h = JointHist::new(self.mi.bins_reflectivity, self.mi.bins_gray);
        for (part, groups) in lv.parts.iter().zip(&folds.parts) {
            for (j, pts) in groups.iter().enumerate() {
                if j != left_out {
                    accumulate(pts, &pose, &lv.cam, &part.img, &mut h, scratch);
                }
            }
        }
        h
    }

    /// Level 0 of every view (its binned image and fixed point set), the points' origin and the
    /// estimator's settings: what the smooth estimator ([`super::smooth`]) scores.
    pub(crate) fn level0(&self) -> (Vec<(&BinnedImage, &PreparedPoints)>, [f64; 3], MiConfig) {
        let parts = self.levels[0]
            .parts
            .iter()
            .map(|p| (p.img.as_ref(), &p.pts))
            .collect();
        (parts, self.origin, self.mi)
    }

    /// The objective the search maximises (MI or NMI, per the configuration).
    pub(crate) fn objective(&self) -> super::mi::Objective {
        self.mi.objective
    }

    /// Score a cell at a level.
    pub fn score(&self, level: u32, idx: u64, scratch: &mut Scratch) -> Scored {
        let h = self.histogram(level, &self.grid.cell(idx), scratch);
        let value = mutual_information(&h, self.mi.parzen);
        Scored {
            idx,
            score: value.get(self.mi.objective),
            value,
        }
    }

    /// Score cells (by number) at a level in parallel, in tiles of consecutive cells (one scratch
    /// per tile), order kept. A score is a pure function of (level, cell), so neither the tiling
    /// nor the thread count can change a result.
    pub(crate) fn score_cells(&self, level: u32, idxs: &[u64]) -> Vec<Scored> {
        // Up to 64 cells a tile, but at least ~4 tiles per thread so that the small batches of the
        // descent and the climb (tens to hundreds of cells) still keep every thread busy.
        let tile = (idxs.len() / (4 * rayon::current_num_threads()).max(1)).clamp(1, 64);
        idxs.par_chunks(tile)
            .flat_map_iter(|tile| {
                let mut s = Scratch::default();
                tile.iter()
                    .map(|&i| self.score(level, i, &mut s))
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// Score many cells in parallel (order kept), adding to the stats.
    fn score_many(&self, level: u32, idxs: &[u64], stats: &mut SearchStats) -> Vec<Scored> {
        let out = self.score_cells(level, idxs);
        let n = self.points_at(level) as u64;
        stats.poses += idxs.len() as u64;
        stats.point_evaluations += idxs.len() as u64 * n;
        let lost = out
            .iter()
            .map(|s| 1.0 - s.value.n as f64 / n.max(1) as f64)
            .fold(0.0, f64::max);
        if level == 0 {
            stats.max_lost_fraction = stats.max_lost_fraction.max(lost);
        }
        out
    }
}

/// Check one view's image against the camera, bin its gray levels and blur it (see
/// [`Evaluator::pooled`]); with the fixed point set, erode its mask too. Errors are the message
/// alone; the caller names the view.
fn prepare_image(
    cam: &Camera,
    gray: &[u8],
    mask: &[u8],
    cfg: &SearchConfig,
) -> std::result::Result<ViewImage, String> {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    if gray.len() != w * h || mask.len() != w * h {
        return Err(format!(
            "image has {} pixels but the camera is {w}×{h}",
            gray.len()
        ));
    }
    let invalid = cfg.mi.bins_gray as u8;

    // Gray LUT from the valid pixels: counts per block of rows on the pool (integer sums, the
    // same in any order).
    let gcounts = gray
        .par_chunks(w.max(1) * 64)
        .zip(mask.par_chunks(w.max(1) * 64))
        .fold(
            || [0u64; 256],
            |mut c, (g, m)| {
                for (&g, &m) in g.iter().zip(m) {
                    c[g as usize] += u64::from(m != 0);
                }
                c
            },
        )
        .reduce(
            || [0u64; 256],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
                a
            },
        );
    if gcounts.iter().sum::<u64>() == 0 {
        return Err("image: no valid pixel in the camera's image circle".into());
    }
    let lut_gray = bin_lut(cfg.mi.binning, cfg.mi.bins_gray, &gcounts);

    // Level 0 image (anti-aliased, see `blur3`), and the eroded one used to pick the fixed set.
    // The erosion's distance transform is a sequential sweep that needs only the mask: it runs
    // beside the blur and binning (which spread over the pool) rather than after them.
    let ((smooth, img0), erosion) = rayon::join(
        || {
            let smooth = blur3(gray, mask, w, h);
            let img0 = BinnedImage::new(w, h, &smooth, mask, &lut_gray, invalid);
            (smooth, img0)
        },
        || {
            cfg.fixed_point_set
                .then(|| erode_with_distance(mask, w, h, cfg.visibility_margin_px))
        },
    );
    let eroded = erosion.map(|(eroded, dist)| {
        let img_e = BinnedImage::new(w, h, &smooth, &eroded, &lut_gray, invalid);
        (img_e, dist)
    });
    let level0 = GrayLevel {
        width: w,
        height: h,
        gray: smooth,
        mask: mask.to_vec(),
    };
    Ok(ViewImage {
        lut_gray,
        eroded,
        levels: Mutex::new(vec![(level0, Arc::new(img0))]),
    })
}

/// Pick one view's fixed point set on its prepared `image` and bin the points' reflectivity
/// (see [`Evaluator::pooled`]). Errors are the message alone; the caller names the view.
#[allow(clippy::too_many_arguments)]
fn prepare_points(
    cam: &Camera,
    points: &[GroundPoint],
    order: &[usize],
    image: &ViewImage,
    init: &CamFromMap,
    origin: [f64; 3],
    grid: &Grid,
    cfg: &SearchConfig,
) -> std::result::Result<PreparedPoints, String> {
    let w = cam.width() as usize;
    let invalid = cfg.mi.bins_gray as u8;
    let cam0 = FastCamera::new(cam, 0);

    // Points with raw reflectivity as "bin" first, to select the fixed set.
    let mut identity = [0u8; 256];
    for (i, v) in identity.iter_mut().enumerate() {
        *v = i as u8;
    }
    let raw = PreparedPoints::gather(points, order, origin, &identity);
    let keep = if let Some((img_e, dist)) = &image.eroded {
        // A point is kept when every pose of the 3^d lattice sees it. Blocks of points in
        // parallel, each tested against all the poses at once (`visible_from_all`): the flags do
        // not depend on how the work is split, since each point's flag is its own AND.
        let poses: Vec<PoseF32> = box_lattice(grid)
            .iter()
            .map(|cell| {
                PoseF32::new(
                    &pose_at_pivot(init, &grid.offsets(cell), grid.pivot),
                    origin,
                )
            })
            .collect();
        // Most points sit far inside the valid area from every pose of a small box: those are
        // settled by one projection per axis extreme (`surely_visible`), and only the rest are
        // tested against the whole lattice. The kept set is the lattice test's.
        let center = pose_at_pivot(init, &grid.offsets(&[0; 6]), grid.pivot);
        let extremes: Vec<CamFromMap> = (0..6)
            .filter(|&i| grid.m[i] != 0)
            .flat_map(|i| {
                [-grid.m[i], grid.m[i]].map(|k| {
                    let mut c = [0i64; 6];
                    c[i] = k;
                    pose_at_pivot(init, &grid.offsets(&c), grid.pivot)
                })
            })
            .collect();
        let sure = surely_visible(&cam0, &raw, origin, &center, &extremes, dist, w);
        let unsure: Vec<bool> = sure.iter().map(|s| !s).collect();
        let rest = raw.select(&unsure);
        const BLOCK: usize = 2048;
        let mut rest_keep = vec![true; rest.len()];
        rest_keep
            .par_chunks_mut(BLOCK)
            .enumerate()
            .for_each(|(b, k)| {
                visible_from_all(&rest, b * BLOCK, &poses, &cam0, img_e, invalid, k)
            });
        let mut rest_keep = rest_keep.into_iter();
        sure.iter()
            .map(|&s| s || rest_keep.next().unwrap_or(false))
            .collect()
    } else {
        let img0 = image.binned_levels(0, invalid);
        let mut vis = vec![false; raw.len()];
        let p = PoseF32::new(init, origin);
        visible(&raw, &p, &cam0, &img0[0], invalid, &mut vis);
        // The naive estimator uses every point; it only needs one visible to be meaningful.
        if !vis.iter().any(|&v| v) {
            vis.iter_mut().for_each(|v| *v = false);
        } else {
            vis.iter_mut().for_each(|v| *v = true);
        }
        vis
    };
    let mut pts0 = raw.select(&keep);
    if pts0.is_empty() {
        return Err(if cfg.fixed_point_set {
            "points: none is visible from every pose of the search box (wrong pose, tile or camera?)"
                .into()
        } else {
            "points: none is visible from the initial pose".into()
        });
    }
    let mut rcounts = [0u64; 256];
    for &b in &pts0.bin {
        rcounts[b as usize] += 1;
    }
    let lut_refl = bin_lut(cfg.mi.binning, cfg.mi.bins_reflectivity, &rcounts);
    pts0.bin.iter_mut().for_each(|b| *b = lut_refl[*b as usize]);
    Ok(pts0)
}

/// 3×3 binomial blur ([1 2 1]⊗[1 2 1]/16) over valid pixels only (weights renormalised at the
/// circle's edge). The sampler takes the nearest pixel; without this, a sub-pixel pose step moves
/// a point between pixels that may differ a lot (sensor noise, aliasing), and the objective over
/// the finest grid gets ripples that are not alignment information.
fn blur3(gray: &[u8], mask: &[u8], w: usize, h: usize) -> Vec<u8> {
    const K: [u32; 3] = [1, 2, 1];
    let mut out = gray.to_vec();
    // A valid pixel near the mask's edge or the image's averages its valid neighbours only.
    let edge = |u: usize, v: usize| -> u8 {
        let (mut acc, mut wsum) = (0u32, 0u32);
        for (j, kj) in K.iter().enumerate() {
            let y = v + j;
            if y < 1 || y > h {
                continue;
            }
            for (i, ki) in K.iter().enumerate() {
                let x = u + i;
                if x < 1 || x > w || mask[(y - 1) * w + x - 1] == 0 {
                    continue;
                }
                acc += kj * ki * gray[(y - 1) * w + x - 1] as u32;
                wsum += kj * ki;
            }
        }
        ((acc + wsum / 2) / wsum.max(1)) as u8
    };
    // Rows in parallel: each output row reads only the input, so the result is the same. Inside
    // the mask (all nine pixels valid, most of the image) the kernel is separable and its weights
    // sum to 16: the column sums once per pixel, then the row's; the same integers as the edge
    // formula.
    out.par_chunks_mut(w.max(1)).enumerate().for_each_init(
        || (vec![0u16; w], vec![false; w]),
        |(col, all), (v, row)| {
            let inner_row = v >= 1 && v + 1 < h;
            if inner_row {
                let r = |k: usize| k * w..(k + 1) * w;
                let (g0, g1, g2) = (&gray[r(v - 1)], &gray[r(v)], &gray[r(v + 1)]);
                let (m0, m1, m2) = (&mask[r(v - 1)], &mask[r(v)], &mask[r(v + 1)]);
                for u in 0..w {
                    col[u] = g0[u] as u16 + 2 * g1[u] as u16 + g2[u] as u16;
                    all[u] = m0[u] != 0 && m1[u] != 0 && m2[u] != 0;
                }
            }
            for (u, o) in row.iter_mut().enumerate() {
                if mask[v * w + u] == 0 {
                    continue;
                }
                *o = if inner_row && u >= 1 && u + 1 < w && all[u - 1] && all[u] && all[u + 1] {
                    let acc = col[u - 1] as u32 + 2 * col[u] as u32 + col[u + 1] as u32;
                    ((acc + 8) / 16) as u8
                } else {
                    edge(u, v)
                };
            }
        },
    );
    out
}

/// Erode a validity mask by `r` pixels (square window: a pixel stays valid only if every pixel
/// within `r`, and the image, reaches that far), and give the eroded mask's chessboard distance
/// map ([`chessboard_distance`]) with it. One distance transform gives both: a pixel survives the
/// erosion exactly when its distance exceeds `r`, and its distance in the eroded mask is `r` less.
fn erode_with_distance(mask: &[u8], w: usize, h: usize, r: usize) -> (Vec<u8>, Vec<u16>) {
    let r = r.min(u16::MAX as usize) as u16;
    let dist: Vec<u16> = chessboard_distance(mask, w, h)
        .into_iter()
        .map(|d| d.saturating_sub(r))
        .collect();
    let eroded = dist.iter().map(|&d| if d > 0 { 255 } else { 0 }).collect();
    (eroded, dist)
}

/// Points that every pose of a box certainly sees on a valid pixel of a mask whose chessboard
/// distance map (`w` wide) is `dist`: a point whose pixel at the box's `center` pose lies farther
/// from any invalid pixel (chessboard distance, a lower bound of the Euclidean one) than its pixel
/// moves over the box. The move is taken as the sum over the axes of the farther of its two axis
/// `extremes`' moves, exact for a map linear in the offsets; ×1.5 and 4 px more cover the
/// projection's curvature over a box and nearest-pixel rounding. That margin is measured, not
/// proven: the worst lattice move found over nadir to near-horizontal cameras, 4.5–10 m poles and
/// boxes up to ±2 m / ±6° was 0.74–1.09 times the sum (the unit test checks nadir and tilted
/// cameras pose by pose). A `false` means "test it", not "unseen". The projections are the
/// kernel's own ([`kernel::surely_visible_block`]), in blocks of points in parallel.
fn surely_visible(
    cam: &FastCamera,
    pts: &PreparedPoints,
    origin: [f64; 3],
    center: &CamFromMap,
    extremes: &[CamFromMap],
    dist: &[u16],
    w: usize,
) -> Vec<bool> {
    const BLOCK: usize = 4096;
    let extremes: Vec<PoseF32> = extremes.iter().map(|e| PoseF32::new(e, origin)).collect();
    let b = kernel::BoxView {
        center: PoseF32::new(center, origin),
        extremes: &extremes,
        cam: *cam,
        dist,
        width: w,
    };
    let mut out = vec![false; pts.len()];
    out.par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(i, o)| kernel::surely_visible_block(pts, i * BLOCK, &b, o));
    out
}

/// Per pixel, the chessboard distance to the nearest pixel whose `mask` is 0 or to the outside of
/// the image (1 on a valid pixel next to an invalid one, 0 on an invalid one). Two chamfer passes
/// with the image border handled apart, so that the inner loops read their neighbours without
/// bounds tests (a pixel on the border has an outside neighbour, so its distance is 1 when valid);
/// the unit tests keep the plain per-neighbour version as the reference.
fn chessboard_distance(mask: &[u8], w: usize, h: usize) -> Vec<u16> {
    let mut d = vec![0u16; w * h];
    if w < 3 || h < 3 {
        // Every pixel is on the border.
        d.iter_mut()
            .zip(mask)
            .for_each(|(d, &m)| *d = u16::from(m != 0));
        return d;
    }
    // Forward: left, up-left, up, up-right.
    for v in 0..h {
        let (done, rest) = d.split_at_mut(v * w);
        let cur = &mut rest[..w];
        let m = &mask[v * w..(v + 1) * w];
        if v == 0 {
            cur.iter_mut()
                .zip(m)
                .for_each(|(d, &m)| *d = u16::from(m != 0));
            continue;
        }
        let prev = &done[(v - 1) * w..];
        cur[0] = u16::from(m[0] != 0);
        for u in 1..w - 1 {
            if m[u] != 0 {
                let a = cur[u - 1].min(prev[u - 1]).min(prev[u]).min(prev[u + 1]);
                cur[u] = a.saturating_add(1);
            }
        }
        cur[w - 1] = u16::from(m[w - 1] != 0);
    }
    // Backward: right, down-right, down, down-left.
    for v in (0..h).rev() {
        let (head, below) = d.split_at_mut((v + 1) * w);
        let cur = &mut head[v * w..];
        if v == h - 1 {
            cur.iter_mut().for_each(|d| *d = (*d).min(1));
            continue;
        }
        let next = &below[..w];
        cur[w - 1] = cur[w - 1].min(1);
        for u in (1..w - 1).rev() {
            if cur[u] != 0 {
                let a = cur[u + 1].min(next[u + 1]).min(next[u]).min(next[u - 1]);
                cur[u] = cur[u].min(a.saturating_add(1));
            }
        }
        cur[0] = cur[0].min(1);
    }
    d
}

/// The 3^d lattice of the box: every combination of {−m, 0, +m} on the enabled axes.
fn box_lattice(g: &Grid) -> Vec<Cell> {
    let mut cells = vec![[0i64; 6]];
    for i in 0..6 {
        if g.m[i] == 0 {
            continue;
        }
        cells = cells
            .into_iter()
            .flat_map(|c| {
                [-g.m[i], 0, g.m[i]].into_iter().map(move |k| {
                    let mut d = c;
                    d[i] = k;
                    d
                })
            })
            .collect();
    }
    cells
}

/// Counters of a search.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SearchStats {
    /// Poses scored.
    pub poses: u64,
    /// Point-pose evaluations (Σ over scored poses of the points used).
    pub point_evaluations: u64,
    /// What the exhaustive grid costs: cells × points.
    pub exhaustive_point_evaluations: u64,
    /// Coarsest level used (0 for exhaustive).
    pub coarsest_level: u32,
    /// Largest fraction of the fixed set not landing on a valid pixel at any level-0 pose.
    pub max_lost_fraction: f64,
}

/// The search's answer.
#[derive(Debug, Clone)]
pub struct SearchResult {
    /// Best cell.
    pub best: Scored,
    /// Its offsets (m, m, m, deg, deg, deg).
    pub offsets: [f64; 6],
    /// Its pose.
    pub pose: CamFromMap,
    /// Other local maxima found at level 0 (best first), for the second-peak test.
    pub other_peaks: Vec<Scored>,
    /// Counters.
    pub stats: SearchStats,
}

/// Coarsest level whose survey fits in `budget` poses.
pub(crate) fn coarsest_level(g: &Grid, budget: u64) -> u32 {
    let mut l = 0;
    while l < MAX_LEVEL {
        let count: u64 = (0..6).map(|i| g.lattice_axis(i, l).len() as u64).product();
        if count <= budget {
            break;
        }
        l += 1;
    }
    l
}

/// Run the search configured by `cfg` on a prepared evaluator.
pub fn search(ev: &Evaluator, cfg: &SearchConfig) -> SearchResult {
    search_thinned(ev, cfg, 1)
}

/// [`search`] whose finest tiled level (the descent's last windows and the hill-climbs) scores
/// every `thinning`-th point of the fixed set, or fewer thinned where that would leave fewer
/// points than `coarse_min_points` (1: all points, [`search`]). For a search that a continuous
/// polish on all points follows: the polish, not the grid cell, sets the answer's precision, and
/// the finest level on all points was about half of a refinement's point-evaluations. The peaks
/// the climbs end on are scored again on all points and the best of them climbs on on all points
/// (steepest ascent, no wide look) to a cell no neighbour beats: the answer is a local maximum of
/// the full estimator, most often the unthinned search's cell, and its score, the second-peak
/// test and the quality's profiles all use the full estimator.
pub(crate) fn search_thinned(ev: &Evaluator, cfg: &SearchConfig, thinning: usize) -> SearchResult {
    let g = ev.grid;
    let mut stats = SearchStats {
        exhaustive_point_evaluations: g.cells().saturating_mul(ev.n_points as u64),
        ..Default::default()
    };
    let (best, others) = match cfg.mode {
        Mode::Exhaustive => exhaustive(ev, &mut stats),
        Mode::Tiled => {
            let stride = thinning.min(ev.n_points / cfg.coarse_min_points.max(1));
            let fine = (stride >= 2).then(|| ev.thinned(stride));
            tiled(ev, fine.as_ref(), cfg, &mut stats)
        }
    };
    let cell = g.cell(best.idx);
    SearchResult {
        best,
        offsets: g.offsets(&cell),
        pose: ev.pose(&cell),
        other_peaks: others,
        stats,
    }
}

fn neighbours(g: &Grid, c: &Cell, f: i64) -> Vec<Cell> {
    let mut out = vec![*c];
    for i in 0..6 {
        if g.m[i] == 0 {
            continue;
        }
        out = out
            .into_iter()
            .flat_map(|d| {
                [-f, 0, f].into_iter().map(move |k| {
                    let mut e = d;
                    e[i] += k;
                    e
                })
            })
            .collect();
    }
    out.retain(|d| d != c && g.contains(d));
    out
}

/// Every cell at level 0; also returns the other local maxima (3^d neighbourhood), best first.
fn exhaustive(ev: &Evaluator, stats: &mut SearchStats) -> (Scored, Vec<Scored>) {
    let g = ev.grid;
    let all: Vec<u64> = (0..g.cells()).collect();
    let scores = ev.score_many(0, &all, stats);
    let best = best_of(&scores).expect("grid has at least one cell");
    let mut peaks: Vec<Scored> = scores
        .par_iter()
        .filter(|s| {
            s.idx != best.idx
                && neighbours(&g, &g.cell(s.idx), 1)
                    .iter()
                    .all(|n| better(s, &scores[g.index(n) as usize]))
        })
        .copied()
        .collect();
    sort_best_first(&mut peaks);
    (best, peaks)
}

fn sort_best_first(v: &mut [Scored]) {
    v.sort_by(|a, b| b.score.total_cmp(&a.score).then_with(|| a.idx.cmp(&b.idx)));
}

/// Coarse-to-fine over sub-lattices.
fn tiled(
    ev: &Evaluator,
    fine: Option<&Evaluator>,
    cfg: &SearchConfig,
    stats: &mut SearchStats,
) -> (Scored, Vec<Scored>) {
    let g = ev.grid;
    let top = (ev.levels.len() as u32 - 1).min(coarsest_level(&g, cfg.coarse_budget));
    stats.coarsest_level = top;
    // A survey at level 0 (a small grid) scores all points already: nothing to thin.
    let fine = fine.filter(|_| top > 0);
    // The evaluator of the finest level's windows and climbs.
    let ev0 = fine.unwrap_or(ev);
    let k = cfg.top_k.max(1);

    // Survey of the whole box at the coarsest level. The lattice is enumerated x-slowest, so
    // contiguous chunks of it are tiles of the search space; score_many runs them in parallel.
    let mut lattice: Vec<Cell> = vec![[0; 6]];
    for i in 0..6 {
        let ax = g.lattice_axis(i, top);
        lattice = lattice
            .into_iter()
            .flat_map(|c| {
                ax.iter().map(move |&v| {
                    let mut d = c;
                    d[i] = v;
                    d
                })
            })
            .collect();
    }
    let idxs: Vec<u64> = lattice.iter().map(|c| g.index(c)).collect();
    let survey = ev.score_many(top, &idxs, stats);
    let mut cands = top_local_maxima(&g, &survey, 1i64 << top, k);
    // Level-0 scores already computed (by the last descent step, or the survey when the grid is
    // small enough to survey at level 0): the climbs start inside those windows and would score
    // most of them again. A score is a pure function of (level, cell), so reusing one changes
    // only the count, never a result.
    let mut cache: HashMap<u64, Scored> = HashMap::new();
    if top == 0 {
        cache.extend(survey.iter().map(|s| (s.idx, *s)));
    }

    // Descend: each candidate is re-examined on a ±2-step window of the next finer lattice.
    for level in (0..top).rev() {
        let f = 1i64 << level;
        let mut union: Vec<u64> = cands
            .iter()
            .flat_map(|&c| window(&g, &g.cell(c), f))
            .collect();
        union.sort_unstable();
        union.dedup();
        let scored = if level == 0 {
            ev0.score_many(0, &union, stats)
        } else {
            ev.score_many(level, &union, stats)
        };
        if level == 0 {
            cache.extend(scored.iter().map(|s| (s.idx, *s)));
        }
        // The next candidates: the top-k local maxima of everything scored at this level. Taking
        // only each window's best would collapse overlapping windows onto one cell and drop the
        // runner-up hills that the finer levels sometimes prove better (a near-tie of two ripples
        // of the objective).
        cands = top_local_maxima(&g, &scored, f, k);
    }

    // Hill-climb each candidate to a local maximum of the finest grid. The climbs run one after
    // the other (each step scores its cells in parallel) and share one cache: candidates are often
    // close, and their climbs meet. A cached score is the same number as a recomputed one, so the
    // sharing changes only the count, and the order is fixed, so the count is deterministic too.
    let climbs: Vec<(Scored, u64)> = cands
        .iter()
        .map(|&c| climb(ev0, c, cfg.max_climb, &mut cache))
        .collect();
    let n0 = ev0.points_at(0) as u64;
    for (_, evals) in &climbs {
        stats.poses += evals;
        stats.point_evaluations += evals * n0;
    }
    // The cache holds every level-0 score, the climbs' own among them: score_many only saw the
    // descent's, and a climb can walk to a pose the descent never scored.
    let lost = cache
        .values()
        .map(|s| 1.0 - s.value.n as f64 / n0.max(1) as f64)
        .fold(0.0, f64::max);
    stats.max_lost_fraction = stats.max_lost_fraction.max(lost);
    let mut peaks: Vec<Scored> = climbs.into_iter().map(|(s, _)| s).collect();
    peaks.sort_unstable_by_key(|s| s.idx);
    peaks.dedup_by_key(|s| s.idx);
    if fine.is_some() {
        // The peaks' scores on all points, and the best of them climbed on all points to a cell
        // no neighbour beats: the answer is a local maximum of the full estimator, as without
        // the thinning (the wide look stays with the thinned climbs: on all points it would cost
        // more than the thinning saves).
        let idxs: Vec<u64> = peaks.iter().map(|s| s.idx).collect();
        peaks = ev.score_many(0, &idxs, stats);
        sort_best_first(&mut peaks);
        let mut full: HashMap<u64, Scored> = peaks.iter().map(|s| (s.idx, *s)).collect();
        let (top, evals) = climb_with(ev, peaks[0].idx, cfg.max_climb, &mut full, false);
        stats.poses += evals;
        stats.point_evaluations += evals * ev.points_at(0) as u64;
        peaks.push(top);
        peaks.sort_unstable_by_key(|s| s.idx);
        peaks.dedup_by_key(|s| s.idx);
    }
    sort_best_first(&mut peaks);
    let best = peaks[0];
    (best, peaks[1..].to_vec())
}

/// The best `k` (best first) of the `scored` cells that beat each of their lattice-`f` neighbours
/// that were scored too.
fn top_local_maxima(g: &Grid, scored: &[Scored], f: i64, k: usize) -> Vec<u64> {
    let map: HashMap<u64, Scored> = scored.iter().map(|s| (s.idx, *s)).collect();
    let mut maxima: Vec<Scored> = scored
        .iter()
        .filter(|s| {
            neighbours(g, &g.cell(s.idx), f)
                .iter()
                .filter_map(|n| map.get(&g.index(n)))
                .all(|n| better(s, n))
        })
        .copied()
        .collect();
    sort_best_first(&mut maxima);
    maxima.truncate(k);
    maxima.iter().map(|s| s.idx).collect()
}

/// The lattice-`f` cells within ±2f of `c` on every axis.
fn window(g: &Grid, c: &Cell, f: i64) -> Vec<u64> {
    window_r(g, c, f, [2; 6])
}

/// The lattice-`f` cells within ±`r[i]`·f of `c` on axis i.
fn window_r(g: &Grid, c: &Cell, f: i64, r: [i64; 6]) -> Vec<u64> {
    let mut cells = vec![*c];
    for i in 0..6 {
        if g.m[i] == 0 {
            continue;
        }
        let ri = r[i];
        cells = cells
            .into_iter()
            .flat_map(|d| {
                (-ri..=ri).map(move |k| {
                    let mut e = d;
                    e[i] += k * f;
                    e
                })
            })
            .collect();
    }
    cells
        .into_iter()
        .filter(|d| g.contains(d))
        .map(|d| g.index(&d))
        .collect()
}

/// Half widths (finest cells) of the climb's wider look, per axis: ±2 on x, y, z, ±3 on the
/// angles. The objective's pose-to-pose ripples are broadest along the angles: in the
/// tiled-vs-exhaustive trials (tests/refine_synthetic.rs) every remaining miss with a ±2 look was
/// a near-tie exactly 3 yaw steps away. ±3 on every axis would also catch them but costs 7⁴ − 5⁴ =
/// 1776 more full-resolution poses per look (≈ doubling the default search); this costs 250.
const WIDE_LOOK: [i64; 6] = [2, 2, 2, 3, 3, 3];

/// Steepest-ascent on the finest grid from `start` until no neighbour is better, then a wider look:
/// if a cell within [`WIDE_LOOK`] steps beats the peak, climb on from it. The MI surface over a
/// nearest-pixel sampler has small pose-to-pose ripples; the wide look steps over them so that the
/// result is the maximum of its neighbourhood (±2 positions, ±3 angles), as the exhaustive search
/// would see it. Returns
/// the peak and the number of poses scored that were not in `cache` (level-0 scores, shared
/// between the climbs of one search).
fn climb(
    ev: &Evaluator,
    start: u64,
    max_iter: usize,
    cache: &mut HashMap<u64, Scored>,
) -> (Scored, u64) {
    climb_with(ev, start, max_iter, cache, true)
}

/// [`climb`], with the wide look or (`wide` false) plain steepest ascent to a cell no neighbour
/// beats.
fn climb_with(
    ev: &Evaluator,
    start: u64,
    max_iter: usize,
    cache: &mut HashMap<u64, Scored>,
    wide: bool,
) -> (Scored, u64) {
    let g = ev.grid;
    let mut evals = 0u64;
    // Scores of `idxs`, the ones not seen yet scored in parallel (the climb itself is sequential,
    // and often only one or two candidates climb, so the parallelism has to be inside a step).
    let mut score = |idxs: &[u64]| -> Vec<Scored> {
        let mut missing: Vec<u64> = idxs
            .iter()
            .copied()
            .filter(|i| !cache.contains_key(i))
            .collect();
        missing.sort_unstable();
        missing.dedup();
        evals += missing.len() as u64;
        for s in ev.score_cells(0, &missing) {
            cache.insert(s.idx, s);
        }
        idxs.iter().map(|i| cache[i]).collect()
    };
    let mut cur = score(&[start])[0];
    for _ in 0..max_iter {
        let nb: Vec<u64> = neighbours(&g, &g.cell(cur.idx), 1)
            .iter()
            .map(|n| g.index(n))
            .collect();
        match best_of(&score(&nb)) {
            Some(b) if better(&b, &cur) => cur = b,
            _ if !wide => break,
            _ => {
                let wide = window_r(&g, &g.cell(cur.idx), 1, WIDE_LOOK);
                match best_of(&score(&wide)) {
                    Some(b) if better(&b, &cur) => cur = b,
                    _ => break,
                }
            }
        }
    }
    (cur, evals)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn axis_ground_hit(p: &CamFromMap, ground_z: f64) -> Point3<f64> {
        let c = p.center();
        let d = p.rotation.inverse() * Vector3::z();
        c + d * ((ground_z - c.z) / d.z)
    }

    /// The erosion from the distance map is the square-window erosion, image edges included,
    /// and the eroded mask's own distance map is the one returned.
    #[test]
    fn erosion_by_distance_is_the_square_window_erosion() {
        let (w, h) = (37, 23);
        let mask: Vec<u8> = (0..w * h)
            .map(|i| {
                let (u, v) = ((i % w) as i64, (i / w) as i64);
                let hole = (u - 20).pow(2) + (v - 9).pow(2) < 10 || (u * 7 + v * 13) % 41 == 0;
                if hole {
                    0
                } else {
                    255
                }
            })
            .collect();
        for r in 0..4usize {
            let (eroded, dist) = erode_with_distance(&mask, w, h, r);
            for v in 0..h {
                for u in 0..w {
                    let inside = u >= r && v >= r && u + r < w && v + r < h;
                    let window = inside
                        && (v - r..=v + r).all(|y| (u - r..=u + r).all(|x| mask[y * w + x] != 0));
                    assert_eq!(eroded[v * w + u] != 0, window, "r {r} at ({u}, {v})");
                }
            }
            assert_eq!(dist, chessboard_distance(&eroded, w, h), "r {r}");
        }
    }

    /// Number of [`pattern_mask`]s.
    const PATTERNS: u64 = 5;

    /// Test masks of a `w`×`h` image: all valid, a centred disc, a lattice of specks, a larger
    /// disc with sparser specks, a larger disc with the specks (holes next to the disc's edge).
    fn pattern_mask(w: usize, h: usize, pattern: u64) -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (u, v) = ((i % w) as i64, (i / w) as i64);
                let r2 = (u - w as i64 / 2).pow(2) + (v - h as i64 / 2).pow(2);
                let big = r2 < (w.max(h) as i64).pow(2) / 5;
                let valid = match pattern {
                    0 => true,
                    1 => r2 < (w.min(h) as i64 / 2).pow(2),
                    2 => (u * 7 + v * 13) % 11 != 0,
                    3 => big && (u * 3 + v * 5) % 29 != 0,
                    _ => big && (u * 7 + v * 13) % 11 != 0,
                };
                if valid {
                    255
                } else {
                    0
                }
            })
            .collect()
    }

    /// The 3×3 masked blur written out per neighbour: what [`blur3`] must equal.
    fn blur3_reference(gray: &[u8], mask: &[u8], w: usize, h: usize) -> Vec<u8> {
        const K: [u32; 3] = [1, 2, 1];
        let mut out = gray.to_vec();
        for v in 0..h {
            for u in 0..w {
                if mask[v * w + u] == 0 {
                    continue;
                }
                let (mut acc, mut wsum) = (0u32, 0u32);
                for (j, kj) in K.iter().enumerate() {
                    for (i, ki) in K.iter().enumerate() {
                        let (x, y) = (u + i, v + j);
                        if x < 1 || y < 1 || x > w || y > h || mask[(y - 1) * w + x - 1] == 0 {
                            continue;
                        }
                        acc += kj * ki * gray[(y - 1) * w + x - 1] as u32;
                        wsum += kj * ki;
                    }
                }
                out[v * w + u] = ((acc + wsum / 2) / wsum.max(1)) as u8;
            }
        }
        out
    }

    #[test]
    fn blur3_equals_the_per_neighbour_blur() {
        for (w, h) in [
            (1, 1),
            (1, 6),
            (6, 1),
            (2, 2),
            (3, 3),
            (5, 8),
            (64, 41),
            (131, 97),
        ] {
            for pattern in 0..PATTERNS {
                let gray: Vec<u8> = (0..w * h)
                    .map(|i| ((i as u64 * 2_654_435_761) >> 7) as u8)
                    .collect();
                let mask = pattern_mask(w, h, pattern);
                assert_eq!(
                    blur3(&gray, &mask, w, h),
                    blur3_reference(&gray, &mask, w, h),
                    "{w}×{h} pattern {pattern}"
                );
            }
        }
    }

    /// The chamfer transform written out with a bounds test per neighbour: what
    /// [`chessboard_distance`] must equal.
    pub(super) fn chessboard_distance_reference(mask: &[u8], w: usize, h: usize) -> Vec<u16> {
        let mut d = vec![0u16; w * h];
        let at = |d: &[u16], u: isize, v: isize| -> u16 {
            if u < 0 || v < 0 || u >= w as isize || v >= h as isize {
                0
            } else {
                d[v as usize * w + u as usize]
            }
        };
        for v in 0..h as isize {
            for u in 0..w as isize {
                let i = v as usize * w + u as usize;
                if mask[i] == 0 {
                    continue;
                }
                let m = [(-1, -1), (0, -1), (1, -1), (-1, 0)]
                    .iter()
                    .map(|&(du, dv)| at(&d, u + du, v + dv))
                    .min()
                    .unwrap_or(0);
                d[i] = m.saturating_add(1);
            }
        }
        for v in (0..h as isize).rev() {
            for u in (0..w as isize).rev() {
                let i = v as usize * w + u as usize;
                if d[i] == 0 {
                    continue;
                }
                let m = [(1, 1), (0, 1), (-1, 1), (1, 0)]
                    .iter()
                    .map(|&(du, dv)| at(&d, u + du, v + dv))
                    .min()
                    .unwrap_or(0);
                d[i] = d[i].min(m.saturating_add(1));
            }
        }
        d
    }

    #[test]
    fn chessboard_distance_equals_the_reference_transform() {
        // Discs, holes, a lattice of specks and the degenerate sizes (every pixel on the border).
        for (w, h) in [
            (1, 1),
            (1, 7),
            (7, 1),
            (2, 5),
            (3, 3),
            (4, 9),
            (41, 23),
            (120, 77),
        ] {
            for pattern in 0..PATTERNS {
                let mask = pattern_mask(w, h, pattern);
                assert_eq!(
                    chessboard_distance(&mask, w, h),
                    chessboard_distance_reference(&mask, w, h),
                    "{w}×{h} pattern {pattern}"
                );
            }
        }
    }

    /// A 185° Mei camera 6 m over textured ground, its rendered view and ground points, a start
    /// a few centimetres and 0.6° off, and a 4-DoF box of 7605 cells around it.
    fn small_scene() -> (
        Camera,
        Vec<u8>,
        Vec<u8>,
        Vec<GroundPoint>,
        CamFromMap,
        SearchConfig,
    ) {
        use super::super::synth::{ground_points, render, Texture};
        let cam = Camera::Mei(crate::camera::Mei {
            width: 480,
            height: 400,
            fx: 220.0,
            fy: 220.4,
            cx: 241.0,
            cy: 199.0,
            skew: 0.0,
            xi: 1.1,
            k1: -0.25,
            k2: 0.08,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        });
        let tex = Texture::new(11);
        let truth = CamFromMap::from_center_ypr(&Point3::new(5.0, 8.0, 6.0), 0.7, 0.0, 0.0);
        let (gray, mask) = render(&tex, &cam, &truth, 0.0, 0.03, 4);
        let pts = ground_points(&tex, (5.0, 8.0), 14.0, 0.25, 0.0, 0.05, 5);
        let start = CamFromMap::from_center_ypr(&Point3::new(5.1, 7.95, 6.05), 0.71, 0.0, 0.0);
        let cfg = SearchConfig {
            spec: SearchSpec {
                x: AxisRange {
                    half: 0.3,
                    step: 0.05,
                },
                y: AxisRange {
                    half: 0.3,
                    step: 0.05,
                },
                z: AxisRange {
                    half: 0.1,
                    step: 0.05,
                },
                yaw: AxisRange {
                    half: 1.0,
                    step: 0.25,
                },
                ..SearchSpec::default()
            },
            ..SearchConfig::default()
        };
        (cam, gray, mask, pts, start, cfg)
    }

    /// The evaluator's shortcuts give the plain evaluator's numbers bit for bit: one built from
    /// a shared image preparation (after another evaluator on the same frame filled the cache),
    /// the split parallel score and the one-pass leave-one-group-out histogram. A thinned
    /// evaluator keeps every `stride`-th point.
    #[test]
    fn shared_preparation_and_split_scores_equal_the_plain_evaluator() {
        let (cam, gray, mask, pts, start, cfg) = small_scene();
        let views = [View {
            gray: &gray,
            mask: &mask,
            points: &pts,
        }];
        let plain = Evaluator::pooled(&cam, &views, &start, &cfg, 2).unwrap();
        let cache = ImageCache::default();
        // A level-0-only evaluator of another box fills the cache first; the pyramid is then
        // built on demand for the second.
        let narrow = SearchConfig {
            spec: SearchSpec {
                x: AxisRange {
                    half: 0.1,
                    step: 0.05,
                },
                ..cfg.spec
            },
            ..cfg
        };
        let first = Evaluator::pooled_cached(&cam, &views, &start, &narrow, 0, &cache).unwrap();
        let shared = Evaluator::pooled_cached(&cam, &views, &start, &cfg, 2, &cache).unwrap();
        assert_eq!(cache.lock().len(), 1, "one preparation for both evaluators");
        assert_eq!(
            first.n_points,
            Evaluator::pooled(&cam, &views, &start, &narrow, 0)
                .unwrap()
                .n_points
        );
        assert_eq!(shared.n_points, plain.n_points);
        let mut sc = Scratch::default();
        let offsets = [0.02, -0.03, 0.01, 0.1, 0.2, -0.1];
        for level in 0..=2 {
            for idx in [0, 7, plain.grid().cells() / 2] {
                let cell = plain.grid().cell(idx);
                assert_eq!(
                    plain.histogram(level, &cell, &mut sc).counts,
                    shared.histogram(level, &cell, &mut sc).counts,
                    "level {level} cell {idx}"
                );
            }
        }
        let whole = plain.value_at(0, &offsets, &mut sc);
        let folds = plain.folds(5);
        assert_eq!(plain.value_at_split(&folds, &offsets), whole);
        let per_group = plain.fold_histograms(&folds, &offsets, &mut sc);
        for left_out in 0..5 {
            let mut sum = JointHist::new(cfg.mi.bins_reflectivity, cfg.mi.bins_gray);
            for (j, h) in per_group.iter().enumerate() {
                if j != left_out {
                    sum.counts
                        .iter_mut()
                        .zip(&h.counts)
                        .for_each(|(a, b)| *a += b);
                }
            }
            assert_eq!(
                plain
                    .histogram_without(&folds, left_out, &offsets, &mut sc)
                    .counts,
                sum.counts
            );
        }
        let thin = plain.thinned(4);
        assert_eq!(thin.n_points, plain.n_points.div_ceil(4));
        assert_eq!(thin.view_points, vec![(pts.len(), thin.n_points)]);
        let n_thin = thin.value_at(0, &offsets, &mut sc).n;
        assert!(n_thin > 0 && n_thin <= thin.n_points as u64, "{n_thin}");
    }

    /// A search whose finest level scores a quarter of the points ends on a local maximum of the
    /// full estimator next to the full search's cell, ranks its peaks by their scores on all
    /// points (so the quality sees the full estimator), and scores fewer point-evaluations; with
    /// no thinning it is the search.
    #[test]
    fn a_thinned_finest_level_ends_next_to_the_full_search_scored_on_all_points() {
        let (cam, gray, mask, pts, start, cfg) = small_scene();
        let views = [View {
            gray: &gray,
            mask: &mask,
            points: &pts,
        }];
        let cfg = SearchConfig {
            coarse_min_points: 1000,
            ..cfg
        };
        let ev = Evaluator::pooled(&cam, &views, &start, &cfg, MAX_LEVEL).unwrap();
        assert!(ev.n_points >= 4 * cfg.coarse_min_points, "{}", ev.n_points);
        let full = search(&ev, &cfg);
        let same = search_thinned(&ev, &cfg, 1);
        assert_eq!(same.best, full.best);
        assert_eq!(same.other_peaks, full.other_peaks);
        assert_eq!(same.stats, full.stats);
        let thin = search_thinned(&ev, &cfg, 4);
        assert!(thin.stats.coarsest_level > 0);
        let rescored = |s: &Scored| ev.score_cells(0, &[s.idx])[0];
        assert_eq!(
            thin.best,
            rescored(&thin.best),
            "the answer's score is on all points"
        );
        for p in &thin.other_peaks {
            assert_eq!(*p, rescored(p));
            assert!(p.score <= thin.best.score);
        }
        // A local maximum of the full estimator, as the unthinned search's answer is.
        let around: Vec<u64> = neighbours(ev.grid(), &ev.grid().cell(thin.best.idx), 1)
            .iter()
            .map(|c| ev.grid().index(c))
            .collect();
        for n in ev.score_cells(0, &around) {
            assert!(better(&thin.best, &n), "{n:?} beats {:?}", thin.best);
        }
        let (a, b) = (ev.grid().cell(thin.best.idx), ev.grid().cell(full.best.idx));
        for i in 0..4 {
            assert!((a[i] - b[i]).abs() <= 1, "axis {i}: {a:?} vs {b:?}");
        }
        assert!(
            thin.stats.point_evaluations < full.stats.point_evaluations * 3 / 4,
            "{} vs {}",
            thin.stats.point_evaluations,
            full.stats.point_evaluations
        );
    }

    /// `surely_visible` may only leave points to the lattice test, never keep one that some pose
    /// of the box loses: checked pose by pose with the kernel's own visibility, on a 185° Mei and
    /// a 185° equidistant camera, for small 6-DoF boxes and wide 4-DoF ones.
    #[test]
    fn surely_visible_points_are_seen_from_every_lattice_pose() {
        let mei = Camera::Mei(crate::camera::Mei {
            width: 640,
            height: 512,
            fx: 300.0,
            fy: 300.5,
            cx: 321.0,
            cy: 255.0,
            skew: 0.0,
            xi: 1.2,
            k1: -0.27,
            k2: 0.09,
            p1: -4.0e-5,
            p2: 1.4e-4,
            fov_deg: Some(185.0),
        });
        let equidistant =
            super::super::kernel::test_camera_equidistant((640, 512), 150.0, (321.0, 255.0));
        for cam in [mei, equidistant] {
            surely_visible_case(&cam);
        }
    }

    /// One camera of [`surely_visible_points_are_seen_from_every_lattice_pose`].
    fn surely_visible_case(cam: &Camera) {
        use super::super::kernel::visible;
        use super::super::synth::{ground_points, Texture};
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let (mask, dist) = erode_with_distance(&cam.valid_mask(), w, h, 3);
        let gray: Vec<u8> = (0..w * h).map(|i| (i * 31 % 251) as u8).collect();
        let lut = bin_lut(super::super::mi::Binning::Uniform, 32, &[0; 256]);
        let img = BinnedImage::new(w, h, &gray, &mask, &lut, 32);
        let origin = [10.0, 20.0, 6.0];
        let tex = Texture::new(5);
        let pts = PreparedPoints::new(
            &ground_points(&tex, (10.0, 20.0), 30.0, 0.3, 0.0, 3.0, 2),
            origin,
            &lut,
        );
        let nadir = CamFromMap::from_center_ypr(&Point3::new(10.2, 19.9, 6.0), 0.4, 0.03, -0.02);
        // Tilted 70° from nadir: its axis still meets the ground, near where the pivot rule
        // switches between tilting about the ground and about the centre.
        let tilted = CamFromMap::from_center_ypr(&Point3::new(10.2, 19.9, 6.0), 0.4, 1.22, 0.0);
        let fc = FastCamera::new(cam, 0);
        // (pose, box, least share of the kept points it must settle): the 6-DoF boxes' 729-pose
        // lattices are what the shortcut is for; a wide 4-DoF box moves most pixels too far.
        for (init, half, settles) in [
            (nadir, [0.15, 0.15, 0.15, 0.5, 1.0, 1.0], 0.7),
            (nadir, [0.3, 0.3, 0.3, 0.9, 3.0, 3.0], 0.3),
            (nadir, [1.0, 1.0, 0.5, 3.0, 0.0, 0.0], 0.0),
            (tilted, [0.15, 0.15, 0.15, 0.5, 1.0, 1.0], 0.3),
            (tilted, [0.5, 0.5, 0.3, 2.0, 5.0, 5.0], 0.0),
        ] {
            let axes: Vec<usize> = (0..6).filter(|&i| half[i] > 0.0).collect();
            let at = |o: [f64; 6]| pose_at_pivot(&init, &o, Some(6.0));
            let mut lattice = vec![[0.0f64; 6]];
            for &i in &axes {
                lattice = lattice
                    .into_iter()
                    .flat_map(|c| {
                        [-half[i], 0.0, half[i]].map(|v| {
                            let mut d = c;
                            d[i] = v;
                            d
                        })
                    })
                    .collect();
            }
            let extremes: Vec<CamFromMap> = axes
                .iter()
                .flat_map(|&i| {
                    [-half[i], half[i]].map(|v| {
                        let mut o = [0.0; 6];
                        o[i] = v;
                        at(o)
                    })
                })
                .collect();
            let sure = surely_visible(&fc, &pts, origin, &at([0.0; 6]), &extremes, &dist, w);
            let mut seen = vec![true; pts.len()];
            let mut one = vec![false; pts.len()];
            for o in &lattice {
                visible(
                    &pts,
                    &PoseF32::new(&at(*o), origin),
                    &fc,
                    &img,
                    32,
                    &mut one,
                );
                seen.iter_mut().zip(&one).for_each(|(s, v)| *s &= v);
            }
            let n_sure = sure.iter().filter(|&&s| s).count();
            assert!(
                sure.iter().zip(&seen).all(|(s, v)| !s || *v),
                "{cam:?} {half:?}: a surely visible point is lost by some pose"
            );
            // It must also settle enough of what the lattice keeps, or it saves nothing.
            let n_seen = seen.iter().filter(|&&s| s).count();
            assert!(
                n_sure as f64 >= settles * n_seen as f64,
                "{cam:?} {half:?}: {n_sure} sure of {n_seen} seen"
            );
        }
    }

    #[test]
    fn tilt_about_the_ground_pivot_keeps_the_axis_ground_point() {
        let init = CamFromMap::from_center_ypr(&Point3::new(10.0, -4.0, 8.0), 0.7, 0.02, -0.01);
        let offsets = [0.0, 0.0, 0.0, 0.0, 1.2, -0.8];
        let before = axis_ground_hit(&init, 0.0);
        let p = pose_at_pivot(&init, &offsets, Some(8.0));
        let after = axis_ground_hit(&p, 0.0);
        assert!((after - before).norm() < 1e-9, "{before} → {after}");
        assert!((p.center().z - 8.0).abs() < 1e-12);
        // The tilt itself is the one the centre pivot applies.
        let q = pose_at(&init, &offsets);
        assert!(crate::pose::rotation_angle_between(&p.rotation, &q.rotation) < 1e-12);
        // About the centre the ground point moves by ≈ h·tan(tilt).
        let moved = (axis_ground_hit(&q, 0.0) - before).norm();
        assert!(moved > 8.0 * 1.0f64.to_radians(), "{moved}");
    }

    #[test]
    fn a_near_horizontal_axis_tilts_about_the_centre() {
        // A forward-looking camera (pitched 80° up from nadir): its axis meets no near ground.
        let init =
            CamFromMap::from_center_ypr(&Point3::new(0.0, 0.0, 2.0), 0.0, 80f64.to_radians(), 0.0);
        let offsets = [0.0, 0.0, 0.0, 0.0, 0.5, 0.5];
        let p = pose_at_pivot(&init, &offsets, Some(2.0));
        assert!((p.center() - init.center()).norm() < 1e-12);
    }

    #[test]
    fn held_axes_are_allowed_in_code_but_not_on_the_command_line() {
        let held = AxisRange {
            half: 0.0,
            step: 0.02,
        };
        let spec = SearchSpec {
            x: held,
            ..SearchSpec::default()
        };
        assert!(spec.validate().is_ok());
        assert_eq!(spec.grid().m[0], 0);
        assert!("x=0:0.02".parse::<SearchSpec>().is_err());
        let all_held = SearchSpec {
            x: held,
            y: held,
            z: held,
            yaw: held,
            ..SearchSpec::default()
        };
        let err = all_held.validate().unwrap_err().to_string();
        assert!(err.contains("nothing to search"), "{err}");
    }
}
