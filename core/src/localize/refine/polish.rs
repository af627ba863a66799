//! Local continuous polish of a grid optimum over the six pose parameters, or over x, y, z and
//! yaw with the tilt held ([`PolishParams::four_dof`]) (pure).
//!
//! The grid search runs over [x, y, z, yaw] with PnP's roll and pitch held. PnP's tilt is
//! typically 0.3–1° off (satellite misregistration, intrinsics error), and from a wrong tilt the
//! 4-DoF optimum trades it for centimetres of x, y, z and tenths of a degree of yaw. A grid over
//! six axes is too costly here (the tiled search's ±2-step windows are 5^6 poses per candidate),
//! and alternating 2-D tilt / 4-D grids zig-zags along the coupled directions. Nelder–Mead
//! adapts its simplex to those couplings, needs no gradient (the single-image MI surface is not
//! smooth at the pixel scale), and converges in a few hundred evaluations of one pose each.
//! Deterministic: no randomness, ties broken by order.

use crate::camera::Camera;
use crate::error::Result;
use crate::localize::mi::kernel::Scratch;
use crate::localize::mi::objective::{Evaluator, ImageCache, View};
use crate::localize::mi::space::{pose_at_pivot, AxisRange, SearchConfig, SearchSpec};
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::Serialize;

/// Settings of [`nelder_mead`] and of [`polish_pose`] (box, steps, stopping rule, tilt starts).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolishParams {
    /// Initial simplex edge per parameter (m, m, m, deg, deg, deg).
    pub initial_step: [f64; 6],
    /// The search stays inside ±this per parameter (clamped).
    pub bound: [f64; 6],
    /// Stop when every vertex is within this of the best, per parameter …
    pub tolerance: [f64; 6],
    /// … or after this many objective evaluations (per start).
    pub max_evaluations: usize,
    /// Extra starts on the tilt axes, degrees: besides the grid optimum itself, the polish also
    /// starts at pitch ±this and roll ±this (each within `bound`) and keeps the best end. 0: one
    /// start. A 4-DoF optimum found at a tilt 2–3° off is often a local maximum of the 6-DoF
    /// objective (the search traded the tilt for position), which a single local start cannot leave.
    /// ([`crate::localize::refine::refine_polished`] uses them in the first polish after each search only.)
    pub tilt_starts_deg: f64,
}

impl Default for PolishParams {
    /// Tilt ±3° (starts at 0 and ±1.5° on each tilt axis), x/y/z ±15 cm, yaw ±0.5° around the
    /// grid optimum; tolerance 2 mm / 0.005°.
    fn default() -> Self {
        PolishParams {
            initial_step: [0.03, 0.03, 0.03, 0.1, 0.3, 0.3],
            bound: [0.15, 0.15, 0.15, 0.5, 3.0, 3.0],
            tolerance: [0.002, 0.002, 0.002, 0.005, 0.005, 0.005],
            max_evaluations: 400,
            tilt_starts_deg: 1.5,
        }
    }
}

impl PolishParams {
    /// Whether parameter `i` moves: a positive initial step and bound. A held one stays at its
    /// start, spans no simplex direction, widens no point-set box and is never "on the edge".
    pub(crate) fn is_free(&self, i: usize) -> bool {
        self.initial_step[i] > 0.0 && self.bound[i] > 0.0
    }

    /// Whether the polish moves the tilt (pitch or roll): its answer's tilt is then an estimate,
    /// which the uncertainty must cover too.
    pub fn frees_tilt(&self) -> bool {
        self.is_free(4) || self.is_free(5)
    }

    /// The default box and stopping rule over x, y, z and yaw only, roll and pitch held (no tilt
    /// starts): the continuous finish of a 4-DoF refinement ([`crate::localize::refine::PolishedSearch::four_dof`]).
    pub fn four_dof() -> Self {
        let mut p = PolishParams::default();
        for i in 4..6 {
            p.initial_step[i] = 0.0;
            p.bound[i] = 0.0;
        }
        p.tilt_starts_deg = 0.0;
        p
    }
}

/// Result of [`nelder_mead`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Polished {
    /// Best parameters found (offsets from the start).
    pub offsets: [f64; 6],
    /// Objective there.
    pub value: f64,
    /// Objective at the start.
    pub start_value: f64,
    /// Evaluations used.
    pub evaluations: usize,
}

