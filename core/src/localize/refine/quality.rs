//! Quality of a refinement: the statistics reported with every result, and the gate that rejects
//! ambiguous ones.
//!
//! Per enabled axis, the objective is profiled through the optimum at the finest step
//! (±`profile-half-steps` cells, level 0: full image, all points):
//! - **curvature**: a least-squares parabola over ±`fit-half-steps` cells gives the MI
//!   curvature κ = −d²MI/dθ² (nats per unit²). `fisher_sigma` = 1/√(N·κ) treats N·MI as a
//!   log-likelihood ratio of N independent points; neighbouring pixels are correlated and the
//!   axes couple, so it is a lower bound, often 10–100× too small. The uncertainty the gate and
//!   the pose file use is [`crate::localize::refine::uncertainty`]'s (`sigma`, `covariance`).
//! - **basin width**: the profile is followed outwards from the optimum while it keeps falling; the
//!   width is the distance between the first rises on both sides (`basin_open` when it reaches the
//!   profile's end on a side).
//!
//! The **second peak** is the best other local maximum found by the search that lies outside the
//! main peak's basin on at least one axis. Its height is reported as a ratio to the optimum and as
//! a *contrast* above the background (the lowest profile value): (s₂ − bg)/(s₁ − bg). Raw MI ratios
//! are close to 1 for any textured scene because misaligned views still share low-frequency
//! structure, so the gate uses the contrast.

// Axis-indexed loops over parallel fixed-size arrays ([_; 6]) read clearer with the index.
#![allow(clippy::needless_range_loop)]

use crate::localize::error::{QualityConfigError, Refusal};
use crate::localize::mi::objective::Evaluator;
use crate::localize::mi::objective::Scored;
use crate::localize::mi::space::{Cell, AXES};
use crate::localize::refine::search::SearchResult;
use crate::localize::refine::uncertainty::Uncertainty;
use crate::localize::refine::verdict::{Grade, Stop};
pub use crate::pose::Sigma;
use serde::{Deserialize, Serialize};

/// Gate and profile settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct QualityConfig {
    /// Profile half length, finest cells.
    pub profile_half_steps: i64,
    /// Parabola-fit half length, finest cells.
    pub fit_half_steps: i64,
    /// Smallest accepted fixed point set.
    pub min_points: usize,
    /// Largest accepted second-peak contrast.
    pub max_second_peak_contrast: f64,
    /// Largest accepted fraction of the fixed set lost at some pose.
    pub max_lost_fraction: f64,
    /// Narrowest accepted basin along any axis, finest cells (both sides together). A genuine
    /// alignment peak falls off over the scale of the image's texture and blur; a peak only one
    /// or two cells wide is a spike of the estimator's noise on a wrong pose.
    pub min_basin_steps: i64,
    /// Two peaks are one hill when the objective along the straight path between them never
    /// falls further below the lower one than this fraction of the optimum's height above
    /// background: a valley floor (axes trading against each other) is one answer with a large
    /// σ, not two answers. 0 (the default) keeps the earlier rule, every peak outside the basin
    /// counts: at 0.2 a 30 %-wrong focal length was accepted (tests/localize_failures.rs), so the
    /// value waits for a measurement.
    pub max_saddle_dip: f64,
    /// Largest accepted σ of x and y (m).
    pub max_sigma_xy_m: f64,
    /// Largest accepted σ of z (m).
    pub max_sigma_z_m: f64,
    /// Largest accepted σ of yaw (deg).
    pub max_sigma_yaw_deg: f64,
    /// Largest accepted σ of pitch and roll when they are estimated (deg).
    pub max_sigma_tilt_deg: f64,
    /// Largest σ of x and y of a coarse result (m): beyond `max-sigma-xy-m` and within this,
    /// the result is served graded `coarse` ([`crate::localize::refine::verdict::judge`]).
    pub coarse_max_sigma_xy_m: f64,
    /// Largest σ of z of a coarse result (m).
    pub coarse_max_sigma_z_m: f64,
    /// Largest σ of yaw of a coarse result (deg).
    pub coarse_max_sigma_yaw_deg: f64,
    /// Largest σ of pitch and roll of a coarse result (deg).
    pub coarse_max_sigma_tilt_deg: f64,
    /// The orthophoto's registration σ against the LiDAR map, per horizontal axis (m): the part
    /// of the initializer's σ that no statistic of one view sees, since every satellite match
    /// shares it ([`crate::localize::refine::uncertainty::initializer`]). Set it from the
    /// orthophoto's stated positional accuracy.
    pub orthophoto_sigma_m: f64,
    /// `jackknife-folds`, a key of the retired nearest-pixel σ: still read, so that an older
    /// config keeps its node running, and named by `validate`'s warnings; never written.
    #[serde(rename = "jackknife-folds", skip_serializing)]
    pub retired_jackknife_folds: Option<serde::de::IgnoredAny>,
    /// The camera file's stated intrinsics uncertainty, carried into the covariance
    /// ([`crate::localize::refine::uncertainty::intrinsics_deltas`]); set from the camera file, not a config key.
    #[serde(skip)]
    pub intrinsics_sigma: Option<crate::camera::import::IntrinsicsSigma>,
}

