//! The gradient ascent of the smooth estimator ([`crate::localize::mi::smooth`]).
//!
//! [`ascend`]: L-BFGS ascent (two-loop recursion, memory [`MEMORY`], Armijo backtracking) over
//! the free ones of θ = (dx, dy, dz, rx, ry, rz) of [`crate::localize::mi::smooth::step`], in scaled units
//! ([`AscentConfig::scale`]) so one unit moves the image by a similar amount along every axis,
//! inside a box around the start. It stops when the scaled gradient's norm falls below
//! [`AscentConfig::grad_tol`], when a line search cannot gain any more (PV's gradient is
//! piecewise smooth: at the optimum it can stall a step short of the tolerance), on the box's
//! edge, or after [`AscentConfig::max_iter`] iterations; the stop's reason is reported.
//! [`ascend_with`] also takes the Hessian at the start: its inverse is the quasi-Newton's initial
//! curvature, and the ascent stops as soon as the Newton step that is left is shorter than a
//! fraction of the Cramér–Rao σ ([`AscentConfig::max_newton_decrement`]).

// Small fixed-size matrices indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use crate::localize::mi::smooth::{step, Smooth, Valued};
use crate::pose::CamFromMap;
use nalgebra::DMatrix;
use serde::Serialize;

/// L-BFGS memory (pairs of steps and gradient changes kept).
pub const MEMORY: usize = 6;

/// Settings of [`ascend`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AscentConfig {
    /// Which of θ's six parameters move.
    pub free: [bool; 6],
    /// One scaled unit per parameter (m, m, m, rad, rad, rad).
    pub scale: [f64; 6],
    /// Largest |θ| per parameter from the start (m, rad): the box whose fixed point set the
    /// estimator holds.
    pub bound: [f64; 6],
    /// Stop when the scaled gradient's norm is below this (objective units per scaled unit):
    /// 1e-6 nats per mm or per 0.01° is a few millimetres from the peak of a basin whose MI
    /// falls by 0.002 nats over 10 cm (the KITTI frames), well inside any σ.
    pub grad_tol: f64,
    /// Iterations at most.
    pub max_iter: usize,
    /// With a Hessian H at the start ([`ascend_with`]): stop when N·gᵀ(−H)⁻¹g, the squared
    /// length of the Newton step that is left measured in the Cramér–Rao metric of N points, is
    /// at most this. 0.25: the answer is within half a Cramér–Rao σ of where the step leads, and
    /// that σ is the smallest the gate judges (the sandwich's is several times larger).
    pub max_newton_decrement: f64,
    /// With a Hessian H at the start ([`ascend_with`]): also stop when the Newton step left,
    /// (−H)⁻¹g, is within this on every free parameter (m, rad; 0 turns it off). An ascent that
    /// only has to locate a peak to a given distance (the competing optima's climbs, on a
    /// thinned set whose gradient stays rough near its peak) stops there instead of creeping.
    pub max_newton_step: [f64; 6],
}

impl AscentConfig {
    /// x, y, z and yaw free (tilt held), units of 1 mm and 0.01°, box ±15 cm / ±0.5°.
    pub fn four_dof() -> Self {
        AscentConfig {
            free: [true, true, true, false, false, true],
            ..Self::six_dof()
        }
    }

    /// All six free; tilts within ±1°.
    pub fn six_dof() -> Self {
        let deg = 1f64.to_radians();
        AscentConfig {
            free: [true; 6],
            scale: [1e-3, 1e-3, 1e-3, 0.01 * deg, 0.01 * deg, 0.01 * deg],
            bound: [0.15, 0.15, 0.15, deg, deg, 0.5 * deg],
            grad_tol: 1e-6,
            max_iter: 50,
            max_newton_decrement: 0.25,
            max_newton_step: [0.0; 6],
        }
    }
}

/// The result of [`ascend`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ascent {
    /// The final pose.
    #[serde(skip)]
    pub pose: CamFromMap,
    /// θ from the start (m, m, m, rad, rad, rad).
    pub theta: [f64; 6],
    /// Objective at the start and at the end.
    pub value_start: f64,
    /// Objective at the end.
    pub value: f64,
    /// Scaled gradient norm at the end (free axes).
    pub grad_norm: f64,
    /// Iterations done.
    pub iterations: usize,
    /// Objective evaluations.
    pub evaluations: usize,
    /// How many of them also took the gradient (the start and every accepted step).
    pub gradients: usize,
    /// Why it stopped: `gradient`, `newton step` (the step left within
    /// [`AscentConfig::max_newton_decrement`] or [`AscentConfig::max_newton_step`]), `no gain`, `edge`, `iterations` or `non-finite`.
    pub stop: &'static str,
}