/// Maximise `f` from the origin with Nelder–Mead (standard coefficients: reflection 1,
/// expansion 2, contraction ½, shrink ½), every vertex clamped to ±`bound`. A held parameter
/// ([`PolishParams::is_free`] false) stays at its start; the simplex spans the others.
#[cfg(test)]
pub(crate) fn nelder_mead(f: &mut dyn FnMut(&[f64; 6]) -> f64, p: &PolishParams) -> Polished {
    nelder_mead_from(f, p, [0.0; 6])
}

/// [`nelder_mead`] from `x0` (clamped to ±`bound`) instead of the origin; `start_value` is the
/// objective at `x0`.
pub(crate) fn nelder_mead_from(
    f: &mut dyn FnMut(&[f64; 6]) -> f64,
    p: &PolishParams,
    x0: [f64; 6],
) -> Polished {
    let clamp = |x: [f64; 6]| clamp_to_box(p, x);
    let mut evals = 0usize;
    let mut eval = |x: &[f64; 6], evals: &mut usize| {
        *evals += 1;
        let v = f(x);
        if v.is_finite() {
            v
        } else {
            f64::NEG_INFINITY
        }
    };
    let first = initial_simplex(p, x0);
    let x0 = first[0];
    let start_value = eval(&x0, &mut evals);
    let n = first.len() - 1;
    let mut simplex: Vec<([f64; 6], f64)> = vec![(x0, start_value)];
    for x in &first[1..] {
        let v = eval(x, &mut evals);
        simplex.push((*x, v));
    }
    let order = |s: &mut Vec<([f64; 6], f64)>| {
        // Best first; a stable sort keeps the earlier vertex on ties (deterministic).
        s.sort_by(|a, b| b.1.total_cmp(&a.1));
    };
    let lerp = |a: &[f64; 6], b: &[f64; 6], t: f64| {
        let mut x = [0.0; 6];
        for i in 0..6 {
            x[i] = a[i] + t * (b[i] - a[i]);
        }
        x
    };
    while n > 0 && evals < p.max_evaluations {
        order(&mut simplex);
        let best = simplex[0].0;
        let converged = simplex
            .iter()
            .all(|(x, _)| (0..6).all(|i| (x[i] - best[i]).abs() <= p.tolerance[i]));
        if converged {
            break;
        }
        let mut centroid = [0.0; 6];
        for (x, _) in &simplex[..n] {
            for i in 0..6 {
                centroid[i] += x[i] / n as f64;
            }
        }
        let (worst, worst_v) = simplex[n];
        let xr = clamp(lerp(&centroid, &worst, -1.0));
        let vr = eval(&xr, &mut evals);
        if vr > simplex[0].1 {
            let xe = clamp(lerp(&centroid, &worst, -2.0));
            let ve = eval(&xe, &mut evals);
            simplex[n] = if ve > vr { (xe, ve) } else { (xr, vr) };
        } else if vr > simplex[n - 1].1 {
            simplex[n] = (xr, vr);
        } else {
            // Contract towards the better of the worst and its reflection.
            let (xc, vc) = if vr > worst_v {
                let xc = lerp(&centroid, &xr, 0.5);
                (xc, eval(&xc, &mut evals))
            } else {
                let xc = lerp(&centroid, &worst, 0.5);
                (xc, eval(&xc, &mut evals))
            };
            if vc > worst_v.max(vr) {
                simplex[n] = (xc, vc);
            } else {
                for vertex in simplex.iter_mut().skip(1) {
                    let x = lerp(&best, &vertex.0, 0.5);
                    *vertex = (x, eval(&x, &mut evals));
                }
            }
        }
    }
    order(&mut simplex);
    Polished {
        offsets: simplex[0].0,
        value: simplex[0].1,
        start_value,
        evaluations: evals,
    }
}

/// `x` clamped to ±[`PolishParams::bound`] per parameter.
fn clamp_to_box(p: &PolishParams, mut x: [f64; 6]) -> [f64; 6] {
    for (v, b) in x.iter_mut().zip(&p.bound) {
        *v = v.clamp(-b, *b);
    }
    x
}