impl Default for QualityConfig {
    fn default() -> Self {
        QualityConfig {
            profile_half_steps: 15,
            fit_half_steps: 3,
            min_points: 1000,
            max_second_peak_contrast: 0.8,
            max_lost_fraction: 0.02,
            min_basin_steps: MIN_BASIN_STEPS,
            max_saddle_dip: 0.0,
            max_sigma_xy_m: 0.05,
            max_sigma_z_m: 0.05,
            max_sigma_yaw_deg: 0.15,
            max_sigma_tilt_deg: 0.5,
            coarse_max_sigma_xy_m: 0.5,
            coarse_max_sigma_z_m: 0.5,
            coarse_max_sigma_yaw_deg: 1.0,
            coarse_max_sigma_tilt_deg: 2.0,
            orthophoto_sigma_m: 0.3,
            retired_jackknife_folds: None,
            intrinsics_sigma: None,
        }
    }
}

impl QualityConfig {
    /// The σ limits results are graded by ([`crate::localize::refine::verdict::judge`]).
    pub fn limits(&self) -> crate::localize::refine::verdict::Limits {
        crate::localize::refine::verdict::Limits {
            precise: [
                self.max_sigma_xy_m,
                self.max_sigma_z_m,
                self.max_sigma_yaw_deg,
                self.max_sigma_tilt_deg,
            ],
            coarse: [
                self.coarse_max_sigma_xy_m,
                self.coarse_max_sigma_z_m,
                self.coarse_max_sigma_yaw_deg,
                self.coarse_max_sigma_tilt_deg,
            ],
        }
    }

    /// Check the values a config file may set; the message names the key.
    pub fn validate(&self) -> std::result::Result<(), QualityConfigError> {
        let positive = [
            ("max-sigma-xy-m", self.max_sigma_xy_m),
            ("max-sigma-z-m", self.max_sigma_z_m),
            ("max-sigma-yaw-deg", self.max_sigma_yaw_deg),
            ("max-sigma-tilt-deg", self.max_sigma_tilt_deg),
            ("orthophoto-sigma-m", self.orthophoto_sigma_m),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(QualityConfigError::NotPositive { key, value: v });
            }
        }
        let coarse = [
            (
                "coarse-max-sigma-xy-m",
                self.coarse_max_sigma_xy_m,
                "max-sigma-xy-m",
                self.max_sigma_xy_m,
            ),
            (
                "coarse-max-sigma-z-m",
                self.coarse_max_sigma_z_m,
                "max-sigma-z-m",
                self.max_sigma_z_m,
            ),
            (
                "coarse-max-sigma-yaw-deg",
                self.coarse_max_sigma_yaw_deg,
                "max-sigma-yaw-deg",
                self.max_sigma_yaw_deg,
            ),
            (
                "coarse-max-sigma-tilt-deg",
                self.coarse_max_sigma_tilt_deg,
                "max-sigma-tilt-deg",
                self.max_sigma_tilt_deg,
            ),
        ];
        for (key, v, precise_key, precise) in coarse {
            if !(v.is_finite() && v >= precise) {
                return Err(QualityConfigError::CoarseBelowPrecise {
                    key,
                    value: v,
                    precise_key,
                    precise,
                });
            }
        }
        let fractions = [
            ("max-second-peak-contrast", self.max_second_peak_contrast),
            ("max-lost-fraction", self.max_lost_fraction),
            ("max-saddle-dip", self.max_saddle_dip),
        ];
        for (key, v) in fractions {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(QualityConfigError::NotFraction { key, value: v });
            }
        }
        if !(1..=1000).contains(&self.profile_half_steps)
            || !(1..=self.profile_half_steps).contains(&self.fit_half_steps)
        {
            return Err(QualityConfigError::HalfSteps {
                profile: self.profile_half_steps,
                fit: self.fit_half_steps,
            });
        }
        if !(0..=1000).contains(&self.min_basin_steps) {
            return Err(QualityConfigError::BasinSteps {
                value: self.min_basin_steps,
            });
        }
        Ok(())
    }
}

