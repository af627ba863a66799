//! Checkerboard corner detection on fisheye images (`calibrate --images`), pure: grey pixels in,
//! labelled corners (or the reason there are none) out. docs/calibrate.md, "Corner detection".
//!
//! 1. **X-corner response.** On the image smoothed with σ = [`SIGMA`], the Hessian's
//!    `Ixy² − Ixx·Iyy` is large and positive at a saddle (where four squares meet), about zero
//!    along a straight edge and negative on blobs; local maxima above a fraction of the strongest
//!    are candidates. The response is local, so it does not care how the lens bends the board.
//! 2. **Ring test.** Around each candidate, a circle of samples must cross the mean grey exactly four
//!    times with enough contrast, and opposite sectors must match: that rejects T-junctions, edges and
//!    texture. The four crossings are the directions of the board's edges at the corner — and so of
//!    its four neighbours.
//! 3. **Sub-pixel refinement.** Every gradient near an ideal corner is orthogonal to the vector
//!    from the corner to where it is measured; the point minimising the weighted sum of those
//!    squared dot products is solved for in closed form and the window re-centred until it moves
//!    less than [`REFINE_TOL`] px. A blurred X-junction is point-symmetric about the corner, so the
//!    estimate is unbiased up to the lines' curvature across the small window.
//! 4. **Grid growing.** From a seed corner, the neighbours along its edge directions give the
//!    first quad; the grid then grows cell by cell, each empty cell predicted from filled ones by
//!    quadratic (or linear) extrapolation along a row or column and by completing parallelograms,
//!    and taking the nearest unused candidate within [`SEARCH_FRAC`] of the local spacing.
//!    Predicting from immediate neighbours only is what tolerates the strong distortion.
//! 5. **Labelling.** A grid of the pattern's size (either orientation) is a full board. A smaller
//!    grid — the board cut by the image or the field of view — is kept when it has at least
//!    [`MIN_PARTIAL`] corners spanning at least 3 in each direction: a square grid's labels need no
//!    absolute origin, since each view has its own pose. A grid larger than the pattern is refused.

use super::error::{DetectError, GridProblem};
use crate::imageops::gaussian_blur;
use rayon::prelude::*;
use std::collections::HashMap;
use std::f64::consts::{PI, TAU};

/// Smoothing before the response, px (σ).
pub const SIGMA: f64 = 1.5;
/// Candidates below this fraction of the strongest response are ignored.
const RESPONSE_FRAC: f32 = 0.02;
/// Non-maximum suppression radius, px.
const NMS_RADIUS: isize = 3;
/// Ring radii tried in turn (px): the larger is more robust to noise, the smaller fits squares
/// compressed by the lens.
const RING_RADII: [f64; 2] = [5.0, 3.5];
/// Samples on the ring.
const RING_SAMPLES: usize = 48;
/// Smallest grey difference across the ring (image in 0–1).
const MIN_CONTRAST: f32 = 0.08;
/// Opposite sectors may differ by at most this fraction of the contrast.
const SECTOR_MATCH: f32 = 0.45;
/// σ of the refinement's Gaussian weight, px (the window's half-width is 2σ).
const REFINE_SIGMA: f64 = 2.5;
/// Smoothing of the image the final refinement reads, px (σ).
const SIGMA_FINE: f64 = 0.7;
/// The final refinement's weight σ as a fraction of the distance to the nearest grid neighbour …
const FINE_WINDOW_FRAC: f64 = 0.2;
/// … but at least this, px.
const FINE_SIGMA_MIN: f64 = 1.2;
/// Largest [`asymmetry`] of a kept corner (rendered boards: median 0.0014, 99th percentile
/// 0.02; corners against the image circle's rim 0.35–0.46).
const MAX_ASYMMETRY: f64 = 0.1;
/// Refinement stops when the estimate moves less than this, px.
const REFINE_TOL: f64 = 0.002;
/// A refined corner may move at most this far from its candidate, px.
const REFINE_MAX_SHIFT: f64 = 2.5;
/// A predicted grid cell takes the nearest candidate within this fraction of the local spacing.
const SEARCH_FRAC: f64 = 0.35;
/// A seed's edge direction and the direction to its neighbour may differ by this much, radians.
const SEED_ANGLE_TOL: f64 = 0.35;
/// Seeds tried, strongest response first.
const MAX_SEEDS: usize = 40;
/// Fewest corners of a partial board.
pub const MIN_PARTIAL: usize = 12;

