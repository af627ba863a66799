//! The set of poses the data cannot tell from the answer, where the local stage's Hessian has no
//! basin (a flat or upward direction: real roadside views, where lateral shift trades against
//! yaw along a valley). There the Cramér–Rao bound and the sandwiches, which invert the
//! curvature, give nothing; the data still bounds the answer, by the same test that tells the
//! competing optima apart ([`super::optima`]): the MI difference D between the answer and a pose
//! against its standard error over the same patches of ground.
//!
//! [`indifference_region`] follows rays from the answer along the eigenvectors of the Hessian
//! (both ways; scaled by the Hessian's steps so that metres and degrees compare), each outwards
//! in doubling steps until the test tells the pose apart (D > [`SEPARATION`] se), then bisects
//! the last step. Where a ray reaches the search box still indistinguishable, the set is
//! unbounded along it and the result is refused, naming the axis it runs along most. The set's
//! extent along each eigenvector is taken as [`REGION_SIGMAS`] σ: every pose the test cannot
//! tell from the answer lies within the reported 3σ.

use super::information::{reported_axes, HESSIAN_STEP};
use super::optima::{difference_se, PATCHES, SEPARATION};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::localize::mi::objective::{Evaluator, ImageCache, View};
use crate::localize::mi::smooth::{step, Pooling, Smooth};
use crate::localize::mi::space::{Axis, AxisRange, SearchConfig};
use crate::pose::CamFromMap;
use crate::stage::StageName;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// A ray's extent is this many σ: at the test's edge (D = 2 se) the pose is as far as the
/// reported 3σ reaches. A quadratic peak's edge lies near 4 sandwich σ (D grows as t², its
/// standard error as t), so on a basin this σ is a third above the sandwich's; along a flat
/// valley, where the answer may lie anywhere in the set, it still spans the whole set.
pub const REGION_SIGMAS: f64 = 3.0;

/// Bisections of a ray's last step: its edge to a quarter of that step.
const BISECTIONS: usize = 2;

/// Half range of pitch and roll the rays may reach when the tilt is free (deg).
const TILT_HALF_DEG: f64 = 1.0;

/// One ray of the set.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ray {
    /// Its edge's offset from the answer over the region's axes (m, deg): the first pose the
    /// test tells apart, or the box's edge when `open`.
    pub edge: Vec<f64>,
    /// The test did not tell any pose on it apart, up to the search box.
    pub open: bool,
}

/// The set of poses the data cannot tell from the answer.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Region {
    /// Axes of `edge`, `sigma` and `matrix` (x, y, z, yaw, then pitch, roll when free).
    pub axes: Vec<String>,
    /// The rays, two per eigenvector of the Hessian.
    pub rays: Vec<Ray>,
    /// σ per axis of `matrix`.
    pub sigma: Vec<f64>,
    /// The covariance the set's extent stands for (m, deg), row-major.
    pub matrix: Vec<Vec<f64>>,
    /// The axis an open ray runs along most and how far it was followed (m or deg).
    pub unbounded: Option<(Axis, f64)>,
    /// Points of the box's fixed set.
    pub points: usize,
    /// Poses tested.
    pub evaluations: usize,
}

