//! Grid search over Θ = [x, y, z, ψ] (optionally pitch and roll) around an initial pose.
//!
//! The grid: axis i has cells at offsets k·step_i, k ∈ −m_i..=m_i, m_i = round(half_i/step_i),
//! around the initial pose (x, y, z offsets of the camera centre in the map frame; yaw about the
//! map's up axis through the camera centre, [`CamFromMap::perturbed`]). Cells are numbered
//! mixed-radix with x slowest; ties between equal scores go to the lowest number.
//!
//! Two modes:
//! - [`Mode::Exhaustive`] evaluates every cell with all points (the seed's method); exact argmax.
//! - [`Mode::Tiled`] (default) is coarse-to-fine on sub-lattices of the same grid: level L surveys
//!   the whole box at step 2^L cells — split into tiles evaluated in parallel — against a 2^L
//!   downsampled image with a point subsample; the top-k local maxima go down a level, where each is
//!   re-examined on a ±2-cell window at half the step and the top-k local maxima of all that was
//!   scored go on, down to level 0 (finest step, full image, all points); finally each candidate
//!   hill-climbs on the finest grid to a local maximum (every step's cells scored in parallel).
//!   The result is always a cell of the exhaustive grid, scored by the same estimator.
//!
//! Bias remedy: MI computed on fewer points is biased upward (≈ (bx−1)(by−1)/2N nats), so a pose
//! that pushes points out of the image would be favoured. The search therefore uses a *fixed point
//! set*: the points that land on the image, at least `visibility-margin-px` inside the valid
//! circle, from every pose of a 3^d lattice of the box (corners, edge and face centres, centre).
//! Every pose of the search then sees (nearly) the same points; the residual loss is counted and
//! reported ([`SearchStats::max_lost_fraction`]).
//!
//! Determinism: every score is a pure function of the cell (integer histogram → f64 entropies in a
//! fixed order); parallel maps are collected in input order and reductions use the total order
//! (score, −cell), so the result does not depend on thread count or scheduling.

// Axis-indexed loops over parallel fixed-size arrays ([_; 6]) read clearer with the index.
#![allow(clippy::needless_range_loop)]

use crate::localize::mi::objective::{best_of, better, Evaluator, Scored, SearchStats};
use crate::localize::mi::space::{Cell, Grid, Mode, SearchConfig, MAX_LEVEL};
use crate::pose::CamFromMap;
use rayon::prelude::*;
use std::collections::HashMap;

/// The search's answer.
#[derive(Debug, Clone)]
pub struct SearchResult {
    /// Best cell.
    pub best: Scored,
    /// Its offsets (m, m, m, deg, deg, deg).
    pub offsets: [f64; 6],
    /// Its pose.
    pub pose: CamFromMap,
    /// Other local maxima found at level 0 (best first), for the second-peak test.
    pub other_peaks: Vec<Scored>,
    /// Counters.
    pub stats: SearchStats,
}

/// Coarsest level whose survey fits in `budget` poses.
pub(crate) fn coarsest_level(g: &Grid, budget: u64) -> u32 {
    let mut l = 0;
    while l < MAX_LEVEL {
        let count: u64 = (0..6).map(|i| g.lattice_axis(i, l).len() as u64).product();
        if count <= budget {
            break;
        }
        l += 1;
    }
    l
}

/// Run the search configured by `cfg` on a prepared evaluator.
pub fn search(ev: &Evaluator, cfg: &SearchConfig) -> SearchResult {
    search_thinned(ev, cfg, 1)
}

/// [`search`] whose finest tiled level (the descent's last windows and the hill-climbs) scores
/// every `thinning`-th point of the fixed set, or fewer thinned where that would leave fewer
/// points than `coarse_min_points` (1: all points, [`search`]). For a search that a continuous
/// polish on all points follows: the polish, not the grid cell, sets the answer's precision, and
/// the finest level on all points was about half of a refinement's point-evaluations. The peaks
/// the climbs end on are scored again on all points and the best of them climbs on on all points
/// (steepest ascent, no wide look) to a cell no neighbour beats: the answer is a local maximum of
/// the full estimator, most often the unthinned search's cell, and its score, the second-peak
/// test and the quality's profiles all use the full estimator.
pub(crate) fn search_thinned(ev: &Evaluator, cfg: &SearchConfig, thinning: usize) -> SearchResult {
    search_to(ev, cfg, thinning, 0)
}

/// [`search_thinned`] whose tiled descent and climbs stop at lattice `level` (steps 2^level
/// finest cells, the level's image and point subsample; 0: [`search_thinned`]): the grid finds
/// the basin, and a continuous local stage that follows sets the answer. The climbs' peaks are
/// scored again at level 0 on all points and the best of them climbs on all points at the
/// finest step, without the wide look ([`finish_on_all_points`]): the answer is a local maximum
/// of the full estimator, and its score, the second-peak test and the quality's profiles see
/// the full estimator, as after a level-0 search. A grid small enough to be surveyed at a finer
/// level than `level` is searched to level 0.
pub(crate) fn search_to(
    ev: &Evaluator,
    cfg: &SearchConfig,
    thinning: usize,
    level: u32,
) -> SearchResult {
    let g = ev.grid;
    let mut stats = SearchStats {
        exhaustive_point_evaluations: g.cells().saturating_mul(ev.n_points as u64),
        ..Default::default()
    };
    let (best, others) = match cfg.mode {
        Mode::Exhaustive => exhaustive(ev, &mut stats),
        Mode::Tiled => {
            let stride = thinning.min(ev.n_points / cfg.coarse_min_points.max(1));
            let fine = (stride >= 2 && level == 0).then(|| ev.thinned(stride));
            tiled(ev, fine.as_ref(), cfg, level, &mut stats)
        }
    };
    let cell = g.cell(best.idx);
    SearchResult {
        best,
        offsets: g.offsets(&cell),
        pose: ev.pose(&cell),
        other_peaks: others,
        stats,
    }
}

