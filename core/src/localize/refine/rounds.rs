//! The global part of the refinement (pure): the nearest-pixel grid search for the basin, the
//! Nelder–Mead polishes and the rounds that alternate them. Its answer carries the grid's checks
//! but no σ: the smooth estimator's stage ([`crate::localize::refine::local`]) takes it from
//! there and gives the covariance.

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::localize::mi::objective::{Evaluator, ImageCache, SearchStats, View};
use crate::localize::mi::space::{Mode, SearchConfig, MAX_LEVEL};
use crate::localize::refine::quality::{assess, Quality, QualityConfig};
use crate::localize::refine::search::search_to;
use crate::pose::CamFromMap;
use serde::Serialize;

/// The refinement's answer.
#[derive(Debug, Clone)]
pub struct Refinement {
    /// The refined pose (roll and pitch kept from the initial pose unless 6-DoF is on).
    pub pose: CamFromMap,
    /// Offsets from the initial pose: x, y, z (m), yaw, pitch, roll (deg).
    pub offsets: [f64; 6],
    /// Search counters. After [`refine_polished`]'s rounds, `poses` and `point_evaluations`
    /// count every search and polish (the work done); the rest describe the last search.
    pub stats: SearchStats,
    /// Quality statistics and the gate's verdict.
    pub quality: Quality,
    /// Points given, and points in the fixed set (all views).
    pub points: (usize, usize),
    /// Per view (image/point-set pair): points given and points in its fixed set.
    pub views: Vec<(usize, usize)>,
    /// The last search's other local maxima (best first): where the smooth stage looks for
    /// optima that compete with the answer ([`crate::localize::refine::optima`]).
    pub peaks: Vec<CamFromMap>,
}

/// Machine-readable summary (`--report`).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Search mode.
    pub mode: Mode,
    /// Offsets from the initial pose: x, y, z (m), yaw, pitch, roll (deg).
    pub offsets: [f64; 6],
    /// Points given.
    pub points_input: usize,
    /// Points in the fixed set.
    pub points_used: usize,
    /// Image/point-set pairs pooled into one joint histogram per pose.
    pub pairs: usize,
    /// Per pair: points given and points in its fixed set.
    pub pair_points: Vec<(usize, usize)>,
    /// Search counters (after search rounds and polishes: `poses` and `point_evaluations` count
    /// them all, see [`Refinement::stats`]).
    pub stats: SearchStats,
    /// exhaustive (one search's grid) / actual point-pose evaluations (every search and polish).
    pub evaluation_ratio: f64,
    /// Quality.
    pub quality: Quality,
}

impl Refinement {
    /// The `--report` summary.
    pub fn report(&self, mode: Mode) -> Report {
        Report {
            mode,
            offsets: self.offsets,
            points_input: self.points.0,
            points_used: self.points.1,
            pairs: self.views.len(),
            pair_points: self.views.clone(),
            stats: self.stats,
            evaluation_ratio: self.stats.exhaustive_point_evaluations as f64
                / self.stats.point_evaluations.max(1) as f64,
            quality: self.quality.clone(),
        }
    }
}

/// The grid search and its quality on pooled views (no σ: the smooth stage estimates it).
/// `(thinning, level)`: the finest level's point stride and the level the search stops at
/// ([`search_to`]).
pub(crate) fn search_views<'a>(
    cam: &Camera,
    views: &[View<'a>],
    init: &CamFromMap,
    cfg: &SearchConfig,
    qcfg: &QualityConfig,
    (thinning, level): (usize, u32),
    cache: &ImageCache<'a>,
) -> Result<Refinement> {
    // `Evaluator::pooled` checks the images' and masks' sizes.
    let levels = if cfg.mode == Mode::Exhaustive {
        0
    } else {
        MAX_LEVEL
    };
    let ev = Evaluator::pooled_cached(cam, views, init, cfg, levels, cache)?;
    let res = search_to(&ev, cfg, thinning, level);
    let quality = assess(&ev, &res, qcfg);
    if !res.pose.translation.iter().all(|v| v.is_finite()) {
        return Err(Error::stage(
            crate::stage::StageName::Mi,
            "refined pose is not finite",
        ));
    }
    Ok(Refinement {
        pose: res.pose,
        offsets: res.offsets,
        stats: res.stats,
        quality,
        points: (ev.n_input, ev.n_points),
        views: ev.view_points.clone(),
        peaks: res
            .other_peaks
            .iter()
            .map(|p| ev.pose(&ev.grid().cell(p.idx)))
            .collect(),
    })
}