/// A refined X-corner with the directions of its four edges.
#[derive(Debug, Clone, Copy)]
struct Corner {
    p: [f64; 2],
    response: f32,
    /// Edge directions, radians, increasing around the ring.
    edges: [f64; 4],
}

/// The board found in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    /// Board-frame points (metres), row by row.
    pub object: Vec<[f64; 3]>,
    /// Their pixels (OpenCV convention).
    pub image: Vec<[f64; 2]>,
    /// Whether every corner of the pattern was found.
    pub full: bool,
}

/// A grey image in 0–1 with bilinear sampling.
struct Plane<'a> {
    w: usize,
    h: usize,
    v: &'a [f32],
}

impl Plane<'_> {
    fn at(&self, x: isize, y: isize) -> f32 {
        let x = x.clamp(0, self.w as isize - 1) as usize;
        let y = y.clamp(0, self.h as isize - 1) as usize;
        self.v[y * self.w + x]
    }

    fn bilinear(&self, x: f64, y: f64) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as isize, y0 as isize);
        let a = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let b = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        a * (1.0 - fy) + b * fy
    }
}

/// Find a `cols × rows` (inner corners) board with squares of `square` metres in an 8-bit grey
/// image; `Err` says why there is none.
pub fn detect(
    pixels: &[u8],
    width: u32,
    height: u32,
    cols: usize,
    rows: usize,
    square: f64,
) -> Result<Found, DetectError> {
    let (w, h) = (width as usize, height as usize);
    if pixels.len() != w * h || w < 16 || h < 16 {
        return Err(DetectError::TooSmall { width, height });
    }
    let mut s: Vec<f32> = pixels.iter().map(|&p| p as f32 / 255.0).collect();
    gaussian_blur(&mut s, w, h, SIGMA);
    let plane = Plane { w, h, v: &s };
    let cands = candidates(&plane);
    if cands.is_empty() {
        return Err(DetectError::NoCandidates);
    }
    let corners: Vec<Corner> = cands
        .par_iter()
        .filter_map(|&(x, y, r)| {
            let edges = RING_RADII
                .iter()
                .find_map(|&rad| ring_edges(&plane, x as f64, y as f64, rad))?;
            let p = refine(&plane, [x as f64, y as f64], REFINE_SIGMA, REFINE_MAX_SHIFT)?;
            Some(Corner {
                p,
                response: r,
                edges,
            })
        })
        .collect();
    if corners.len() < 4 {
        return Err(DetectError::TooFewCorners {
            found: corners.len(),
            needed: cols * rows,
        });
    }
    let mut order: Vec<usize> = (0..corners.len()).collect();
    order.sort_by(|a, b| corners[*b].response.total_cmp(&corners[*a].response));
    let mut best: Option<HashMap<(i32, i32), usize>> = None;
    let mut why = GridProblem::NoSeed;
    for &seed in order.iter().take(MAX_SEEDS) {
        let Some(grid) = grow(&corners, seed) else {
            continue;
        };
        let (nx, ny) = dims(&grid);
        let fits = (nx <= cols && ny <= rows) || (nx <= rows && ny <= cols);
        if !fits {
            why = GridProblem::TooLarge { nx, ny, cols, rows };
            continue;
        }
        if grid.len() == cols * rows {
            best = Some(grid);
            break;
        }
        if best.as_ref().is_none_or(|b| grid.len() > b.len()) {
            why = GridProblem::Partial {
                found: grid.len(),
                needed: cols * rows,
            };
            best = Some(grid);
        }
    }
    let grid = best.ok_or_else(|| DetectError::NoGrid {
        why: why.clone(),
        partial_min: None,
    })?;
    // Final refinement on the lightly smoothed image, the window fitted to the local spacing: the
    // detection window would reach the next squares' far edges where the lens compresses the board.
    let mut fine: Vec<f32> = pixels.iter().map(|&p| p as f32 / 255.0).collect();
    gaussian_blur(&mut fine, w, h, SIGMA_FINE);
    let fine = Plane { w, h, v: &fine };
    let mut corners = corners;
    let refined: Vec<(usize, [f64; 2])> = grid
        .par_iter()
        .filter_map(|(&(i, j), &k)| {
            let spacing = [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .filter_map(|(di, dj)| grid.get(&(i + di, j + dj)))
                .map(|&n| {
                    let (a, b) = (corners[k].p, corners[n].p);
                    (a[0] - b[0]).hypot(a[1] - b[1])
                })
                .fold(f64::MAX, f64::min);
            let sigma = (FINE_WINDOW_FRAC * spacing).clamp(FINE_SIGMA_MIN, REFINE_SIGMA);
            let p = refine(&fine, corners[k].p, sigma, 1.0)?;
            let asym = asymmetry(&fine, p, (2.0 * sigma).ceil());
            (asym <= MAX_ASYMMETRY).then_some((k, p))
        })
        .collect();
    let kept: std::collections::HashSet<usize> = refined.iter().map(|(k, _)| *k).collect();
    for (k, p) in refined {
        corners[k].p = p;
    }
    let grid: HashMap<(i32, i32), usize> =
        grid.into_iter().filter(|(_, k)| kept.contains(k)).collect();
    let (nx, ny) = dims(&grid);
    let full = grid.len() == cols * rows;
    if !full && (grid.len() < MIN_PARTIAL || nx < 3 || ny < 3) {
        return Err(DetectError::NoGrid {
            why,
            partial_min: Some(MIN_PARTIAL),
        });
    }
    Ok(label(&grid, &corners, cols, rows, square, full))
}

/// Local maxima of the saddle response, strongest first: (x, y, response).
fn candidates(p: &Plane) -> Vec<(usize, usize, f32)> {
    let (w, h) = (p.w, p.h);
    let resp: Vec<f32> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).map(move |x| {
                if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
                    return 0.0;
                }
                let v = |dx: isize, dy: isize| {
                    p.v[(y as isize + dy) as usize * w + (x as isize + dx) as usize]
                };
                let c = v(0, 0);
                let ixx = v(1, 0) - 2.0 * c + v(-1, 0);
                let iyy = v(0, 1) - 2.0 * c + v(0, -1);
                let ixy = (v(1, 1) - v(1, -1) - v(-1, 1) + v(-1, -1)) * 0.25;
                (ixy * ixy - ixx * iyy).max(0.0)
            })
        })
        .collect();
    let max = resp.par_iter().cloned().reduce(|| 0.0, f32::max);
    if !(max > 0.0) {
        return Vec::new();
    }
    let thr = RESPONSE_FRAC * max;
    // Keep clear of the border: the refinement window and the ring must lie inside.
    let margin = ((2.0 * REFINE_SIGMA).ceil() as usize + 2).max(RING_RADII[0].ceil() as usize + 2);
    let mut out: Vec<(usize, usize, f32)> = (margin..h.saturating_sub(margin))
        .into_par_iter()
        .flat_map_iter(|y| {
            let resp = &resp;
            (margin..w.saturating_sub(margin)).filter_map(move |x| {
                let r = resp[y * w + x];
                if r < thr {
                    return None;
                }
                for dy in -NMS_RADIUS..=NMS_RADIUS {
                    for dx in -NMS_RADIUS..=NMS_RADIUS {
                        let (xx, yy) = ((x as isize + dx) as usize, (y as isize + dy) as usize);
                        let o = resp[yy * w + xx];
                        // Ties go to the first in raster order.
                        if o > r || (o == r && (dy < 0 || (dy == 0 && dx < 0))) {
                            return None;
                        }
                    }
                }
                Some((x, y, r))
            })
        })
        .collect();
    out.sort_by(|a, b| b.2.total_cmp(&a.2));
    out
}