/// The set of poses the data cannot tell from `answer` (module docs), over the free parameters
/// `free` of θ, along the eigenvectors of the objective's Hessian at the answer, inside `cfg`'s search box
/// centred on the answer (the tilt within ±[`TILT_HALF_DEG`] when free), on that box's fixed
/// point set, pooled as `pooling` says. Errors (one line) when the box sees no points or a
/// difference is not finite.
#[allow(clippy::too_many_arguments)]
pub(crate) fn indifference_region<'a>(
    cam: &Camera,
    views: &[View<'a>],
    answer: &CamFromMap,
    cfg: &SearchConfig,
    pooling: Pooling,
    free: &[bool; 6],
    cache: &ImageCache<'a>,
) -> Result<Region> {
    let s = cfg.spec;
    let tilt = free[3] || free[4];
    let tilt_range = tilt.then_some(AxisRange {
        half: TILT_HALF_DEG,
        step: 0.1,
    });
    let local = SearchConfig {
        spec: crate::localize::mi::space::SearchSpec {
            pitch: tilt_range,
            roll: tilt_range,
            tilt_pivot_m: None,
            ..s
        },
        ..*cfg
    };
    let ev = Evaluator::pooled_cached(cam, views, answer, &local, 0, cache)?;
    let est = Smooth::of_evaluator(cam, &ev, pooling);
    let (axes, minv) =
        reported_axes(answer, free).map_err(|e| Error::stage(StageName::Mi, e.to_string()))?;
    let idx: Vec<usize> = (0..6).filter(|&k| free[k]).collect();
    let d = idx.len();
    // θ's box: m, m, m, rad (rx, ry: the tilts), rad (rz: yaw).
    let r = |deg: f64| deg.to_radians();
    let bound = [
        s.x.half,
        s.y.half,
        s.z.half,
        r(TILT_HALF_DEG),
        r(TILT_HALF_DEG),
        r(s.yaw.half),
    ];
    let hessian = est.hessian(answer, free, &HESSIAN_STEP);
    let scale = DVector::from_fn(d, |i, _| HESSIAN_STEP[idx[i]]);
    let info = DMatrix::from_fn(d, d, |i, j| -hessian[idx[i]][idx[j]] * scale[i] * scale[j]);
    if !info.iter().all(|v| v.is_finite()) {
        return Err(Error::stage(
            StageName::Mi,
            "indifference region: the MI Hessian is not finite",
        ));
    }
    let eig = info.symmetric_eigen();
    let at = est.cluster_histograms(answer, PATCHES);
    let mut evaluations = 1 + Smooth::hessian_evaluations(free);
    let mut told_apart = |t_dir: &DVector<f64>, t: f64| -> Result<bool> {
        let mut theta = [0.0; 6];
        for (i, &k) in idx.iter().enumerate() {
            theta[k] = t * t_dir[i];
        }
        evaluations += 1;
        let (diff, se) = difference_se(
            &est,
            &at,
            &est.cluster_histograms(&step(answer, &theta), PATCHES),
        );
        if !(diff.is_finite() && se.is_finite()) {
            return Err(Error::stage(
                StageName::Mi,
                "indifference region: the MI difference or its standard error is not finite",
            ));
        }
        Ok(diff > SEPARATION * se)
    };
    let mut rays = Vec::with_capacity(2 * d);
    let mut cov_s = DMatrix::<f64>::zeros(d, d);
    let mut unbounded: Option<(Axis, f64)> = None;
    for k in 0..d {
        let v = eig.eigenvectors.column(k).into_owned();
        let mut widest = 0.0f64;
        for sign in [1.0, -1.0] {
            // θ per unit of t (t in Hessian steps).
            let dir = v.component_mul(&scale) * sign;
            let t_max = (0..d)
                .filter(|&i| dir[i].abs() > 0.0)
                .map(|i| bound[idx[i]] / dir[i].abs())
                .fold(f64::INFINITY, f64::min);
            let (edge, open) = ray_edge(t_max, |t| told_apart(&dir, t))?;
            let offset = &minv * &dir * edge;
            if open && unbounded.is_none() {
                unbounded = Some(named_axis(&axes, &offset));
            }
            widest = widest.max(edge);
            rays.push(Ray {
                edge: offset.iter().copied().collect(),
                open,
            });
        }
        cov_s += &v * v.transpose() * (widest / REGION_SIGMAS).powi(2);
    }
    let sd = DMatrix::from_diagonal(&scale);
    let cov = &minv * (&sd * cov_s * &sd) * minv.transpose();
    Ok(Region {
        axes: axes.iter().map(|a| a.to_string()).collect(),
        rays,
        sigma: (0..d).map(|i| cov[(i, i)].max(0.0).sqrt()).collect(),
        matrix: (0..d)
            .map(|i| (0..d).map(|j| cov[(i, j)]).collect())
            .collect(),
        unbounded,
        points: est.n(),
        evaluations,
    })
}