fn neighbours(g: &Grid, c: &Cell, f: i64) -> Vec<Cell> {
    let mut out = vec![*c];
    for i in 0..6 {
        if g.m[i] == 0 {
            continue;
        }
        out = out
            .into_iter()
            .flat_map(|d| {
                [-f, 0, f].into_iter().map(move |k| {
                    let mut e = d;
                    e[i] += k;
                    e
                })
            })
            .collect();
    }
    out.retain(|d| d != c && g.contains(d));
    out
}

/// Every cell at level 0; also returns the other local maxima (3^d neighbourhood), best first.
fn exhaustive(ev: &Evaluator, stats: &mut SearchStats) -> (Scored, Vec<Scored>) {
    let g = ev.grid;
    let all: Vec<u64> = (0..g.cells()).collect();
    let scores = ev.score_many(0, &all, stats);
    let best = best_of(&scores).expect("grid has at least one cell");
    let mut peaks: Vec<Scored> = scores
        .par_iter()
        .filter(|s| {
            s.idx != best.idx
                && neighbours(&g, &g.cell(s.idx), 1)
                    .iter()
                    .all(|n| better(s, &scores[g.index(n) as usize]))
        })
        .copied()
        .collect();
    sort_best_first(&mut peaks);
    (best, peaks)
}

fn sort_best_first(v: &mut [Scored]) {
    v.sort_by(|a, b| b.score.total_cmp(&a.score).then_with(|| a.idx.cmp(&b.idx)));
}

/// Coarse-to-fine over sub-lattices, down to lattice `basin_level` ([`search_to`]; a level
/// beyond the survey's is 0).
fn tiled(
    ev: &Evaluator,
    fine: Option<&Evaluator>,
    cfg: &SearchConfig,
    basin_level: u32,
    stats: &mut SearchStats,
) -> (Scored, Vec<Scored>) {
    let g = ev.grid;
    let top = (ev.levels.len() as u32 - 1).min(coarsest_level(&g, cfg.coarse_budget));
    stats.coarsest_level = top;
    let basin = if basin_level <= top { basin_level } else { 0 };
    // A survey at level 0 (a small grid) scores all points already: nothing to thin. (A search
    // that stops above level 0 has no thinned evaluator: `search_to` builds none.)
    let fine = fine.filter(|_| top > 0);
    // The evaluator of the finest level's windows and climbs.
    let ev0 = fine.unwrap_or(ev);
    let k = cfg.top_k.max(1);

    let survey = ev.score_many(top, &survey_lattice(&g, top), stats);
    let cands = top_local_maxima(&g, &survey, 1i64 << top, k);
    let (cands, last) = descend(ev, ev0, cands, top, basin, k, stats);
    // Scores of the basin's level already computed (by the last descent step, or the survey when
    // the grid is small enough to survey at that level): the climbs start inside those windows
    // and would score most of them again. A score is a pure function of (level, cell), so reusing
    // one changes only the count, never a result.
    let mut cache: HashMap<u64, Scored> = if top == basin { &survey } else { &last }
        .iter()
        .map(|s| (s.idx, *s))
        .collect();

    // Hill-climb each candidate to a local maximum of the basin's lattice. The climbs run one
    // after the other (each step scores its cells in parallel) and share one cache: candidates
    // are often close, and their climbs meet. A cached score is the same number as a recomputed
    // one, so the sharing changes only the count, and the order is fixed, so the count is
    // deterministic too.
    let climber = if basin == 0 { ev0 } else { ev };
    let climbs: Vec<(Scored, u64)> = cands
        .iter()
        .map(|&c| climb(climber, basin, c, cfg.max_climb, &mut cache, true))
        .collect();
    let n = climber.points_at(basin) as u64;
    for (_, evals) in &climbs {
        stats.poses += evals;
        stats.point_evaluations += evals * n;
    }
    if basin == 0 {
        // The cache holds every level-0 score, the climbs' own among them: score_many only saw
        // the descent's, and a climb can walk to a pose the descent never scored.
        let lost = cache
            .values()
            .map(|s| 1.0 - s.value.n as f64 / n.max(1) as f64)
            .fold(0.0, f64::max);
        stats.max_lost_fraction = stats.max_lost_fraction.max(lost);
    }
    let mut peaks: Vec<Scored> = climbs.into_iter().map(|(s, _)| s).collect();
    peaks.sort_unstable_by_key(|s| s.idx);
    peaks.dedup_by_key(|s| s.idx);
    if fine.is_some() || basin > 0 {
        // The wide look stays with the thinned or coarser climbs: on all points at the finest
        // step it would cost more than they save.
        let idxs: Vec<u64> = peaks.iter().map(|s| s.idx).collect();
        peaks = finish_on_all_points(ev, &idxs, cfg, stats);
    }
    sort_best_first(&mut peaks);
    let best = peaks[0];
    (best, peaks[1..].to_vec())
}

