//! Gradient-based local refinement on the smooth estimator ([`crate::localize::mi::smooth`]), and the
//! covariance from the observed information.
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
//!
//! [`information`]: the Cramér–Rao covariance of Pandey et al.: MI estimates the expected
//! log-likelihood ratio per point, so the observed information of N points is −N·∇²MI and its
//! inverse bounds the estimate's covariance. ∇²MI is the central difference of the analytic
//! gradient. A Hessian that is not negative definite over the free axes (no basin) or any
//! non-finite entry is a one-line refusal, never a number.

// Small fixed-size matrices (2×3, 6×6) indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use crate::localize::mi::smooth::{step, Smooth};
use crate::pose::CamFromMap;
use nalgebra::{DMatrix, DVector, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

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
    /// Objective evaluations (each with its gradient).
    pub evaluations: usize,
    /// Why it stopped: `gradient`, `newton step` (the step left within
    /// [`AscentConfig::max_newton_decrement`]), `no gain`, `edge`, `iterations` or `non-finite`.
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
    let mut evals = 0usize;
    // f(y) = objective at θ = y ⊙ scale, and its gradient in y (free axes only).
    let mut eval = |y: &[f64; 6]| -> (f64, [f64; 6]) {
        evals += 1;
        let th: [f64; 6] = std::array::from_fn(|k| y[k] * cfg.scale[k]);
        let v = est.evaluate(&step(start, &th), true);
        let g = v.grad.unwrap_or([f64::NAN; 6]);
        let gy: [f64; 6] = std::array::from_fn(|k| {
            if cfg.free[k] {
                g[k] * cfg.scale[k]
            } else {
                0.0
            }
        });
        (v.value, gy)
    };
    let lim: [f64; 6] = std::array::from_fn(|k| cfg.bound[k] / cfg.scale[k]);
    let mut y = [0.0; 6];
    let (f0, mut g) = eval(&y);
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
            .is_some_and(|m| m.decrement(&g) <= cfg.max_newton_decrement)
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
            let (fnew, gnew) = eval(&yn);
            if fnew.is_finite() && fnew >= f + 1e-4 * t * slope.min(dot(&g, &sub(&yn, &y)) / t) {
                accepted = Some((yn, fnew, gnew));
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
        stop,
    }
}

fn sub(a: &[f64; 6], b: &[f64; 6]) -> [f64; 6] {
    std::array::from_fn(|k| a[k] - b[k])
}

/// Central-difference steps of the Hessian: 2 cm and 0.1° (m, rad). PV's value is continuous
/// but its gradient changes in steps as points cross pixels, and real images add texture bumps
/// of a few centimetres; the curvature that bounds the answer is the basin's, a step of about a
/// fifth of its width (±10 cm / ±0.5° on the KITTI frames) measures it.
pub const HESSIAN_STEP: [f64; 6] = [0.02, 0.02, 0.02, 1.745e-3, 1.745e-3, 1.745e-3];

/// The observed-information covariance ([`information`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Information {
    /// Axis names (x, y, z, yaw, then pitch, roll when free), as the jackknife's.
    pub axes: Vec<String>,
    /// Units (m or deg).
    pub units: Vec<String>,
    /// Marginal σ per axis.
    pub sigma: Vec<f64>,
    /// Covariance (m, deg), row-major.
    pub matrix: Vec<Vec<f64>>,
    /// Points N (the fixed sets, all views).
    pub points: usize,
    /// Objective evaluations spent on the Hessian.
    pub evaluations: usize,
    /// The cluster-robust ("sandwich") σ per axis, same axes and units: see [`information`].
    pub sandwich_sigma: Vec<f64>,
    /// The cluster-robust covariance (m, deg), row-major.
    pub sandwich_matrix: Vec<Vec<f64>>,
    /// Clusters (compact patches of ground) the sandwich's score scatter is taken over.
    pub clusters: usize,
    /// With [`FRAME_CLUSTERS_MIN`] or more pairs: the sandwich with each pair as one cluster
    /// (σ per axis, same axes and units), which sees what a frame's own systematic errors (its
    /// sweep's skew, its light) do to the answer; patches of one frame share those.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_sigma: Option<Vec<f64>>,
    /// The frame-clustered covariance (m, deg), row-major.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_matrix: Option<Vec<Vec<f64>>>,
}

/// Pairs needed for [`Information::frame_sigma`]: the scatter of fewer frames' scores is too
/// noisy to stand for a covariance over four axes.
pub const FRAME_CLUSTERS_MIN: usize = 5;

/// Clusters of [`information`]'s sandwich: enough patches for a stable 6 × 6 scatter (≫ 6),
/// few enough that each patch spans more ground than a texture's correlation length on the
/// frames measured (docs/refine.md "Sampling").
pub const SANDWICH_CLUSTERS: usize = 32;

