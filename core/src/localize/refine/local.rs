//! The smooth estimator's local stage: from the grid search's basin, the gradient ascent
//! ([`super::ascent`]) of the partial-volume MI, the observed information at the answer
//! ([`super::information`]), and the σ the gate judges ([`super::quality::smooth_gate`]).

// Small fixed-size matrices indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use super::ascent::{ascend_with, Ascent, AscentConfig};
use super::information::{information, information_covariance, Information, HESSIAN_STEP};
use crate::localize::error::InformationError;
use crate::localize::mi::smooth::Smooth;
use crate::pose::CamFromMap;
use serde::Serialize;

/// What [`refine_smooth`] answers beside the grid search's [`Refinement`].
#[derive(Debug, Clone, Serialize)]
pub struct SmoothRefinement {
    /// Pooling of the pairs.
    pub pooling: crate::localize::mi::smooth::Pooling,
    /// The local ascents, one per round (a round that ended on its box's edge starts another,
    /// centred on its end).
    pub ascents: Vec<Ascent>,
    /// MI per histogram at the answer (one, or one per pair).
    pub mi: Vec<f64>,
    /// The Cramér–Rao covariance at the answer, or why there is none.
    pub information: std::result::Result<Information, InformationError>,
    /// The grid search's gate verdict (its reason when it refused).
    pub grid_reason: Option<String>,
}

/// Rounds of [`refine_smooth`]'s local ascent at most.
pub const ASCENT_ROUNDS: usize = 3;

/// The tiled grid search for the global basin (nearest-pixel, to the finest step, no
/// uncertainty estimate of its own), then the smooth estimator's gradient ascent from its cell,
/// the observed information at the answer and the competing optima ([`smooth_stage`]). The
/// gate: the grid's checks of the global basin (too few points, points lost, the optimum on the
/// box's edge) stand; its local-shape checks (basin width, curvature, second peak) are replaced
/// by the information's — a Hessian that is negative definite and finite — and the σ limits,
/// which judge per axis the largest of the information's bound, its patch, region and frame
/// sandwiches and (x, y, z) the search's floor, with the spread of the optima the data cannot
/// tell apart added ([`judged_sigma`]).
pub fn refine_smooth(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'_>],
    init: &CamFromMap,
    cfg: &crate::localize::mi::space::SearchConfig,
    qcfg: &super::quality::QualityConfig,
    six_dof: bool,
) -> crate::error::Result<(super::rounds::Refinement, SmoothRefinement)> {
    let cache = crate::localize::mi::objective::ImageCache::default();
    let r = super::rounds::search_views(cam, views, init, cfg, qcfg, (1, 0), &cache)?;
    let free = if six_dof {
        SmoothFree::Six
    } else {
        SmoothFree::Four
    };
    smooth_stage(cam, views, init, r, cfg, qcfg, free, &cache)
}