/// Default of [`QualityConfig::min_basin_steps`]. Measured on the simulator (pipeline
/// `small` 1–40 twice, `5mp` 1–10): every result within 0.1 m of the truth had basins of ≥ 15
/// cells on every axis (0.3 m, 0.75°) except `5mp` seed 6 (x: 17 cells); the wrong results the
/// other checks accepted had a 2-cell yaw basin (`small` 29, 16.6 m off) and 3-, 4- and 5-cell
/// z, y, x basins (`5mp` 3, 11 m off); a biased but nearby one (`5mp` 4, 0.21 m) had 6 cells.
/// One good result has since been refused by it (`small` 86 on main 6de2e75: 5.9 cm off, a
/// 4-cell z basin; CHANGELOG.md "Quality gate: basin rule"). A refused good pose costs a retry and the node keeps its last pose; a published wrong one
/// sends every detection metres astray, so the margin sits on the refusing side.
pub const MIN_BASIN_STEPS: i64 = 5;

/// Per-axis statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisQuality {
    /// Axis name (x, y, z, yaw, pitch, roll).
    pub axis: String,
    /// Unit of the values below (m or deg).
    pub unit: String,
    /// MI curvature κ at the peak, nats per unit².
    pub curvature: f64,
    /// 1/√(N·κ) (∞ when κ ≤ 0): the σ N independent points would give along this axis alone.
    /// A lower bound, not the uncertainty: see [`Quality::sigma`].
    pub fisher_sigma: f64,
    /// Vertex offset of the fitted parabola from the optimum (sub-step peak estimate).
    pub vertex_offset: f64,
    /// Basin width along the axis.
    pub basin_width: f64,
    /// The profile reached its end on a side while still falling.
    pub basin_open: bool,
    /// Whether the optimum sits on the search box's edge on this axis.
    pub on_edge: bool,
}

/// Which of the grid's checks refused a result ([`Refusal`] says it in words). The
/// checks run in this order and the first failing one refuses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GateCheck {
    /// Too few points seen from every pose of the box.
    TooFewPoints,
    /// Too much of the fixed point set left the image at some pose.
    PointsLost,
    /// The optimum sits on the box's edge.
    OnEdge,
    /// The objective rises again too close to the optimum along an axis.
    NoBasin,
    /// No negative curvature along an axis.
    NoPeak,
    /// A separate second peak reaches too close to the optimum's height: every other check
    /// passed, so the optimum itself is a clear peak.
    Ambiguous,
}

impl Refusal {
    /// The gate's check that gives this refusal.
    pub fn check(&self) -> GateCheck {
        match self {
            Refusal::TooFewPoints { .. } => GateCheck::TooFewPoints,
            Refusal::PointsLost { .. } => GateCheck::PointsLost,
            Refusal::OnEdge { .. } => GateCheck::OnEdge,
            Refusal::NoBasin { .. } => GateCheck::NoBasin,
            Refusal::NoPeak { .. } => GateCheck::NoPeak,
            Refusal::Ambiguous { .. } => GateCheck::Ambiguous,
        }
    }
}

