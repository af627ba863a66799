//! The uncertainty of a refined pose: the marginal covariance of [x, y, z, yaw(, pitch, roll)],
//! by the jackknife below ([`estimate`]); the node's smooth path takes it from the observed
//! information instead ([`crate::localize::refine::information::information_covariance`]), in the
//! same [`Uncertainty`] with [`CovarianceSource::Information`].
//!
//! Two things make a single MI optimum less certain than its peak's sharpness suggests, and both
//! are measured here instead of assumed:
//! - **Coupling.** Axes trade against each other along valleys of the objective (a forward
//!   camera's lateral shift against its yaw, a nadir camera's height against its focal length).
//!   Per-axis 1-D curvatures cannot see a valley; re-optimising all free axes together can.
//! - **Estimator noise.** MI is estimated from a finite, spatially correlated sample: neighbouring
//!   points share pixels, texture and blur, so `N` points are worth far fewer independent ones,
//!   and how many is unknown. A *delete-a-group jackknife* measures it: each view's fixed point
//!   set (in Morton order) is cut into `folds` contiguous runs — compact patches of ground — and
//!   group k is run k of every view. Leaving one group out at a time, the answer is polished
//!   again (Nelder–Mead over x, y, z and yaw from the answer) on the remaining points; the spread
//!   of those `folds` optima, scaled by (K − 1)/K, is the covariance of the answer. Whole patches
//!   go out together, so correlation within a patch is kept, and a patch that drags the peak (a
//!   parked car, a shadow, a repainted marking) shows up as spread; along a valley the optima
//!   scatter along its floor, so the coupling appears in the off-diagonal terms.
//!
//! The MI peak is a cusp rather than a parabola at the pixel scale (nearest-pixel sampling), so
//! the optima are found by re-optimising, not by Newton steps on a fitted quadratic: a quadratic
//! fitted over a cusp's stencil invents curvature in the coupled directions (tried: on a forward
//! camera it found no peak on results 1–2 cm from the truth).
//!
//! A leave-one-out histogram is the sum of the other groups' histograms at the pose, one pass of
//! the kernel over (K − 1)/K of the points per evaluation.
//!
//! Because every group's re-optimisation starts on the answer's cusp, all of them can stay there
//! while the data cannot tell the answer from poses far along a valley. A [`Region`] test probes
//! that directly, ray by ray; a region that stays open to the gate's reach means no peak.

use crate::camera::import::IntrinsicsSigma;
use crate::camera::{Camera, CameraModel};
use crate::error::Result;
use crate::localize::mi::kernel::Scratch;
use crate::localize::mi::objective::{Evaluator, ImageCache, View};
use crate::localize::mi::space::{pose_at_pivot, SearchConfig, AXES};
use crate::localize::mi::{pooled_information, JointHist};
use crate::localize::pnp::{refine_lm, Correspondence};
use crate::localize::refine::polish::{box_config, initial_simplex, nelder_mead, PolishParams};
use crate::pose::angle_difference;
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of the estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct UncertaintyConfig {
    /// Jackknife groups (contiguous patches of each view's points).
    pub folds: usize,
    /// How far the [`Region`]'s rays reach from the answer per axis (x, y, z in m, then yaw,
    /// pitch, roll in degrees), at least the re-optimisation box. A ray that reaches this far
    /// without the data telling the pose apart leaves σ unbounded, so it must lie beyond 2·z·σ
    /// for the largest σ the gate accepts: the default is 6× the default [`QualityConfig`]
    /// limits (2·[`REGION_Z`] with a margin of 1.5).
    ///
    /// [`QualityConfig`]: crate::localize::refine::quality::QualityConfig
    /// (its `Default` and `QualityConfig::region_bound` live beside the gate, which sets the limits)
    pub region_bound: [f64; 6],
}