/// Refine `init` against one frame `gray` (row-major, camera size; the validity mask is the
/// camera's image circle) and its ground `points`, over x, y, z and yaw: [`refine_smooth`] on one
/// view. Errors (one line) on empty/invisible/non-finite points, image size ≠ camera size, a bad
/// search spec or a non-finite value or gradient. A result the gate refuses is returned with
/// `quality.accepted = false`; the caller decides whether to write it.
pub fn refine(
    cam: &crate::camera::Camera,
    gray: &[u8],
    points: &[crate::localize::mi::points::GroundPoint],
    init: &CamFromMap,
    cfg: &crate::localize::mi::space::SearchConfig,
    qcfg: &super::quality::QualityConfig,
) -> crate::error::Result<super::rounds::Refinement> {
    use crate::camera::CameraModel;
    let mask = cam.valid_mask();
    let views = [crate::localize::mi::objective::View {
        gray,
        mask: &mask,
        points,
    }];
    refine_smooth(cam, &views, init, cfg, qcfg, false).map(|(r, _)| r)
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

    /// The names of the axes the information covers, as it reports them.
    fn axis_names(self) -> Vec<String> {
        let n = if self.information()[3] { 6 } else { 4 };
        ["x", "y", "z", "yaw", "pitch", "roll"][..n]
            .iter()
            .map(|a| a.to_string())
            .collect()
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
/// the answer, and the gate of [`refine_smooth`]. `r` keeps its grid checks; its pose, offsets
/// and verdict become the stage's, and its covariance the information's
/// ([`information_covariance`]) with the competing optima's spread. The pairs pool as
/// `cfg.mi.pooling` says, as in the grid search. The views' image preparations come from
/// `cache`, the one the search before it filled.
#[allow(clippy::too_many_arguments)]
pub(crate) fn smooth_stage<'a>(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'a>],
    init: &CamFromMap,
    mut r: super::rounds::Refinement,
    cfg: &crate::localize::mi::space::SearchConfig,
    qcfg: &super::quality::QualityConfig,
    free: SmoothFree,
    cache: &crate::localize::mi::objective::ImageCache<'a>,
) -> crate::error::Result<(super::rounds::Refinement, SmoothRefinement)> {
    let pooling = cfg.mi.pooling;
    let grid_reason = r.quality.reason.clone();
    let acfg = free.ascent();
    // The fixed point set is the ascent's box's. With `FourAfterSix` the information also steps
    // the tilt (±0.1°, inside that box's margins): on 96 seeds of `small` and `5mp` a set built
    // for the ±1° tilt box held the same points and gave the same σ to 1.2 %.
    let local = crate::localize::mi::space::SearchConfig {
        spec: super::ascent::box_spec(&acfg),
        ..*cfg
    };
    let mut pose = r.pose;
    let mut ascents = Vec::new();
    let mut restarted = false;
    let (information, mi, optima) = loop {
        let (information, mi) = climb(
            cam,
            views,
            &local,
            &acfg,
            free,
            &mut pose,
            &mut ascents,
            &mut r,
            cache,
        )?;
        // The optima that compete with the answer, sought on purpose: the data may not tell
        // them apart from it, and no local measure at the answer sees them.
        let (axes, cov, curvature) = match &information {
            Ok(info) => (
                info.axes.clone(),
                Some(info.frame_matrix.as_ref().unwrap_or(&info.sandwich_matrix)),
                Some(&info.hessian),
            ),
            Err(_) => (free.axis_names(), None, None),
        };
        let o = super::optima::competing_optima(
            cam,
            views,
            &pose,
            &r.peaks,
            cfg,
            pooling,
            &axes,
            cov.map(|c| c.as_slice()),
            curvature,
            cache,
        )?;
        r.stats.poses += o.evaluations as u64;
        r.stats.point_evaluations += o.point_evaluations;
        let optima = Some(o);
        // An optimum the data prefers to the answer is where the answer should be: the stage
        // climbs again from it, once.
        let better = optima
            .as_ref()
            .and_then(|o| o.better())
            .and_then(|b| b.pose);
        match better {
            Some(b) if !restarted => {
                restarted = true;
                pose = b;
            }
            _ => break (information, mi, optima),
        }
    };
    r.pose = pose;
    r.offsets = crate::pose::offsets_between(init, &pose);
    // The σ the gate judges, once: the gate refuses on it and the report is widened to it. The
    // local part (bound, sandwiches, floor) shapes the reported covariance; the
    // optima the data cannot tell apart add their spread to both.
    let local_judged = information
        .as_ref()
        .ok()
        .map(|info| judged_sigma(info, cfg));
    let judged = match (&information, &local_judged) {
        (Ok(info), Some(j)) => Some(
            info.axes
                .iter()
                .zip(j)
                .map(|(a, s)| {
                    let o = optima.as_ref().map_or(0.0, |o| o.sigma(a));
                    s.hypot(o)
                })
                .collect::<Vec<f64>>(),
        ),
        _ => None,
    };
    super::quality::smooth_gate(
        &mut r.quality,
        &information,
        judged.as_deref().unwrap_or_default(),
        qcfg,
        optima.as_ref(),
    );
    if let (Ok(info), Some(local_judged), Some(judged)) = (&information, &local_judged, &judged) {
        // The information's covariance, with the camera file's intrinsics uncertainty added.
        let deltas = qcfg
            .intrinsics_sigma
            .as_ref()
            .map(|s| crate::localize::refine::uncertainty::intrinsics_deltas(cam, views, &pose, s));
        let mut u = information_covariance(info, local_judged, deltas.as_deref());
        if let Some(o) = &optima {
            add_spread(&mut u, o);
        }
        // The gate judged the local σ with the optima's spread: that is the covariance's too.
        u.gate_sigma = judged.clone();
        r.quality.sigma = Some(super::quality::Sigma::of(&u));
        // Each part was finite on its own; their sum is checked too, as the pose file and the
        // gate would carry it.
        if r.quality.accepted && !u.is_finite() {
            r.quality.accepted = false;
            r.quality.reason = Some("uncertainty: the reported covariance is not finite".into());
            r.quality.refused_by = Some(super::quality::GateCheck::Uncertain);
        }
        r.quality.covariance = Some(u);
    }
    r.quality.optima = optima;
    r.quality.information = information.as_ref().ok().cloned();
    if let Some(v) = mi.first() {
        if pooling == crate::localize::mi::smooth::Pooling::Joint {
            r.quality.mi = *v;
        }
    }
    Ok((
        r,
        SmoothRefinement {
            pooling,
            ascents,
            mi,
            information,
            grid_reason,
        },
    ))
}