/// Quality of one result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Quality {
    /// MI at the optimum (nats).
    pub mi: f64,
    /// NMI at the optimum.
    pub nmi: f64,
    /// Points that counted at the optimum.
    pub points: u64,
    /// Lowest profile value of the objective (background).
    pub background: f64,
    /// Objective of the best separated second peak over the optimum's (None: no such peak found).
    pub second_peak_ratio: Option<f64>,
    /// (s₂ − bg)/(s₁ − bg) (None: no separated peak).
    pub second_peak_contrast: Option<f64>,
    /// Offsets of the second peak from the optimum (m, m, m, deg, deg, deg).
    pub second_peak_offset: Option<[f64; 6]>,
    /// Per-axis statistics.
    pub axes: Vec<AxisQuality>,
    /// Poses scored for these statistics.
    pub poses: u64,
    /// Marginal σ per axis (m, deg) from [`crate::localize::refine::uncertainty`]; `None` until estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<Sigma>,
    /// The marginal covariance and how it was estimated; `None` until estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Uncertainty>,
    /// The smooth estimator's observed information, sandwich and frame covariances at the
    /// answer, when that stage ran and its Hessian had a basin
    /// ([`crate::localize::refine::information::information`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub information: Option<crate::localize::refine::information::Information>,
    /// The optima that compete with the answer, from the smooth stage
    /// ([`crate::localize::refine::optima`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optima: Option<crate::localize::refine::optima::Optima>,
    /// The set of poses the data cannot tell from the answer, followed where the local stage's
    /// Hessian has no basin ([`crate::localize::refine::region`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<crate::localize::refine::region::Region>,
    /// The verdict: the grid's checks alone ([`assess`]), or the smooth stage's grade from the
    /// covariance ([`crate::localize::refine::verdict::judge`]).
    #[serde(flatten)]
    pub grade: Grade,
    /// Present when the served pose is the initializer's own, graded by its own σ
    /// ([`crate::localize::refine::uncertainty::initializer`]) because the refinement was
    /// refused: why it was. Serialized as `source` (`initializer`) and `refinement_refused`.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub initializer: Option<FromInitializer>,
}

/// The refinement's refusal behind a pose served from the initializer ([`Quality::initializer`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FromInitializer(pub Stop);

impl Serialize for FromInitializer {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(Some(2))?;
        m.serialize_entry("source", "initializer")?;
        m.serialize_entry("refinement_refused", &self.0.to_string())?;
        m.end()
    }
}

impl Quality {
    /// Graded precise.
    pub fn precise(&self) -> bool {
        self.grade == Grade::Precise
    }

    /// Served: precise or coarse.
    pub fn served(&self) -> bool {
        self.grade.served()
    }

    /// The grid check that refused it, if one did.
    pub fn grid_refusal(&self) -> Option<&Refusal> {
        match &self.grade {
            Grade::Refused(Stop::Grid(r)) => Some(r),
            _ => None,
        }
    }
}

impl Sigma {
    /// From an estimate (axes it did not estimate are 0 for x..yaw, absent for the tilts).
    pub(crate) fn of(u: &Uncertainty) -> Self {
        Self::by_axis(|a| u.sigma_of(a))
    }
}

/// The lowest objective on the straight path between two cells (level 0, continuous offsets),
/// sampled at about one finest step (at most 32 samples, ends excluded), and the poses scored.
fn path_minimum(
    ev: &Evaluator,
    a: &[f64; 6],
    b: &[f64; 6],
    ca: &[i64; 6],
    cb: &[i64; 6],
) -> (f64, u64) {
    let cells = (0..6)
        .map(|i| (cb[i] - ca[i]).abs())
        .max()
        .unwrap_or(0)
        .clamp(1, 32);
    let objective = ev.objective();
    let mut scratch = crate::localize::mi::kernel::Scratch::default();
    let mut low = f64::INFINITY;
    for j in 1..cells {
        let t = j as f64 / cells as f64;
        let mut o = [0.0; 6];
        for i in 0..6 {
            o[i] = a[i] + t * (b[i] - a[i]);
        }
        low = low.min(ev.value_at(0, &o, &mut scratch).get(objective));
    }
    (low, cells.saturating_sub(1) as u64)
}

