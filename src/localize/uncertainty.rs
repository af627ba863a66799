//! The uncertainty of a refined pose: the marginal covariance of [x, y, z, yaw].
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

use super::kernel::Scratch;
use super::mi::{mutual_information, JointHist};
use super::polish::{nelder_mead, PolishParams};
use super::search::{AxisRange, Evaluator, SearchConfig, SearchSpec, View, AXES};
use crate::camera::Camera;
use crate::error::Result;
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of the estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct UncertaintyConfig {
    /// Jackknife groups (contiguous patches of each view's points).
    pub folds: usize,
}

impl Default for UncertaintyConfig {
    fn default() -> Self {
        UncertaintyConfig { folds: 8 }
    }
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
    /// Each group's optimum without it, as offsets from the reported pose (m, deg).
    pub group_optima: Vec<Vec<f64>>,
    /// Whether every group's re-optimisation found a peak inside its box (else σ is ∞).
    pub peak: bool,
    /// Jackknife groups used.
    pub folds: usize,
    /// Points in the re-optimisation box's fixed set, all views.
    pub points: usize,
    /// Poses scored (every group's re-optimisation).
    pub poses: usize,
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
    pub fn is_finite(&self) -> bool {
        self.sigma.iter().all(|v| v.is_finite())
            && self.matrix.iter().flatten().all(|v| v.is_finite())
    }
}

/// Estimate the uncertainty of `pose` on `views` (the same views and estimator the search used)
/// over x, y, z and yaw (the tilt held). `polish` bounds and stops each group's re-optimisation
/// (its tilt entries are ignored).
pub fn estimate(
    cam: &Camera,
    views: &[View<'_>],
    pose: &CamFromMap,
    search: &SearchConfig,
    polish: &PolishParams,
    ucfg: &UncertaintyConfig,
) -> Result<Uncertainty> {
    let p = PolishParams {
        tilt_starts_deg: 0.0,
        bound: [
            polish.bound[0],
            polish.bound[1],
            polish.bound[2],
            polish.bound[3],
            0.0,
            0.0,
        ],
        ..*polish
    };
    // The box only selects the fixed point set: the points seen from every pose a group's
    // polish may reach.
    let r = |i: usize| AxisRange {
        half: p.bound[i],
        step: p.bound[i] / 2.0,
    };
    let cfg = SearchConfig {
        spec: SearchSpec {
            x: r(0),
            y: r(1),
            z: r(2),
            yaw: r(3),
            pitch: None,
            roll: None,
            tilt_pivot_m: None,
        },
        ..*search
    };
    let ev = Evaluator::pooled(cam, views, pose, &cfg, 0)?;
    let k = ucfg.folds.max(2);
    let folds = ev.folds(k);
    let objective = ev.objective();
    let parzen = search.mi.parzen;
    let (ev, folds) = (&ev, &folds);
    // Group by group, each polish on the other groups' points (deterministic: no randomness,
    // results collected in group order).
    let ends: Vec<([f64; 6], usize, bool)> = (0..k)
        .into_par_iter()
        .map(|left_out| {
            let mut scratch = Scratch::default();
            let mut f = |o: &[f64; 6]| {
                let hists = ev.fold_histograms(folds, o, &mut scratch);
                let mut h = JointHist::new(hists[0].rows, hists[0].cols);
                for (j, hk) in hists.iter().enumerate() {
                    if j != left_out {
                        h.counts
                            .iter_mut()
                            .zip(&hk.counts)
                            .for_each(|(a, b)| *a += b);
                    }
                }
                mutual_information(&h, parzen).get(objective)
            };
            let end = nelder_mead(&mut f, &p);
            let on_edge = (0..4).any(|i| end.offsets[i].abs() >= 0.95 * p.bound[i]);
            (end.offsets, end.evaluations, on_edge)
        })
        .collect();
    let d = 4;
    let mean: Vec<f64> = (0..d)
        .map(|i| ends.iter().map(|e| e.0[i]).sum::<f64>() / k as f64)
        .collect();
    let scale = (k as f64 - 1.0) / k as f64;
    let mut matrix = vec![vec![0.0; d]; d];
    for (a, row) in matrix.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            *v = scale
                * ends
                    .iter()
                    .map(|e| (e.0[a] - mean[a]) * (e.0[b] - mean[b]))
                    .sum::<f64>();
        }
    }
    // A group that walked to its box's edge found no peak within reach: the spread is at least
    // that far, and the answer unbounded in truth.
    let peak = !ends.iter().any(|e| e.2);
    if !peak {
        for (a, row) in matrix.iter_mut().enumerate() {
            row[a] = f64::INFINITY;
        }
    }
    let sigma = (0..d).map(|a| matrix[a][a].max(0.0).sqrt()).collect();
    Ok(Uncertainty {
        axes: AXES[..d].iter().map(|a| a.to_string()).collect(),
        units: ["m", "m", "m", "deg"]
            .iter()
            .map(|u| u.to_string())
            .collect(),
        sigma,
        matrix,
        group_optima: ends.iter().map(|e| e.0[..d].to_vec()).collect(),
        peak,
        folds: k,
        points: ev.n_points,
        poses: ends.iter().map(|e| e.1).sum(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_cover_the_fixed_set_once() {
        // Covered by tests/refine_pooled.rs end to end; here: the config's defaults are sane.
        let c = UncertaintyConfig::default();
        assert!(c.folds >= 2);
    }
}
