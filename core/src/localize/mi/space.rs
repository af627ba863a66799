//! The search space of the MI refinement: the box of poses around an initial pose ([`SearchSpec`],
//! [`Grid`]), the pose at a grid offset ([`pose_at`]) and the search's settings ([`SearchConfig`]).
//! Both steps' MI objective ([`super::objective`]) and the refinement's search (`refine::search`)
//! share it.

// Axis-indexed loops over parallel fixed-size arrays ([_; 6]) read clearer with the index.
#![allow(clippy::needless_range_loop)]

use crate::error::{Error, Result};
use crate::localize::error::LocalizeError;
use crate::localize::mi::MiConfig;
use crate::pose::CamFromMap;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Axis names in grid order.
pub const AXES: [&str; 6] = ["x", "y", "z", "yaw", "pitch", "roll"];
/// One axis of a pose's offsets: x, y, z in metres, yaw, pitch, roll in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// Map x (easting).
    X,
    /// Map y (northing).
    Y,
    /// Height.
    Z,
    /// Rotation about the map's up axis.
    Yaw,
    /// Pitch.
    Pitch,
    /// Roll.
    Roll,
}

impl Axis {
    /// All six, in the offsets' order.
    pub const ALL: [Axis; 6] = [
        Axis::X,
        Axis::Y,
        Axis::Z,
        Axis::Yaw,
        Axis::Pitch,
        Axis::Roll,
    ];

    /// The axis's name as reports and pose files spell it.
    pub fn name(self) -> &'static str {
        ["x", "y", "z", "yaw", "pitch", "roll"][self as usize]
    }

    /// The axis named `name`, if any.
    pub fn from_name(name: &str) -> Option<Axis> {
        Axis::ALL.into_iter().find(|a| a.name() == name)
    }

    /// `m` or `deg`.
    pub fn unit(self) -> &'static str {
        if (self as usize) < 3 {
            "m"
        } else {
            "deg"
        }
    }
}

impl std::fmt::Display for Axis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

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
            let bad = || LocalizeError::SearchSyntax {
                item: item.to_string(),
            };
            let (axis, val) = item.split_once('=').ok_or_else(bad)?;
            let (h, st) = val.split_once(':').ok_or_else(bad)?;
            let r = AxisRange {
                half: h.trim().parse().map_err(|_| bad())?,
                step: st.trim().parse().map_err(|_| bad())?,
            };
            if r.half == 0.0 {
                return Err(LocalizeError::SearchZero {
                    item: item.to_string(),
                }
                .into());
            }
            match axis.trim() {
                "x" => spec.x = r,
                "y" => spec.y = r,
                "z" => spec.z = r,
                "yaw" => spec.yaw = r,
                "pitch" => spec.pitch = Some(r),
                "roll" => spec.roll = Some(r),
                _ => return Err(bad().into()),
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
                return Err(LocalizeError::SearchNotPositive {
                    axis: name,
                    half: a.half,
                    step: a.step,
                }
                .into());
            }
            if a.half > limits[i] {
                return Err(LocalizeError::SearchTooWide {
                    axis: name,
                    half: a.half,
                    limit: limits[i],
                }
                .into());
            }
            if a.step > a.half {
                return Err(LocalizeError::SearchStep {
                    axis: name,
                    step: a.step,
                    half: a.half,
                }
                .into());
            }
        }
        let cells = self.grid().cells();
        if cells <= 1 {
            return Err(LocalizeError::SearchHeld.into());
        }
        if cells > MAX_CELLS {
            return Err(LocalizeError::SearchCells {
                cells,
                limit: MAX_CELLS,
            }
            .into());
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
    pub(crate) fn lattice_axis(&self, i: usize, level: u32) -> Vec<i64> {
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
pub(crate) const MIN_PIVOT_AXIS_Z: f64 = 0.3;

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
            _ => Err(super::choice("mode", s, "tiled or exhaustive")),
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

/// The 3^d lattice of the box: every combination of {−m, 0, +m} on the enabled axes.
pub(crate) fn box_lattice(g: &Grid) -> Vec<Cell> {
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