/// Settings of [`refine_polished`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolishedSearch {
    /// The polish after each search (6-DoF by default, 4-DoF in [`PolishedSearch::four_dof`]).
    pub polish: crate::localize::refine::polish::PolishParams,
    /// Polishes per search at most (each from the previous one's result when it ended on its
    /// box's edge, or moved, see `repolish_when_moved`). Only the first polish after a search
    /// uses the tilt starts ([`crate::localize::refine::polish::PolishParams::tilt_starts_deg`]); a re-polish
    /// starts from the previous end alone.
    pub polish_rounds: usize,
    /// Searches at most, see [`refine_polished`].
    pub search_rounds: usize,
    /// Polish again (within `polish_rounds`) also when a polish moved the pose by more than the
    /// re-search thresholds (`RESEARCH_MOVE_M`, `RESEARCH_MOVE_DEG`), not only when it ended
    /// on its box's edge: each polish's point set is the one its own box sees, so one that moved
    /// far has a new set, and a further polish may move it on (the 4-DoF finish, where no
    /// re-search follows).
    pub repolish_when_moved: bool,
    /// The searches' finest level scores every this-th point (1: all), see
    /// [`crate::localize::refine::search::search_thinned`]: the 6-DoF polish on all points that follows sets the
    /// answer, so the grid cell it starts from needs less than the full point set.
    pub search_thinning: usize,
    /// The level the searches stop at ([`crate::localize::refine::search::search_to`]; 0: the
    /// finest step). A search that a continuous local stage follows, from the basin's cell to
    /// the peak, need not climb to the finest cell: 1 for the smooth estimator's path
    /// ([`PolishedSearch::basin`]).
    pub basin_level: u32,
    /// Polish once from the start, before the first search (the polish's settings from the start
    /// alone, no tilt starts), when the polish frees the tilt. The searches hold their start's
    /// roll and pitch; when the start's tilt is a degree or more off (PnP on a low pole), the
    /// first search's optimum is a compromise that the polish then walks away from, and a second
    /// search follows. Settled first, the first search is made at the polished tilt.
    pub settle_tilt_first: bool,
}

impl Default for PolishedSearch {
    fn default() -> Self {
        PolishedSearch {
            polish: crate::localize::refine::polish::PolishParams::default(),
            polish_rounds: POLISH_ROUNDS,
            search_rounds: SEARCH_ROUNDS,
            repolish_when_moved: false,
            search_thinning: SEARCH_THINNING,
            basin_level: 0,
            settle_tilt_first: false,
        }
    }
}

impl PolishedSearch {
    /// The 4-DoF refinement's finish (`infraloc refine` and `infraloc study` by default): the
    /// search, then Nelder–Mead over x, y, z and yaw only ([`PolishParams::four_dof`]), roll and
    /// pitch kept. The grid's cell is the exhaustive argmax at the grid's step, on the point set
    /// visible from the *whole* search box; the polish continues off the grid on the point set of
    /// its ±15 cm / ±0.5° box, which keeps the ground the big box had to drop. That matters most
    /// for a forward-looking camera: moving it ±1 m along its view and ±0.5 m in height moves
    /// the nearest ground (the rows that pin the along-track position: image motion ∝
    /// 1/distance²) across the image's bottom edge, so the search's fixed set loses it, and its
    /// objective can have two near-equal humps 0.3 m apart along the view.
    /// - A polish that moved more than 5 cm / 0.5° polishes again from its end (at most
    ///   `POLISH_ROUNDS`): the grid's cell can be 20 cm along the view from the peak, more than
    ///   one ±15 cm box.
    /// - When the polishes moved the pose that far in all, one more search, centred on the
    ///   polished pose, and its polish: the gate then judges the search around the answer, not
    ///   the one around the start (as in the 6-DoF rounds).
    ///
    /// On KITTI-like scenes (`examples/forward_pinhole.rs`, 50 seeds, issue 3's start box) the
    /// along-track median error drops from 6.7 to 0.44 cm and all 50 are accepted within
    /// 10 cm / 0.2° (grid alone: 36, with 11 accepted 10–15 cm off).
    ///
    /// [`PolishParams::four_dof`]: crate::localize::refine::polish::PolishParams::four_dof
    pub fn four_dof() -> Self {
        PolishedSearch {
            polish: crate::localize::refine::polish::PolishParams::four_dof(),
            polish_rounds: POLISH_ROUNDS,
            search_rounds: 2,
            repolish_when_moved: true,
            // Its grid cell can be the peak itself (a forward view's along-track hump, above):
            // the search keeps every point.
            search_thinning: 1,
            basin_level: 0,
            settle_tilt_first: false,
        }
    }