/// The estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// Axis names, in the order of `sigma` and `covariance` (x, y, z, yaw, then pitch, roll
    /// when free).
    pub axes: Vec<String>,
    /// Units of the axes (m or deg).
    pub units: Vec<String>,
    /// Marginal standard deviation per axis (√ of the covariance's diagonal); ∞ where the
    /// objective has no peak.
    pub sigma: Vec<f64>,
    /// Marginal covariance in the map frame (m, deg), row-major.
    pub matrix: Vec<Vec<f64>>,
    /// Each group's optimum without it: the change of the camera centre (m) and angles (deg)
    /// from the reported pose, per axis (empty for the information's estimate).
    pub group_optima: Vec<Vec<f64>>,
    /// Whether every group's re-optimisation found a peak inside its box (else σ is ∞); for the
    /// information's estimate, that its Hessian had a basin (always, or there is no estimate).
    pub peak: bool,
    /// Jackknife groups used (0 for the information's estimate).
    pub folds: usize,
    /// Per 1σ intrinsics mode (focal scale, cx, cy) stated by the camera file, the change of the
    /// answer it makes (same axes and units); empty when the file states no uncertainty.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics: Vec<Vec<f64>>,
    /// Points in the re-optimisation box's fixed set, all views (the information's: the
    /// smooth stage's set).
    pub points: usize,
    /// Poses scored (every group's re-optimisation and the region's probes; for the
    /// information's estimate, its Hessian's and cluster scores' evaluations).
    pub poses: usize,
    /// The jackknife's own covariance (floored at half the finest step per axis), before the
    /// Student-t widening.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub jackknife: Vec<Vec<f64>>,
    /// The region the data cannot tell from the answer ([`Region`]): when it is open, σ is
    /// unbounded; its ellipsoid is reported for diagnosis, not added to `matrix`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<Region>,
    /// The σ the gate judges (same axes): the jackknife's estimate (or the information's judged
    /// σ, the largest of its bound, sandwiches and the floor), without the Student-t widening
    /// that makes the reported `sigma`'s 3σ bounds cover and without the intrinsics' part;
    /// unbounded where `matrix` is.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gate_sigma: Vec<f64>,
    /// Where the covariance comes from: the jackknife above, or the smooth estimator's observed
    /// information (its fields then empty: no groups, folds 0, no region).
    #[serde(default)]
    pub source: CovarianceSource,
}

/// What an [`Uncertainty`]'s covariance was estimated by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CovarianceSource {
    /// The jackknife of Nelder–Mead re-optimisations on the nearest-pixel objective
    /// ([`estimate`]).
    #[default]
    Jackknife,
    /// The smooth estimator's observed information over all the answer's axes: the largest of
    /// its Cramér–Rao bound, patch and frame sandwiches and the search's floor
    /// ([`crate::localize::refine::information::information_covariance`]).
    Information,
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