/// The cells of the whole box's lattice at `level`. It is enumerated x-slowest, so contiguous
/// chunks of it are tiles of the search space; `score_many` runs them in parallel.
fn survey_lattice(g: &Grid, level: u32) -> Vec<u64> {
    let mut lattice: Vec<Cell> = vec![[0; 6]];
    for i in 0..6 {
        let ax = g.lattice_axis(i, level);
        lattice = lattice
            .into_iter()
            .flat_map(|c| {
                ax.iter().map(move |&v| {
                    let mut d = c;
                    d[i] = v;
                    d
                })
            })
            .collect();
    }
    lattice.iter().map(|c| g.index(c)).collect()
}

/// The descent from the candidates `cands` of level `top` to level `to`: each candidate is
/// re-examined on a ±2-step window of the next finer lattice, and the top-`k` local maxima of
/// all that was scored there go on. Level 0 is scored by `ev0` (the thinned evaluator of
/// [`search_thinned`], or `ev`), the others by `ev`. Returns the candidates at `to` and every
/// score of that level (empty when `to == top`).
fn descend(
    ev: &Evaluator,
    ev0: &Evaluator,
    mut cands: Vec<u64>,
    top: u32,
    to: u32,
    k: usize,
    stats: &mut SearchStats,
) -> (Vec<u64>, Vec<Scored>) {
    let g = ev.grid;
    let mut last = Vec::new();
    for level in (to..top).rev() {
        let f = 1i64 << level;
        let mut union: Vec<u64> = cands
            .iter()
            .flat_map(|&c| window(&g, &g.cell(c), f))
            .collect();
        union.sort_unstable();
        union.dedup();
        let scorer = if level == 0 { ev0 } else { ev };
        let scored = scorer.score_many(level, &union, stats);
        // Taking only each window's best would collapse overlapping windows onto one cell and
        // drop the runner-up hills that the finer levels sometimes prove better (a near-tie of
        // two ripples of the objective).
        cands = top_local_maxima(&g, &scored, f, k);
        last = scored;
    }
    (cands, last)
}

/// The climbs' `peaks` scored at level 0 on all points, and the best of them climbed on all
/// points (steepest ascent, no wide look) to a cell no neighbour beats: the answer is a local
/// maximum of the full estimator on the finest grid, as an unthinned level-0 search's is.
/// Returns the peaks and that cell, once each, unordered.
fn finish_on_all_points(
    ev: &Evaluator,
    peaks: &[u64],
    cfg: &SearchConfig,
    stats: &mut SearchStats,
) -> Vec<Scored> {
    // score_many at level 0 records the points the peaks lose.
    let mut peaks = ev.score_many(0, peaks, stats);
    sort_best_first(&mut peaks);
    let mut full: HashMap<u64, Scored> = peaks.iter().map(|s| (s.idx, *s)).collect();
    let (top, evals) = climb(ev, 0, peaks[0].idx, cfg.max_climb, &mut full, false);
    stats.poses += evals;
    stats.point_evaluations += evals * ev.points_at(0) as u64;
    peaks.push(top);
    peaks.sort_unstable_by_key(|s| s.idx);
    peaks.dedup_by_key(|s| s.idx);
    peaks
}

/// The best `k` (best first) of the `scored` cells that beat each of their lattice-`f` neighbours
/// that were scored too.
fn top_local_maxima(g: &Grid, scored: &[Scored], f: i64, k: usize) -> Vec<u64> {
    let map: HashMap<u64, Scored> = scored.iter().map(|s| (s.idx, *s)).collect();
    let mut maxima: Vec<Scored> = scored
        .iter()
        .filter(|s| {
            neighbours(g, &g.cell(s.idx), f)
                .iter()
                .filter_map(|n| map.get(&g.index(n)))
                .all(|n| better(s, n))
        })
        .copied()
        .collect();
    sort_best_first(&mut maxima);
    maxima.truncate(k);
    maxima.iter().map(|s| s.idx).collect()
}

/// The lattice-`f` cells within ±2f of `c` on every axis.
fn window(g: &Grid, c: &Cell, f: i64) -> Vec<u64> {
    window_r(g, c, f, [2; 6])
}

/// The lattice-`f` cells within ±`r[i]`·f of `c` on axis i.
fn window_r(g: &Grid, c: &Cell, f: i64, r: [i64; 6]) -> Vec<u64> {
    let mut cells = vec![*c];
    for i in 0..6 {
        if g.m[i] == 0 {
            continue;
        }
        let ri = r[i];
        cells = cells
            .into_iter()
            .flat_map(|d| {
                (-ri..=ri).map(move |k| {
                    let mut e = d;
                    e[i] += k * f;
                    e
                })
            })
            .collect();
    }
    cells
        .into_iter()
        .filter(|d| g.contains(d))
        .map(|d| g.index(&d))
        .collect()
}

/// Half widths (finest cells) of the climb's wider look, per axis: ±2 on x, y, z, ±3 on the
/// angles. The objective's pose-to-pose ripples are broadest along the angles: in the
/// tiled-vs-exhaustive trials (tests/refine_synthetic.rs) every remaining miss with a ±2 look was
/// a near-tie exactly 3 yaw steps away. ±3 on every axis would also catch them but costs 7⁴ − 5⁴ =
/// 1776 more full-resolution poses per look (≈ doubling the default search); this costs 250.
const WIDE_LOOK: [i64; 6] = [2, 2, 2, 3, 3, 3];