/// The first simplex of [`nelder_mead_from`] from `x0`, in evaluation order: `x0` clamped to
/// ±`bound`, then one vertex per free parameter, `initial_step` from it towards the box's
/// interior (a zero initial step or bound holds a parameter, e.g. pitch and roll in a 4-DoF
/// polish, and the simplex spans the others only). Callers that run many polishes from one
/// start can score these poses once.
pub(crate) fn initial_simplex(p: &PolishParams, x0: [f64; 6]) -> Vec<[f64; 6]> {
    let clamp = |x: [f64; 6]| clamp_to_box(p, x);
    let x0 = clamp(x0);
    let mut out = vec![x0];
    for i in (0..6).filter(|&i| p.is_free(i)) {
        let mut x = x0;
        x[i] += if x0[i] + p.initial_step[i] > p.bound[i] {
            -p.initial_step[i]
        } else {
            p.initial_step[i]
        };
        out.push(clamp(x));
    }
    out
}

/// [`nelder_mead`] from the origin and, when [`PolishParams::tilt_starts_deg`] > 0, from pitch
/// and roll ±that; the best end wins (ties: the earlier start, in the order origin, +pitch,
/// −pitch, +roll, −roll). The starts run in parallel, each on its own objective from `make`
/// (e.g. with its own scratch buffers); the result does not depend on the thread count.
/// `start_value` is the objective at the origin, `evaluations` the total.
pub(crate) fn nelder_mead_multi<F, M>(make: M, p: &PolishParams) -> Polished
where
    F: FnMut(&[f64; 6]) -> f64,
    M: Fn() -> F + Sync,
{
    let ends = multi_start_ends(make, p);
    let best = ends[best_end(&ends)];
    Polished {
        start_value: ends[0].start_value,
        evaluations: ends.iter().map(|r| r.evaluations).sum(),
        ..best
    }
}

/// Every start's end of [`nelder_mead_multi`], in start order (the origin first).
fn multi_start_ends<F, M>(make: M, p: &PolishParams) -> Vec<Polished>
where
    F: FnMut(&[f64; 6]) -> f64,
    M: Fn() -> F + Sync,
{
    start_offsets(p)
        .par_iter()
        .map(|x0| nelder_mead_from(&mut make(), p, *x0))
        .collect()
}

/// The starts of a multi-start polish: the origin, then pitch ±`tilt_starts_deg` and roll ± that
/// (each only where that tilt is free).
fn start_offsets(p: &PolishParams) -> Vec<[f64; 6]> {
    let mut starts = vec![[0.0; 6]];
    let a = p.tilt_starts_deg;
    if a > 0.0 {
        for (axis, sign) in [(4, 1.0), (4, -1.0), (5, 1.0), (5, -1.0)] {
            if !p.is_free(axis) {
                continue; // a held tilt has no start of its own
            }
            let mut x0 = [0.0; 6];
            x0[axis] = sign * a;
            starts.push(x0);
        }
    }
    starts
}

/// The index of the best end (ties: the earlier).
fn best_end(ends: &[Polished]) -> usize {
    let mut best = 0;
    for (i, r) in ends.iter().enumerate().skip(1) {
        if r.value > ends[best].value {
            best = i;
        }
    }
    best
}

/// What a polish did: the optimiser's record, the point set's size and the pivot used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PolishRecord {
    /// Offsets of the polished pose from the start (m, m, m, deg, deg, deg).
    pub offsets: [f64; 6],
    /// Objective at the start.
    #[serde(rename = "start")]
    pub start_value: f64,
    /// Objective at the polished pose.
    pub value: f64,
    /// Objective evaluations used.
    pub evaluations: usize,
    /// Size of the fixed point set.
    pub points: usize,
    /// Pivot depth of pitch/roll, metres (`None`: about the camera centre).
    pub pivot_m: Option<f64>,
    /// The starts' screening on a thinned point set, when the polish had several starts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub screening: Option<Screening>,
}

/// The screening of a multi-start polish: every start's run on a thinned point set.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Screening {
    /// Objective evaluations of all the starts' runs.
    pub evaluations: usize,
    /// Points of the thinned set.
    pub points: usize,
}

impl PolishRecord {
    /// Point-evaluations of the polish: its runs on the whole set and the screening's.
    pub fn point_evaluations(&self) -> u64 {
        self.evaluations as u64 * self.points as u64
            + self
                .screening
                .map_or(0, |s| s.evaluations as u64 * s.points as u64)
    }

    /// Objective evaluations, the screening's included.
    pub fn all_evaluations(&self) -> usize {
        self.evaluations + self.screening.map_or(0, |s| s.evaluations)
    }

