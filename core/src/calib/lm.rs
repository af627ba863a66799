//! Levenberg–Marquardt over the intrinsics and every view's pose (dense normal equations: at most
//! a few hundred parameters), with the Jacobian from jets.

use super::init::Pose;
use super::jet::{Jet, N};
use super::model::LensModel;
use nalgebra::{DMatrix, DVector, Rotation3, Vector3};

/// One view's observations.
pub(crate) struct Obs<'a> {
    pub object: &'a [[f64; 3]],
    pub image: &'a [[f64; 2]],
}

/// The unknowns.
#[derive(Debug, Clone)]
pub(super) struct State {
    pub intr: Vec<f64>,
    pub poses: Vec<Pose>,
}

/// Iteration cap.
const MAX_ITER: usize = 500;
/// Stop when an accepted step lowers the cost by less than this fraction.
const REL_TOL: f64 = 1e-12;

/// Residual of one point (projection − observation) as jets, the pose entering as a left
/// perturbation `exp(ω)·R` (value 0) and `t` (indices k..k+6).
#[inline]
fn point_jet(
    model: LensModel,
    intr: &[Jet],
    pose: &Pose,
    x: &[f64; 3],
    uv: &[f64; 2],
) -> Option<[Jet; 2]> {
    let k = model.n_params();
    let rx = pose.r * Vector3::new(x[0], x[1], x[2]);
    let w = [Jet::var(0.0, k), Jet::var(0.0, k + 1), Jet::var(0.0, k + 2)];
    let t = [
        Jet::var(pose.t.x, k + 3),
        Jet::var(pose.t.y, k + 4),
        Jet::var(pose.t.z, k + 5),
    ];
    // X + ω × X + t
    let xc = [
        t[0] + w[1] * rx.z - w[2] * rx.y + rx.x,
        t[1] + w[2] * rx.x - w[0] * rx.z + rx.y,
        t[2] + w[0] * rx.y - w[1] * rx.x + rx.z,
    ];
    let p = model.project(intr, xc)?;
    Some([p[0] + -uv[0], p[1] + -uv[1]])
}

/// Sum of squared residuals; `None` if any point does not project.
pub(crate) fn cost(model: LensModel, s: &State, views: &[Obs]) -> Option<f64> {
    let mut c = 0.0;
    for (v, pose) in views.iter().zip(&s.poses) {
        for (x, uv) in v.object.iter().zip(v.image) {
            let xc = pose.apply(x);
            let p = model.project(&s.intr, [xc.x, xc.y, xc.z])?;
            c += (p[0] - uv[0]).powi(2) + (p[1] - uv[1]).powi(2);
        }
    }
    c.is_finite().then_some(c)
}

/// Per-point residuals (projection − observation) of every view.
pub(crate) fn residuals(model: LensModel, s: &State, views: &[Obs]) -> Option<Vec<Vec<[f64; 2]>>> {
    views
        .iter()
        .zip(&s.poses)
        .map(|(v, pose)| {
            v.object
                .iter()
                .zip(v.image)
                .map(|(x, uv)| {
                    let xc = pose.apply(x);
                    let p = model.project(&s.intr, [xc.x, xc.y, xc.z])?;
                    Some([p[0] - uv[0], p[1] - uv[1]])
                })
                .collect()
        })
        .collect()
}

/// JᵀJ and Jᵀr over all parameters (intrinsics first, then 6 per view).
// Index loops: the upper triangle of a symmetric block, addressed by local and global index.
#[allow(clippy::needless_range_loop)]
fn normal_equations(
    model: LensModel,
    s: &State,
    views: &[Obs],
) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let k = model.n_params();
    let n = k + 6 * views.len();
    let mut a = DMatrix::<f64>::zeros(n, n);
    let mut g = DVector::<f64>::zeros(n);
    let intr: Vec<Jet> = s
        .intr
        .iter()
        .enumerate()
        .map(|(i, v)| Jet::var(*v, i))
        .collect();
    let used = k + 6;
    for (vi, (v, pose)) in views.iter().zip(&s.poses).enumerate() {
        let global = |j: usize| if j < k { j } else { k + 6 * vi + (j - k) };
        // Accumulate the view's local 16×16 block first, then scatter once.
        let mut la = [[0.0; N]; N];
        let mut lg = [0.0; N];
        for (x, uv) in v.object.iter().zip(v.image) {
            let r = point_jet(model, &intr, pose, x, uv)?;
            for comp in &r {
                for i in 0..used {
                    let di = comp.d[i];
                    if di == 0.0 {
                        continue;
                    }
                    lg[i] += di * comp.v;
                    for j in i..used {
                        la[i][j] += di * comp.d[j];
                    }
                }
            }
        }
        for i in 0..used {
            g[global(i)] += lg[i];
            for j in i..used {
                let (gi, gj) = (global(i), global(j));
                a[(gi, gj)] += la[i][j];
                if gi != gj {
                    a[(gj, gi)] += la[i][j];
                }
            }
        }
    }
    Some((a, g))
}