/// Least-squares parabola y = a x² + b x + c; returns (a, b).
fn fit_parabola(pts: &[(f64, f64)]) -> Option<(f64, f64)> {
    if pts.len() < 3 {
        return None;
    }
    // Normal equations of [x², x, 1].
    let mut s = [0f64; 5];
    let mut t = [0f64; 3];
    for &(x, y) in pts {
        let mut p = 1.0;
        for v in s.iter_mut() {
            *v += p;
            p *= x;
        }
        t[0] += y * x * x;
        t[1] += y * x;
        t[2] += y;
    }
    // [s4 s3 s2; s3 s2 s1; s2 s1 s0] [a b c] = t
    let m = nalgebra::Matrix3::new(s[4], s[3], s[2], s[3], s[2], s[1], s[2], s[1], s[0]);
    let r = m.lu().solve(&nalgebra::Vector3::new(t[0], t[1], t[2]))?;
    Some((r[0], r[1]))
}

/// Compute the quality statistics and apply the gate.
pub fn assess(ev: &Evaluator, res: &SearchResult, cfg: &QualityConfig) -> Quality {
    let g = *ev.grid();
    let best_cell = g.cell(res.best.idx);
    let mut poses = 0u64;
    let mut axes = Vec::new();
    let mut background = res.best.score;
    // Basin half widths in cells per axis and side (for the second-peak separation).
    let mut basin_cells = [[0i64; 2]; 6];
    for i in 0..6 {
        if g.m[i] == 0 {
            continue;
        }
        let p = profile_axis(ev, res, cfg, &best_cell, i);
        background = p.objective.iter().copied().fold(background, f64::min);
        poses += p.poses;
        basin_cells[i] = p.basin;
        axes.push(p.quality);
    }
    let (second, path_poses) = second_peak(ev, res, cfg, &best_cell, &basin_cells, background);
    poses += path_poses;
    let s1 = res.best.score;
    let (ratio, contrast, offset) = match second {
        Some(p) => {
            let c = g.cell(p.idx);
            let mut off = [0.0; 6];
            for i in 0..6 {
                off[i] = (c[i] - best_cell[i]) as f64 * g.step[i];
            }
            let denom = s1 - background;
            let contrast = if denom > 0.0 {
                (p.score - background) / denom
            } else {
                1.0
            };
            (Some(p.score / s1), Some(contrast), Some(off))
        }
        None => (None, None, None),
    };
    let grade = match gate(ev, res, cfg, &axes, &basin_cells, contrast.zip(offset)) {
        Some(r) => Grade::Refused(Stop::Grid(r)),
        None => Grade::Precise,
    };
    Quality {
        mi: res.best.value.mi,
        nmi: res.best.value.nmi,
        points: res.best.value.n,
        background,
        second_peak_ratio: ratio,
        second_peak_contrast: contrast,
        second_peak_offset: offset,
        axes,
        poses,
        sigma: None,
        covariance: None,
        information: None,
        optima: None,
        region: None,
        grade,
        initializer: None,
    }
}

/// One axis's profile through the optimum.
struct AxisProfile {
    /// The axis's statistics.
    quality: AxisQuality,
    /// The basin's half widths in cells below and above the optimum.
    basin: [i64; 2],
    /// The objective along the profile, the optimum included, in cell order.
    objective: Vec<f64>,
    /// Poses scored for it.
    poses: u64,
}