/// Estimate the uncertainty of `pose` on `views` (the same views and estimator the search used)
/// over x, y, z and yaw, and over pitch and roll too when `polish` frees them (tilting about the
/// ground `pivot` metres below the camera, as the pipeline's polish does). A nadir camera's tilt
/// trades against its position (a pitch of δ at height h moves the image like a shift of h·δ),
/// so a position σ with the tilt held would miss that valley. `polish` bounds and stops each
/// group's re-optimisation; the covariance is of the camera centre (map frame) and the angles.
pub fn estimate(
    cam: &Camera,
    views: &[View<'_>],
    pose: &CamFromMap,
    search: &SearchConfig,
    polish: &PolishParams,
    pivot: Option<f64>,
    ucfg: &UncertaintyConfig,
) -> Result<Uncertainty> {
    estimate_cached(
        cam,
        views,
        pose,
        search,
        polish,
        pivot,
        ucfg,
        &ImageCache::default(),
    )
}

/// [`estimate`] taking the views' image preparations from `cache`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn estimate_cached<'a>(
    cam: &Camera,
    views: &[View<'a>],
    pose: &CamFromMap,
    search: &SearchConfig,
    polish: &PolishParams,
    pivot: Option<f64>,
    ucfg: &UncertaintyConfig,
    cache: &ImageCache<'a>,
) -> Result<Uncertainty> {
    let mut p = PolishParams {
        tilt_starts_deg: 0.0,
        ..*polish
    };
    // Each group's optimum is wanted to a quarter of the finest step, not to the answer's own
    // tolerance: the variance is floored at half a step anyway, and the last halvings of a
    // simplex that sits on the answer's cusp were a fifth of the jackknife's evaluations.
    for (t, u) in p.tolerance.iter_mut().zip(step_units(search, 6)) {
        *t = t.max(JACKKNIFE_TOLERANCE_STEPS * u);
    }
    let tilt = p.frees_tilt();
    let ev = Evaluator::pooled_cached(cam, views, pose, &box_config(search, &p, pivot), 0, cache)?;
    let k = ucfg.folds.max(2);
    let folds = ev.folds(k);
    let objective = ev.objective();
    let parzen = search.mi.parzen;
    // The tilt pivot the evaluator applies (none for a near-horizontal optical axis).
    let applied_pivot = ev.grid().pivot;
    let (ev, folds) = (&ev, &folds);
    // Every group's polish starts on the same simplex: its poses' per-group histograms are taken
    // once (one pass over all points each), and a group's objective there is the sum of the
    // others' — integer counts, so the very histogram `histogram_without` would build.
    let first = initial_simplex(&p, [0.0; 6]);
    let first_hists: Vec<Vec<Vec<JointHist>>> = first
        .par_iter()
        .map(|o| ev.fold_histograms(folds, o, &mut Scratch::default()))
        .collect();
    let same =
        |a: &[f64; 6], b: &[f64; 6]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    let (first, first_hists) = (&first, &first_hists);
    // Group by group, each polish on the other groups' points (deterministic: no randomness,
    // results collected in group order).
    let jackknife_ends = || -> Vec<([f64; 6], usize, bool)> {
        (0..k)
            .into_par_iter()
            .map(|left_out| {
                let mut scratch = Scratch::default();
                let mut f = |o: &[f64; 6]| match first.iter().position(|x| same(x, o)) {
                    Some(i) => value_without(&first_hists[i], Some(left_out), objective, parzen),
                    None => {
                        let hs = ev.histograms_without(folds, left_out, o, &mut scratch);
                        pooled_information(&hs, parzen).get(objective)
                    }
                };
                let end = nelder_mead(&mut f, &p);
                let on_edge =
                    (0..6).any(|i| p.is_free(i) && end.offsets[i].abs() >= 0.95 * p.bound[i]);
                (end.offsets, end.evaluations, on_edge)
            })
            .collect()
    };
    // The groups' polishes are sequential simplexes of unequal length, so the pool runs out of
    // groups before the last one ends; the region (below) does not depend on them and fills
    // that tail. Both are deterministic, so running them side by side changes no result.
    let mut rp = p;
    for i in 0..6 {
        if rp.is_free(i) {
            rp.bound[i] = rp.bound[i].max(ucfg.region_bound[i]);
        }
    }
    let d = if tilt { 6 } else { 4 };
    let unit = step_units(search, d);
    let (ends, reg) = rayon::join(jackknife_ends, || -> Result<Region> {
        // Its own fixed point set: the points every pose of its wider box sees.
        let rev =
            Evaluator::pooled_cached(cam, views, pose, &box_config(search, &rp, pivot), 0, cache)?;
        // Its standard errors from more, smaller patches than the re-optimisations: every probe
        // scores every patch in one pass, so more patches cost nothing, and the standard error
        // has REGION_FOLDS − 1 degrees of freedom instead of K − 1 (with 7, its own noise opened
        // the region along one of the rays on a quarter of the simulated scenes).
        let rfolds = rev.folds(REGION_FOLDS.max(k));
        Ok(region(&rev, &rfolds, objective, parzen, &rp, &unit, d))
    });
    let reg = reg?;
    let deltas = group_deltas(pose, &ends, applied_pivot);
    let matrix = jackknife_covariance(&deltas, k, &unit);
    let jackknife = matrix.clone();
    // The jackknife's variance has K − 1 degrees of freedom: a 3σ bound from it covers what 3
    // true σ do only when widened to the Student-t quantile (×1.51 for 8 groups). The reported
    // covariance is widened so; the gate judges the estimate itself (`gate_sigma`).
    let widen = (student_t_3sigma(k - 1) / 3.0).powi(2);
    let mut matrix: Vec<Vec<f64>> = jackknife
        .iter()
        .map(|r| r.iter().map(|v| v * widen).collect())
        .collect();
    let mut judged = jackknife.clone();
    // The groups' re-optimisations can also all stay on the answer's cusp while the data cannot
    // tell it from poses far along a valley. The region they cannot tell apart finds that: when
    // it stays open to the gate's reach there is no peak. Its ellipsoid, where it closes, is
    // reported but not added: on simulated scenes it overstated the error several times along
    // the height (σ z 7 cm on an answer 0.2 cm from the oracle) and refused 2 of 100 results the
    // jackknife's σ covered (docs/refine.md "Uncertainty"). It was computed above, beside the
    // groups' polishes.
    // A group that walked to its box's edge found no peak within reach, and a region that reaches
    // the edge has none either: the spread is at least that far, and the answer unbounded in truth.
    let peak = !ends.iter().any(|e| e.2) && reg.open.is_none();
    if !peak {
        for a in 0..d {
            matrix[a][a] = f64::INFINITY;
            judged[a][a] = f64::INFINITY;
        }
    }
    let sigma = (0..d).map(|a| matrix[a][a].max(0.0).sqrt()).collect();
    let gate_sigma = (0..d).map(|a| judged[a][a].max(0.0).sqrt()).collect();
    Ok(Uncertainty {
        axes: AXES[..d].iter().map(|a| a.to_string()).collect(),
        units: ["m", "m", "m", "deg", "deg", "deg"][..d]
            .iter()
            .map(|u| u.to_string())
            .collect(),
        sigma,
        matrix,
        group_optima: deltas.iter().map(|e| e[..d].to_vec()).collect(),
        peak,
        folds: k,
        intrinsics: Vec::new(),
        points: ev.n_points,
        poses: ends.iter().map(|e| e.1).sum::<usize>() + reg.poses,
        jackknife,
        region: Some(reg),
        gate_sigma,
        source: CovarianceSource::Jackknife,
    })
}

/// Each group's optimum (`ends`: offsets, evaluations, on the box's edge) as the change of the
/// camera centre and of the angles (degrees) it makes; a tilt about a ground pivot also moves
/// the centre.
fn group_deltas(
    pose: &CamFromMap,
    ends: &[([f64; 6], usize, bool)],
    applied_pivot: Option<f64>,
) -> Vec<[f64; 6]> {
    ends.iter()
        .map(|e| pose_delta(pose, &pose_at_pivot(pose, &e.0, applied_pivot)))
        .collect()
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

/// The jackknife covariance of the `k` groups' optima over the first `unit.len()` axes, each
/// variance floored at (half the finest step `unit`)².
fn jackknife_covariance(deltas: &[[f64; 6]], k: usize, unit: &[f64]) -> Vec<Vec<f64>> {
    let d = unit.len();
    let mean: Vec<f64> = (0..d)
        .map(|i| deltas.iter().map(|e| e[i]).sum::<f64>() / k as f64)
        .collect();
    let scale = (k as f64 - 1.0) / k as f64;
    let mut matrix = vec![vec![0.0; d]; d];
    for (a, row) in matrix.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            *v = scale
                * deltas
                    .iter()
                    .map(|e| (e[a] - mean[a]) * (e[b] - mean[b]))
                    .sum::<f64>();
        }
    }
    // The objective is rugged at the pixel scale (nearest-pixel sampling), and every group's
    // re-optimisation starts at the answer, so they can share one local bump and spread less than
    // the search resolves: the variance is floored at (half the finest step)² per axis.
    for (a, row) in matrix.iter_mut().enumerate() {
        row[a] = row[a].max((0.5 * unit[a]).powi(2));
    }
    matrix
}