fn dot(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The start's curvature in [`ascend_with`]: (−H)⁻¹ over the free axes in scaled units, and N.
struct Metric {
    free: Vec<usize>,
    inv: DMatrix<f64>,
    n: f64,
}

impl Metric {
    /// `None` when −H is not positive definite over the free axes (no basin to take the
    /// curvature from: the ascent runs as [`ascend`]) or not finite.
    fn new(h: &[[f64; 6]; 6], cfg: &AscentConfig, n: usize) -> Option<Self> {
        let free: Vec<usize> = (0..6).filter(|&k| cfg.free[k]).collect();
        let d = free.len();
        let neg = DMatrix::from_fn(d, d, |i, j| {
            let (a, b) = (free[i], free[j]);
            -h[a][b] * cfg.scale[a] * cfg.scale[b]
        });
        if !neg.iter().all(|v| v.is_finite()) {
            return None;
        }
        let inv = neg.cholesky()?.inverse();
        Some(Metric {
            free,
            inv,
            n: n as f64,
        })
    }

    /// (−H)⁻¹·q.
    fn apply(&self, q: &[f64; 6]) -> [f64; 6] {
        let mut d = [0.0; 6];
        for (i, &a) in self.free.iter().enumerate() {
            for (j, &b) in self.free.iter().enumerate() {
                d[a] += self.inv[(i, j)] * q[b];
            }
        }
        d
    }

    /// Whether the Newton step left, (−H)⁻¹g in θ, is within `tol` on every free parameter
    /// (`false` when `tol` is all zero).
    fn step_within(&self, g: &[f64; 6], cfg: &AscentConfig) -> bool {
        if cfg.max_newton_step.iter().all(|t| *t <= 0.0) {
            return false;
        }
        let d = self.apply(g);
        self.free
            .iter()
            .all(|&k| (d[k] * cfg.scale[k]).abs() <= cfg.max_newton_step[k])
    }

    /// N·gᵀ(−H)⁻¹g: the Newton step left, squared, in Cramér–Rao σ.
    fn decrement(&self, g: &[f64; 6]) -> f64 {
        self.n * dot(g, &self.apply(g))
    }
}

/// Maximise `est`'s objective from `start` (see the module docs).
pub fn ascend(est: &Smooth<'_>, start: &CamFromMap, cfg: &AscentConfig) -> Ascent {
    ascend_with(est, start, cfg, None)
}

/// [`ascend`] with `hessian`, the objective's Hessian in θ at `start` ([`Smooth::hessian`]): when
/// it is negative definite over the free axes, its inverse is the quasi-Newton's initial
/// curvature (the first step is Newton's) and the ascent also stops on
/// [`AscentConfig::max_newton_decrement`].
pub fn ascend_with(
    est: &Smooth<'_>,
    start: &CamFromMap,
    cfg: &AscentConfig,
    hessian: Option<&[[f64; 6]; 6]>,
) -> Ascent {
    let metric = hessian.and_then(|h| Metric::new(h, cfg, est.n()));
    let (mut evals, mut gradients) = (0usize, 0usize);
    // f(y) = objective at θ = y ⊙ scale; its gradient in y (free axes only) only where a step is
    // taken: a line search's refused trial needs no second pass over the points.
    let mut value = |y: &[f64; 6]| -> (f64, Valued) {
        evals += 1;
        let th: [f64; 6] = std::array::from_fn(|k| y[k] * cfg.scale[k]);
        let v = est.evaluate_value(&step(start, &th));
        (v.value.value, v)
    };
    let mut gradient = |v: &Valued| -> [f64; 6] {
        gradients += 1;
        let g = est.gradient_of(v);
        std::array::from_fn(|k| {
            if cfg.free[k] {
                g[k] * cfg.scale[k]
            } else {
                0.0
            }
        })
    };
    let lim: [f64; 6] = std::array::from_fn(|k| cfg.bound[k] / cfg.scale[k]);
    let mut y = [0.0; 6];
    let (f0, v0) = value(&y);
    let mut g = gradient(&v0);
    let mut f = f0;
    let mut hist: Vec<([f64; 6], [f64; 6])> = Vec::new();
    let mut stop = "iterations";
    let mut it = 0;
    while it < cfg.max_iter {
        if !(f.is_finite() && g.iter().all(|v| v.is_finite())) {
            stop = "non-finite";
            break;
        }
        if dot(&g, &g).sqrt() < cfg.grad_tol {
            stop = "gradient";
            break;
        }
        if metric
            .as_ref()
            .is_some_and(|m| m.decrement(&g) <= cfg.max_newton_decrement || m.step_within(&g, cfg))
        {
            stop = "newton step";
            break;
        }
        it += 1;
        // Two-loop recursion for the ascent direction d ≈ −H⁻¹ g (H the negative-definite
        // Hessian): minimising −f.
        let mut q: [f64; 6] = std::array::from_fn(|k| -g[k]);
        let mut alphas = Vec::with_capacity(hist.len());
        for (s, t) in hist.iter().rev() {
            let rho = 1.0 / dot(t, s);
            let a = rho * dot(s, &q);
            q.iter_mut().zip(t).for_each(|(qi, ti)| *qi -= a * ti);
            alphas.push((a, rho));
        }
        let mut d: [f64; 6] = match &metric {
            Some(m) => m.apply(&q),
            None => {
                let gamma = hist
                    .last()
                    .map_or(1.0 / dot(&g, &g).sqrt().max(1e-300), |(s, t)| {
                        dot(s, t) / dot(t, t)
                    });
                std::array::from_fn(|k| gamma * q[k])
            }
        };
        for ((s, t), (a, rho)) in hist.iter().zip(alphas.iter().rev()) {
            let b = rho * dot(t, &d);
            d.iter_mut().zip(s).for_each(|(di, si)| *di += (a - b) * si);
        }
        // d is a descent direction of −f: ascent of f means dot(g, d) > 0 (g is ∇f).
        let mut d: [f64; 6] = std::array::from_fn(|k| -d[k]);
        if !(dot(&g, &d) > 0.0) {
            hist.clear();
            let n = dot(&g, &g).sqrt();
            d = std::array::from_fn(|k| g[k] / n);
        }
        // Armijo backtracking inside the box.
        let slope = dot(&g, &d);
        let mut t = 1.0;
        let mut accepted = None;
        let mut hit_edge = false;
        for _ in 0..30 {
            let mut yn: [f64; 6] = std::array::from_fn(|k| y[k] + t * d[k]);
            let mut clipped = false;
            for k in 0..6 {
                if yn[k].abs() > lim[k] {
                    yn[k] = yn[k].clamp(-lim[k], lim[k]);
                    clipped = true;
                }
            }
            let (fnew, vnew) = value(&yn);
            if fnew.is_finite() && fnew >= f + 1e-4 * t * slope.min(dot(&g, &sub(&yn, &y)) / t) {
                accepted = Some((yn, fnew, gradient(&vnew)));
                hit_edge = clipped;
                break;
            }
            t *= 0.5;
        }
        let Some((yn, fnew, gnew)) = accepted else {
            stop = "no gain";
            break;
        };
        let s = sub(&yn, &y);
        // Curvature pair of −f: t = −(gnew − g).
        let tv: [f64; 6] = std::array::from_fn(|k| -(gnew[k] - g[k]));
        if dot(&s, &tv) > 1e-12 * dot(&s, &s).sqrt() * dot(&tv, &tv).sqrt() {
            hist.push((s, tv));
            if hist.len() > MEMORY {
                hist.remove(0);
            }
        }
        let gained = fnew - f;
        y = yn;
        f = fnew;
        g = gnew;
        if hit_edge && dot(&g, &g).sqrt() >= cfg.grad_tol {
            stop = "edge";
            break;
        }
        if gained <= 1e-13 * f.abs().max(1e-12) {
            stop = "no gain";
            break;
        }
    }
    let th: [f64; 6] = std::array::from_fn(|k| y[k] * cfg.scale[k]);
    Ascent {
        pose: step(start, &th),
        theta: th,
        value_start: f0,
        value: f,
        grad_norm: dot(&g, &g).sqrt(),
        iterations: it,
        evaluations: evals,
        gradients,
        stop,
    }
}

fn sub(a: &[f64; 6], b: &[f64; 6]) -> [f64; 6] {
    std::array::from_fn(|k| a[k] - b[k])
}

/// The box of an ascent (its bound around the start), with a search step for the lattice of
/// the fixed point set that every pose in the box sees.
pub(crate) fn box_spec(cfg: &AscentConfig) -> crate::localize::mi::space::SearchSpec {
    let deg = |r: f64| r.to_degrees();
    let mut s = format!(
        "x={}:0.01,y={}:0.01,z={}:0.01,yaw={}:0.05",
        cfg.bound[0],
        cfg.bound[1],
        cfg.bound[2],
        deg(cfg.bound[5])
    );
    if cfg.free[3] || cfg.free[4] {
        s += &format!(
            ",pitch={}:0.1,roll={}:0.1",
            deg(cfg.bound[3]),
            deg(cfg.bound[4])
        );
    }
    // The bounds above are fixed constants that always parse.
    s.parse().unwrap_or_default()
}