/// The four edge directions of an X-corner seen on a ring of radius `rad`, or `None` if the ring
/// does not show one.
fn ring_edges(p: &Plane, x: f64, y: f64, rad: f64) -> Option<[f64; 4]> {
    let n = RING_SAMPLES;
    let vals: Vec<f32> = (0..n)
        .map(|k| {
            let a = TAU * k as f64 / n as f64;
            p.bilinear(x + rad * a.cos(), y + rad * a.sin())
        })
        .collect();
    let (lo, hi) = vals
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    if hi - lo < MIN_CONTRAST {
        return None;
    }
    let mid = (lo + hi) / 2.0;
    let mut crossings: Vec<f64> = Vec::with_capacity(4);
    for k in 0..n {
        let (a, b) = (vals[k] - mid, vals[(k + 1) % n] - mid);
        if (a < 0.0) != (b < 0.0) {
            if crossings.len() == 4 {
                return None;
            }
            let f = (a / (a - b)) as f64;
            crossings.push(TAU * (k as f64 + f) / n as f64);
        }
    }
    if crossings.len() != 4 {
        return None;
    }
    // Sector means; each sector must span a fair angle, and opposite ones match.
    let mut sums = [0.0f32; 4];
    let mut counts = [0usize; 4];
    for (k, v) in vals.iter().enumerate() {
        let a = TAU * k as f64 / n as f64;
        let sector = crossings.iter().filter(|&&c| c <= a).count() % 4;
        sums[sector] += v;
        counts[sector] += 1;
    }
    if counts.iter().any(|&c| c < 3) {
        return None;
    }
    let m: Vec<f32> = (0..4).map(|i| sums[i] / counts[i] as f32).collect();
    let contrast = ((m[0] + m[2]) - (m[1] + m[3])).abs() / 2.0;
    if contrast < MIN_CONTRAST / 2.0
        || (m[0] - m[2]).abs() > SECTOR_MATCH * contrast
        || (m[1] - m[3]).abs() > SECTOR_MATCH * contrast
    {
        return None;
    }
    Some([crossings[0], crossings[1], crossings[2], crossings[3]])
}

