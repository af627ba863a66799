//! Competing optima: the poses the data cannot tell apart from the answer.
//!
//! A local curvature, a patch sandwich or a jackknife each measures one peak. On a real roadside
//! view the MI surface holds several optima within a few per cent of each other, decimetres
//! apart along an x/y–yaw valley, and no local measure sees them. So the optima that compete with
//! the answer are sought on purpose ([`competing_optima`]): the smooth estimator climbs from the
//! grid search's other local maxima and from starts dispersed around the answer (both ways
//! along the three directions the answer's covariance is longest in, at [`REACH`]; each of x,
//! y, z and yaw both ways where there is no covariance), on one fixed point set that every pose
//! of a box 2.6 × [`REACH`] wide sees (each climb may move 1.6 × [`REACH`] from its start).
//! The climbs run on a thinning of that set; an end the test below cannot tell from the answer
//! climbs on over every point before it counts, since a thinned climb can stop short of the
//! answer's basin (on its iteration limit, or a thinned σ from the full peak).
//!
//! Whether the data tells an optimum apart from the answer is a test, not a height ratio: the MI
//! difference D between them and its standard error over the same patches of ground the sandwich
//! uses (a delete-a-patch jackknife of D over [`PATCHES`] compact Morton runs of every view's
//! fixed set, [`Smooth::cluster_histograms`]). An optimum is told apart when D > [`SEPARATION`]
//! standard errors. The optima that are not enter the answer's covariance as an equal-weight
//! mixture about the answer ([`Optima::spread`]): with K of them, each offset δₖ adds δₖδₖᵀ/(K+1),
//! so each lies within √(K+1) ≤ 3 of the reported σ along its own direction whenever K ≤ 8.
//! An optimum better than the answer by more than [`SEPARATION`] standard errors means the
//! answer is not the data's best ([`Optima::better`]); the local stage then starts again from it.

use super::ascent::{ascend_with, box_spec, AscentConfig};
use super::information::HESSIAN_STEP;
use crate::camera::Camera;
use crate::error::Result;
use crate::localize::mi::objective::{Evaluator, ImageCache, View};
use crate::localize::mi::smooth::{Pooling, Smooth};
use crate::localize::mi::space::{pose_at, Axis, SearchConfig};
use crate::pose::{offsets_between, CamFromMap};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// How far from the answer the dispersed starts stand, per reported axis (x, y, z in m; yaw,
/// pitch, roll in degrees); each start's ascent may move as far again. A quarter metre and three
/// quarters of a degree reach the competing optima measured on a real gantry (0.2–0.5 m, 0.5°
/// apart) from one side or the other, and stay inside the grid search's box.
pub const REACH: [f64; 6] = [0.25, 0.25, 0.12, 0.75, 0.5, 0.5];

/// An optimum is told apart from the answer when the answer's MI exceeds it by more than this
/// many standard errors (one-sided, 97.7 % for a normal difference).
pub const SEPARATION: f64 = 2.0;

/// The answer covariance's longest axes that get dispersed starts (both ways).
const LONG_AXES: usize = 3;

/// Patches of the delete-a-patch jackknife of the MI difference: as many as the sandwich's.
pub const PATCHES: usize = super::information::SANDWICH_CLUSTERS;

/// Two optima closer than this on every axis (m, m, m, deg, deg, deg), after scaling, are one:
/// the Hessian's own steps (2 cm, 0.1°), inside which the estimator's value is one basin.
const SAME: [f64; 6] = [0.02, 0.02, 0.02, 0.1, 0.1, 0.1];

/// A climb stops once the Newton step left (from the answer's curvature) is within this on every
/// free parameter (m, m, m, rad, rad, rad of θ): half of [`SAME`], so that the end it stands
/// for is located well within the merge distance. Near its peak the thinned set's gradient is
/// rough and a climb would otherwise creep for tens of iterations.
const LOCATE: [f64; 6] = [0.01, 0.01, 0.01, 8.7e-4, 8.7e-4, 8.7e-4];

/// How far each competitor's ascent may move from its start, in units of [`REACH`].
const CLIMB_BOX: f64 = 1.6;