/// The Cramér–Rao covariance at `pose` over the free axes of `free` (θ of [`step`]): inverse of
/// −N·∇²(objective), and beside it the cluster-robust ("sandwich", Huber–White) covariance
/// A⁻¹·B·A⁻¹ with A = −∇²(objective) and B the scatter of the score over
/// [`SANDWICH_CLUSTERS`] patches of ground ([`Smooth::cluster_gradients`], scaled by K/(K−1)).
/// The Cramér–Rao bound holds when every point is an independent sample of a correct model;
/// neighbouring points share pixels and a real frame's gray–reflectivity relation varies over
/// the ground, and the sandwich counts that: it equals the bound when points are independent
/// and grows with the correlation within a patch. Both are expressed over the axes the jackknife
/// reports (x, y, z in m, yaw about the
/// map's up axis in degrees, and pitch and roll as [`crate::localize::mi::space::pose_at`] adds them, in
/// degrees). Errors (one line) when the Hessian or the covariance is not finite or the Hessian
/// is not negative definite over the free axes.
pub fn information(
    est: &Smooth<'_>,
    pose: &CamFromMap,
    free: &[bool; 6],
) -> Result<Information, String> {
    information_with_step(est, pose, free, &HESSIAN_STEP)
}

/// [`information`] with the Hessian's central-difference steps `step` (m, rad) instead of
/// [`HESSIAN_STEP`], for measuring the choice.
pub fn information_with_step(
    est: &Smooth<'_>,
    pose: &CamFromMap,
    free: &[bool; 6],
    step: &[f64; 6],
) -> Result<Information, String> {
    let h = est.hessian(pose, free, step);
    let idx: Vec<usize> = (0..6).filter(|&k| free[k]).collect();
    let n = est.n();
    let d = idx.len();
    let info = DMatrix::from_fn(d, d, |i, j| -(n as f64) * h[idx[i]][idx[j]]);
    if !info.iter().all(|v| v.is_finite()) {
        return Err("information: the MI Hessian is not finite".into());
    }
    let (axes, minv) = reported_axes(pose, free)?;
    let Some(chol) = info.clone().cholesky() else {
        let min_eig = info.clone().symmetric_eigenvalues().min();
        // The direction is sought in steps of the Hessian (metres and radians made comparable):
        // in θ's own units a radian of yaw would outweigh a metre.
        let scale = DMatrix::from_diagonal(&DVector::from_fn(d, |i, _| step[idx[i]]));
        let eig = (&scale * &info * &scale).symmetric_eigen();
        let k = eig.eigenvalues.imin();
        let theta = &scale * eig.eigenvectors.column(k);
        let along = upward_direction(&(&minv * theta), &axes, step);
        return Err(format!(
            "information: the MI Hessian is not negative definite over the free axes (no basin along {along}; largest curvature {:.3e})",
            -min_eig
        ));
    };
    let cov_theta = chol.inverse();
    // The sandwich over θ: A⁻¹·B·A⁻¹ = (N·A)⁻¹ (N²·B) (N·A)⁻¹ with N·A the information above.
    let sandwich = |scores: &[[f64; 6]]| -> DMatrix<f64> {
        let k = scores.len() as f64;
        let mean: Vec<f64> = (0..d)
            .map(|i| scores.iter().map(|g| g[idx[i]]).sum::<f64>() / k)
            .collect();
        let scatter = DMatrix::from_fn(d, d, |i, j| {
            let nn = (n as f64).powi(2);
            nn * k / (k - 1.0).max(1.0)
                * scores
                    .iter()
                    .map(|g| (g[idx[i]] - mean[i]) * (g[idx[j]] - mean[j]))
                    .sum::<f64>()
        });
        &cov_theta * scatter * &cov_theta
    };
    let scores = est.cluster_gradients(pose, SANDWICH_CLUSTERS);
    let sandwich_theta = sandwich(&scores);
    let frame_theta =
        (est.views() >= FRAME_CLUSTERS_MIN).then(|| sandwich(&est.view_gradients(pose)));
    let cov = &minv * cov_theta * minv.transpose();
    if !cov.iter().all(|v| v.is_finite()) {
        return Err("information: the covariance is not finite".into());
    }
    let sw = &minv * sandwich_theta * minv.transpose();
    if !sw.iter().all(|v| v.is_finite()) {
        return Err("information: the sandwich covariance is not finite".into());
    }
    let frame = frame_theta.map(|f| &minv * f * minv.transpose());
    if frame
        .as_ref()
        .is_some_and(|f| !f.iter().all(|v| v.is_finite()))
    {
        return Err("information: the frame-clustered covariance is not finite".into());
    }
    let sigma_of = |m: &DMatrix<f64>| -> Vec<f64> {
        (0..axes.len()).map(|i| m[(i, i)].max(0.0).sqrt()).collect()
    };
    let rows_of = |m: &DMatrix<f64>| -> Vec<Vec<f64>> {
        (0..axes.len())
            .map(|i| (0..axes.len()).map(|j| m[(i, j)]).collect())
            .collect()
    };
    let units: Vec<String> = axes
        .iter()
        .map(|a| {
            if ["x", "y", "z"].contains(a) {
                "m"
            } else {
                "deg"
            }
            .to_string()
        })
        .collect();
    Ok(Information {
        axes: axes.iter().map(|s| s.to_string()).collect(),
        units,
        sigma: sigma_of(&cov),
        matrix: rows_of(&cov),
        points: n,
        evaluations: Smooth::hessian_evaluations(free) + 1,
        sandwich_sigma: sigma_of(&sw),
        sandwich_matrix: rows_of(&sw),
        clusters: scores.len(),
        frame_sigma: frame.as_ref().map(sigma_of),
        frame_matrix: frame.as_ref().map(rows_of),
    })
}