/// Apply a step.
fn step(model: LensModel, s: &State, d: &DVector<f64>) -> State {
    let k = model.n_params();
    let mut out = s.clone();
    for (i, p) in out.intr.iter_mut().enumerate() {
        *p += d[i];
    }
    for (vi, pose) in out.poses.iter_mut().enumerate() {
        let o = k + 6 * vi;
        let w = Vector3::new(d[o], d[o + 1], d[o + 2]);
        pose.r = Rotation3::new(w) * pose.r;
        pose.t += Vector3::new(d[o + 3], d[o + 4], d[o + 5]);
    }
    out
}

/// Outcome of a run.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LmRun {
    pub iterations: usize,
    pub cost: f64,
}

/// Minimise the sum of squared reprojection errors from `s` (updated in place).
pub(crate) fn optimise(model: LensModel, s: &mut State, views: &[Obs]) -> Option<LmRun> {
    let mut c = cost(model, s, views)?;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    while iterations < MAX_ITER {
        iterations += 1;
        let (a, g) = normal_equations(model, s, views)?;
        // Jacobi scaling: the unknowns span pixels (focal) to milliradians (poses), and in the
        // Mei model focal, ξ and k1 are strongly correlated; solving the unit-diagonal system
        // keeps the Cholesky factor accurate enough to walk that valley to its floor.
        // (Marquardt's damping λ·diag(A) is λ·I in these units.)
        let scale: Vec<f64> = (0..a.nrows())
            .map(|i| 1.0 / a[(i, i)].max(1e-12).sqrt())
            .collect();
        let mut scaled = a.clone();
        for i in 0..a.nrows() {
            for j in 0..a.ncols() {
                scaled[(i, j)] *= scale[i] * scale[j];
            }
        }
        let gs = DVector::from_iterator(g.len(), g.iter().zip(&scale).map(|(v, s)| v * s));
        let mut accepted = false;
        while lambda < 1e16 {
            let mut damped = scaled.clone();
            for i in 0..a.nrows() {
                damped[(i, i)] += lambda;
            }
            let Some(ch) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let y = -ch.solve(&gs);
            let d = DVector::from_iterator(y.len(), y.iter().zip(&scale).map(|(v, s)| v * s));
            let trial = step(model, s, &d);
            match cost(model, &trial, views) {
                Some(ct) if ct < c => {
                    let gain = (c - ct) / c.max(1e-300);
                    *s = trial;
                    c = ct;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = true;
                    if gain < REL_TOL {
                        return Some(LmRun {
                            iterations,
                            cost: c,
                        });
                    }
                    break;
                }
                _ => lambda *= 4.0,
            }
        }
        if !accepted {
            break;
        }
    }
    Some(LmRun {
        iterations,
        cost: c,
    })
}

/// Standard deviations of the intrinsics: σ²·(JᵀJ)⁻¹ with σ² = cost / (residuals − parameters).
pub(crate) fn intrinsic_std(
    model: LensModel,
    s: &State,
    views: &[Obs],
    cost: f64,
) -> Option<Vec<f64>> {
    let (a, _) = normal_equations(model, s, views)?;
    let m: usize = views.iter().map(|v| 2 * v.object.len()).sum();
    let n = a.nrows();
    if m <= n {
        return None;
    }
    let sigma2 = cost / (m - n) as f64;
    let inv = a.cholesky()?.inverse();
    Some(
        (0..model.n_params())
            .map(|i| (sigma2 * inv[(i, i)]).max(0.0).sqrt())
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jet_jacobian_matches_finite_differences() {
        let model = LensModel::Mei;
        let intr = vec![
            400.0, 402.0, 640.0, 480.0, 0.3, -0.1, 0.02, 1e-3, -2e-3, 1.1,
        ];
        let pose = Pose {
            r: Rotation3::from_euler_angles(0.3, -0.2, 0.5),
            t: Vector3::new(0.1, -0.2, 0.6),
        };
        let (x, uv) = ([0.2, 0.1, 0.0], [600.0, 500.0]);
        let jets: Vec<Jet> = intr
            .iter()
            .enumerate()
            .map(|(i, v)| Jet::var(*v, i))
            .collect();
        let r = point_jet(model, &jets, &pose, &x, &uv).unwrap();
        let f = |s: &State| {
            let c = s.poses[0].apply(&x);
            model.project(&s.intr, [c.x, c.y, c.z]).unwrap()
        };
        let s0 = State {
            intr: intr.clone(),
            poses: vec![pose],
        };
        for j in 0..16 {
            let h = if j < 10 {
                1e-6 * intr[j].abs().max(1e-3)
            } else {
                1e-7
            };
            let mut d = DVector::zeros(16);
            d[j] = h;
            let plus = f(&step(model, &s0, &d));
            d[j] = -h;
            let minus = f(&step(model, &s0, &d));
            for c in 0..2 {
                let fd = (plus[c] - minus[c]) / (2.0 * h);
                let scale = 1.0 + fd.abs();
                assert!(
                    (r[c].d[j] - fd).abs() < 1e-4 * scale,
                    "param {j} comp {c}: {} vs {fd}",
                    r[c].d[j]
                );
            }
        }
    }
}