/// The local stage's rounds from `pose` (moved to the answer): an ascent in the box of `acfg`
/// ([`ASCENT_ROUNDS`] at most, re-centred while it ends on the edge), then the information at
/// the answer over the axes of `free`, and the MI per histogram there. The work goes into `r`'s
/// counters, the ascents into `ascents`.
#[allow(clippy::too_many_arguments)]
fn climb<'a>(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'a>],
    local: &crate::localize::mi::space::SearchConfig,
    acfg: &AscentConfig,
    free: SmoothFree,
    pose: &mut CamFromMap,
    ascents: &mut Vec<Ascent>,
    r: &mut super::rounds::Refinement,
    cache: &crate::localize::mi::objective::ImageCache<'a>,
) -> crate::error::Result<(std::result::Result<Information, InformationError>, Vec<f64>)> {
    let pooling = local.mi.pooling;
    let mut last = None;
    for _ in 0..ASCENT_ROUNDS {
        let ev = crate::localize::mi::objective::Evaluator::pooled_cached(
            cam, views, pose, local, 0, cache,
        )?;
        let est = Smooth::of_evaluator(cam, &ev, pooling);
        // The curvature at the start (the information's Hessian, a basin-wide central
        // difference): with it the first step is Newton's, and the ascent stops once the step
        // left is a fraction of a Cramér–Rao σ instead of creeping to `grad_tol` across the
        // gradient's pixel steps, most of a plain ascent's evaluations.
        let h = est.hessian(pose, &acfg.free, &HESSIAN_STEP);
        let a = ascend_with(&est, pose, acfg, Some(&h));
        let spent = a.evaluations + Smooth::hessian_evaluations(&acfg.free);
        r.stats.poses += spent as u64;
        r.stats.point_evaluations += (spent * est.n()) as u64;
        *pose = a.pose;
        let edge = a.stop == "edge";
        ascents.push(a);
        if !edge {
            let info = information(&est, pose, &free.information());
            // The Hessian's evaluations (and the value below) are work done too.
            let spent = 1 + info.as_ref().map_or(0, |i| i.evaluations);
            r.stats.poses += spent as u64;
            r.stats.point_evaluations += (spent * est.n()) as u64;
            let v = est.evaluate(pose, false);
            last = Some((info, v.mi));
            break;
        }
    }
    if ascents.iter().any(|a| a.stop == "non-finite") {
        return Err(crate::error::Error::stage(
            crate::stage::StageName::Mi,
            "the smooth estimator's value or gradient is not finite",
        ));
    }
    Ok(last.unwrap_or_else(|| {
        (
            Err(InformationError::OnEdge {
                rounds: ASCENT_ROUNDS,
            }),
            Vec::new(),
        )
    }))
}

/// Add the spread of the optima the data cannot tell apart ([`super::optima::Optima::spread`])
/// to the reported covariance `u`, on the axes the two share.
fn add_spread(
    u: &mut crate::localize::refine::uncertainty::Uncertainty,
    o: &super::optima::Optima,
) {
    let at = |a: &String| u.axes.iter().position(|b| b == a);
    for (i, ai) in o.axes.iter().enumerate() {
        for (j, aj) in o.axes.iter().enumerate() {
            if let (Some(p), Some(q)) = (at(ai), at(aj)) {
                u.matrix[p][q] += o.spread[i][j];
            }
        }
    }
    for (k, s) in u.sigma.iter_mut().enumerate() {
        *s = u.matrix[k][k].max(0.0).sqrt();
    }
}

