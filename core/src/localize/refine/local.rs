//! The smooth estimator's local stage: from the grid search's basin, the gradient ascent
//! ([`super::ascent`]) of the partial-volume MI, the evidence at the answer (its observed
//! [`super::information`], the competing [`super::optima`], the indifference [`super::region`]),
//! the covariance composed from it ([`super::uncertainty::compose`]) and the grade judged from
//! that ([`super::verdict::judge`]).

// Small fixed-size matrices indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use super::ascent::{ascend_with, Ascent, AscentConfig};
use super::information::{information, Information, HESSIAN_STEP};
use super::quality::GateCheck;
use super::uncertainty::{compose, Evidence};
use super::verdict::{judge, Grade, Stop};
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
/// the evidence at the answer, its covariance and its grade ([`smooth_stage`]).
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
/// search spec or a non-finite value or gradient. Every result is returned with its grade
/// (`quality.grade`); the caller decides whether to write it.
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

/// The smooth estimator's stage after the grid's refinement `grid` that started at `init`: its
/// gradient ascent from `grid`'s pose over the axes of `free` (in the box of [`AscentConfig`],
/// re-centred while it ends on the edge, [`ASCENT_ROUNDS`] at most), the evidence at the answer
/// (the observed information, the competing optima, and where the Hessian has no basin the
/// poses the data cannot tell from the answer), the covariance composed from it
/// ([`compose`]) and the grade judged from that ([`judge`]); the grid's global checks (too few
/// points, points lost, its optimum on the box's edge) refuse before any of it. The answer is a
/// new [`Refinement`](super::rounds::Refinement) with the grid's counters and the stage's
/// work added. The pairs pool as `cfg.mi.pooling` says, as in the grid search. The views'
/// image preparations come from `cache`, the one the search before it filled.
#[allow(clippy::too_many_arguments)]
pub(crate) fn smooth_stage<'a>(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'a>],
    init: &CamFromMap,
    grid: super::rounds::Refinement,
    cfg: &crate::localize::mi::space::SearchConfig,
    qcfg: &super::quality::QualityConfig,
    free: SmoothFree,
    cache: &crate::localize::mi::objective::ImageCache<'a>,
) -> crate::error::Result<(super::rounds::Refinement, SmoothRefinement)> {
    let pooling = cfg.mi.pooling;
    let grid_reason = grid.quality.grid_refusal().map(|r| r.to_string());
    let acfg = free.ascent();
    // The fixed point set is the ascent's box's. With `FourAfterSix` the information also steps
    // the tilt (±0.1°, inside that box's margins): on 96 seeds of `small` and `5mp` a set built
    // for the ±1° tilt box held the same points and gave the same σ to 1.2 %.
    let local = crate::localize::mi::space::SearchConfig {
        spec: super::ascent::box_spec(&acfg),
        ..*cfg
    };
    let mut work = Work::default();
    let mut pose = grid.pose;
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
            &mut work,
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
            &grid.peaks,
            cfg,
            pooling,
            &axes,
            cov.map(|c| c.as_slice()),
            curvature,
            cache,
        )?;
        work.add(o.evaluations, o.point_evaluations);
        // An optimum the data prefers to the answer is where the answer should be: the stage
        // climbs again from it, once.
        match o.better().and_then(|b| b.pose) {
            Some(b) if !restarted => {
                restarted = true;
                pose = b;
            }
            _ => break (information, mi, o),
        }
    };
    // Where the Hessian has no basin, the poses the data cannot tell from the answer.
    let region = match &information {
        Err(InformationError::NoBasin { .. }) => {
            let r = super::region::indifference_region(
                cam,
                views,
                &pose,
                cfg,
                pooling,
                &free.information(),
                cache,
            )?;
            work.add(r.evaluations, (r.evaluations * r.points) as u64);
            Some(r)
        }
        _ => None,
    };
    // The intrinsics' part only where there will be a covariance to add it to.
    let composable = information.is_ok() || region.is_some();
    let deltas = qcfg
        .intrinsics_sigma
        .as_ref()
        .filter(|_| composable)
        .map(|s| super::uncertainty::intrinsics_deltas(cam, views, &pose, s));
    let evidence = Evidence {
        information: &information,
        region: region.as_ref(),
        optima: Some(&optima),
        search: cfg,
        intrinsics: deltas.as_deref(),
    };
    // The grid's global checks stand; its local ones (basin, curvature, second peak) are the
    // evidence's: the grid's second peak was one of the optima's starts.
    let global = grid.quality.grid_refusal().filter(|r| {
        matches!(
            r.check(),
            GateCheck::TooFewPoints | GateCheck::PointsLost | GateCheck::OnEdge
        )
    });
    let composed = compose(&evidence);
    let grade = match (global, &composed) {
        (Some(g), _) => Grade::Refused(Stop::Grid(g.clone())),
        (None, Ok(u)) => judge(u, &qcfg.limits()),
        (None, Err(e)) => Grade::Refused(Stop::Information(e.clone())),
    };
    let covariance = composed.ok();
    let quality = super::quality::Quality {
        sigma: covariance.as_ref().map(super::quality::Sigma::of),
        covariance,
        information: information.as_ref().ok().cloned(),
        optima: Some(optima),
        region,
        grade,
        initializer: None,
        mi: match (pooling, mi.first()) {
            (crate::localize::mi::smooth::Pooling::Joint, Some(v)) => *v,
            _ => grid.quality.mi,
        },
        ..grid.quality
    };
    let mut stats = grid.stats;
    stats.poses += work.poses;
    stats.point_evaluations += work.point_evaluations;
    Ok((
        super::rounds::Refinement {
            pose,
            offsets: crate::pose::offsets_between(init, &pose),
            stats,
            quality,
            ..grid
        },
        SmoothRefinement {
            pooling,
            ascents,
            mi,
            information,
            grid_reason,
        },
    ))
}

/// Work done by the local stage, added to the grid's counters.
#[derive(Debug, Default)]
struct Work {
    poses: u64,
    point_evaluations: u64,
}

impl Work {
    fn add(&mut self, poses: usize, point_evaluations: u64) {
        self.poses += poses as u64;
        self.point_evaluations += point_evaluations;
    }
}

/// The local stage's rounds from `pose` (moved to the answer): an ascent in the box of `acfg`
/// ([`ASCENT_ROUNDS`] at most, re-centred while it ends on the edge), then the information at
/// the answer over the axes of `free`, and the MI per histogram there. The work goes into
/// `work`, the ascents into `ascents`.
#[allow(clippy::too_many_arguments)]
fn climb<'a>(
    cam: &crate::camera::Camera,
    views: &[crate::localize::mi::objective::View<'a>],
    local: &crate::localize::mi::space::SearchConfig,
    acfg: &AscentConfig,
    free: SmoothFree,
    pose: &mut CamFromMap,
    ascents: &mut Vec<Ascent>,
    work: &mut Work,
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
        work.add(spent, (spent * est.n()) as u64);
        *pose = a.pose;
        let edge = a.stop == "edge";
        ascents.push(a);
        if !edge {
            let info = information(&est, pose, &free.information());
            // The Hessian's evaluations (and the value below) are work done too.
            let spent = 1 + info.as_ref().map_or(0, |i| i.evaluations);
            work.add(spent, (spent * est.n()) as u64);
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