/// Score the profile of axis `i` through the optimum (cells within `profile_half_steps`, in
/// parallel), fit its MI parabola and walk its basin.
fn profile_axis(
    ev: &Evaluator,
    res: &SearchResult,
    cfg: &QualityConfig,
    best_cell: &Cell,
    i: usize,
) -> AxisProfile {
    let g = *ev.grid();
    let n = res.best.value.n.max(1) as f64;
    // The profile's cells (k ≠ 0 inside the grid), scored in parallel.
    let ks: Vec<i64> = (-cfg.profile_half_steps..=cfg.profile_half_steps)
        .filter(|&k| {
            let mut c = *best_cell;
            c[i] += k;
            k != 0 && g.contains(&c)
        })
        .collect();
    let idxs: Vec<u64> = ks
        .iter()
        .map(|&k| {
            let mut c = *best_cell;
            c[i] += k;
            g.index(&c)
        })
        .collect();
    let mut prof: Vec<(i64, f64, f64)> = ks
        .iter()
        .zip(ev.score_cells(0, &idxs))
        .map(|(&k, s)| (k, s.score, s.value.mi))
        .collect(); // (k, objective, mi)
    let at = prof.partition_point(|p| p.0 < 0);
    prof.insert(at, (0, res.best.score, res.best.value.mi));
    let step = g.step[i];
    let fit: Vec<(f64, f64)> = prof
        .iter()
        .filter(|p| p.0.abs() <= cfg.fit_half_steps)
        .map(|p| (p.0 as f64 * step, p.2))
        .collect();
    let (a, b) = fit_parabola(&fit).unwrap_or((0.0, 0.0));
    let curvature = -2.0 * a;
    let sigma = if curvature > 0.0 {
        1.0 / (n * curvature).sqrt()
    } else {
        f64::INFINITY
    };
    let vertex_offset = if a != 0.0 { -b / (2.0 * a) } else { 0.0 };
    let zero = prof.iter().position(|p| p.0 == 0).unwrap_or(0);
    let mut open = false;
    let mut walk = |dir: i64| -> i64 {
        let mut j = zero as i64;
        loop {
            let nxt = j + dir;
            if nxt < 0 || nxt >= prof.len() as i64 {
                open = true;
                break;
            }
            if prof[nxt as usize].1 > prof[j as usize].1 {
                break;
            }
            j = nxt;
        }
        (j - zero as i64).abs()
    };
    let (lo, hi) = (walk(-1), walk(1));
    AxisProfile {
        quality: AxisQuality {
            axis: AXES[i].into(),
            unit: if i < 3 { "m" } else { "deg" }.into(),
            curvature,
            fisher_sigma: sigma,
            vertex_offset,
            basin_width: (lo + hi) as f64 * step,
            basin_open: open,
            on_edge: best_cell[i].abs() == g.m[i],
        },
        basin: [lo, hi],
        objective: prof.iter().map(|p| p.1).collect(),
        poses: idxs.len() as u64,
    }
}

/// The second peak and the poses its saddle search scored: the best other local maximum outside
/// the basin on some axis that is a hill of its own, the objective dipping between it and the
/// optimum. One on the same valley floor (axes trading against each other) is the same answer,
/// whose spread the σ reports.
fn second_peak<'a>(
    ev: &Evaluator,
    res: &'a SearchResult,
    cfg: &QualityConfig,
    best_cell: &Cell,
    basin_cells: &[[i64; 2]; 6],
    background: f64,
) -> (Option<&'a Scored>, u64) {
    let g = *ev.grid();
    let s1 = res.best.score;
    let height = s1 - background;
    let mut path_poses = 0u64;
    let second = res.other_peaks.iter().find(|p| {
        let c = g.cell(p.idx);
        let outside = (0..6).any(|i| {
            let d = c[i] - best_cell[i];
            (d < 0 && -d > basin_cells[i][0].max(1)) || (d > 0 && d > basin_cells[i][1].max(1))
        });
        if !outside {
            return false;
        }
        if cfg.max_saddle_dip <= 0.0 {
            return true;
        }
        let (saddle, n) = path_minimum(ev, &g.offsets(best_cell), &g.offsets(&c), best_cell, &c);
        path_poses += n;
        height <= 0.0 || p.score.min(s1) - saddle > cfg.max_saddle_dip * height
    });
    (second, path_poses)
}