    /// These settings with the searches stopping at lattice level [`BASIN_LEVEL`]: for the
    /// smooth estimator's path, whose polish and gradient ascent start from the basin's cell.
    pub fn basin(self) -> Self {
        PolishedSearch {
            basin_level: BASIN_LEVEL,
            ..self
        }
    }

    /// These settings with the start's tilt polished before the first search
    /// (`settle_tilt_first`) when the start's own tilt σ, `tilt_sigma_deg` (PnP's, from its
    /// reprojection residuals), puts 3σ beyond the tilt move that would send the polish's result
    /// to a second search ([`RESEARCH_MOVE_DEG`]): a second search is then likely, and settling
    /// the tilt first makes it unneeded. A start whose tilt is known that well (or whose σ is
    /// unknown, NaN) keeps its path.
    pub fn settle_uncertain_tilt(self, tilt_sigma_deg: f64) -> Self {
        PolishedSearch {
            settle_tilt_first: 3.0 * tilt_sigma_deg > RESEARCH_MOVE_DEG,
            ..self
        }
    }
}

/// The level the searches stop at before the smooth estimator's stage
/// ([`PolishedSearch::basin`]): steps of 4 cm and 0.1° with the default grid, on the level's
/// half-resolution image. Below it the nearest-pixel surface's ripples (a pixel's jump) are as
/// large as the step, and on a low pole its climbs were most of a localization (`5mp` 4: the
/// first search's level-0 windows and climbs 7 of its 10 CPU-s).
pub const BASIN_LEVEL: u32 = 1;

/// The name of what follows the grid search, for reports and pose files: `6-dof` (a polish that
/// moves the tilt), `4-dof` (one that holds it) or `none`.
pub fn finish_name(finish: Option<&PolishedSearch>) -> &'static str {
    match finish {
        None => "none",
        Some(p) if p.polish.frees_tilt() => "6-dof",
        Some(_) => "4-dof",
    }
}

/// Polish rounds per search at most (default of [`PolishedSearch::polish_rounds`]).
pub(crate) const POLISH_ROUNDS: usize = 3;
/// Default of [`PolishedSearch::search_thinning`]: the finest level on half the points. A quarter
/// (the level above's count) changed the path on the scenes whose outcome hangs on it (`5mp` 11
/// accepted 0.28° off, `small` 98/100; docs/benchmarks.md).
pub(crate) const SEARCH_THINNING: usize = 2;
/// Searches at most (default of [`PolishedSearch::search_rounds`]). A round only starts when the
/// previous polish moved (or the gate refused an optimum on the box's edge), so the limit only
/// bites on a polish that is still walking along a ridge; with 3, `5mp` seed 3's last polish moved roll by 2° after its search and the gate judged
/// that stale search (refused a 1 cm / 0.04° pose); the 4th search confirms it. No other seed of
/// `small` 1–100 and `5mp` 1–20 reaches a 4th round.
pub(crate) const SEARCH_ROUNDS: usize = 4;
/// A polish that moved the search's optimum by more than this (metres, in its x, y, z parameters)
/// triggers another search.
pub(crate) const RESEARCH_MOVE_M: f64 = 0.05;
/// … or by more than this on any angle (degrees).
pub(crate) const RESEARCH_MOVE_DEG: f64 = 0.5;

/// One search of [`refine_polished`] and the polishes after it.
#[derive(Debug, Clone, Serialize)]
pub struct Round {
    /// Why this search ran: `init` (the first), `polish moved` or `edge`.
    pub start: &'static str,
    /// The polish of the start before the first search
    /// ([`PolishedSearch::settle_tilt_first`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settle: Option<crate::localize::refine::polish::PolishRecord>,
    /// The polishes after it.
    pub polish: Vec<crate::localize::refine::polish::PolishRecord>,
}