/// The jackknife groups' re-optimisations stop when every vertex is within this many finest
/// search steps of the best (or the polish's own tolerance, if coarser).
pub(crate) const JACKKNIFE_TOLERANCE_STEPS: f64 = 0.25;

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

/// z of the contrast test that bounds [`Region`]: a probe is told apart from the answer when the
/// answer's objective exceeds the probe's by more than `REGION_Z` jackknife standard errors of
/// that difference.
pub(crate) const REGION_Z: f64 = 2.0;

/// Patches for the region's standard errors.
pub(crate) const REGION_FOLDS: usize = 32;

/// Probe radii along each ray, in units of the search's finest step per axis; the last probe of a
/// ray is at the polish box's edge.
const REGION_RADII: [f64; 12] = [
    1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0,
];

/// The poses the data cannot tell apart from the answer, probed along rays from it.
///
/// A pose is *indistinguishable* when the objective's drop from the answer to it, D, is within
/// [`REGION_Z`] jackknife standard errors of D (the same delete-a-group scheme: D on each
/// leave-one-out histogram pair). This is the test-inversion confidence region; it needs no
/// smoothness of the objective, so a pixel-scale cusp at the answer cannot hide a flat valley
/// behind it. For a locally quadratic objective (Hessian H) whose gradient's noise has covariance
/// J, the boundary along a direction u lies at 2·z·√(uᵀJu)/(uᵀHu), and where J ∝ H that boundary
/// is the ellipsoid δᵀ Σ⁻¹ δ = (2z)² of the sandwich covariance Σ = H⁻¹JH⁻¹. So the boundary
/// points, fitted with an ellipsoid, give a covariance in the same units as the jackknife's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Region {
    /// The test's z ([`REGION_Z`]).
    pub z: f64,
    /// Each ray's boundary: the offsets from the answer (x, y, z in m, then degrees) where the
    /// drop first exceeds z standard errors (interpolated between probes); `None` where the ray
    /// reached its box edge without that.
    pub boundary: Vec<Option<Vec<f64>>>,
    /// Covariance of the ellipsoid fitted through the boundary, scaled by 1/(2z)² (same axes and
    /// units as [`Uncertainty::matrix`]); `None` when the region is open or no ellipsoid fits.
    pub matrix: Option<Vec<Vec<f64>>>,
    /// The first open ray, as a direction like "+x-yaw": the data cannot tell the answer from
    /// the box's edge that way.
    pub open: Option<String>,
    /// How far that ray reached (offsets from the answer, x, y, z in m, then degrees): the σ of
    /// each axis it moves is at least its reach over 2z.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub open_reach: Option<Vec<f64>>,
    /// Poses scored.
    pub poses: usize,
    /// Points in the region's fixed set, all views.
    #[serde(default)]
    pub points: usize,
}