    /// Whether the polish ended on (within 5 % of) its box's edge on some parameter: the optimum
    /// may lie outside, and a caller may polish again from there.
    /// A held parameter ([`PolishParams::is_free`] false) is never on an edge.
    pub(crate) fn on_edge(&self, p: &PolishParams) -> bool {
        (0..6).any(|i| p.is_free(i) && self.offsets[i].abs() >= 0.95 * p.bound[i])
    }
}

/// The search configuration whose fixed point set a local optimisation within `p`'s ±bound box
/// uses: the points visible from every lattice pose of that box (two cells per side; the grid
/// only selects the point set). A held axis (bound 0) is not an axis of the box.
pub(crate) fn box_config(
    search: &SearchConfig,
    p: &PolishParams,
    pivot: Option<f64>,
) -> SearchConfig {
    let r = |i: usize| AxisRange {
        half: p.bound[i],
        step: p.bound[i] / 2.0,
    };
    SearchConfig {
        spec: SearchSpec {
            x: r(0),
            y: r(1),
            z: r(2),
            yaw: r(3),
            pitch: p.is_free(4).then(|| r(4)),
            roll: p.is_free(5).then(|| r(5)),
            tilt_pivot_m: pivot,
        },
        ..*search
    }
}

/// Polish `pose` over the free parameters of `p` (all six by default) on `views` (one or more
/// image/point-set pairs sharing the pose, pooled into one histogram per pose):
/// pitch and roll pivot `pivot` metres below the camera on its axis (see
/// [`SearchSpec::tilt_pivot_m`]); the objective and estimator are `search`'s; the fixed point set
/// is the one visible from every lattice pose of the ±`bound` box. Returns the polished pose and
/// what the polish did.
pub fn polish_pose(
    camera: &Camera,
    views: &[View<'_>],
    pose: &CamFromMap,
    pivot: Option<f64>,
    search: &SearchConfig,
    p: &PolishParams,
) -> Result<(CamFromMap, PolishRecord)> {
    polish_pose_cached(
        camera,
        views,
        pose,
        pivot,
        search,
        p,
        &ImageCache::default(),
    )
}

/// [`polish_pose`] taking the views' image preparations from `cache`.
pub(crate) fn polish_pose_cached<'a>(
    camera: &Camera,
    views: &[View<'a>],
    pose: &CamFromMap,
    pivot: Option<f64>,
    search: &SearchConfig,
    p: &PolishParams,
    cache: &ImageCache<'a>,
) -> Result<(CamFromMap, PolishRecord)> {
    let ev =
        Evaluator::pooled_cached(camera, views, pose, &box_config(search, p, pivot), 0, cache)?;
    let objective = ev.objective();
    // The quarter set must keep as many points as the search's coarsest levels do, or its
    // noise could pick the wrong start: a smaller set polishes every start on all points.
    let stride = SCREEN_STRIDE.min(ev.n_points / search.coarse_min_points.max(1));
    let (res, screening) = if start_offsets(p).len() > 1 && stride >= 2 {
        screened_polish(&ev, p, stride)
    } else {
        let ev = &ev;
        let res = nelder_mead_multi(
            || {
                let mut scratch = Scratch::default();
                move |x: &[f64; 6]| ev.value_at(0, x, &mut scratch).get(objective)
            },
            p,
        );
        (res, None)
    };
    let record = PolishRecord {
        offsets: res.offsets,
        start_value: res.start_value,
        value: res.value,
        evaluations: res.evaluations,
        points: ev.n_points,
        pivot_m: pivot,
        screening,
    };
    Ok((pose_at_pivot(pose, &res.offsets, pivot), record))
}

/// Every `SCREEN_STRIDE`-th point of the polish's set scores its starts (see [`screened_polish`]),
/// or a smaller stride where that would leave fewer points than the search's coarse levels use
/// (`SearchConfig::coarse_min_points`).
const SCREEN_STRIDE: usize = 4;

/// Point groups a single Nelder–Mead run's evaluations are split into, so that it uses every
/// thread ([`Evaluator::value_at_split`]).
const SPLIT_GROUPS: usize = 8;

/// The multi-start polish with its extra starts screened on a thinned point set (every
/// `stride`-th, spread over the whole ground): Nelder–Mead on all the points from the origin,
/// and from an extra start's screened end only when one ends best on the thinned set
/// ([`nelder_mead_screened`]). Returns the polish and what the screening did.
fn screened_polish(
    ev: &Evaluator,
    p: &PolishParams,
    stride: usize,
) -> (Polished, Option<Screening>) {
    let objective = ev.objective();
    let thin = ev.thinned(stride);
    let thin_ref = &thin;
    let folds = ev.folds(SPLIT_GROUPS);
    let folds = &folds;
    let (res, screen_evaluations) = nelder_mead_screened(
        || {
            let mut scratch = Scratch::default();
            move |x: &[f64; 6]| thin_ref.value_at(0, x, &mut scratch).get(objective)
        },
        || move |x: &[f64; 6]| ev.value_at_split(folds, x).get(objective),
        p,
    );
    (
        res,
        Some(Screening {
            evaluations: screen_evaluations,
            points: thin.n_points,
        }),
    )
}

/// [`nelder_mead_multi`] with the extra starts screened on a cheap approximation of `full`
/// (`make_full` makes `full`, `make_screen` the approximation). Nelder–Mead on `full` always
/// runs from the origin, exactly as the plain multi-start's first start; every start also runs
/// on the approximation, and when one of the *extra* starts ends best there, `full` runs again
/// from that end and the better of the two full runs wins (ties: the origin's). The extra starts
/// exist to leave a local maximum a tilt trade left behind, a difference far above the
/// approximation's noise; where they find nothing better, the answer is the origin's run itself.
/// `start_value` is `full` at the origin and `evaluations` counts `full`'s; the second value is
/// the screening's evaluations.
pub(crate) fn nelder_mead_screened<F, G, M, N>(
    make_screen: M,
    make_full: N,
    p: &PolishParams,
) -> (Polished, usize)
where
    F: FnMut(&[f64; 6]) -> f64,
    G: FnMut(&[f64; 6]) -> f64,
    M: Fn() -> F + Sync,
    N: Fn() -> G + Sync,
{
    let single = PolishParams {
        tilt_starts_deg: 0.0,
        ..*p
    };
    let run = |x0: [f64; 6]| nelder_mead_from(&mut make_full(), &single, x0);
    // The origin's full run does not depend on the screening, so it runs beside it: the
    // screening's starts are sequential simplexes of unequal length, and the full run's
    // evaluations fill the pool while the last of them ends. Each run is deterministic, so the
    // result is the same as one after the other.
    let (screen, own) = rayon::join(|| multi_start_ends(&make_screen, p), || run([0.0; 6]));
    let screen_evaluations = screen.iter().map(|r| r.evaluations).sum();
    let winner = best_end(&screen);
    let other = (winner != 0).then(|| run(screen[winner].offsets));
    let evaluations = own.evaluations + other.map_or(0, |r| r.evaluations);
    let end = match other {
        Some(o) if o.value > own.value => o,
        _ => own,
    };
    (
        Polished {
            start_value: own.start_value,
            evaluations,
            ..end
        },
        screen_evaluations,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_polish_first_scores_its_initial_simplex() {
        // A caller that scores these poses once for many polishes gets the same polishes only
        // if each scores exactly them, in this order, first.
        let mut p = PolishParams::four_dof();
        p.initial_step[5] = 0.2;
        p.bound[5] = 1.0;
        for x0 in [
            [0.0; 6],
            [0.14, -0.15, 0.0, 0.45, 0.0, 0.9],
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ] {
            let first = initial_simplex(&p, x0);
            // x, y, z, yaw and roll move; pitch is held.
            assert_eq!(first.len(), 6);
            let mut seen = Vec::new();
            let mut f = |x: &[f64; 6]| {
                seen.push(*x);
                -x.iter().map(|v| (v - 0.01).powi(2)).sum::<f64>()
            };
            let r = nelder_mead_from(&mut f, &p, x0);
            assert_eq!(&seen[..first.len()], &first[..], "start {x0:?}");
            assert!(r.evaluations > first.len());
            // Every vertex inside the box, one step from the start along its own axis.
            for (v, i) in first[1..].iter().zip([0, 1, 2, 3, 5]) {
                assert!(
                    (v[i] - first[0][i]).abs() > 0.0 && v[i].abs() <= p.bound[i],
                    "{v:?}"
                );
                assert_eq!(v[4], first[0][4]);
            }
        }
    }

    #[test]
    fn finds_the_peak_of_a_coupled_quadratic() {
        // A ridge coupling x with pitch (the tilt/translation trade) and z with yaw.
        let peak = [0.05, -0.03, 0.02, 0.1, 0.6, -0.4];
        let mut f = |x: &[f64; 6]| {
            let d: Vec<f64> = (0..6).map(|i| x[i] - peak[i]).collect();
            let ridge = (d[0] * 10.0 - d[4]).powi(2) + (d[2] * 5.0 + d[3]).powi(2);
            -(d.iter().map(|v| v * v).sum::<f64>() * 0.1 + ridge)
        };
        let r = nelder_mead(&mut f, &PolishParams::default());
        for i in 0..6 {
            assert!(
                (r.offsets[i] - peak[i]).abs() < 0.02,
                "axis {i}: {:?} vs {peak:?}",
                r.offsets
            );
        }
        assert!(r.value > r.start_value && r.evaluations <= 400);
    }

    #[test]
    fn tilt_starts_leave_a_local_maximum_at_the_origin() {
        // A narrow local peak at the origin (the 4-DoF compromise) and the real, higher peak
        // 2.2° away in pitch: one start stays at the origin, the extra tilt starts find the peak.
        let f = |x: &[f64; 6]| {
            let d2 = |c: [f64; 6]| (0..6).map(|i| (x[i] - c[i]).powi(2)).sum::<f64>();
            let real = [0.02, 0.0, 0.0, 0.0, 2.2, 0.0];
            0.5 * (-d2([0.0; 6]) / 0.05).exp() + (-d2(real) / 0.5).exp()
        };
        let single = PolishParams {
            tilt_starts_deg: 0.0,
            ..PolishParams::default()
        };
        let r1 = nelder_mead_multi(|| f, &single);
        assert!(r1.offsets[4].abs() < 0.3, "single start: {:?}", r1.offsets);
        let r = nelder_mead_multi(|| f, &PolishParams::default());
        assert!(
            (r.offsets[4] - 2.2).abs() < 0.05,
            "multi start: {:?}",
            r.offsets
        );
        assert!(r.value > r1.value && r.start_value == r1.start_value);
        assert!(r.evaluations > r1.evaluations);
    }

    #[test]
    fn screened_starts_find_the_real_peak_and_finish_on_the_full_objective() {
        // The two-peak objective above, screened through a slightly shifted copy of itself (a
        // thinned point set's noisier objective): an extra start wins the screening, so the
        // full objective runs from the origin (which stays on the local peak) and from that
        // start's screened end, which converges on the full objective's own real peak.
        use std::sync::atomic::{AtomicUsize, Ordering};
        let peak = |x: &[f64; 6], shift: f64| {
            let d2 = |c: [f64; 6]| (0..6).map(|i| (x[i] - c[i]).powi(2)).sum::<f64>();
            let real = [0.02 + shift, 0.0, 0.0, 0.0, 2.2 + shift, 0.0];
            0.5 * (-d2([0.0; 6]) / 0.05).exp() + (-d2(real) / 0.5).exp()
        };
        let full_evals = AtomicUsize::new(0);
        let (r, screened) = nelder_mead_screened(
            || |x: &[f64; 6]| peak(x, 0.03),
            || {
                |x: &[f64; 6]| {
                    full_evals.fetch_add(1, Ordering::Relaxed);
                    peak(x, 0.0)
                }
            },
            &PolishParams::default(),
        );
        assert!((r.offsets[4] - 2.2).abs() < 0.02, "{:?}", r.offsets);
        assert!((r.offsets[0] - 0.02).abs() < 0.01, "{:?}", r.offsets);
        assert_eq!(r.start_value, peak(&[0.0; 6], 0.0));
        assert_eq!(r.evaluations, full_evals.load(Ordering::Relaxed));
        // Two full runs instead of five; all five ran on the screen.
        let five = nelder_mead_multi(|| |x: &[f64; 6]| peak(x, 0.0), &PolishParams::default());
        assert!(
            r.evaluations < five.evaluations,
            "{} vs {}",
            r.evaluations,
            five.evaluations
        );
        assert!(screened > r.evaluations, "{screened} vs {}", r.evaluations);
    }

    #[test]
    fn a_misleading_screen_leaves_the_origin_run() {
        // The screen's best peak (1.5° in pitch, only reached from the +pitch start) is only a
        // low bump of the full objective, whose highest peak is at the origin: the full run
        // from the screened end stays on the bump, and the origin's run wins.
        let d2 = |x: &[f64; 6], pitch: f64| {
            (x[4] - pitch).powi(2) + x.iter().take(4).map(|v| v * v).sum::<f64>()
        };
        let full = |x: &[f64; 6]| (-d2(x, 0.0) / 0.05).exp() + 0.5 * (-d2(x, 1.5) / 0.05).exp();
        let screen = |x: &[f64; 6]| (-d2(x, 1.5) / 0.05).exp();
        let (r, _) = nelder_mead_screened(|| screen, || full, &PolishParams::default());
        assert!(r.offsets.iter().all(|v| v.abs() < 0.01), "{:?}", r.offsets);
        assert!(r.value > 0.99 && r.value >= r.start_value, "{}", r.value);
        // Exactly the plain run from the origin.
        let own = nelder_mead(&mut { full }, &PolishParams::default());
        assert_eq!((r.offsets, r.value), (own.offsets, own.value));
    }

    #[test]
    fn when_the_origin_wins_the_screening_the_answer_is_its_full_run() {
        // The screen has one narrow peak at the origin that the tilt starts (±1.5°) cannot see:
        // the origin's screened run ends best, the full objective runs from the origin only,
        // and the answer is bit for bit that run's.
        let full = |x: &[f64; 6]| -(x.iter().map(|v| (v - 0.01).powi(2)).sum::<f64>());
        let screen = |x: &[f64; 6]| (-(x.iter().map(|v| v * v).sum::<f64>()) / 0.05).exp();
        let (r, _) = nelder_mead_screened(|| screen, || full, &PolishParams::default());
        let own = nelder_mead(&mut { full }, &PolishParams::default());
        assert_eq!(r, own);
    }

    #[test]
    fn multi_start_result_does_not_depend_on_the_thread_count() {
        // A rugged objective (ties and many local maxima), so the winner depends on every start.
        let f = |x: &[f64; 6]| {
            let r: f64 = x.iter().map(|v| v * v).sum();
            (x[4] * 7.0).cos() + (x[5] * 5.0).sin() - 0.1 * r + (x[0] * 40.0).sin() * 0.01
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| nelder_mead_multi(|| f, &PolishParams::default()))
        };
        let (one, two) = (run(1), run(2));
        assert_eq!(one, two);
        assert_eq!(one.offsets.map(f64::to_bits), two.offsets.map(f64::to_bits));
    }

    #[test]
    fn four_dof_holds_the_tilt_and_finds_the_rest() {
        // The peak is tilted too, but a 4-DoF polish must not move pitch or roll: it finds the
        // best x, y, z, yaw at the held tilt, with a 5-vertex simplex (fewer evaluations).
        let peak = [0.05, -0.03, 0.02, 0.1, 0.6, -0.4];
        let f = |x: &[f64; 6]| -(0..6).map(|i| (x[i] - peak[i]).powi(2)).sum::<f64>();
        let p = PolishParams::four_dof();
        let r = nelder_mead_multi(|| f, &p);
        assert_eq!((r.offsets[4], r.offsets[5]), (0.0, 0.0));
        for (got, want) in r.offsets.iter().zip(&peak).take(4) {
            assert!((got - want).abs() < 0.005, "{:?}", r.offsets);
        }
        // The held tilt sits at its (zero) bound but is not an edge to polish on from.
        let record = PolishRecord {
            offsets: r.offsets,
            start_value: r.start_value,
            value: r.value,
            evaluations: r.evaluations,
            points: 1,
            pivot_m: None,
            screening: None,
        };
        assert!(!record.on_edge(&p));
        let six = nelder_mead(&mut { f }, &PolishParams::default());
        assert!(
            r.evaluations < six.evaluations,
            "{} vs {}",
            r.evaluations,
            six.evaluations
        );
    }

    #[test]
    fn stays_inside_the_bounds() {
        let mut f = |x: &[f64; 6]| x.iter().sum::<f64>();
        let p = PolishParams::default();
        let r = nelder_mead(&mut f, &p);
        for i in 0..6 {
            assert!(r.offsets[i].abs() <= p.bound[i] + 1e-12);
        }
    }

    #[test]
    fn non_finite_objective_is_never_chosen() {
        let mut f = |x: &[f64; 6]| if x[0] > 0.0 { f64::NAN } else { -x[1].abs() };
        let r = nelder_mead(&mut f, &PolishParams::default());
        assert!(r.value.is_finite() && r.offsets[0] <= 0.0);
    }
}