/// Iterations of each competitor's ascent at most. The first step is Newton's (the answer's
/// curvature), so a climb that returns to the answer's basin needs a few; one that finds a
/// shallow peak of its own can need tens. A climb stopped by this limit has not found an
/// optimum; when the test cannot tell its end from the answer, its climb goes on over every
/// point ([`CONFIRM_ITER`]).
const MAX_ITER: usize = 60;

/// Iterations at most of the continuation on every point of an end the test could not tell
/// apart from the answer (or that beat it).
const CONFIRM_ITER: usize = 40;

/// Points the competitors' ascents climb on at most (a regular thinning of the fixed set): they
/// locate the optima; the test between each and the answer uses every point.
const CLIMB_POINTS: usize = 16_000;

/// One optimum that competes with the answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Optimum {
    /// Its offset from the answer: x, y, z (m), yaw, pitch, roll (deg).
    pub offset: [f64; 6],
    /// The answer's MI minus this optimum's, on the competitors' common point set (nats).
    pub delta_mi: f64,
    /// The standard error of `delta_mi` (delete-a-patch jackknife over [`PATCHES`] patches).
    pub se: f64,
    /// `delta_mi / se`: how many standard errors the data puts between the two.
    pub z: f64,
    /// Told apart from the answer (`z > SEPARATION`).
    pub separated: bool,
    /// Where its climb started: `grid` (a local maximum of the grid search) or `start` (a
    /// dispersed start).
    pub from: String,
    /// Its ascent ended on its box's edge: the valley goes on beyond it.
    pub edge: bool,
    /// Why its last ascent stopped (`gradient`, `newton step`, `no gain`, `edge`,
    /// `iterations`): an end that stopped on `iterations` is a climb that had not converged.
    #[serde(default)]
    pub stop: String,
    /// The optimum's pose.
    #[serde(skip)]
    pub pose: Option<CamFromMap>,
}

/// What [`competing_optima`] found.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Optima {
    /// The distinct optima other than the answer, the closest in MI first.
    pub found: Vec<Optimum>,
    /// Ascents climbed (grid maxima and dispersed starts).
    pub starts: usize,
    /// Objective evaluations spent (on every point of the set or on the climbs' thinning).
    pub evaluations: usize,
    /// Points evaluated, summed over those evaluations.
    #[serde(default)]
    pub point_evaluations: u64,
    /// Points of the common fixed set.
    pub points: usize,
    /// Axes of [`Optima::spread`] (those of the answer's covariance).
    pub axes: Vec<String>,
    /// The covariance the optima the data cannot tell apart add to the answer's (units of the
    /// axes: m, deg), row-major; zero when every optimum is told apart.
    pub spread: Vec<Vec<f64>>,
}

impl Optima {
    /// The optima the data cannot tell apart from the answer.
    pub fn unresolved(&self) -> impl Iterator<Item = &Optimum> {
        self.found.iter().filter(|o| !o.separated)
    }

    /// The best optimum that beats the answer by more than [`SEPARATION`] standard errors.
    pub fn better(&self) -> Option<&Optimum> {
        self.found
            .iter()
            .filter(|o| o.z < -SEPARATION)
            .min_by(|a, b| a.delta_mi.total_cmp(&b.delta_mi))
    }

    /// σ that the spread adds on `axis` (0 where it has none).
    pub fn sigma(&self, axis: &str) -> f64 {
        self.axes
            .iter()
            .position(|a| a == axis)
            .map_or(0.0, |i| self.spread[i][i].max(0.0).sqrt())
    }

    /// One line for people naming the optima the data cannot tell apart, e.g. "2 optima the MI
    /// cannot tell from the answer: (+0.23 m x, −0.05 m y, +0.00 m z, −0.41° yaw; ΔMI 0.6 se), …".
    pub fn describe(&self) -> Option<String> {
        let list: Vec<String> = self.unresolved().map(Optimum::describe).collect();
        (!list.is_empty()).then(|| {
            format!(
                "{} optim{} the MI cannot tell from the answer: {}",
                list.len(),
                if list.len() == 1 { "um" } else { "a" },
                list.join(", ")
            )
        })
    }
}