/// Each free axis' unit for the region's rays and the σ floor: the search's finest step (tilts
/// are not searched on a grid and share the yaw's).
fn step_units(search: &SearchConfig, d: usize) -> Vec<f64> {
    let axes = search.spec.axes();
    (0..d).map(|i| axes[i.min(3)].step).collect()
}

/// The σ floor of a named axis (x, y, z, yaw, pitch, roll): half the search's finest step on it
/// (tilts the yaw's), as [`estimate`] floors the jackknife's. An unknown name has none (0).
pub(crate) fn sigma_floor(search: &SearchConfig, axis: &str) -> f64 {
    AXES.iter()
        .position(|a| *a == axis)
        .map_or(0.0, |i| 0.5 * step_units(search, i + 1)[i])
}

/// The rays: every free axis both ways, and every pair of free axes in all four sign
/// combinations, in step units.
fn rays(d: usize) -> Vec<Vec<f64>> {
    let mut out = Vec::new();
    for i in 0..d {
        for s in [1.0, -1.0] {
            let mut u = vec![0.0; d];
            u[i] = s;
            out.push(u);
        }
    }
    for i in 0..d {
        for j in i + 1..d {
            for (si, sj) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                let mut u = vec![0.0; d];
                u[i] = si;
                u[j] = sj;
                out.push(u);
            }
        }
    }
    out
}

/// How far a ray reaches, in step units: where its first component reaches its box bound.
fn ray_reach(u: &[f64], p: &PolishParams, unit: &[f64]) -> f64 {
    (0..u.len())
        .filter(|&i| u[i] != 0.0)
        .map(|i| p.bound[i] / unit[i])
        .fold(f64::INFINITY, f64::min)
}

/// A ray's name, e.g. "+x-yaw".
fn ray_name(u: &[f64]) -> String {
    u.iter()
        .zip(AXES)
        .filter(|(v, _)| **v != 0.0)
        .map(|(v, a)| format!("{}{a}", if *v > 0.0 { '+' } else { '-' }))
        .collect()
}