/// Sub-pixel corner by gradient orthogonality: solve Σ w·g·gᵀ·(q − x) = 0 for q, re-centre.
fn refine(p: &Plane, start: [f64; 2], sigma: f64, max_shift: f64) -> Option<[f64; 2]> {
    let mut q = start;
    let radius = (2.0 * sigma).ceil() as isize;
    for _ in 0..20 {
        let (cx, cy) = (q[0].round() as isize, q[1].round() as isize);
        let (mut a, mut b, mut c, mut bx, mut by) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (x, y) = (cx + dx, cy + dy);
                let gx = 0.5 * (p.at(x + 1, y) - p.at(x - 1, y)) as f64;
                let gy = 0.5 * (p.at(x, y + 1) - p.at(x, y - 1)) as f64;
                let (rx, ry) = (x as f64 - q[0], y as f64 - q[1]);
                let wgt = (-(rx * rx + ry * ry) / (2.0 * sigma * sigma)).exp();
                let (gxx, gxy, gyy) = (wgt * gx * gx, wgt * gx * gy, wgt * gy * gy);
                a += gxx;
                b += gxy;
                c += gyy;
                bx += gxx * x as f64 + gxy * y as f64;
                by += gxy * x as f64 + gyy * y as f64;
            }
        }
        let det = a * c - b * b;
        if !(det > 1e-12 * (a + c) * (a + c)) || !(det > 0.0) {
            return None;
        }
        let nq = [(c * bx - b * by) / det, (a * by - b * bx) / det];
        let moved = (nq[0] - q[0]).hypot(nq[1] - q[1]);
        q = nq;
        if (q[0] - start[0]).hypot(q[1] - start[1]) > max_shift {
            return None;
        }
        if moved < REFINE_TOL {
            break;
        }
    }
    Some(q)
}