/// The σ per axis of `info` that the gate judges: the largest of the Cramér–Rao bound, the
/// patch sandwich, the region sandwich, the frame sandwich (when there is one) and the floor
/// ([`crate::localize::refine::uncertainty::sigma_floor`]). Each sandwich sees error shared over
/// a wider scale than the one before: a point's with its neighbours in the same pixels, a
/// patch's with its neighbours over a region of ground (a long shadow, a reflectance change), a
/// frame's over its whole view (its light, its sweep). The floor stands for what every frame
/// shares; pooled frames do not shrink it.
fn judged_sigma(info: &Information, cfg: &crate::localize::mi::space::SearchConfig) -> Vec<f64> {
    let frame = |i: usize| info.frame_sigma.as_ref().map_or(0.0, |f| f[i]);
    let region = |i: usize| info.region_sigma.get(i).copied().unwrap_or(0.0);
    info.axes
        .iter()
        .zip(info.sigma.iter().zip(&info.sandwich_sigma))
        .enumerate()
        .map(|(i, (a, (s, w)))| {
            let floor = crate::localize::refine::uncertainty::sigma_floor(cfg, a);
            s.max(*w).max(region(i)).max(frame(i)).max(floor)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reported covariance is the sandwich's shape at the judged σ:
    /// every axis at least its judged σ (the search's floor included), correlations kept, widened
    /// by the sandwich's Student-t factor, and the intrinsics' part added on top.
    #[test]
    fn the_reported_covariance_is_the_sandwich_s_shape_at_the_judged_sigma() {
        use super::super::quality::Sigma;
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
            region_sigma: Vec::new(),
            region_matrix: Vec::new(),
            regions: 0,
            frame_sigma: None,
            frame_matrix: None,
            frames: 0,
            hessian: [[0.0; 6]; 6],
        };
        let judged = judged_sigma(&info, &crate::localize::mi::space::SearchConfig::default());
        // The default search's floor: half of 2 cm on x, y and z, none on the angles.
        assert_eq!(judged, vec![0.01, 0.02, 0.01, 0.01, 0.05, 0.03]);
        let t = (super::super::uncertainty::student_t_3sigma(31) / 3.0).powi(2);
        let u = information_covariance(&info, &judged, None);
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

    /// With region and frame sandwiches each estimate is widened by its own degrees of freedom:
    /// the frames' (K − 1) or the regions' (7) where they decide the axis, the patches' (31, the
    /// floor's too) elsewhere; the floor stays.
    #[test]
    fn each_sandwich_widens_by_its_own_clusters_above_the_floor() {
        let axes: Vec<String> = ["x", "y", "z", "yaw"].map(String::from).to_vec();
        let diag = |sd: &[f64]| -> Vec<Vec<f64>> {
            (0..4)
                .map(|i| {
                    (0..4)
                        .map(|j| if i == j { sd[i] * sd[i] } else { 0.0 })
                        .collect()
                })
                .collect()
        };
        let patch = [0.003, 0.004, 0.006, 0.007];
        let frame = [0.008, 0.001, 0.001, 0.004];
        let region = [0.002, 0.009, 0.001, 0.012];
        let info = |frames: usize| Information {
            axes: axes.clone(),
            units: ["m", "m", "m", "deg"].map(String::from).to_vec(),
            sigma: vec![0.0005; 4],
            matrix: diag(&[0.0005; 4]),
            points: 100_000,
            evaluations: 9,
            sandwich_sigma: patch.to_vec(),
            sandwich_matrix: diag(&patch),
            clusters: 32,
            region_sigma: region.to_vec(),
            region_matrix: diag(&region),
            regions: 8,
            frame_sigma: Some(frame.to_vec()),
            frame_matrix: Some(diag(&frame)),
            frames,
            hessian: [[0.0; 6]; 6],
        };
        let cfg = crate::localize::mi::space::SearchConfig::default();
        let judged = judged_sigma(&info(6), &cfg);
        // x, y and z at the default floor (1 cm); yaw, which has none, at its region σ.
        assert_eq!(judged, vec![0.01, 0.01, 0.01, 0.012]);
        let t = |dof: usize| super::super::uncertainty::student_t_3sigma(dof) / 3.0;
        // Six frames: x's frame σ widened by t₅ (1.46 cm) passes the floor widened by t₃₁
        // (1.09 cm). Twelve: by t₁₁ (1.03 cm) it does not. y's and yaw's region σ widened by
        // t₇ pass their judged σ widened by t₃₁.
        for (frames, x) in [(6, 0.008 * t(5)), (12, 0.01 * t(31))] {
            let u = information_covariance(&info(frames), &judged, None);
            assert_eq!(u.gate_sigma, judged);
            let want = [x, 0.009 * t(7), 0.01 * t(31), 0.012 * t(7)];
            for i in 0..4 {
                assert!(
                    (u.sigma[i] - want[i]).abs() < 1e-12,
                    "{frames} {i}: {:?}",
                    u.sigma
                );
            }
        }
    }
}