/// Steepest ascent on lattice `level` (steps of 2^`level` finest cells, that level's scores)
/// from `start` until no neighbour is better, then, with `wide`, a wider look: if a cell within
/// [`WIDE_LOOK`] steps beats the peak, climb on from it. The MI surface over a nearest-pixel
/// sampler has small pose-to-pose ripples; the wide look steps over them so that the result is
/// the maximum of its neighbourhood (±2 positions, ±3 angles), as the exhaustive search would
/// see it; without it the climb ends on a cell no neighbour beats. Returns the peak and the
/// number of poses scored that were not in `cache` (the level's scores, shared between the
/// climbs of one search).
fn climb(
    ev: &Evaluator,
    level: u32,
    start: u64,
    max_iter: usize,
    cache: &mut HashMap<u64, Scored>,
    wide: bool,
) -> (Scored, u64) {
    let f = 1i64 << level;
    let g = ev.grid;
    let mut evals = 0u64;
    // Scores of `idxs`, the ones not seen yet scored in parallel (the climb itself is sequential,
    // and often only one or two candidates climb, so the parallelism has to be inside a step).
    let mut score = |idxs: &[u64]| -> Vec<Scored> {
        let mut missing: Vec<u64> = idxs
            .iter()
            .copied()
            .filter(|i| !cache.contains_key(i))
            .collect();
        missing.sort_unstable();
        missing.dedup();
        evals += missing.len() as u64;
        for s in ev.score_cells(level, &missing) {
            cache.insert(s.idx, s);
        }
        idxs.iter().map(|i| cache[i]).collect()
    };
    let mut cur = score(&[start])[0];
    for _ in 0..max_iter {
        let nb: Vec<u64> = neighbours(&g, &g.cell(cur.idx), f)
            .iter()
            .map(|n| g.index(n))
            .collect();
        match best_of(&score(&nb)) {
            Some(b) if better(&b, &cur) => cur = b,
            _ if !wide => break,
            _ => {
                let wide = window_r(&g, &g.cell(cur.idx), f, WIDE_LOOK);
                match best_of(&score(&wide)) {
                    Some(b) if better(&b, &cur) => cur = b,
                    _ => break,
                }
            }
        }
    }
    (cur, evals)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Camera, CameraModel};
    use crate::localize::mi::kernel::*;
    use crate::localize::mi::objective::*;
    use crate::localize::mi::points::*;
    use crate::localize::mi::space::*;
    use crate::localize::mi::*;
    use nalgebra::Point3;
    use nalgebra::Vector3;

    fn axis_ground_hit(p: &CamFromMap, ground_z: f64) -> Point3<f64> {
        let c = p.center();
        let d = p.rotation.inverse() * Vector3::z();
        c + d * ((ground_z - c.z) / d.z)
    }

    /// The erosion from the distance map is the square-window erosion, image edges included,
    /// and the eroded mask's own distance map is the one returned.
    #[test]
    fn erosion_by_distance_is_the_square_window_erosion() {
        let (w, h) = (37, 23);
        let mask: Vec<u8> = (0..w * h)
            .map(|i| {
                let (u, v) = ((i % w) as i64, (i / w) as i64);
                let hole = (u - 20).pow(2) + (v - 9).pow(2) < 10 || (u * 7 + v * 13) % 41 == 0;
                if hole {
                    0
                } else {
                    255
                }
            })
            .collect();
        for r in 0..4usize {
            let (eroded, dist) = erode_with_distance(&mask, w, h, r);
            for v in 0..h {
                for u in 0..w {
                    let inside = u >= r && v >= r && u + r < w && v + r < h;
                    let window = inside
                        && (v - r..=v + r).all(|y| (u - r..=u + r).all(|x| mask[y * w + x] != 0));
                    assert_eq!(eroded[v * w + u] != 0, window, "r {r} at ({u}, {v})");
                }
            }
            assert_eq!(dist, chessboard_distance(&eroded, w, h), "r {r}");
        }
    }

    /// Number of [`pattern_mask`]s.
    const PATTERNS: u64 = 5;

    /// Test masks of a `w`×`h` image: all valid, a centred disc, a lattice of specks, a larger
    /// disc with sparser specks, a larger disc with the specks (holes next to the disc's edge).
    fn pattern_mask(w: usize, h: usize, pattern: u64) -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (u, v) = ((i % w) as i64, (i / w) as i64);
                let r2 = (u - w as i64 / 2).pow(2) + (v - h as i64 / 2).pow(2);
                let big = r2 < (w.max(h) as i64).pow(2) / 5;
                let valid = match pattern {
                    0 => true,
                    1 => r2 < (w.min(h) as i64 / 2).pow(2),
                    2 => (u * 7 + v * 13) % 11 != 0,
                    3 => big && (u * 3 + v * 5) % 29 != 0,
                    _ => big && (u * 7 + v * 13) % 11 != 0,
                };
                if valid {
                    255
                } else {
                    0
                }
            })
            .collect()
    }

    /// The 3×3 masked blur written out per neighbour: what [`blur3`] must equal.
    fn blur3_reference(gray: &[u8], mask: &[u8], w: usize, h: usize) -> Vec<u8> {
        const K: [u32; 3] = [1, 2, 1];
        let mut out = gray.to_vec();
        for v in 0..h {
            for u in 0..w {
                if mask[v * w + u] == 0 {
                    continue;
                }
                let (mut acc, mut wsum) = (0u32, 0u32);
                for (j, kj) in K.iter().enumerate() {
                    for (i, ki) in K.iter().enumerate() {
                        let (x, y) = (u + i, v + j);
                        if x < 1 || y < 1 || x > w || y > h || mask[(y - 1) * w + x - 1] == 0 {
                            continue;
                        }
                        acc += kj * ki * gray[(y - 1) * w + x - 1] as u32;
                        wsum += kj * ki;
                    }
                }
                out[v * w + u] = ((acc + wsum / 2) / wsum.max(1)) as u8;
            }
        }
        out
    }

    #[test]
    fn blur3_equals_the_per_neighbour_blur() {
        for (w, h) in [
            (1, 1),
            (1, 6),
            (6, 1),
            (2, 2),
            (3, 3),
            (5, 8),
            (64, 41),
            (131, 97),
        ] {
            for pattern in 0..PATTERNS {
                let gray: Vec<u8> = (0..w * h)
                    .map(|i| ((i as u64 * 2_654_435_761) >> 7) as u8)
                    .collect();
                let mask = pattern_mask(w, h, pattern);
                assert_eq!(
                    blur3(&gray, &mask, w, h),
                    blur3_reference(&gray, &mask, w, h),
                    "{w}×{h} pattern {pattern}"
                );
            }
        }
    }

    /// The chamfer transform written out with a bounds test per neighbour: what
    /// [`chessboard_distance`] must equal.
    pub(super) fn chessboard_distance_reference(mask: &[u8], w: usize, h: usize) -> Vec<u16> {
        let mut d = vec![0u16; w * h];
        let at = |d: &[u16], u: isize, v: isize| -> u16 {
            if u < 0 || v < 0 || u >= w as isize || v >= h as isize {
                0
            } else {
                d[v as usize * w + u as usize]
            }
        };
        for v in 0..h as isize {
            for u in 0..w as isize {
                let i = v as usize * w + u as usize;
                if mask[i] == 0 {
                    continue;
                }
                let m = [(-1, -1), (0, -1), (1, -1), (-1, 0)]
                    .iter()
                    .map(|&(du, dv)| at(&d, u + du, v + dv))
                    .min()
                    .unwrap_or(0);
                d[i] = m.saturating_add(1);
            }
        }
        for v in (0..h as isize).rev() {
            for u in (0..w as isize).rev() {
                let i = v as usize * w + u as usize;
                if d[i] == 0 {
                    continue;
                }
                let m = [(1, 1), (0, 1), (-1, 1), (1, 0)]
                    .iter()
                    .map(|&(du, dv)| at(&d, u + du, v + dv))
                    .min()
                    .unwrap_or(0);
                d[i] = d[i].min(m.saturating_add(1));
            }
        }
        d
    }

    #[test]
    fn chessboard_distance_equals_the_reference_transform() {
        // Discs, holes, a lattice of specks and the degenerate sizes (every pixel on the border).
        for (w, h) in [
            (1, 1),
            (1, 7),
            (7, 1),
            (2, 5),
            (3, 3),
            (4, 9),
            (41, 23),
            (120, 77),
        ] {
            for pattern in 0..PATTERNS {
                let mask = pattern_mask(w, h, pattern);
                assert_eq!(
                    chessboard_distance(&mask, w, h),
                    chessboard_distance_reference(&mask, w, h),
                    "{w}×{h} pattern {pattern}"
                );
            }
        }
    }

    /// A 185° Mei camera 6 m over textured ground, its rendered view and ground points, a start
    /// a few centimetres and 0.6° off, and a 4-DoF box of 7605 cells around it.
    fn small_scene() -> (
        Camera,
        Vec<u8>,
        Vec<u8>,
        Vec<GroundPoint>,
        CamFromMap,
        SearchConfig,
    ) {
        use crate::localize::synth::{ground_points, render, Texture};
        let cam = Camera::Mei(crate::camera::Mei {
            width: 480,
            height: 400,
            fx: 220.0,
            fy: 220.4,
            cx: 241.0,
            cy: 199.0,
            skew: 0.0,
            xi: 1.1,
            k1: -0.25,
            k2: 0.08,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        });
        let tex = Texture::new(11);
        let truth = CamFromMap::from_center_ypr(&Point3::new(5.0, 8.0, 6.0), 0.7, 0.0, 0.0);
        let (gray, mask) = render(&tex, &cam, &truth, 0.0, 0.03, 4);
        let pts = ground_points(&tex, (5.0, 8.0), 14.0, 0.25, 0.0, 0.05, 5);
        let start = CamFromMap::from_center_ypr(&Point3::new(5.1, 7.95, 6.05), 0.71, 0.0, 0.0);
        let cfg = SearchConfig {
            spec: SearchSpec {
                x: AxisRange {
                    half: 0.3,
                    step: 0.05,
                },
                y: AxisRange {
                    half: 0.3,
                    step: 0.05,
                },
                z: AxisRange {
                    half: 0.1,
                    step: 0.05,
                },
                yaw: AxisRange {
                    half: 1.0,
                    step: 0.25,
                },
                ..SearchSpec::default()
            },
            ..SearchConfig::default()
        };
        (cam, gray, mask, pts, start, cfg)
    }

    /// The evaluator's shortcuts give the plain evaluator's numbers bit for bit: one built from
    /// a shared image preparation (after another evaluator on the same frame filled the cache),
    /// the split parallel score and the one-pass leave-one-group-out histogram. A thinned
    /// evaluator keeps every `stride`-th point.
    #[test]
    fn shared_preparation_and_split_scores_equal_the_plain_evaluator() {
        let (cam, gray, mask, pts, start, cfg) = small_scene();
        let views = [View {
            gray: &gray,
            mask: &mask,
            points: &pts,
        }];
        let plain = Evaluator::pooled(&cam, &views, &start, &cfg, 2).unwrap();
        let cache = ImageCache::default();
        // A level-0-only evaluator of another box fills the cache first; the pyramid is then
        // built on demand for the second.
        let narrow = SearchConfig {
            spec: SearchSpec {
                x: AxisRange {
                    half: 0.1,
                    step: 0.05,
                },
                ..cfg.spec
            },
            ..cfg
        };
        let first = Evaluator::pooled_cached(&cam, &views, &start, &narrow, 0, &cache).unwrap();
        let shared = Evaluator::pooled_cached(&cam, &views, &start, &cfg, 2, &cache).unwrap();
        assert_eq!(cache.lock().len(), 1, "one preparation for both evaluators");
        assert_eq!(
            first.n_points,
            Evaluator::pooled(&cam, &views, &start, &narrow, 0)
                .unwrap()
                .n_points
        );
        assert_eq!(shared.n_points, plain.n_points);
        let mut sc = Scratch::default();
        let offsets = [0.02, -0.03, 0.01, 0.1, 0.2, -0.1];
        for level in 0..=2 {
            for idx in [0, 7, plain.grid().cells() / 2] {
                let cell = plain.grid().cell(idx);
                assert_eq!(
                    plain.histogram(level, &cell, &mut sc).counts,
                    shared.histogram(level, &cell, &mut sc).counts,
                    "level {level} cell {idx}"
                );
            }
        }
        let whole = plain.value_at(0, &offsets, &mut sc);
        let folds = plain.folds(5);
        assert_eq!(plain.value_at_split(&folds, &offsets), whole);
        let thin = plain.thinned(4);
        assert_eq!(thin.n_points, plain.n_points.div_ceil(4));
        assert_eq!(thin.view_points, vec![(pts.len(), thin.n_points)]);
        let n_thin = thin.value_at(0, &offsets, &mut sc).n;
        assert!(n_thin > 0 && n_thin <= thin.n_points as u64, "{n_thin}");
    }

    /// A search whose finest level scores a quarter of the points ends on a local maximum of the
    /// full estimator next to the full search's cell, ranks its peaks by their scores on all
    /// points (so the quality sees the full estimator), and scores fewer point-evaluations; with
    /// no thinning it is the search.
    /// Per-pair pooling scores each view on its own histogram: two views of one frame give the
    /// point-weighted mean of the single views' statistics, and the split path agrees with it;
    /// on one view it is the joint score bit for bit.
    #[test]
    fn per_pair_pooling_weights_each_views_own_statistics() {
        use crate::localize::mi::Pooling;
        let (cam, gray, mask, pts, start, cfg) = small_scene();
        let per_pair = SearchConfig {
            mi: crate::localize::mi::MiConfig {
                pooling: Pooling::PerPair,
                ..cfg.mi
            },
            ..cfg
        };
        // The frame darkened as another time of day would: same texture, other gray levels.
        let dim: Vec<u8> = gray.iter().map(|&g| 20 + g / 3).collect();
        let (a, b) = pts.split_at(pts.len() / 3);
        let views = [
            View {
                gray: &gray,
                mask: &mask,
                points: a,
            },
            View {
                gray: &dim,
                mask: &mask,
                points: b,
            },
        ];
        let offsets = [0.02, -0.03, 0.01, 0.1, 0.0, 0.0];
        let mut sc = Scratch::default();
        let single = |v: &View<'_>| {
            let ev = Evaluator::pooled(&cam, std::slice::from_ref(v), &start, &cfg, 0).unwrap();
            (
                ev.n_points as f64,
                ev.value_at(0, &offsets, &mut Scratch::default()),
            )
        };
        let (na, va) = single(&views[0]);
        let (nb, vb) = single(&views[1]);
        let ev = Evaluator::pooled(&cam, &views, &start, &per_pair, 0).unwrap();
        assert_eq!(ev.slots(), 2);
        let v = ev.value_at(0, &offsets, &mut sc);
        let want = (na * va.mi + nb * vb.mi) / (na + nb);
        assert!((v.mi - want).abs() < 1e-12, "{} vs {want}", v.mi);
        assert_eq!(v.n, va.n + vb.n);
        let joint = Evaluator::pooled(&cam, &views, &start, &cfg, 0).unwrap();
        assert_eq!(joint.slots(), 1);
        assert_ne!(joint.value_at(0, &offsets, &mut sc).mi, v.mi);
        let folds = ev.folds(4);
        assert_eq!(ev.value_at_split(&folds, &offsets), v);
        let one = Evaluator::pooled(&cam, &views[..1], &start, &per_pair, 0).unwrap();
        assert_eq!(one.value_at(0, &offsets, &mut sc), va);
        let one_joint = Evaluator::pooled(&cam, &views[..1], &start, &cfg, 0).unwrap();
        assert_eq!(one.score(0, 3, &mut sc), one_joint.score(0, 3, &mut sc));
    }

    #[test]
    fn a_thinned_finest_level_ends_next_to_the_full_search_scored_on_all_points() {
        let (cam, gray, mask, pts, start, cfg) = small_scene();
        let views = [View {
            gray: &gray,
            mask: &mask,
            points: &pts,
        }];
        let cfg = SearchConfig {
            coarse_min_points: 1000,
            ..cfg
        };
        let ev = Evaluator::pooled(&cam, &views, &start, &cfg, MAX_LEVEL).unwrap();
        assert!(ev.n_points >= 4 * cfg.coarse_min_points, "{}", ev.n_points);
        let full = search(&ev, &cfg);
        let same = search_thinned(&ev, &cfg, 1);
        assert_eq!(same.best, full.best);
        assert_eq!(same.other_peaks, full.other_peaks);
        assert_eq!(same.stats, full.stats);
        let thin = search_thinned(&ev, &cfg, 4);
        assert!(thin.stats.coarsest_level > 0);
        let rescored = |s: &Scored| ev.score_cells(0, &[s.idx])[0];
        assert_eq!(
            thin.best,
            rescored(&thin.best),
            "the answer's score is on all points"
        );
        for p in &thin.other_peaks {
            assert_eq!(*p, rescored(p));
            assert!(p.score <= thin.best.score);
        }
        // A local maximum of the full estimator, as the unthinned search's answer is.
        let around: Vec<u64> = neighbours(ev.grid(), &ev.grid().cell(thin.best.idx), 1)
            .iter()
            .map(|c| ev.grid().index(c))
            .collect();
        for n in ev.score_cells(0, &around) {
            assert!(better(&thin.best, &n), "{n:?} beats {:?}", thin.best);
        }
        let (a, b) = (ev.grid().cell(thin.best.idx), ev.grid().cell(full.best.idx));
        for i in 0..4 {
            assert!((a[i] - b[i]).abs() <= 1, "axis {i}: {a:?} vs {b:?}");
        }
        assert!(
            thin.stats.point_evaluations < full.stats.point_evaluations * 3 / 4,
            "{} vs {}",
            thin.stats.point_evaluations,
            full.stats.point_evaluations
        );
    }

    #[test]
    fn a_search_to_level_one_ends_on_a_local_maximum_next_to_the_full_search() {
        let (cam, gray, mask, pts, start, cfg) = small_scene();
        let views = [View {
            gray: &gray,
            mask: &mask,
            points: &pts,
        }];
        let ev = Evaluator::pooled(&cam, &views, &start, &cfg, MAX_LEVEL).unwrap();
        let full = search(&ev, &cfg);
        assert!(full.stats.coarsest_level >= 1);
        // Level 0 is the plain search, bit for bit.
        let zero = search_to(&ev, &cfg, 1, 0);
        assert_eq!(
            (zero.best, &zero.other_peaks, zero.stats),
            (full.best, &full.other_peaks, full.stats)
        );
        let basin = search_to(&ev, &cfg, 1, 1);
        let g = ev.grid();
        let cell = g.cell(basin.best.idx);
        // Scored at level 0 on all points, as are the other peaks (worse than it), and a local
        // maximum of that estimator on the finest grid.
        let rescored = |s: &Scored| ev.score_cells(0, &[s.idx])[0];
        assert_eq!(basin.best, rescored(&basin.best));
        for p in &basin.other_peaks {
            assert_eq!(*p, rescored(p));
            assert!(p.score <= basin.best.score);
        }
        let around: Vec<u64> = neighbours(g, &cell, 1).iter().map(|c| g.index(c)).collect();
        for n in ev.score_cells(0, &around) {
            assert!(better(&basin.best, &n), "{n:?} beats {:?}", basin.best);
        }
        // In the full search's basin: within one level-1 step on every axis.
        let b = g.cell(full.best.idx);
        for i in 0..4 {
            assert!((cell[i] - b[i]).abs() <= 2, "axis {i}: {cell:?} vs {b:?}");
        }
        assert!(
            basin.stats.point_evaluations < full.stats.point_evaluations * 3 / 4,
            "{} vs {}",
            basin.stats.point_evaluations,
            full.stats.point_evaluations
        );
        // A level beyond the survey's is searched to level 0.
        let deep = search_to(&ev, &cfg, 1, MAX_LEVEL + 1);
        assert_eq!(deep.best, full.best);
    }

    /// `surely_visible` may only leave points to the lattice test, never keep one that some pose
    /// of the box loses: checked pose by pose with the kernel's own visibility, on a 185° Mei and
    /// a 185° equidistant camera, for small 6-DoF boxes and wide 4-DoF ones.
    #[test]
    fn surely_visible_points_are_seen_from_every_lattice_pose() {
        let mei = Camera::Mei(crate::camera::Mei {
            width: 640,
            height: 512,
            fx: 300.0,
            fy: 300.5,
            cx: 321.0,
            cy: 255.0,
            skew: 0.0,
            xi: 1.2,
            k1: -0.27,
            k2: 0.09,
            p1: -4.0e-5,
            p2: 1.4e-4,
            fov_deg: Some(185.0),
        });
        let equidistant = crate::localize::mi::kernel::selftest::test_camera_equidistant(
            (640, 512),
            150.0,
            (321.0, 255.0),
        );
        for cam in [mei, equidistant] {
            surely_visible_case(&cam);
        }
    }

    /// One camera of [`surely_visible_points_are_seen_from_every_lattice_pose`].
    fn surely_visible_case(cam: &Camera) {
        use crate::localize::mi::kernel::visible;
        use crate::localize::synth::{ground_points, Texture};
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let (mask, dist) = erode_with_distance(&cam.valid_mask(), w, h, 3);
        let gray: Vec<u8> = (0..w * h).map(|i| (i * 31 % 251) as u8).collect();
        let lut = bin_lut(crate::localize::mi::Binning::Uniform, 32, &[0; 256]);
        let img = BinnedImage::new(w, h, &gray, &mask, &lut, 32);
        let origin = [10.0, 20.0, 6.0];
        let tex = Texture::new(5);
        let pts = PreparedPoints::new(
            &ground_points(&tex, (10.0, 20.0), 30.0, 0.3, 0.0, 3.0, 2),
            origin,
            &lut,
        );
        let nadir = CamFromMap::from_center_ypr(&Point3::new(10.2, 19.9, 6.0), 0.4, 0.03, -0.02);
        // Tilted 70° from nadir: its axis still meets the ground, near where the pivot rule
        // switches between tilting about the ground and about the centre.
        let tilted = CamFromMap::from_center_ypr(&Point3::new(10.2, 19.9, 6.0), 0.4, 1.22, 0.0);
        let fc = FastCamera::new(cam, 0);
        // (pose, box, least share of the kept points it must settle): the 6-DoF boxes' 729-pose
        // lattices are what the shortcut is for; a wide 4-DoF box moves most pixels too far.
        for (init, half, settles) in [
            (nadir, [0.15, 0.15, 0.15, 0.5, 1.0, 1.0], 0.7),
            (nadir, [0.3, 0.3, 0.3, 0.9, 3.0, 3.0], 0.3),
            (nadir, [1.0, 1.0, 0.5, 3.0, 0.0, 0.0], 0.0),
            (tilted, [0.15, 0.15, 0.15, 0.5, 1.0, 1.0], 0.3),
            (tilted, [0.5, 0.5, 0.3, 2.0, 5.0, 5.0], 0.0),
        ] {
            let axes: Vec<usize> = (0..6).filter(|&i| half[i] > 0.0).collect();
            let at = |o: [f64; 6]| pose_at_pivot(&init, &o, Some(6.0));
            let mut lattice = vec![[0.0f64; 6]];
            for &i in &axes {
                lattice = lattice
                    .into_iter()
                    .flat_map(|c| {
                        [-half[i], 0.0, half[i]].map(|v| {
                            let mut d = c;
                            d[i] = v;
                            d
                        })
                    })
                    .collect();
            }
            let extremes: Vec<CamFromMap> = axes
                .iter()
                .flat_map(|&i| {
                    [-half[i], half[i]].map(|v| {
                        let mut o = [0.0; 6];
                        o[i] = v;
                        at(o)
                    })
                })
                .collect();
            let sure = surely_visible(&fc, &pts, origin, &at([0.0; 6]), &extremes, &dist, w);
            let mut seen = vec![true; pts.len()];
            let mut one = vec![false; pts.len()];
            for o in &lattice {
                visible(
                    &pts,
                    &PoseF32::new(&at(*o), origin),
                    &fc,
                    &img,
                    32,
                    &mut one,
                );
                seen.iter_mut().zip(&one).for_each(|(s, v)| *s &= v);
            }
            let n_sure = sure.iter().filter(|&&s| s).count();
            assert!(
                sure.iter().zip(&seen).all(|(s, v)| !s || *v),
                "{cam:?} {half:?}: a surely visible point is lost by some pose"
            );
            // It must also settle enough of what the lattice keeps, or it saves nothing.
            let n_seen = seen.iter().filter(|&&s| s).count();
            assert!(
                n_sure as f64 >= settles * n_seen as f64,
                "{cam:?} {half:?}: {n_sure} sure of {n_seen} seen"
            );
        }
    }

    #[test]
    fn tilt_about_the_ground_pivot_keeps_the_axis_ground_point() {
        let init = CamFromMap::from_center_ypr(&Point3::new(10.0, -4.0, 8.0), 0.7, 0.02, -0.01);
        let offsets = [0.0, 0.0, 0.0, 0.0, 1.2, -0.8];
        let before = axis_ground_hit(&init, 0.0);
        let p = pose_at_pivot(&init, &offsets, Some(8.0));
        let after = axis_ground_hit(&p, 0.0);
        assert!((after - before).norm() < 1e-9, "{before} → {after}");
        assert!((p.center().z - 8.0).abs() < 1e-12);
        // The tilt itself is the one the centre pivot applies.
        let q = pose_at(&init, &offsets);
        assert!(crate::pose::rotation_angle_between(&p.rotation, &q.rotation) < 1e-12);
        // About the centre the ground point moves by ≈ h·tan(tilt).
        let moved = (axis_ground_hit(&q, 0.0) - before).norm();
        assert!(moved > 8.0 * 1.0f64.to_radians(), "{moved}");
    }

    #[test]
    fn a_near_horizontal_axis_tilts_about_the_centre() {
        // A forward-looking camera (pitched 80° up from nadir): its axis meets no near ground.
        let init =
            CamFromMap::from_center_ypr(&Point3::new(0.0, 0.0, 2.0), 0.0, 80f64.to_radians(), 0.0);
        let offsets = [0.0, 0.0, 0.0, 0.0, 0.5, 0.5];
        let p = pose_at_pivot(&init, &offsets, Some(2.0));
        assert!((p.center() - init.center()).norm() < 1e-12);
    }

    #[test]
    fn held_axes_are_allowed_in_code_but_not_on_the_command_line() {
        let held = AxisRange {
            half: 0.0,
            step: 0.02,
        };
        let spec = SearchSpec {
            x: held,
            ..SearchSpec::default()
        };
        assert!(spec.validate().is_ok());
        assert_eq!(spec.grid().m[0], 0);
        assert!("x=0:0.02".parse::<SearchSpec>().is_err());
        let all_held = SearchSpec {
            x: held,
            y: held,
            z: held,
            yaw: held,
            ..SearchSpec::default()
        };
        let err = all_held.validate().unwrap_err().to_string();
        assert!(err.contains("nothing to search"), "{err}");
    }
}