impl Optimum {
    /// "(+0.23 m x, −0.05 m y, +0.00 m z, −0.41° yaw; ΔMI 0.6 se)".
    pub fn describe(&self) -> String {
        let o = &self.offset;
        let tilt = if o[4] != 0.0 || o[5] != 0.0 {
            format!(", {:+.2}° pitch, {:+.2}° roll", o[4], o[5])
        } else {
            String::new()
        };
        format!(
            "({:+.2} m x, {:+.2} m y, {:+.2} m z, {:+.2}° yaw{tilt}; ΔMI {:.1} se{})",
            o[0],
            o[1],
            o[2],
            o[3],
            self.z,
            if self.edge { ", valley open" } else { "" }
        )
    }
}

/// The covariance an equal-weight mixture of the answer and `deltas` (offsets from it, in the
/// order of `axes`) has about the answer, beyond the answer's own: Σₖ δₖδₖᵀ / (K + 1).
pub fn mixture_spread(deltas: &[Vec<f64>], d: usize) -> Vec<Vec<f64>> {
    let w = 1.0 / (deltas.len() as f64 + 1.0);
    (0..d)
        .map(|i| {
            (0..d)
                .map(|j| w * deltas.iter().map(|v| v[i] * v[j]).sum::<f64>())
                .collect()
        })
        .collect()
}

/// D and its jackknife standard error from the per-patch histograms at the answer (`a`) and at
/// an optimum (`b`), `[patch][view]` as [`Smooth::cluster_histograms`] gives them: D on all the
/// patches, and on each set without one patch; se² = (K−1)/K · Σ (D₋ₖ − mean)².
pub fn difference_se(est: &Smooth<'_>, a: &[Vec<Vec<f64>>], b: &[Vec<Vec<f64>>]) -> (f64, f64) {
    let sum = |h: &[Vec<Vec<f64>>], skip: Option<usize>| -> Vec<Vec<f64>> {
        let views = h.first().map_or(0, |p| p.len());
        (0..views)
            .map(|v| {
                let len = h[0][v].len();
                let mut s = vec![0.0; len];
                for (k, patch) in h.iter().enumerate() {
                    if Some(k) == skip {
                        continue;
                    }
                    s.iter_mut().zip(&patch[v]).for_each(|(x, y)| *x += y);
                }
                s
            })
            .collect()
    };
    let d_all = est.value_of(&sum(a, None)) - est.value_of(&sum(b, None));
    let k = a.len().min(b.len());
    if k < 2 {
        return (d_all, f64::INFINITY);
    }
    let loo: Vec<f64> = (0..k)
        .map(|j| est.value_of(&sum(a, Some(j))) - est.value_of(&sum(b, Some(j))))
        .collect();
    let mean = loo.iter().sum::<f64>() / k as f64;
    let var = (k as f64 - 1.0) / k as f64 * loo.iter().map(|d| (d - mean).powi(2)).sum::<f64>();
    (d_all, var.max(0.0).sqrt())
}

/// The starts around `answer` (reported offsets, tilt held), at [`REACH`]: both ways along the
/// three longest axes of `cov` (over `axes`, the answer's covariance in m and deg) measured in
/// units of [`REACH`], where the valleys run; without a usable `cov`, each of x, y, z and yaw
/// both ways.
fn dispersed_offsets(axes: &[String], cov: Option<&[Vec<f64>]>) -> Vec<[f64; 6]> {
    let mut out = Vec::new();
    let index = |name: &str| ["x", "y", "z", "yaw"].iter().position(|a| *a == name);
    if let Some(cov) = cov {
        // The answer's covariance over the four held-tilt axes, in units of REACH.
        let map: Vec<(usize, usize)> = axes
            .iter()
            .enumerate()
            .filter_map(|(i, a)| index(a).map(|k| (i, k)))
            .collect();
        let d = map.len();
        let m = DMatrix::from_fn(d, d, |i, j| {
            let ((ri, ki), (rj, kj)) = (map[i], map[j]);
            cov[ri][rj] / (REACH[ki] * REACH[kj])
        });
        if d > 0 && m.iter().all(|v| v.is_finite()) {
            let eig = m.symmetric_eigen();
            let mut order: Vec<usize> = (0..d).collect();
            order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
            for &e in order.iter().take(LONG_AXES) {
                let v = eig.eigenvectors.column(e);
                for s in [1.0, -1.0] {
                    let mut o = [0.0; 6];
                    for (i, &(_, k)) in map.iter().enumerate() {
                        o[k] = s * v[i] * REACH[k];
                    }
                    out.push(o);
                }
            }
        }
    }
    if out.is_empty() {
        for a in [0usize, 1, 2, 3] {
            for s in [1.0, -1.0] {
                let mut o = [0.0; 6];
                o[a] = s * REACH[a];
                out.push(o);
            }
        }
    }
    out
}