/// The axes `information` reports for the free parameters `free` (x, y, z, yaw, and pitch and
/// roll when the tilt is free) and the inverse of M = dθ/d(reported offsets) over them: θ's x, y,
/// z are the offsets', yaw is rz (rad → deg), pitch and roll go through the Jacobian of
/// [`crate::localize::mi::space::pose_at`]'s Euler increments.
fn reported_axes(
    pose: &CamFromMap,
    free: &[bool; 6],
) -> Result<(Vec<&'static str>, DMatrix<f64>), String> {
    let idx: Vec<usize> = (0..6).filter(|&k| free[k]).collect();
    let tilt = free[3] || free[4];
    let axes: Vec<&str> = if tilt {
        vec!["x", "y", "z", "yaw", "pitch", "roll"]
    } else {
        vec!["x", "y", "z", "yaw"]
    };
    // M: d θ / d(reported offsets), columns per reported axis, rows per θ index (all six).
    let mut m = DMatrix::<f64>::zeros(6, axes.len());
    for (c, _) in axes.iter().enumerate() {
        // Reported offsets: x, y, z (m), yaw, pitch, roll (deg) of pose_at.
        let mut off = [0.0; 6];
        let h = 1e-6;
        off[c] = h;
        let plus = theta_between(pose, &crate::localize::mi::space::pose_at(pose, &off));
        off[c] = -h;
        let minus = theta_between(pose, &crate::localize::mi::space::pose_at(pose, &off));
        for r in 0..6 {
            m[(r, c)] = (plus[r] - minus[r]) / (2.0 * h);
        }
    }
    let m_free = DMatrix::from_fn(idx.len(), axes.len(), |i, j| m[(idx[i], j)]);
    if m_free.nrows() != m_free.ncols() {
        return Err(format!(
            "information: {} free parameters but {} reported axes",
            idx.len(),
            axes.len()
        ));
    }
    let Some(minv) = m_free.try_inverse() else {
        return Err("information: the axes' Jacobian is singular".into());
    };
    Ok((axes, minv))
}

/// A direction `o` of the reported offsets (m, deg) for people: each axis in units of the
/// Hessian's step on it (`step`: m, rad), so that metres and degrees compare, as a unit vector
/// whose components of 0.2 or more are named, e.g. "x +0.88, yaw −0.29 (steps of 2 cm / 0.10°)".
fn upward_direction(o: &DVector<f64>, axes: &[&str], step: &[f64; 6]) -> String {
    let unit = |i: usize| if i < 3 { step[i] } else { step[i].to_degrees() };
    let v: Vec<f64> = (0..axes.len()).map(|i| o[i] / unit(i)).collect();
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !(norm > 0.0 && norm.is_finite()) {
        return "an undetermined direction".into();
    }
    // The sign of an eigenvector is arbitrary: the largest component is shown positive.
    let big = v
        .iter()
        .copied()
        .max_by(|a, b| a.abs().total_cmp(&b.abs()))
        .unwrap_or(1.0);
    let s = big.signum() / norm;
    let parts: Vec<String> = axes
        .iter()
        .zip(&v)
        .filter(|(_, x)| (**x * s).abs() >= 0.2)
        .map(|(a, x)| format!("{a} {:+.2}", x * s))
        .collect();
    format!(
        "{} (steps of {:.0} cm / {:.2}°)",
        parts.join(", "),
        100.0 * step[0],
        step[3].to_degrees()
    )
}