/// The objective on the sum of the groups' histograms `hists` (`[group][slot]`), without group
/// `left_out`, pooled as the evaluator's slots are.
fn value_without(
    hists: &[Vec<JointHist>],
    left_out: Option<usize>,
    objective: crate::localize::mi::Objective,
    parzen: bool,
) -> f64 {
    let mut sum = hists[0]
        .iter()
        .map(|h| JointHist::new(h.rows, h.cols))
        .collect::<Vec<_>>();
    for (j, hk) in hists.iter().enumerate() {
        if Some(j) != left_out {
            for (a, b) in sum.iter_mut().zip(hk) {
                a.add(b);
            }
        }
    }
    pooled_information(&sum, parzen).get(objective)
}

/// The objective's drop from the answer to `at` on all points, and its jackknife standard error
/// (the drop on each leave-one-group-out histogram pair). `base` holds the answer's per-group
/// histograms.
fn contrast(
    ev: &Evaluator,
    folds: &crate::localize::mi::objective::Folds,
    objective: crate::localize::mi::Objective,
    parzen: bool,
    base: &[Vec<JointHist>],
    at: &[f64; 6],
    scratch: &mut Scratch,
) -> (f64, f64) {
    let hists = ev.fold_histograms(folds, at, scratch);
    let value = |hs: &[Vec<JointHist>], left_out| value_without(hs, left_out, objective, parzen);
    let k = hists.len();
    let drop = value(base, None) - value(&hists, None);
    let loo: Vec<f64> = (0..k)
        .map(|j| value(base, Some(j)) - value(&hists, Some(j)))
        .collect();
    let mean = loo.iter().sum::<f64>() / k as f64;
    let var = (k as f64 - 1.0) / k as f64 * loo.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
    (drop, var.sqrt())
}

/// Probe the [`Region`] around the evaluator's base pose over the first `d` axes.
fn region(
    ev: &Evaluator,
    folds: &crate::localize::mi::objective::Folds,
    objective: crate::localize::mi::Objective,
    parzen: bool,
    p: &PolishParams,
    unit: &[f64],
    d: usize,
) -> Region {
    let base = ev.fold_histograms(folds, &[0.0; 6], &mut Scratch::default());
    let rays = rays(d);
    let ends: Vec<(Option<Vec<f64>>, usize)> = rays
        .par_iter()
        .map(|u| {
            let mut scratch = Scratch::default();
            let t_max = ray_reach(u, p, unit);
            let radii = REGION_RADII
                .iter()
                .copied()
                .filter(|&t| t < t_max)
                .chain(std::iter::once(t_max));
            let (mut t0, mut r0, mut n) = (0.0, 0.0, 0);
            for t in radii {
                let mut at = [0.0; 6];
                for i in 0..d {
                    at[i] = t * u[i] * unit[i];
                }
                let (drop, se) = contrast(ev, folds, objective, parzen, &base, &at, &mut scratch);
                n += 1;
                let r = if se > 0.0 {
                    drop / (REGION_Z * se)
                } else if drop > 0.0 {
                    f64::INFINITY
                } else {
                    0.0
                };
                if r >= 1.0 {
                    let tb = if r.is_finite() {
                        t0 + (1.0 - r0) / (r - r0) * (t - t0)
                    } else {
                        t
                    };
                    return (Some((0..d).map(|i| tb * u[i] * unit[i]).collect()), n);
                }
                (t0, r0) = (t, r);
            }
            (None, n)
        })
        .collect();
    let poses = ends.iter().map(|e| e.1).sum();
    let first_open = rays.iter().zip(&ends).find(|(_, e)| e.0.is_none());
    let open = first_open.map(|(u, _)| ray_name(u));
    let open_reach = first_open.map(|(u, _)| {
        let t = ray_reach(u, p, unit);
        (0..d).map(|i| t * u[i] * unit[i]).collect::<Vec<f64>>()
    });
    let boundary: Vec<Option<Vec<f64>>> = ends.into_iter().map(|e| e.0).collect();
    let matrix = if open.is_none() {
        let pts: Vec<Vec<f64>> = boundary
            .iter()
            .flatten()
            .map(|b| (0..d).map(|i| b[i] / unit[i]).collect())
            .collect();
        fit_ellipsoid(&pts, d).map(|m| {
            // Back from step units to the axes' own (m, deg).
            let s = 1.0 / (2.0 * REGION_Z).powi(2);
            (0..d)
                .map(|a| (0..d).map(|b| s * m[a][b] * unit[a] * unit[b]).collect())
                .collect()
        })
    } else {
        None
    };
    Region {
        z: REGION_Z,
        boundary,
        matrix,
        open,
        open_reach,
        poses,
        points: ev.n_points,
    }
}