/// One climb's end.
struct End {
    pose: CamFromMap,
    value: f64,
    from: &'static str,
    stop: &'static str,
}

impl End {
    /// The end of climb `a` from a start of kind `from`; an error (one line) when the climb met
    /// a value or gradient that is not finite.
    fn of(a: super::ascent::Ascent, from: &'static str) -> Result<Self> {
        if a.stop == "non-finite" || !a.value.is_finite() {
            return Err(crate::error::Error::stage(
                crate::stage::StageName::Mi,
                "competing optima: the smooth estimator's value or gradient is not finite",
            ));
        }
        Ok(End {
            pose: a.pose,
            value: a.value,
            from,
            stop: a.stop,
        })
    }
}

/// Offsets as reported (m, m, m, then yaw, pitch, roll in degrees: [`REACH`],
/// [`offsets_between`]) in θ's units and order (m, m, m, rad, rad, rad, as
/// [`AscentConfig::bound`] takes them).
fn theta_order(o: &[f64; 6]) -> [f64; 6] {
    let r = 1f64.to_radians();
    [o[0], o[1], o[2], o[5] * r, o[4] * r, o[3] * r]
}

/// `ends` without those in the answer's basin or in the basin of a higher end (`same`).
fn distinct(
    answer: &CamFromMap,
    mut ends: Vec<End>,
    same: &impl Fn(&CamFromMap, &CamFromMap) -> bool,
) -> Vec<End> {
    // Best first, so that of two ends in one basin the higher stands for it.
    ends.sort_by(|a, b| b.value.total_cmp(&a.value));
    let mut kept: Vec<End> = Vec::new();
    for e in ends {
        if same(answer, &e.pose) || kept.iter().any(|q| same(&q.pose, &e.pose)) {
            continue;
        }
        kept.push(e);
    }
    kept
}

/// Each end tested against the answer (`at`: the answer's per-patch histograms) on every point
/// of `est`.
fn test_ends(
    est: &Smooth<'_>,
    answer: &CamFromMap,
    at: &[Vec<Vec<f64>>],
    ends: Vec<End>,
    evaluations: &mut usize,
) -> Result<Vec<Optimum>> {
    let mut found = Vec::with_capacity(ends.len());
    for e in ends {
        let h = est.cluster_histograms(&e.pose, PATCHES);
        *evaluations += 1;
        let (d, se) = difference_se(est, at, &h);
        if !(d.is_finite() && se.is_finite()) {
            return Err(crate::error::Error::stage(
                crate::stage::StageName::Mi,
                "competing optima: the MI difference or its standard error is not finite",
            ));
        }
        let z = if se > 0.0 {
            d / se
        } else {
            d.signum() * f64::INFINITY
        };
        found.push(Optimum {
            offset: offsets_between(answer, &e.pose),
            delta_mi: d,
            se,
            z,
            separated: z > SEPARATION,
            from: e.from.to_string(),
            edge: e.stop == "edge",
            stop: e.stop.to_string(),
            pose: Some(e.pose),
        });
    }
    Ok(found)
}