/// The gate: the first failing check, or `None` when the optimum passes.
/// `second` is the second peak's contrast and offset from the optimum.
fn gate(
    ev: &Evaluator,
    res: &SearchResult,
    cfg: &QualityConfig,
    axes: &[AxisQuality],
    basin_cells: &[[i64; 2]; 6],
    second: Option<(f64, [f64; 6])>,
) -> Option<Refusal> {
    if ev.n_points < cfg.min_points {
        return Some(Refusal::TooFewPoints {
            points: ev.n_points,
            min: cfg.min_points,
        });
    }
    if res.stats.max_lost_fraction > cfg.max_lost_fraction {
        return Some(Refusal::PointsLost {
            lost: res.stats.max_lost_fraction,
            max: cfg.max_lost_fraction,
        });
    }
    if let Some(a) = axes.iter().find(|a| a.on_edge) {
        return Some(Refusal::OnEdge {
            axis: a.axis.to_string(),
        });
    }
    if let Some((a, cells)) = axes
        .iter()
        .filter_map(|a| {
            let i = AXES.iter().position(|n| *n == a.axis)?;
            Some((a, basin_cells[i][0] + basin_cells[i][1]))
        })
        .find(|(_, cells)| *cells < cfg.min_basin_steps)
    {
        return Some(Refusal::NoBasin {
            axis: a.axis.to_string(),
            cells,
            min: cfg.min_basin_steps,
        });
    }
    if let Some(a) = axes.iter().find(|a| !(a.curvature > 0.0)) {
        return Some(Refusal::NoPeak {
            axis: a.axis.to_string(),
            curvature: a.curvature,
            unit: a.unit.to_string(),
        });
    }
    let (c, o) = second?;
    let a = res.offsets;
    (c > cfg.max_second_peak_contrast).then(|| Refusal::Ambiguous {
        optimum: [a[0], a[1], a[2], a[3]],
        second: [o[0], o[1], o[2], o[3]],
        contrast: c,
        max: cfg.max_second_peak_contrast,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The limits come from the keys in the order the verdict reads them (xy, z, yaw, tilt).
    #[test]
    fn the_limits_follow_the_keys() {
        let q = QualityConfig {
            max_sigma_xy_m: 0.01,
            max_sigma_z_m: 0.02,
            max_sigma_yaw_deg: 0.03,
            max_sigma_tilt_deg: 0.04,
            coarse_max_sigma_xy_m: 0.1,
            coarse_max_sigma_z_m: 0.2,
            coarse_max_sigma_yaw_deg: 0.3,
            coarse_max_sigma_tilt_deg: 0.4,
            ..QualityConfig::default()
        };
        let l = q.limits();
        assert_eq!(l.precise, [0.01, 0.02, 0.03, 0.04]);
        assert_eq!(l.coarse, [0.1, 0.2, 0.3, 0.4]);
        let d = QualityConfig::default().limits();
        assert_eq!(
            (d.precise, d.coarse),
            ([0.05, 0.05, 0.15, 0.5], [0.5, 0.5, 1.0, 2.0])
        );
        assert!(q.validate().is_ok());
        let bad = QualityConfig {
            coarse_max_sigma_z_m: 0.01,
            ..q
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("coarse-max-sigma-z-m = 0.01"));
    }

    #[test]
    fn parabola_fit_recovers_coefficients() {
        let pts: Vec<(f64, f64)> = (-3..=3)
            .map(|k| {
                let x = k as f64 * 0.02;
                (x, -50.0 * x * x + 0.7 * x + 1.3)
            })
            .collect();
        let (a, b) = fit_parabola(&pts).unwrap();
        assert!((a + 50.0).abs() < 1e-6 && (b - 0.7).abs() < 1e-9, "{a} {b}");
        assert!(fit_parabola(&pts[..2]).is_none());
    }
}