impl Information {
    /// One line for people: σ per axis in cm and degrees.
    pub fn describe(&self) -> String {
        let line = |sigma: &[f64]| -> String {
            self.axes
                .iter()
                .zip(sigma)
                .zip(&self.units)
                .map(|((a, s), u)| {
                    if u == "m" {
                        format!("{a} {:.1} cm", 100.0 * s)
                    } else {
                        format!("{a} {s:.3}°")
                    }
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        let frames = self.frame_sigma.as_ref().map_or(String::new(), |f| {
            format!("; frame σ {} (one cluster per pair)", line(f))
        });
        format!(
            "σ {} (Cramér–Rao, N = {}); sandwich σ {} ({} patches){frames}",
            line(&self.sigma),
            self.points,
            line(&self.sandwich_sigma),
            self.clusters
        )
    }
}

/// θ (of [`step`]) that takes `from` to `to`.
pub fn theta_between(from: &CamFromMap, to: &CamFromMap) -> [f64; 6] {
    let d = to.center() - from.center();
    let q: Rotation3<f64> = to.rotation.inverse() * from.rotation;
    // Angle from the skew part and the trace together (atan2): exact for tiny rotations, where
    // the acos of the trace alone rounds to 0 (the axes' Jacobian takes 1e-6 steps).
    let m = q.matrix();
    let v = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    ) * 0.5;
    let s = v.norm();
    let angle = s.atan2(0.5 * (m.trace() - 1.0));
    let r = if s > 0.0 { v * (angle / s) } else { v };
    [d.x, d.y, d.z, r.x, r.y, r.z]
}

/// What [`refine_smooth`] answers beside the grid search's [`Refinement`].
#[derive(Debug, Clone, Serialize)]
pub struct SmoothRefinement {
    /// Sampling (`pv`) and pooling of the local stage.
    pub sampling: crate::localize::mi::smooth::Sampling,
    /// Pooling of the pairs.
    pub pooling: crate::localize::mi::smooth::Pooling,
    /// The local ascents, one per round (a round that ended on its box's edge starts another,
    /// centred on its end).
    pub ascents: Vec<Ascent>,
    /// MI per histogram at the answer (one, or one per pair).
    pub mi: Vec<f64>,
    /// The Cramér–Rao covariance at the answer, or why there is none.
    pub information: std::result::Result<Information, String>,
    /// The grid search's gate verdict (its reason when it refused).
    pub grid_reason: Option<String>,
}

/// Rounds of [`refine_smooth`]'s local ascent at most.
pub const ASCENT_ROUNDS: usize = 3;

/// The local box of a round: the ascent's bound, with a search step for the fixed set's lattice.
fn local_spec(cfg: &AscentConfig) -> crate::localize::mi::space::SearchSpec {
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

/// The tiled grid search for the global basin (nearest-pixel, as without `--sampling pv`, with its
/// jackknife σ), then the smooth estimator's gradient ascent from its cell, then the observed
/// information at the answer. The gate: the grid's checks of the global basin (too few points,
/// points lost, the optimum on the box's edge, a separate second peak) stand; its local-shape
/// checks (basin width, curvature) are replaced by the information's — a Hessian that is
/// negative definite and finite — and the σ limits judge per axis the largest of the
/// information's bound, its patch and frame sandwiches, the jackknife σ and the search's floor
/// ([`judged_sigma`]).
pub fn refine_smooth(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'_>],
    init: &CamFromMap,
    cfg: &crate::localize::mi::space::SearchConfig,
    qcfg: &super::quality::QualityConfig,
    six_dof: bool,
) -> crate::error::Result<(super::rounds::Refinement, SmoothRefinement)> {
    let (r, _) = super::rounds::refine_polished(cam, views, init, cfg, qcfg, None, &|_| None)?;
    let free = if six_dof {
        SmoothFree::Six
    } else {
        SmoothFree::Four
    };
    smooth_stage(cam, views, init, r, cfg, qcfg, free)
}

/// The axes of [`smooth_stage`]: which its ascent moves and which its information covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SmoothFree {
    /// x, y, z and yaw, the tilt held (`refine`'s default).
    Four,
    /// All six (`refine --polish`).
    Six,
    /// The ascent over x, y, z and yaw at the tilt an earlier 6-DoF polish estimated (the
    /// node's), the information over all six: the answer's tilt is an estimate too, and a nadir
    /// camera's tilt trades against its position, so a σ over four axes at a held tilt would miss
    /// that valley (docs/accuracy.md "Which σ covers").
    FourAfterSix,
}

impl SmoothFree {
    /// The ascent's settings.
    fn ascent(self) -> AscentConfig {
        match self {
            SmoothFree::Six => AscentConfig::six_dof(),
            SmoothFree::Four | SmoothFree::FourAfterSix => AscentConfig::four_dof(),
        }
    }

    /// The axes of θ the information covers.
    fn information(self) -> [bool; 6] {
        match self {
            SmoothFree::Four => AscentConfig::four_dof().free,
            SmoothFree::Six | SmoothFree::FourAfterSix => [true; 6],
        }
    }
}

/// The smooth estimator's stage after a nearest-pixel refinement `r` that started at `init`:
/// its gradient ascent from `r`'s pose over the axes of `free` (in the box of [`AscentConfig`],
/// re-centred while it ends on the edge, [`ASCENT_ROUNDS`] at most), the observed information at
/// the answer, and the gate of [`refine_smooth`]. `r` keeps its grid checks and its jackknife σ
/// when it has one; its pose, offsets and verdict become the stage's. When `r` has no σ (the
/// node's path, [`super::rounds::PolishedSearch::without_jackknife`]), the reported covariance is
/// the information's ([`information_covariance`]). The pairs pool as `cfg.mi.pooling` says, as in
/// the grid search.
pub fn smooth_stage(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'_>],
    init: &CamFromMap,
    mut r: super::rounds::Refinement,
    cfg: &crate::localize::mi::space::SearchConfig,
    qcfg: &super::quality::QualityConfig,
    free: SmoothFree,
) -> crate::error::Result<(super::rounds::Refinement, SmoothRefinement)> {
    let pooling = cfg.mi.pooling;
    let grid_reason = r.quality.reason.clone();
    let acfg = free.ascent();
    // The fixed point set is the ascent's box's. With `FourAfterSix` the information also steps
    // the tilt (±0.1°, inside that box's margins): on 96 seeds of `small` and `5mp` a set built
    // for the ±1° tilt box held the same points and gave the same σ to 1.2 %.
    let local = crate::localize::mi::space::SearchConfig {
        spec: local_spec(&acfg),
        ..*cfg
    };
    let mut pose = r.pose;
    let mut ascents = Vec::new();
    let mut last = None;
    for _ in 0..ASCENT_ROUNDS {
        let ev = crate::localize::mi::objective::Evaluator::pooled(cam, views, &pose, &local, 0)?;
        let est = Smooth::of_evaluator(cam, &ev, pooling);
        // The curvature at the start (the information's Hessian, a basin-wide central
        // difference): with it the first step is Newton's, and the ascent stops once the step
        // left is a fraction of a Cramér–Rao σ instead of creeping to `grad_tol` across the
        // gradient's pixel steps, most of a plain ascent's evaluations.
        let h = est.hessian(&pose, &acfg.free, &HESSIAN_STEP);
        let a = ascend_with(&est, &pose, &acfg, Some(&h));
        let spent = a.evaluations + Smooth::hessian_evaluations(&acfg.free);
        r.stats.poses += spent as u64;
        r.stats.point_evaluations += (spent * est.n()) as u64;
        pose = a.pose;
        let edge = a.stop == "edge";
        ascents.push(a);
        if !edge {
            let info = information(&est, &pose, &free.information());
            // The Hessian's evaluations (and the value below) are work done too.
            let spent = 1 + info.as_ref().map_or(0, |i| i.evaluations);
            r.stats.poses += spent as u64;
            r.stats.point_evaluations += (spent * est.n()) as u64;
            let v = est.evaluate(&pose, false);
            last = Some((info, v.mi));
            break;
        }
    }
    let (information, mi) = last.unwrap_or_else(|| {
        (
            Err(format!(
                "the gradient ascent still ended on its box's edge after {ASCENT_ROUNDS} rounds"
            )),
            Vec::new(),
        )
    });
    if ascents.iter().any(|a| a.stop == "non-finite") {
        return Err(crate::error::Error::stage(
            crate::stage::StageName::Mi,
            "the smooth estimator's value or gradient is not finite",
        ));
    }
    r.pose = pose;
    r.offsets = crate::pose::offsets_between(init, &pose);
    // The σ the gate judges, once: the gate refuses on it and the report is widened to it.
    let judged = information
        .as_ref()
        .ok()
        .map(|info| judged_sigma(&r.quality, info, cfg));
    smooth_gate(
        &mut r,
        &information,
        judged.as_deref().unwrap_or_default(),
        qcfg,
    );
    if let (Ok(info), Some(judged)) = (&information, &judged) {
        if r.quality.covariance.is_some() {
            report_judged(&mut r.quality, info, judged);
        } else {
            // No jackknife ran: the information's covariance is the answer's, with the camera
            // file's intrinsics uncertainty added as the jackknife's is.
            let deltas = qcfg.intrinsics_sigma.as_ref().map(|s| {
                crate::localize::refine::uncertainty::intrinsics_deltas(cam, views, &pose, s)
            });
            let u = information_covariance(info, judged, deltas.as_deref());
            r.quality.sigma = Some(super::quality::Sigma::of(&u));
            r.quality.covariance = Some(u);
        }
    }
    r.quality.information = information.as_ref().ok().cloned();
    if let Some(v) = mi.first() {
        if pooling == crate::localize::mi::smooth::Pooling::Joint {
            r.quality.mi = *v;
        }
    }
    Ok((
        r,
        SmoothRefinement {
            sampling: crate::localize::mi::smooth::Sampling::Pv,
            pooling,
            ascents,
            mi,
            information,
            grid_reason,
        },
    ))
}

/// The grid's jackknife σ as its own gate judges it (the estimate itself, before the reported
/// σ is widened by the intrinsics' uncertainty), if it has one.
fn jackknife_judged(q: &super::quality::Quality) -> Option<super::quality::Sigma> {
    q.covariance
        .as_ref()
        .map(super::quality::Sigma::judged)
        .or(q.sigma)
}

/// The σ per axis of `info` that the gate judges: the largest of the Cramér–Rao bound, the
/// patch sandwich, the frame sandwich (when there is one), the grid's jackknife σ in `q`
/// ([`jackknife_judged`], 0 without one) and the jackknife's floor, half the search's finest
/// step ([`crate::localize::refine::uncertainty::sigma_floor`]: where a jackknife ran, its σ is
/// floored there already); ∞ where the jackknife found no peak (NaN).
fn judged_sigma(
    q: &super::quality::Quality,
    info: &Information,
    cfg: &crate::localize::mi::space::SearchConfig,
) -> Vec<f64> {
    let judged_jack = jackknife_judged(q);
    let jack = |axis: &str| judged_jack.as_ref().map_or(0.0, |s| s.axis(axis));
    let frame = |i: usize| info.frame_sigma.as_ref().map_or(0.0, |f| f[i]);
    info.axes
        .iter()
        .zip(info.sigma.iter().zip(&info.sandwich_sigma))
        .enumerate()
        .map(|(i, (a, (s, w)))| {
            let j = jack(a);
            if j.is_nan() {
                f64::INFINITY
            } else {
                let floor = crate::localize::refine::uncertainty::sigma_floor(cfg, a);
                s.max(*w).max(j).max(frame(i)).max(floor)
            }
        })
        .collect()
}

/// The reported covariance when the information gives it (no jackknife ran): the patch
/// sandwich's, each axis scaled up to the σ the gate judged (`judged`, [`judged_sigma`];
/// correlations kept), widened to the Student-t 3σ quantile of its K − 1 degrees of freedom
/// (the frames' count − 1 at most where a frame sandwich exists) as the jackknife's is, then the
/// intrinsics' part added (`deltas`, [`crate::localize::refine::uncertainty::intrinsics_deltas`]).
/// `gate_sigma` is `judged`.
pub fn information_covariance(
    info: &Information,
    judged: &[f64],
    deltas: Option<&[[f64; 6]]>,
) -> crate::localize::refine::uncertainty::Uncertainty {
    let d = info.axes.len();
    let base = &info.sandwich_matrix;
    let have: Vec<f64> = (0..d).map(|i| base[i][i].max(0.0).sqrt()).collect();
    let f: Vec<f64> = (0..d)
        .map(|i| {
            if have[i] > 0.0 && judged[i] > have[i] {
                judged[i] / have[i]
            } else {
                1.0
            }
        })
        .collect();
    // The fewest degrees of freedom among the estimates the judged σ may come from: the
    // patches', or the frames' when there is a frame sandwich (at least FRAME_CLUSTERS_MIN).
    let dof = match info.frame_sigma {
        Some(_) => FRAME_CLUSTERS_MIN - 1,
        None => info.clusters.saturating_sub(1),
    };
    let widen = (crate::localize::refine::uncertainty::student_t_3sigma(dof.max(1)) / 3.0).powi(2);
    let matrix: Vec<Vec<f64>> = (0..d)
        .map(|i| {
            (0..d)
                .map(|j| match (have[i] > 0.0, have[j] > 0.0) {
                    (true, true) => base[i][j] * f[i] * f[j] * widen,
                    // An axis the patches left without scatter still carries its judged σ.
                    _ if i == j => judged[i] * judged[i] * widen,
                    _ => 0.0,
                })
                .collect()
        })
        .collect();
    let mut u = crate::localize::refine::uncertainty::Uncertainty {
        axes: info.axes.clone(),
        units: info.units.clone(),
        sigma: (0..d).map(|i| matrix[i][i].max(0.0).sqrt()).collect(),
        matrix,
        group_optima: Vec::new(),
        peak: true,
        folds: 0,
        intrinsics: Vec::new(),
        points: info.points,
        poses: info.evaluations,
        jackknife: Vec::new(),
        region: None,
        gate_sigma: judged.to_vec(),
        source: crate::localize::refine::uncertainty::CovarianceSource::Information,
    };
    if let Some(deltas) = deltas {
        crate::localize::refine::uncertainty::add_intrinsics(&mut u, deltas);
    }
    u
}

/// Widen the reported covariance of `q` (the jackknife's, with the intrinsics' part) so that no
/// axis's σ is below `judged`, the σ the gate judged per axis of `info` ([`judged_sigma`]): an
/// axis whose sandwich or bound exceeds the jackknife has its row and column scaled up
/// (correlations kept). What the pose file says is then at least what the gate accepted on.
fn report_judged(q: &mut super::quality::Quality, info: &Information, judged: &[f64]) {
    let Some(u) = q.covariance.as_mut() else {
        return;
    };
    for (axis, want) in info.axes.iter().zip(judged) {
        let Some(k) = u.axes.iter().position(|a| a == axis) else {
            continue;
        };
        let have = u.sigma[k];
        if !(want.is_finite() && have.is_finite() && *want > have && have > 0.0) {
            continue;
        }
        let f = want / have;
        for (i, row) in u.matrix.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                if i == k {
                    *v *= f;
                }
                if j == k {
                    *v *= f;
                }
            }
        }
        u.sigma[k] = *want;
    }
    q.sigma = Some(super::quality::Sigma::of(u));
}