/// How far the patch around `p` is from point symmetry: Σ (I(p+d) − I(p−d))² over Σ (I(p±d) −
/// mean)², over offsets up to `radius`. A blurred X-junction is point-symmetric about its centre
/// (≈ 0 up to noise); a corner against the dark rim of the image circle, the sensor's edge or a
/// thin board margin is not, and its refined position is biased, so it is dropped.
fn asymmetry(p: &Plane, c: [f64; 2], radius: f64) -> f64 {
    let r = radius as isize;
    let mut vals: Vec<(f32, f32)> = Vec::new();
    for dy in 0..=r {
        for dx in -r..=r {
            if dy == 0 && dx <= 0 || (dx * dx + dy * dy) as f64 > radius * radius {
                continue;
            }
            let (ox, oy) = (dx as f64, dy as f64);
            vals.push((
                p.bilinear(c[0] + ox, c[1] + oy),
                p.bilinear(c[0] - ox, c[1] - oy),
            ));
        }
    }
    let n = (2 * vals.len()).max(1) as f64;
    let mean = vals.iter().map(|(a, b)| (a + b) as f64).sum::<f64>() / n;
    let spread: f64 = vals
        .iter()
        .map(|(a, b)| (*a as f64 - mean).powi(2) + (*b as f64 - mean).powi(2))
        .sum();
    let diff: f64 = vals.iter().map(|(a, b)| ((a - b) as f64).powi(2)).sum();
    if spread > 0.0 {
        diff / spread
    } else {
        f64::INFINITY
    }
}

/// Nearest corner to `at` within `radius`, not in `used`.
fn nearest(corners: &[Corner], at: [f64; 2], radius: f64, used: &[bool]) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, c) in corners.iter().enumerate() {
        if used[i] {
            continue;
        }
        let d = (c.p[0] - at[0]).hypot(c.p[1] - at[1]);
        if d <= radius && best.is_none_or(|(_, bd)| d < bd) {
            best = Some((i, d));
        }
    }
    best.map(|(i, _)| i)
}

/// Smallest signed difference between two angles.
fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(TAU);
    if d > PI {
        d - TAU
    } else {
        d
    }
}

/// Nearest corner from `c` in direction `dir` (within [`SEED_ANGLE_TOL`]) that has an edge
/// pointing back at `c`.
fn neighbour_along(corners: &[Corner], c: usize, dir: f64) -> Option<usize> {
    let p = corners[c].p;
    let mut best: Option<(usize, f64)> = None;
    for (i, q) in corners.iter().enumerate() {
        if i == c {
            continue;
        }
        let (dx, dy) = (q.p[0] - p[0], q.p[1] - p[1]);
        let d = dx.hypot(dy);
        if d < 3.0 || angle_diff(dy.atan2(dx), dir).abs() > SEED_ANGLE_TOL {
            continue;
        }
        let back = (-dy).atan2(-dx);
        if !q
            .edges
            .iter()
            .any(|&e| angle_diff(e, back).abs() < SEED_ANGLE_TOL)
        {
            continue;
        }
        if best.is_none_or(|(_, bd)| d < bd) {
            best = Some((i, d));
        }
    }
    best.map(|(i, _)| i)
}

/// Grow a grid from a seed; `None` if the seed has no quad.
fn grow(corners: &[Corner], seed: usize) -> Option<HashMap<(i32, i32), usize>> {
    let e = corners[seed].edges;
    let nb: Vec<Option<usize>> = e
        .iter()
        .map(|&a| neighbour_along(corners, seed, a))
        .collect();
    // Two adjacent edge directions with neighbours span the grid's axes.
    let k = (0..4).find(|&k| nb[k].is_some() && nb[(k + 1) % 4].is_some())?;
    let mut grid: HashMap<(i32, i32), usize> = HashMap::new();
    let mut used = vec![false; corners.len()];
    let mut put = |grid: &mut HashMap<(i32, i32), usize>, cell: (i32, i32), i: usize| {
        grid.insert(cell, i);
        used[i] = true;
    };
    put(&mut grid, (0, 0), seed);
    put(&mut grid, (1, 0), nb[k]?);
    put(&mut grid, (0, 1), nb[(k + 1) % 4]?);
    const DIRS: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    loop {
        let mut added = false;
        let mut frontier: Vec<(i32, i32)> = grid
            .keys()
            .flat_map(|&(i, j)| DIRS.iter().map(move |&(di, dj)| (i + di, j + dj)))
            .filter(|c| !grid.contains_key(c))
            .collect();
        frontier.sort_unstable();
        frontier.dedup();
        for cell in frontier {
            if grid.contains_key(&cell) {
                continue;
            }
            let Some((pred, spacing)) = predict(&grid, corners, cell) else {
                continue;
            };
            if let Some(i) = nearest(corners, pred, SEARCH_FRAC * spacing, &used) {
                grid.insert(cell, i);
                used[i] = true;
                added = true;
            }
        }
        if !added {
            break;
        }
        // A runaway grid (clutter) is not a board; stop early.
        if grid.len() > 4096 {
            return None;
        }
    }
    Some(grid)
}