/// A ray's edge in units of t: tested outwards at 0.5, 1, 2, 4, … and at `t_max` (the box's
/// edge), then the last step bisected [`BISECTIONS`] times; the edge is the nearest t told
/// apart. `(t_max, true)` when nothing up to the box's edge is.
fn ray_edge(t_max: f64, mut told_apart: impl FnMut(f64) -> Result<bool>) -> Result<(f64, bool)> {
    let mut inside = 0.0;
    let mut t = 0.5f64.min(t_max);
    loop {
        if told_apart(t)? {
            break;
        }
        if t >= t_max {
            return Ok((t_max, true));
        }
        inside = t;
        t = (2.0 * t).min(t_max);
    }
    let mut out = t;
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (inside + out);
        if told_apart(mid)? {
            out = mid;
        } else {
            inside = mid;
        }
    }
    Ok((out, false))
}

/// The axis an offset (m, deg over `axes`) runs along most, measured in the Hessian's steps
/// (2 cm, 0.1°), and its extent on that axis.
fn named_axis(axes: &[&str], offset: &DVector<f64>) -> (Axis, f64) {
    let unit = |a: &str| match Axis::from_name(a).map(Axis::unit) {
        Some("m") => HESSIAN_STEP[0],
        _ => HESSIAN_STEP[3].to_degrees(),
    };
    let (i, _) = axes
        .iter()
        .enumerate()
        .map(|(i, a)| (i, offset[i].abs() / unit(a)))
        .fold((0, -1.0), |b, c| if c.1 > b.1 { c } else { b });
    (Axis::from_name(axes[i]).unwrap_or(Axis::X), offset[i].abs())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The edge is the nearest t told apart, to a quarter of the last doubling; a ray never
    /// told apart is open at the box's edge.
    #[test]
    fn a_ray_s_edge_is_bracketed_and_bisected() {
        // Told apart beyond 5.3: doublings 0.5 … 4 inside, 8 out; bisected to 6, then 5.
        let (edge, open) = ray_edge(100.0, |t| Ok(t > 5.3)).unwrap();
        assert!(!open);
        assert!((5.3..=6.0).contains(&edge), "{edge}");
        // Told apart already at the first step: bisected inside (0, 0.5].
        let (edge, open) = ray_edge(100.0, |t| Ok(t > 0.2)).unwrap();
        assert!(!open && (0.2..=0.25).contains(&edge), "{edge}");
        // Never told apart: open at the box's edge, which is tested.
        let mut tested = Vec::new();
        let (edge, open) = ray_edge(10.0, |t| {
            tested.push(t);
            Ok(false)
        })
        .unwrap();
        assert!(open && edge == 10.0);
        assert_eq!(tested.last(), Some(&10.0));
        // An error ends the ray.
        assert!(ray_edge(10.0, |_| Err(Error::stage(StageName::Mi, "x"))).is_err());
    }

    /// An open ray is named by the axis it runs along most in the Hessian's steps: 10 cm of x
    /// (5 steps) against 0.3° of yaw (3 steps) is x.
    #[test]
    fn an_open_ray_is_named_by_its_longest_axis_in_steps() {
        let axes = ["x", "y", "z", "yaw"];
        let o = DVector::from_vec(vec![0.1, 0.0, 0.0, 0.3]);
        assert_eq!(named_axis(&axes, &o), (Axis::X, 0.1));
        let o = DVector::from_vec(vec![0.02, 0.0, 0.0, -0.6]);
        assert_eq!(named_axis(&axes, &o), (Axis::Yaw, 0.6));
    }
}