/// The 4-DoF search, then the polish (6-DoF by default; 4-DoF with [`PolishedSearch::four_dof`]),
/// in rounds. The search holds its start's roll and
/// pitch, and an initial tilt can be 2–3° off: from there the search trades the tilt for
/// position, height and yaw, and its quality (the gate's evidence) describes that compromise, not
/// the peak. So the search runs again, centred on the polished pose, when the polish moved the
/// pose by more than `RESEARCH_MOVE_M` / `RESEARCH_MOVE_DEG` (the optimum was found at a stale
/// tilt), or when the gate refused an optimum on the box's edge (the edge may be the tilt trade
/// rather than a wrong start), at most `p.search_rounds` searches. Each search is centred on the
/// previous polished pose, so the answer can lie up to `search_rounds` box half-widths from
/// `init` (a start metres off walks to the edge in every search and is still refused). The
/// answer is the last polished pose with the last search's quality, its `offsets` taken from
/// `init`. `pivot` gives the tilt pivot depth for a pose (see [`crate::localize::refine::polish::polish_pose`]).
/// With `p.settle_tilt_first` the start is polished once before the first search, and the
/// searches begin from that pose (the first round's `settle`).
/// With `p = None`: the one 4-DoF search, no polish, no rounds (PnP's tilt kept). The answer
/// has the last search's checks and no σ ([`crate::localize::refine::local::smooth_stage`]
/// follows). After each
/// search, a polish that ended on its box's edge (or, with `repolish_when_moved`, moved) polishes
/// again from its end, without the tilt starts, at most `p.polish_rounds` polishes.
///
/// "Moved" is measured on the polish's parameters: x, y, z offsets and the three angles, with
/// pitch and roll about the pivot (a tilt of 0.4° about a 10 m pivot also moves the camera centre
/// ≈ 7 cm, which the 0.5° threshold, not the 5 cm one, stands for).
pub fn refine_polished(
    cam: &Camera,
    views: &[View<'_>],
    init: &CamFromMap,
    cfg: &SearchConfig,
    qcfg: &QualityConfig,
    p: Option<&PolishedSearch>,
    pivot: &dyn Fn(&CamFromMap) -> Option<f64>,
) -> Result<(Refinement, Vec<Round>)> {
    // Every search and polish below works on the same frames: they share one image preparation.
    let cache = ImageCache::default();
    refine_polished_cached(cam, views, init, cfg, qcfg, p, pivot, &cache)
}

/// [`refine_polished`] taking the views' image preparations from `cache` (and leaving its own
/// there): for a caller whose smooth stage follows on the same frames.
#[allow(clippy::too_many_arguments)]
pub(crate) fn refine_polished_cached<'a>(
    cam: &Camera,
    views: &[View<'a>],
    init: &CamFromMap,
    cfg: &SearchConfig,
    qcfg: &QualityConfig,
    p: Option<&PolishedSearch>,
    pivot: &dyn Fn(&CamFromMap) -> Option<f64>,
    cache: &ImageCache<'a>,
) -> Result<(Refinement, Vec<Round>)> {
    let Some(p) = p else {
        let r = search_views(cam, views, init, cfg, qcfg, (1, 0), cache)?;
        return Ok((r, Vec::new()));
    };
    let mut rounds = Vec::new();
    let mut start = *init;
    let mut why = "init";
    // Work done by all the searches and polishes: the reported evaluation ratio counts it all.
    let (mut poses, mut point_evaluations) = (0u64, 0u64);
    let mut settle = None;
    if p.settle_tilt_first && p.polish.frees_tilt() {
        let params = crate::localize::refine::polish::PolishParams {
            tilt_starts_deg: 0.0,
            ..p.polish
        };
        let (pose, record) = crate::localize::refine::polish::polish_pose_cached(
            cam,
            views,
            &start,
            pivot(&start),
            cfg,
            &params,
            cache,
        )?;
        poses += record.all_evaluations() as u64;
        point_evaluations += record.point_evaluations();
        settle = Some(record);
        start = pose;
    }
    loop {
        let mut r = search_views(
            cam,
            views,
            &start,
            cfg,
            qcfg,
            (p.search_thinning, p.basin_level),
            cache,
        )?;
        poses += r.stats.poses;
        point_evaluations += r.stats.point_evaluations;
        let mut polish = Vec::new();
        for pi in 0..p.polish_rounds.max(1) {
            // A re-polish (after one ended on its box's edge or moved) starts from that end only:
            // the tilt starts already explored ±`tilt_starts_deg` around this search's optimum, and five starts
            // per re-polish were most of the slow seeds' time (`5mp` 7 and 14: three 5-start
            // polishes in their first round). CHANGELOG.md "Re-polishes from one start".
            let params = if pi > 0 {
                crate::localize::refine::polish::PolishParams {
                    tilt_starts_deg: 0.0,
                    ..p.polish
                }
            } else {
                p.polish
            };
            let (pose, record) = crate::localize::refine::polish::polish_pose_cached(
                cam,
                views,
                &r.pose,
                pivot(&r.pose),
                cfg,
                &params,
                cache,
            )?;
            r.pose = pose;
            poses += record.all_evaluations() as u64;
            point_evaluations += record.point_evaluations();
            polish.push(record);
            let again = record.on_edge(&params)
                || (p.repolish_when_moved && polish_moved(std::slice::from_ref(&record)));
            if !again {
                break;
            }
        }
        let moved = polish_moved(&polish);
        let edge = r.quality.grid_refusal().is_some() && r.quality.axes.iter().any(|a| a.on_edge);
        rounds.push(Round {
            start: why,
            settle: settle.take(),
            polish,
        });
        let next = match (moved, edge) {
            _ if rounds.len() >= p.search_rounds.max(1) => None,
            (true, _) => Some("polish moved"),
            (false, true) => Some("edge"),
            (false, false) => None,
        };
        match next {
            Some(n) => {
                start = r.pose;
                why = n;
            }
            None => {
                // Offsets of the answer from `init` (the last search's own offsets start from the
                // previous polished pose and leave out the polish).
                r.offsets = crate::pose::offsets_between(init, &r.pose);
                r.stats.poses = poses;
                r.stats.point_evaluations = point_evaluations;
                return Ok((r, rounds));
            }
        }
    }
}

/// The polishes' offsets added up (m, m, m, deg, deg, deg): how far the polishes after one search
/// moved its optimum.
pub fn summed_offsets(records: &[crate::localize::refine::polish::PolishRecord]) -> [f64; 6] {
    let mut total = [0.0f64; 6];
    for r in records {
        for (t, v) in total.iter_mut().zip(r.offsets) {
            *t += v;
        }
    }
    total
}

/// Whether the polishes after one search moved the pose by more than the re-search thresholds
/// in total.
fn polish_moved(rounds: &[crate::localize::refine::polish::PolishRecord]) -> bool {
    let total = summed_offsets(rounds);
    let moved_m = (total[0].powi(2) + total[1].powi(2) + total[2].powi(2)).sqrt();
    let moved_deg = total[3..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    moved_m > RESEARCH_MOVE_M || moved_deg > RESEARCH_MOVE_DEG
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::localize::refine::polish::PolishRecord;

    fn record(offsets: [f64; 6]) -> PolishRecord {
        PolishRecord {
            offsets,
            start_value: 0.3,
            value: 0.31,
            evaluations: 150,
            points: 40_000,
            pivot_m: Some(5.0),
            screening: None,
        }
    }

    /// The start's tilt is settled first exactly when its 3σ exceeds the re-search threshold; an
    /// unknown σ (a verified sweep pose) keeps the path.
    #[test]
    fn an_uncertain_start_tilt_is_settled_first() {
        let p = PolishedSearch::default().basin();
        assert!(!p.settle_tilt_first);
        let edge = RESEARCH_MOVE_DEG / 3.0;
        assert!(p.settle_uncertain_tilt(edge * 1.01).settle_tilt_first);
        assert!(!p.settle_uncertain_tilt(edge * 0.99).settle_tilt_first);
        assert!(!p.settle_uncertain_tilt(f64::NAN).settle_tilt_first);
        // Only that flag changes.
        let s = p.settle_uncertain_tilt(1.0);
        assert_eq!(
            PolishedSearch {
                settle_tilt_first: false,
                ..s
            },
            p
        );
    }

    #[test]
    fn finish_names_follow_the_polish_s_free_axes() {
        assert_eq!(finish_name(None), "none");
        assert_eq!(finish_name(Some(&PolishedSearch::default())), "6-dof");
        assert_eq!(finish_name(Some(&PolishedSearch::four_dof())), "4-dof");
    }

    #[test]
    fn polish_moved_sums_the_rounds_and_uses_both_thresholds() {
        // Nothing to re-search: no polish, or a polish that stayed within 5 cm and 0.5°.
        assert!(!polish_moved(&[]));
        assert!(!polish_moved(&[record([0.03, 0.03, 0.02, 0.1, 0.4, -0.4])]));
        // A tilt move beyond 0.5° (pitch or roll, either sign) or a 6 cm translation.
        assert!(polish_moved(&[record([0.0, 0.0, 0.0, 0.0, 0.0, -0.6])]));
        assert!(polish_moved(&[record([0.06, 0.0, 0.0, 0.0, 0.0, 0.0])]));
        // Two rounds of 0.3° each add up to 0.6°; opposite moves cancel.
        let half = record([0.0, 0.0, 0.0, 0.0, 0.3, 0.0]);
        assert!(polish_moved(&[half, half]));
        assert!(!polish_moved(&[
            half,
            record([0.0, 0.0, 0.0, 0.0, -0.3, 0.0])
        ]));
    }
}