/// The inverse of the symmetric positive-definite M whose quadric bᵀMb = 1 passes closest (least
/// squares) through the points; `None` when the fit is not positive definite (the points do not
/// enclose the origin like an ellipsoid).
fn fit_ellipsoid(pts: &[Vec<f64>], d: usize) -> Option<Vec<Vec<f64>>> {
    let pairs: Vec<(usize, usize)> = (0..d).flat_map(|a| (a..d).map(move |b| (a, b))).collect();
    if pts.len() < pairs.len() {
        return None;
    }
    let a = nalgebra::DMatrix::from_fn(pts.len(), pairs.len(), |r, c| {
        let (i, j) = pairs[c];
        let f = if i == j { 1.0 } else { 2.0 };
        f * pts[r][i] * pts[r][j]
    });
    let rhs = nalgebra::DVector::from_element(pts.len(), 1.0);
    let m_vec = a.svd(true, true).solve(&rhs, 1e-12).ok()?;
    let mut m = nalgebra::DMatrix::zeros(d, d);
    for (c, &(i, j)) in pairs.iter().enumerate() {
        m[(i, j)] = m_vec[c];
        m[(j, i)] = m_vec[c];
    }
    let eig = m.symmetric_eigen();
    let max = eig.eigenvalues.iter().fold(0.0f64, |a, &b| a.max(b));
    if !(max > 0.0) || eig.eigenvalues.iter().any(|&l| l <= 1e-9 * max) {
        return None;
    }
    let inv = &eig.eigenvectors
        * nalgebra::DMatrix::from_diagonal(&eig.eigenvalues.map(|l| 1.0 / l))
        * eig.eigenvectors.transpose();
    Some(
        (0..d)
            .map(|i| (0..d).map(|j| inv[(i, j)]).collect())
            .collect(),
    )
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
            group_optima: Vec::new(),
            peak: true,
            folds: 8,
            intrinsics: Vec::new(),
            points: points.len(),
            poses: 0,
            jackknife: Vec::new(),
            region: None,
            gate_sigma: Vec::new(),
            source: CovarianceSource::Jackknife,
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

    #[test]
    fn an_ellipsoid_through_its_rays_gives_back_its_covariance() {
        // Boundary points of δᵀ M δ = 1 along every ray of `rays(3)`: the fit recovers M⁻¹.
        let m = nalgebra::Matrix3::new(4.0, 1.0, 0.0, 1.0, 2.0, 0.5, 0.0, 0.5, 1.0);
        let pts: Vec<Vec<f64>> = rays(3)
            .iter()
            .map(|u| {
                let v = nalgebra::Vector3::new(u[0], u[1], u[2]);
                let t = 1.0 / (v.transpose() * m * v)[0].sqrt();
                (0..3).map(|i| t * u[i]).collect()
            })
            .collect();
        let inv = m.try_inverse().unwrap();
        let got = fit_ellipsoid(&pts, 3).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                assert!((got[i][j] - inv[(i, j)]).abs() < 1e-9, "{got:?}");
            }
        }
        // Points that do not enclose the origin (a slab: one direction unbounded) fit no
        // ellipsoid.
        let slab: Vec<Vec<f64>> = rays(2)
            .iter()
            .map(|u| vec![u[0] * if u[1] == 0.0 { 1.0 } else { 1e6 }, u[1] * 1e6])
            .collect();
        assert!(fit_ellipsoid(&slab, 2).is_none());
    }

    #[test]
    fn rays_cover_every_axis_and_pair() {
        let r = rays(4);
        assert_eq!(r.len(), 8 + 6 * 4);
        assert_eq!(ray_name(&r[0]), "+x");
        assert!(r.iter().any(|u| ray_name(u) == "-y+yaw"));
    }

    #[test]
    fn groups_cover_the_fixed_set_once() {
        // Covered by tests/refine_pooled.rs end to end; here: the config's defaults are sane.
        let c = UncertaintyConfig::default();
        assert!(c.folds >= 2);
    }
}