/// Predicted position of an empty cell from its filled neighbours, and the local spacing.
fn predict(
    grid: &HashMap<(i32, i32), usize>,
    corners: &[Corner],
    (i, j): (i32, i32),
) -> Option<([f64; 2], f64)> {
    let at = |c: (i32, i32)| grid.get(&c).map(|&k| corners[k].p);
    let mut sum = [0.0, 0.0];
    let mut n = 0.0;
    let mut spacing = f64::MAX;
    let mut add = |p: [f64; 2], s: f64| {
        sum[0] += p[0];
        sum[1] += p[1];
        n += 1.0;
        spacing = spacing.min(s);
    };
    for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
        let back = |m: i32| at((i - m * di, j - m * dj));
        if let (Some(p1), Some(p2)) = (back(1), back(2)) {
            let s = (p1[0] - p2[0]).hypot(p1[1] - p2[1]);
            match back(3) {
                Some(p3) => add(
                    [
                        3.0 * p1[0] - 3.0 * p2[0] + p3[0],
                        3.0 * p1[1] - 3.0 * p2[1] + p3[1],
                    ],
                    s,
                ),
                None => add([2.0 * p1[0] - p2[0], 2.0 * p1[1] - p2[1]], s),
            }
        }
    }
    for (di, dj) in [(1, 1), (1, -1), (-1, 1), (-1, -1)] {
        if let (Some(a), Some(b), Some(c)) =
            (at((i - di, j)), at((i, j - dj)), at((i - di, j - dj)))
        {
            let s = (a[0] - c[0])
                .hypot(a[1] - c[1])
                .min((b[0] - c[0]).hypot(b[1] - c[1]));
            add([a[0] + b[0] - c[0], a[1] + b[1] - c[1]], s);
        }
    }
    (n > 0.0).then(|| ([sum[0] / n, sum[1] / n], spacing))
}

/// Extent of a grid: (columns, rows) of its bounding box; (0, 0) when it is empty.
fn dims(grid: &HashMap<(i32, i32), usize>) -> (usize, usize) {
    if grid.is_empty() {
        return (0, 0);
    }
    let (mut i0, mut i1, mut j0, mut j1) = (i32::MAX, i32::MIN, i32::MAX, i32::MIN);
    for &(i, j) in grid.keys() {
        i0 = i0.min(i);
        i1 = i1.max(i);
        j0 = j0.min(j);
        j1 = j1.max(j);
    }
    ((i1 - i0 + 1) as usize, (j1 - j0 + 1) as usize)
}

/// Board-frame labels for a grid, row by row; a grid grown with its axes swapped relative to the
/// pattern is transposed so a full board always comes out as `cols` per row.
fn label(
    grid: &HashMap<(i32, i32), usize>,
    corners: &[Corner],
    cols: usize,
    rows: usize,
    square: f64,
    full: bool,
) -> Found {
    let (nx, ny) = dims(grid);
    let i0 = grid.keys().map(|c| c.0).min().unwrap_or(0);
    let j0 = grid.keys().map(|c| c.1).min().unwrap_or(0);
    let transpose = nx != cols && ny == cols && nx == rows;
    let mut cells: Vec<((usize, usize), usize)> = grid
        .iter()
        .map(|(&(i, j), &k)| {
            let (a, b) = ((i - i0) as usize, (j - j0) as usize);
            (if transpose { (b, a) } else { (a, b) }, k)
        })
        .collect();
    cells.sort_by_key(|&((a, b), _)| (b, a));
    Found {
        object: cells
            .iter()
            .map(|&((a, b), _)| [a as f64 * square, b as f64 * square, 0.0])
            .collect(),
        image: cells.iter().map(|&(_, k)| corners[k].p).collect(),
        full,
    }
}