/// The optima that compete with `answer` (module docs): climbs of the smooth estimator
/// (4-DoF, the answer's tilt held) from the grid search's other local maxima `grid_peaks` that
/// lie within [`REACH`] of the answer and from the dispersed starts, on the fixed point set of a
/// box 2.6 × [`REACH`] wide around the answer (`cfg`'s estimator and grid otherwise), pooled as
/// `pooling` says; each distinct end tested against the answer. `axes` and `cov` are the
/// answer's covariance (its long axes get starts of their own, and the spread is over `axes`);
/// `curvature`, the objective's Hessian in θ at the answer where the local stage has one (the
/// information's), is where the climbs' Newton steps start, else it is measured on the set.
/// The views' image preparations come from `cache` (the refinement's). Errors (one line) when
/// the box sees no points or the values are not finite.
#[allow(clippy::too_many_arguments)]
pub(crate) fn competing_optima<'a>(
    cam: &Camera,
    views: &[View<'a>],
    answer: &CamFromMap,
    grid_peaks: &[CamFromMap],
    cfg: &SearchConfig,
    pooling: Pooling,
    axes: &[String],
    cov: Option<&[Vec<f64>]>,
    curvature: Option<&[[f64; 6]; 6]>,
    cache: &ImageCache<'a>,
) -> Result<Optima> {
    // Each climb may go CLIMB_BOX × REACH from its start, so that the answer (REACH away) lies
    // well inside its box: a box whose edge passed through the answer would stop climbs there.
    let reach = theta_order(&REACH);
    let climb = AscentConfig {
        bound: reach.map(|b| CLIMB_BOX * b),
        max_iter: MAX_ITER,
        max_newton_step: LOCATE,
        ..AscentConfig::four_dof()
    };
    let wide = AscentConfig {
        bound: reach.map(|b| (1.0 + CLIMB_BOX) * b),
        ..climb
    };
    let local = SearchConfig {
        spec: box_spec(&wide),
        ..*cfg
    };
    let ev = Evaluator::pooled_cached(cam, views, answer, &local, 0, cache)?;
    let est = Smooth::of_evaluator(cam, &ev, pooling);
    let stride = ev.n_points.div_ceil(CLIMB_POINTS).max(1);
    let thin = (stride > 1).then(|| ev.thinned(stride));
    let climber = thin
        .as_ref()
        .map_or_else(|| est.clone(), |t| Smooth::of_evaluator(cam, t, pooling));
    let at_answer = |o: &[f64; 6]| pose_at(answer, &[o[0], o[1], o[2], o[3], 0.0, 0.0]);
    let mut starts: Vec<(CamFromMap, &'static str)> = grid_peaks
        .iter()
        .map(|p| offsets_between(answer, p))
        .filter(|o| (0..4).all(|k| o[k].abs() <= REACH[k]))
        .map(|o| (at_answer(&o), "grid"))
        .collect();
    starts.extend(
        dispersed_offsets(axes, cov)
            .iter()
            .map(|o| (at_answer(o), "start")),
    );
    // The answer's curvature on every point (a thinning's is too rough to be negative definite
    // where the basin is shallow): the local stage's, whose point set sees the same ground, or
    // measured on this set. Each climb's first step is Newton's, so a start in the answer's
    // basin returns to it in a few iterations instead of creeping there from a millimetre first
    // step, and the climb stops once the step left is within `LOCATE`.
    let mut evaluations = 0;
    let h = match curvature {
        Some(h) => *h,
        None => {
            evaluations += Smooth::hessian_evaluations(&climb.free);
            est.hessian(answer, &climb.free, &HESSIAN_STEP)
        }
    };
    // Evaluations on every point (above), and on the climbers' (the same set when it is not
    // thinned).
    let mut climber_evaluations = 0;
    let mut ends: Vec<End> = Vec::new();
    for (s, from) in &starts {
        let a = ascend_with(&climber, s, &climb, Some(&h));
        climber_evaluations += a.evaluations;
        ends.push(End::of(a, from)?);
    }
    let same = |a: &CamFromMap, b: &CamFromMap| {
        let o = offsets_between(a, b);
        (0..6).map(|k| (o[k] / SAME[k]).powi(2)).sum::<f64>() <= 1.0
    };
    let at = est.cluster_histograms(answer, PATCHES);
    evaluations += 1;
    let test = |ends: Vec<End>, evaluations: &mut usize| {
        test_ends(
            &est,
            answer,
            &at,
            distinct(answer, ends, &same),
            evaluations,
        )
    };
    let mut found = test(ends, &mut evaluations)?;
    // An end the test cannot tell apart from the answer, or that beats it, decides the answer's
    // σ or sends the local stage elsewhere; when it was found on a thinned set, its climb goes
    // on over every point (the thinned peak sits up to a thinned σ from the full one, and a
    // climb may have stopped on its iteration limit), from the answer's curvature on every
    // point, inside the fixed set's box.
    if thin.is_some() && found.iter().any(|o| !o.separated) {
        let (mut kept, unresolved): (Vec<Optimum>, Vec<Optimum>) =
            found.into_iter().partition(|o| o.separated);
        let mut ends = Vec::with_capacity(unresolved.len());
        for o in unresolved {
            let Some(p) = o.pose else { continue };
            let off = theta_order(&offsets_between(answer, &p));
            let room: [f64; 6] =
                std::array::from_fn(|k| (wide.bound[k] - off[k].abs()).clamp(0.0, climb.bound[k]));
            let cont = AscentConfig {
                bound: room,
                max_iter: CONFIRM_ITER,
                max_newton_step: [0.0; 6],
                ..climb
            };
            let a = ascend_with(&est, &p, &cont, Some(&h));
            evaluations += a.evaluations;
            ends.push(End::of(a, if o.from == "grid" { "grid" } else { "start" })?);
        }
        let confirmed = test(ends, &mut evaluations)?;
        // A told-apart end in the basin of a confirmed one is that one's slope.
        kept.retain(|o| {
            !confirmed
                .iter()
                .any(|c| o.pose.zip(c.pose).is_some_and(|(a, b)| same(&a, &b)))
        });
        kept.extend(confirmed);
        found = kept;
    }
    found.sort_by(|a, b| a.z.total_cmp(&b.z));
    Ok(Optima {
        spread: unresolved_spread(&found, axes),
        found,
        starts: starts.len(),
        evaluations: evaluations + climber_evaluations,
        point_evaluations: (evaluations * est.n() + climber_evaluations * climber.n()) as u64,
        points: est.n(),
        axes: axes.to_vec(),
    })
}

/// [`mixture_spread`] of the optima in `found` the data cannot tell from the answer, over `axes`.
fn unresolved_spread(found: &[Optimum], axes: &[String]) -> Vec<Vec<f64>> {
    let index = |name: &str| {
        ["x", "y", "z", "yaw", "pitch", "roll"]
            .iter()
            .position(|a| *a == name)
    };
    let deltas: Vec<Vec<f64>> = found
        .iter()
        .filter(|o| !o.separated)
        .map(|o| {
            axes.iter()
                .map(|a| index(a).map_or(0.0, |k| o.offset[k]))
                .collect()
        })
        .collect();
    mixture_spread(&deltas, axes.len())
}

/// Spread of the self-check's starts by default ([`self_check_starts`]): 0.2 m horizontally,
/// 0.1 m in height, 1° of yaw.
pub const START_SPREAD: [f64; 3] = [0.2, 0.1, 1.0];

/// The starts of a truth-free self-check around `init`: `init` itself, then `n − 1` starts
/// spread evenly on a circle of radius `spread[0]` (m) around it, their heights alternately
/// `+spread[1]` and `−spread[1]` (m) and their yaws alternately `+spread[2]` and `−spread[2]`
/// (deg) in the other phase, so that no two share both signs. Deterministic.
pub fn self_check_starts(init: &CamFromMap, n: usize, spread: [f64; 3]) -> Vec<CamFromMap> {
    let mut out = vec![*init];
    let m = n.saturating_sub(1);
    for k in 0..m {
        let phi = std::f64::consts::TAU * k as f64 / m as f64;
        let z = if k % 2 == 0 { spread[1] } else { -spread[1] };
        let yaw = if (k / 2) % 2 == 0 {
            spread[2]
        } else {
            -spread[2]
        };
        out.push(pose_at(
            init,
            &[
                spread[0] * phi.cos(),
                spread[0] * phi.sin(),
                z,
                yaw,
                0.0,
                0.0,
            ],
        ));
    }
    out
}

/// Whether two accepted answers agree within their combined 3σ: per axis (x, y, z, yaw, and
/// pitch and roll where both estimated them) |Δ| ≤ 3·√(σ_a² + σ_b²). `None` when they agree;
/// otherwise the axis that disagrees most, its difference (m or deg) and how many combined σ
/// that is.
pub fn disagreement(
    a: &CamFromMap,
    sa: &crate::pose::Sigma,
    b: &CamFromMap,
    sb: &crate::pose::Sigma,
) -> Option<(Axis, f64, f64)> {
    let d = offsets_between(a, b);
    let pairs = [
        (Axis::X, sa.x, sb.x),
        (Axis::Y, sa.y, sb.y),
        (Axis::Z, sa.z, sb.z),
        (Axis::Yaw, sa.yaw, sb.yaw),
        (
            Axis::Pitch,
            sa.pitch.unwrap_or(f64::NAN),
            sb.pitch.unwrap_or(f64::NAN),
        ),
        (
            Axis::Roll,
            sa.roll.unwrap_or(f64::NAN),
            sb.roll.unwrap_or(f64::NAN),
        ),
    ];
    pairs
        .iter()
        .enumerate()
        .filter(|(_, (_, x, y))| x.is_finite() && y.is_finite())
        .map(|(k, (name, x, y))| {
            let s = x.hypot(*y);
            let z = if s > 0.0 {
                d[k].abs() / s
            } else if d[k] == 0.0 {
                0.0
            } else {
                f64::INFINITY
            };
            (*name, d[k], z)
        })
        .filter(|(_, _, z)| *z > 3.0)
        .max_by(|a, b| a.2.total_cmp(&b.2))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each optimum the data cannot tell apart lies within 3σ of the answer along its own
    /// direction once the spread is added, for up to eight of them.
    #[test]
    fn the_spread_covers_each_unresolved_optimum() {
        for k in 1..=8usize {
            let deltas: Vec<Vec<f64>> = (0..k)
                .map(|i| vec![0.1 * (i as f64 + 1.0), -0.05 * i as f64, 0.0, 0.3])
                .collect();
            let s = mixture_spread(&deltas, 4);
            let m = DMatrix::from_fn(4, 4, |i, j| s[i][j] + if i == j { 1e-8 } else { 0.0 });
            let inv = m
                .try_inverse()
                .expect("spread plus a small diagonal inverts");
            for d in &deltas {
                let v = nalgebra::DVector::from_vec(d.clone());
                let maha = (v.transpose() * &inv * &v)[(0, 0)].sqrt();
                assert!(maha <= 3.0 + 1e-6, "k {k}: {maha}");
            }
        }
        assert!(mixture_spread(&[], 4).iter().flatten().all(|v| *v == 0.0));
    }

    /// The dispersed starts: each held-tilt axis both ways at REACH without a covariance; with
    /// one, both ways along its three longest axes (here the x–yaw valley first), in REACH's
    /// units.
    #[test]
    fn the_starts_follow_the_axes_and_the_long_directions() {
        let axes: Vec<String> = ["x", "y", "z", "yaw"].map(String::from).to_vec();
        assert_eq!(dispersed_offsets(&axes, None).len(), 8);
        // x and yaw strongly correlated, y a little longer than z.
        let c = 0.9 * REACH[0] * REACH[3];
        let cov = vec![
            vec![REACH[0].powi(2), 0.0, 0.0, c],
            vec![0.0, 0.2 * REACH[1].powi(2), 0.0, 0.0],
            vec![0.0, 0.0, 0.1 * REACH[2].powi(2), 0.0],
            vec![c, 0.0, 0.0, REACH[3].powi(2)],
        ];
        let s = dispersed_offsets(&axes, Some(&cov));
        assert_eq!(s.len(), 6);
        let first = s[0];
        let r = 1.0 / 2f64.sqrt();
        assert!((first[0].abs() - r * REACH[0]).abs() < 1e-9, "{first:?}");
        assert!((first[3].abs() - r * REACH[3]).abs() < 1e-9, "{first:?}");
        assert_eq!(first[0].signum(), first[3].signum());
        assert!(s[2][1].abs() > 0.99 * REACH[1], "{:?}", s[2]);
        assert_eq!(s[0].map(|v| -v), s[1]);
    }

    /// Optima are reported worst-separated first; `better` finds one that beats the answer by
    /// more than SEPARATION standard errors and none otherwise; the description names the
    /// unresolved ones only.
    #[test]
    fn better_and_describe_read_the_tests() {
        let o = |d: f64, se: f64| Optimum {
            offset: [0.2, -0.1, 0.0, 0.4, 0.0, 0.0],
            delta_mi: d,
            se,
            z: d / se,
            separated: d / se > SEPARATION,
            from: "start".into(),
            edge: false,
            stop: "gradient".into(),
            pose: None,
        };
        let mut q = Optima {
            found: vec![o(0.001, 0.002), o(0.02, 0.002)],
            ..Default::default()
        };
        assert!(q.better().is_none());
        let line = q.describe().expect("one unresolved optimum");
        assert!(line.starts_with("1 optimum the MI cannot tell"), "{line}");
        assert!(
            line.contains("+0.20 m x") && line.contains("ΔMI 0.5 se"),
            "{line}"
        );
        q.found.push(o(-0.01, 0.002));
        assert_eq!(q.better().map(|b| b.delta_mi), Some(-0.01));
        q.found.retain(|o| o.separated);
        assert!(q.describe().is_none());
    }

    /// The self-check's starts: the start itself first, then distinct poses at the spread's
    /// radius with alternating height and yaw; no two alike.
    #[test]
    fn the_self_check_starts_are_spread_and_distinct() {
        let init =
            CamFromMap::from_center_ypr(&nalgebra::Point3::new(10.0, 20.0, 8.0), 0.3, 0.01, -0.02);
        let s = self_check_starts(&init, 5, START_SPREAD);
        assert_eq!(s.len(), 5);
        assert_eq!(s[0], init);
        for (i, p) in s.iter().enumerate().skip(1) {
            let o = offsets_between(&init, p);
            assert!((o[0].hypot(o[1]) - 0.2).abs() < 1e-9, "{i}: {o:?}");
            assert!(
                (o[2].abs() - 0.1).abs() < 1e-9 && (o[3].abs() - 1.0).abs() < 1e-6,
                "{o:?}"
            );
            for q in &s[..i] {
                let d = offsets_between(q, p);
                assert!(d[0].hypot(d[1]) > 0.1 || d[3].abs() > 0.5, "{i}");
            }
        }
        assert_eq!(self_check_starts(&init, 1, START_SPREAD), vec![init]);
    }

    /// Two answers agree when every axis is within 3 combined σ; otherwise the worst axis is
    /// named with its difference and its multiple of the combined σ.
    #[test]
    fn disagreement_is_judged_in_combined_sigma() {
        let c = nalgebra::Point3::new(0.0, 0.0, 8.0);
        let a = CamFromMap::from_center_ypr(&c, 0.0, 0.0, 0.0);
        let b = CamFromMap::from_center_ypr(
            &(c + nalgebra::Vector3::new(0.13, 0.0, 0.0)),
            0.0,
            0.0,
            0.0,
        );
        let sig = |x: f64| crate::pose::Sigma {
            x,
            y: x,
            z: x,
            yaw: 0.1,
            pitch: None,
            roll: None,
        };
        // 13 cm apart with σ 3 cm each: 3.06 combined σ.
        let (axis, d, z) = disagreement(&a, &sig(0.03), &b, &sig(0.03)).expect("3.06σ apart");
        assert_eq!(axis, Axis::X);
        assert!((d - 0.13).abs() < 1e-12 && (z - 0.13 / 0.03f64.hypot(0.03)).abs() < 1e-9);
        assert!(disagreement(&a, &sig(0.05), &b, &sig(0.03)).is_none());
        assert!(disagreement(&a, &sig(0.0), &a, &sig(0.0)).is_none());
    }
}