/// [`refine_smooth`]'s gate on `r`: the grid's global checks stand, its local ones are replaced
/// by `information`'s (a finite, negative-definite Hessian; the largest of the bound's, the
/// sandwiches', the jackknife's where one ran, and the search's floor within the limits).
/// `judged`: [`judged_sigma`] of `information` when it is `Ok` (unread otherwise).
fn smooth_gate(
    r: &mut super::rounds::Refinement,
    information: &std::result::Result<Information, String>,
    judged: &[f64],
    qcfg: &super::quality::QualityConfig,
) {
    use super::quality::GateCheck;
    // The gate: the grid's global checks stand, the local ones are the information's. A second
    // peak inside the sandwich's 3σ ellipsoid is the same answer's long axis (a lateral–yaw
    // valley), not a second answer.
    // The grid's second peak lies at the held tilt (its tilt offsets are 0), so over six axes
    // its distance is taken at that tilt: the conditional metric, stricter than the marginal.
    let covered = |o: &[f64; 6]| -> bool {
        let Ok(info) = information else {
            return false;
        };
        let d = info.axes.len();
        let v = nalgebra::DVector::from_fn(d, |i, _| o[i]);
        let m = info.frame_matrix.as_ref().unwrap_or(&info.sandwich_matrix);
        let cov = DMatrix::from_fn(d, d, |i, j| m[i][j]);
        cov.try_inverse()
            .map(|inv| (v.transpose() * inv * &v)[(0, 0)].sqrt() <= 3.0)
            .unwrap_or(false)
    };
    let global = match r.quality.refused_by {
        Some(GateCheck::TooFewPoints | GateCheck::PointsLost | GateCheck::OnEdge) => true,
        Some(GateCheck::Ambiguous) => !r.quality.second_peak_offset.is_some_and(|o| covered(&o)),
        _ => false,
    };
    if !global {
        r.quality.accepted = true;
        r.quality.reason = None;
        r.quality.refused_by = None;
        match information {
            Err(m) => {
                r.quality.accepted = false;
                r.quality.reason = Some(m.clone());
                r.quality.refused_by = Some(GateCheck::Uncertain);
            }
            Ok(info) => {
                let limit = |axis: &str| match axis {
                    "x" | "y" => (qcfg.max_sigma_xy_m, "xy"),
                    "z" => (qcfg.max_sigma_z_m, "z"),
                    "yaw" => (qcfg.max_sigma_yaw_deg, "yaw"),
                    _ => (qcfg.max_sigma_tilt_deg, "tilt"),
                };
                // The Cramér–Rao σ counts every point as independent; on real frames it was
                // 40–90× smaller than the answers' scatter (docs/refine.md "Sampling"). The gate
                // judges the largest of it, the sandwich σ, the grid's jackknife σ where one ran
                // (∞ where it found no peak) and the search's floor.
                let judged_jack = jackknife_judged(&r.quality);
                if let Some((i, (lim, key))) = info
                    .axes
                    .iter()
                    .enumerate()
                    .map(|(i, a)| (i, limit(a)))
                    .find(|(i, (lim, _))| !(judged[*i] <= *lim))
                {
                    let axis = &info.axes[i];
                    r.quality.accepted = false;
                    r.quality.reason = Some(format!(
                        "σ {axis} {:.4} {} over the limit {key}={lim} (information σ {:.4}, sandwich σ {:.4}{}{})",
                        judged[i],
                        info.units[i],
                        info.sigma[i],
                        info.sandwich_sigma[i],
                        info.frame_sigma
                            .as_ref()
                            .map_or(String::new(), |f| format!(", frame σ {:.4}", f[i])),
                        judged_jack
                            .as_ref()
                            .map_or(String::new(), |s| format!(", jackknife σ {:.4}", s.axis(axis)))
                    ));
                    r.quality.refused_by = Some(GateCheck::Uncertain);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    /// A "no basin" refusal names its direction in steps of the Hessian (metres and degrees
    /// compared), with the sign of its largest component, and leaves out the small ones.
    #[test]
    fn the_upward_direction_is_named_in_steps() {
        let axes = ["x", "y", "z", "yaw"];
        // 2 cm along x and 0.1° of yaw: one step each.
        let o = DVector::from_vec(vec![0.02, 0.0, 0.001, 0.1]);
        let want = "x +0.71, yaw +0.71 (steps of 2 cm / 0.10°)";
        assert_eq!(upward_direction(&o, &axes, &HESSIAN_STEP), want);
        assert_eq!(upward_direction(&(-o), &axes, &HESSIAN_STEP), want);
        let o = DVector::from_vec(vec![0.0, -0.04, 0.0, 0.1]);
        assert_eq!(
            upward_direction(&o, &axes, &HESSIAN_STEP),
            "y +0.89, yaw -0.45 (steps of 2 cm / 0.10°)"
        );
        let zero = DVector::from_vec(vec![0.0; 4]);
        assert_eq!(
            upward_direction(&zero, &axes, &HESSIAN_STEP),
            "an undetermined direction"
        );
    }

    /// An accepted grid quality with the jackknife's estimate `covariance` (and its σ), if any.
    fn accepted_quality(
        covariance: Option<super::super::uncertainty::Uncertainty>,
    ) -> super::super::quality::Quality {
        super::super::quality::Quality {
            mi: 0.3,
            nmi: 1.0,
            points: 1000,
            background: 0.1,
            second_peak_ratio: None,
            second_peak_contrast: None,
            second_peak_offset: None,
            axes: Vec::new(),
            poses: 0,
            sigma: covariance.as_ref().map(super::super::quality::Sigma::of),
            covariance,
            information: None,
            accepted: true,
            reason: None,
            refused_by: None,
        }
    }

    /// The pose file's σ is at least the σ the gate judged: an axis whose sandwich exceeds the
    /// jackknife is widened to it with its correlations kept; the others are left alone.
    #[test]
    fn the_reported_sigma_is_at_least_the_judged_one() {
        use super::super::uncertainty::Uncertainty;
        let axes: Vec<String> = ["x", "y", "z", "yaw"].map(String::from).to_vec();
        let sd = [0.01, 0.01, 0.02, 0.03];
        let matrix: Vec<Vec<f64>> = (0..4)
            .map(|i| {
                (0..4)
                    .map(|j| match (i, j) {
                        _ if i == j => sd[i] * sd[i],
                        (0, 3) | (3, 0) => 0.5 * sd[0] * sd[3],
                        _ => 0.0,
                    })
                    .collect()
            })
            .collect();
        let u = Uncertainty {
            axes: axes.clone(),
            units: ["m", "m", "m", "deg"].map(String::from).to_vec(),
            sigma: sd.to_vec(),
            matrix,
            group_optima: Vec::new(),
            peak: true,
            folds: 8,
            intrinsics: Vec::new(),
            points: 1000,
            poses: 0,
            jackknife: Vec::new(),
            region: None,
            gate_sigma: vec![0.008, 0.008, 0.015, 0.025],
            source: crate::localize::refine::uncertainty::CovarianceSource::Jackknife,
        };
        let mut q = accepted_quality(Some(u));
        let diag = |s: [f64; 4]| -> Vec<Vec<f64>> {
            (0..4)
                .map(|i| {
                    (0..4)
                        .map(|j| if i == j { s[i] * s[i] } else { 0.0 })
                        .collect()
                })
                .collect()
        };
        let info = Information {
            axes,
            units: ["m", "m", "m", "deg"].map(String::from).to_vec(),
            sigma: vec![0.001; 4],
            matrix: diag([0.001; 4]),
            points: 1000,
            evaluations: 9,
            sandwich_sigma: vec![0.03, 0.005, 0.001, 0.01],
            sandwich_matrix: diag([0.03, 0.005, 0.001, 0.01]),
            clusters: 32,
            frame_sigma: None,
            frame_matrix: None,
        };
        let judged = judged_sigma(
            &q,
            &info,
            &crate::localize::mi::space::SearchConfig::default(),
        );
        report_judged(&mut q, &info, &judged);
        let u = q.covariance.as_ref().unwrap();
        let s = q.sigma.unwrap();
        assert_eq!((s.x, s.y, s.z, s.yaw), (0.03, 0.01, 0.02, 0.03), "{s:?}");
        assert!((u.matrix[0][0] - 0.03f64.powi(2)).abs() < 1e-15);
        let rho = u.matrix[0][3] / (u.sigma[0] * u.sigma[3]);
        assert!((rho - 0.5).abs() < 1e-12, "{rho}");
        assert_eq!(u.matrix[1][1], 1e-4);
    }

    /// Without a jackknife the reported covariance is the sandwich's shape at the judged σ:
    /// every axis at least its judged σ (the search's floor included), correlations kept, widened
    /// by the sandwich's Student-t factor, and the intrinsics' part added on top.
    #[test]
    fn the_information_s_covariance_stands_where_no_jackknife_ran() {
        use super::super::quality::Sigma;
        use super::super::uncertainty::CovarianceSource;
        let axes: Vec<String> = ["x", "y", "z", "yaw", "pitch", "roll"]
            .map(String::from)
            .to_vec();
        let sd = [0.004, 0.02, 0.003, 0.01, 0.05, 0.03];
        let sandwich: Vec<Vec<f64>> = (0..6)
            .map(|i| {
                (0..6)
                    .map(|j| match (i, j) {
                        _ if i == j => sd[i] * sd[i],
                        (0, 4) | (4, 0) => -0.9 * sd[0] * sd[4],
                        _ => 0.0,
                    })
                    .collect()
            })
            .collect();
        let info = Information {
            axes,
            units: ["m", "m", "m", "deg", "deg", "deg"]
                .map(String::from)
                .to_vec(),
            sigma: vec![0.001; 6],
            matrix: sandwich.clone(),
            points: 1000,
            evaluations: 13,
            sandwich_sigma: sd.to_vec(),
            sandwich_matrix: sandwich,
            clusters: 32,
            frame_sigma: None,
            frame_matrix: None,
        };
        let q = accepted_quality(None);
        let judged = judged_sigma(
            &q,
            &info,
            &crate::localize::mi::space::SearchConfig::default(),
        );
        // The default search's floor: half of 2 cm and of 0.05°.
        assert_eq!(judged, vec![0.01, 0.02, 0.01, 0.025, 0.05, 0.03]);
        let t = (super::super::uncertainty::student_t_3sigma(31) / 3.0).powi(2);
        let u = information_covariance(&info, &judged, None);
        assert_eq!(u.source, CovarianceSource::Information);
        assert_eq!(u.gate_sigma, judged);
        for i in 0..6 {
            assert!(
                (u.matrix[i][i] - judged[i] * judged[i] * t).abs() < 1e-15,
                "{i}"
            );
        }
        let rho = u.matrix[0][4] / (u.sigma[0] * u.sigma[4]);
        assert!((rho + 0.9).abs() < 1e-12, "{rho}");
        let d = [[0.0, 0.0, 0.02, 0.0, 0.0, 0.0]; 1];
        let w = information_covariance(&info, &judged, Some(&d));
        assert!((w.matrix[2][2] - (u.matrix[2][2] + 4e-4)).abs() < 1e-15);
        assert_eq!(Sigma::of(&w).x, u.sigma[0]);
    }

    #[test]
    fn theta_between_inverts_step_down_to_tiny_rotations() {
        let p = CamFromMap::from_center_ypr(&Point3::new(1.0, -2.0, 6.0), 0.7, 0.05, -0.1);
        for th in [
            [0.1, -0.2, 0.05, 0.01, -0.02, 0.03],
            [0.0, 0.0, 0.0, 1e-8, 0.0, -2e-8],
            [1e-7, 0.0, 0.0, 0.0, 3e-9, 0.0],
        ] {
            let back = theta_between(&p, &step(&p, &th));
            for k in 0..6 {
                assert!(
                    (back[k] - th[k]).abs() < 1e-12 + 1e-9 * th[k].abs(),
                    "{th:?} -> {back:?}"
                );
            }
        }
    }

    /// The reported yaw is θ's rz in degrees (the covariance's axis mapping).
    #[test]
    fn reported_yaw_is_rz_in_degrees() {
        let p = CamFromMap::from_center_ypr(&Point3::new(0.0, 0.0, 5.0), 0.3, 0.0, 0.0);
        let mut off = [0.0; 6];
        off[3] = 1e-6;
        let th = theta_between(&p, &crate::localize::mi::space::pose_at(&p, &off));
        assert!((th[5] - 1e-6f64.to_radians()).abs() < 1e-15, "{th:?}");
        assert!(th[..5].iter().all(|v| v.abs() < 1e-15), "{th:?}");
    }
}
