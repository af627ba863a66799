//! Map tiles: georeferenced grids and layers, the pure model (the tile cache and GeoTIFF I/O are
//! the application's `map::cache` and `map::geotiff`; layout in `docs/map.md`).
//!
//! A [`GeoGrid`] is north-up and square-pixelled: pixel (col, row) has its *centre* at
//! `x = x0 + (col + 0.5)·res`, `y = y0 − (row + 0.5)·res`, where (x0, y0) is the outer corner of the
//! top-left pixel (GeoTIFF "PixelIsArea" convention).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use crate::geo::Crs;

/// A north-up, square-pixel georeferenced grid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeoGrid {
    /// CRS of x/y.
    pub crs: Crs,
    /// x of the outer (west) edge of column 0, metres.
    pub x0: f64,
    /// y of the outer (north) edge of row 0, metres.
    pub y0: f64,
    /// Pixel size, metres.
    pub res: f64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl GeoGrid {
    /// Map coordinates of the centre of pixel (col, row).
    #[inline]
    pub fn pixel_center(&self, col: usize, row: usize) -> (f64, f64) {
        (
            self.x0 + (col as f64 + 0.5) * self.res,
            self.y0 - (row as f64 + 0.5) * self.res,
        )
    }

    /// Continuous pixel coordinates of a map point, pixel centres at integers.
    #[inline]
    pub fn to_pixel(self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.x0) / self.res - 0.5,
            (self.y0 - y) / self.res - 0.5,
        )
    }

    /// Map extent `(xmin, ymin, xmax, ymax)` of the outer pixel edges.
    pub fn bounds(&self) -> (f64, f64, f64, f64) {
        (
            self.x0,
            self.y0 - self.height as f64 * self.res,
            self.x0 + self.width as f64 * self.res,
            self.y0,
        )
    }

    /// Whether (x, y) is at least `margin` metres inside the grid.
    pub(crate) fn contains(&self, x: f64, y: f64, margin: f64) -> bool {
        let (a, b, c, d) = self.bounds();
        x >= a + margin && x <= c - margin && y >= b + margin && y <= d - margin
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// Whether the grid has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// One raster layer on a [`GeoGrid`], row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Raster<T> {
    /// Georeference.
    pub grid: GeoGrid,
    /// `grid.width × grid.height` samples, row-major from the north-west corner.
    pub data: Vec<T>,
    /// The value that means "no data" (for f32 layers NaN is always no-data as well).
    pub nodata: Option<T>,
}

impl<T: Copy> Raster<T> {
    /// A raster filled with `value`.
    pub fn filled(grid: GeoGrid, value: T, nodata: Option<T>) -> Self {
        Raster {
            grid,
            data: vec![value; grid.len()],
            nodata,
        }
    }

    /// Sample at (col, row), `None` outside.
    #[inline]
    pub fn get(&self, col: usize, row: usize) -> Option<T> {
        (col < self.grid.width && row < self.grid.height)
            .then(|| self.data[row * self.grid.width + col])
    }
}

/// A surveyed control point of a tile (map CRS).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControlPoint {
    /// Identifier.
    pub id: String,
    /// Easting, northing, height.
    pub xyz: [f64; 3],
}

/// A map tile in memory: satellite image, LiDAR reflectivity and height on a shared grid.
#[derive(Debug, Clone)]
pub struct Tile {
    /// Tile identifier (its directory name in the cache).
    pub id: String,
    /// BEV satellite/aerial image, RGB (gray sources are replicated), on its own grid. `None`: a
    /// LiDAR-only tile (a survey with neither colour nor orthophoto). Refinement, the drift check
    /// and georeferencing read only the LiDAR layers; the initializer needs this one.
    pub satellite: Option<Raster<[u8; 3]>>,
    /// LiDAR ground reflectivity 0..255.
    pub reflectivity: Raster<u8>,
    /// LiDAR ground height, metres; NaN = no data. Same grid as `reflectivity`.
    pub height: Raster<f32>,
    /// Optional surveyed control points.
    pub control_points: Vec<ControlPoint>,
}

/// A LiDAR ground point of a tile: the centre of one valid reflectivity/height cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundPoint {
    /// Easting, map CRS metres.
    pub x: f64,
    /// Northing, map CRS metres.
    pub y: f64,
    /// Height, metres (the tile's height datum).
    pub z: f64,
    /// Ground reflectivity 0..255.
    pub reflectivity: u8,
}

/// The ground points of `tile` whose cell centres lie within `radius_m` of `center_xy` (map CRS).
///
/// Cells whose reflectivity is the reflectivity no-data value, or whose height is NaN or the height
/// no-data value, are skipped. Order is deterministic: row-major from the north-west (rows north →
/// south, columns west → east), i.e. the raster order. A tile whose reflectivity and height grids
/// differ yields no points ([`cache::write_tile`] and [`cache::load_tile`] refuse such tiles).
pub fn ground_points(tile: &Tile, center_xy: (f64, f64), radius_m: f64) -> Vec<GroundPoint> {
    ground_points_iter(tile, center_xy, radius_m).collect()
}

/// [`ground_points`] one at a time, in the same order, without collecting them: a caller that
/// keeps only a stride of them (initialization's verifier) counts them and then walks them again
/// instead of allocating all the disc's points.
pub fn ground_points_iter(
    tile: &Tile,
    center_xy: (f64, f64),
    radius_m: f64,
) -> impl Iterator<Item = GroundPoint> + '_ {
    let w = DiscWindow::new(tile, center_xy, radius_m);
    (w.r0..w.r1).flat_map(move |row| {
        (w.c0..w.c1).filter_map(move |col| {
            if !w.inside(col, row) {
                return None;
            }
            ground_point(tile, col, row)
        })
    })
}

/// The cell (`col`, `row`) of `tile` as a ground point, `None` where either layer has no data.
#[inline]
fn ground_point(tile: &Tile, col: usize, row: usize) -> Option<GroundPoint> {
    let (refl, hgt) = (&tile.reflectivity, &tile.height);
    let g = refl.grid;
    let (x, y) = g.pixel_center(col, row);
    let i = row * g.width + col;
    let r = refl.data[i];
    let z = hgt.data[i];
    if Some(r) == refl.nodata || z.is_nan() || Some(z) == hgt.nodata {
        return None;
    }
    Some(GroundPoint {
        x,
        y,
        z: f64::from(z),
        reflectivity: r,
    })
}

/// The cells a disc of [`ground_points_iter`] looks at: the pixel window of its bounding box,
/// clamped to the grid (empty when the tile is unusable), and the disc test.
#[derive(Debug, Clone, Copy)]
struct DiscWindow {
    grid: GeoGrid,
    center: (f64, f64),
    r2: f64,
    c0: usize,
    c1: usize,
    r0: usize,
    r1: usize,
}

impl DiscWindow {
    fn new(tile: &Tile, center: (f64, f64), radius_m: f64) -> Self {
        let g = tile.reflectivity.grid;
        let usable = radius_m >= 0.0 && !g.is_empty() && tile.height.grid == g;
        let (pc, pr) = g.to_pixel(center.0, center.1);
        let rpx = radius_m / g.res;
        let clamp = |v: f64, n: usize| -> usize { v.max(0.0).min(n as f64) as usize };
        let (c0, c1) = (
            clamp((pc - rpx).floor(), g.width),
            clamp((pc + rpx).ceil() + 1.0, g.width),
        );
        let (r0, r1) = if usable {
            (
                clamp((pr - rpx).floor(), g.height),
                clamp((pr + rpx).ceil() + 1.0, g.height),
            )
        } else {
            (0, 0)
        };
        DiscWindow {
            grid: g,
            center,
            r2: radius_m * radius_m,
            c0,
            c1,
            r0,
            r1,
        }
    }

    /// Whether the centre of cell (`col`, `row`) lies in the disc.
    #[inline]
    fn inside(&self, col: usize, row: usize) -> bool {
        let (x, y) = self.grid.pixel_center(col, row);
        let (cx, cy) = self.center;
        (x - cx).powi(2) + (y - cy).powi(2) <= self.r2
    }

    /// The disc's columns in `row`, as `lo..hi` (possibly empty). The cells inside are one run
    /// around the column nearest the centre (along a row the test is monotone on each side of
    /// it: rounding keeps the squares' order), so each end is a binary search with the test.
    fn run(&self, row: usize) -> (usize, usize) {
        let (c0, c1) = (self.c0, self.c1);
        if c0 >= c1 {
            return (c0, c0);
        }
        let pc = ((self.center.0 - self.grid.x0) / self.grid.res - 0.5).round();
        let mid = pc.clamp(c0 as f64, (c1 - 1) as f64) as usize;
        // On a tie of two columns either may be the one inside.
        let near = [mid, mid.saturating_sub(1).max(c0), (mid + 1).min(c1 - 1)];
        let Some(&m) = near.iter().find(|&&c| self.inside(c, row)) else {
            return (c0, c0);
        };
        // The first column of [a, b) where `pred` turns false (`pred` true then false).
        let edge = |mut a: usize, mut b: usize, pred: &dyn Fn(usize) -> bool| {
            while a < b {
                let c = a + (b - a) / 2;
                if pred(c) {
                    a = c + 1;
                } else {
                    b = c;
                }
            }
            a
        };
        let lo = edge(c0, m, &|c| !self.inside(c, row));
        let hi = edge(m + 1, c1, &|c| self.inside(c, row));
        (lo, hi)
    }
}

/// Per-row counts of a tile's ground cells (both layers with data) over a window, so that a
/// disc's ground points can be counted and every `stride`-th one taken without walking all its
/// cells: the initializer's verifier samples a few thousand of the ~10⁵ points of dozens of
/// discs. A disc that leaves the window is walked instead (same result). The window bounds the
/// memory (4 bytes per cell) on large tiles.
#[derive(Debug, Clone)]
pub struct GroundIndex<'a> {
    tile: &'a Tile,
    /// The window's cells: columns `c0..c1`, rows `r0..r1`.
    c0: usize,
    c1: usize,
    r0: usize,
    r1: usize,
    /// `prefix[(row − r0)·(c1 − c0 + 1) + col − c0]`: ground cells of `row` from `c0` to left
    /// of `col`.
    prefix: Vec<u32>,
}

impl<'a> GroundIndex<'a> {
    /// Index the cells of `tile` within `reach_m` of `center_xy` (their bounding box; a negative
    /// reach indexes nothing, and every disc is walked).
    pub(crate) fn new(tile: &'a Tile, center_xy: (f64, f64), reach_m: f64) -> Self {
        let d = DiscWindow::new(tile, center_xy, reach_m);
        let (c0, c1) = (d.c0, d.c1.max(d.c0));
        let (r0, r1) = (d.r0, d.r1.max(d.r0));
        let w1 = c1 - c0 + 1;
        let mut prefix = vec![0u32; (r1 - r0) * w1];
        // Rows on the thread pool: each row's counts are its own.
        prefix
            .par_chunks_exact_mut(w1)
            .enumerate()
            .for_each(|(j, p)| {
                let mut n = 0u32;
                for (col, v) in (c0..c1).zip(p.iter_mut()) {
                    *v = n;
                    n += u32::from(ground_point(tile, col, r0 + j).is_some());
                }
                p[w1 - 1] = n;
            });
        GroundIndex {
            tile,
            c0,
            c1,
            r0,
            r1,
            prefix,
        }
    }

    /// Whether a disc's cells lie in the window (and there are any): only then is it indexed.
    fn covers(&self, d: &DiscWindow) -> bool {
        let empty = d.r0 >= d.r1 || d.c0 >= d.c1;
        !empty && d.c0 >= self.c0 && d.c1 <= self.c1 && d.r0 >= self.r0 && d.r1 <= self.r1
    }

    /// Whether the disc is counted from the index (true) or walked.
    #[cfg(test)]
    fn indexes(&self, center_xy: (f64, f64), radius_m: f64) -> bool {
        self.covers(&DiscWindow::new(self.tile, center_xy, radius_m))
    }

    /// `ground_points_iter(tile, center_xy, radius_m).count()` and, with `stride` from it,
    /// `….step_by(stride)` collected: the same points in the same order.
    pub(crate) fn disc_strided(
        &self,
        center_xy: (f64, f64),
        radius_m: f64,
        stride: impl FnOnce(usize) -> usize,
    ) -> Vec<GroundPoint> {
        let d = DiscWindow::new(self.tile, center_xy, radius_m);
        if !self.covers(&d) {
            let walk = || ground_points_iter(self.tile, center_xy, radius_m);
            let step = stride(walk().count()).max(1);
            return walk().step_by(step).collect();
        }
        let w1 = self.c1 - self.c0 + 1;
        let row_prefix = |row: usize| &self.prefix[(row - self.r0) * w1..(row - self.r0 + 1) * w1];
        let runs: Vec<(usize, usize, usize)> = (d.r0..d.r1)
            .map(|row| {
                let (lo, hi) = d.run(row);
                (row, lo - self.c0, hi - self.c0)
            })
            .collect();
        let count_in = |&(row, lo, hi): &(usize, usize, usize)| -> usize {
            let p = row_prefix(row);
            (p[hi] - p[lo]) as usize
        };
        let total: usize = runs.iter().map(count_in).sum();
        let step = stride(total).max(1);
        let mut out = Vec::with_capacity(total.div_ceil(step));
        // `a`: ordinal of the row's first point in the disc; kept ordinals are multiples of step.
        let mut a = 0usize;
        for run in &runs {
            let (row, lo, hi) = *run;
            let n = count_in(run);
            let p = row_prefix(row);
            let mut k = a.div_ceil(step) * step;
            while k < a + n {
                // The row's (k − a)-th ground cell from `lo`: the last column whose prefix is at
                // most that many past `lo`'s (a ground cell raises the next column's prefix).
                let want = p[lo] + (k - a) as u32;
                let col = self.c0 + lo + p[lo..hi].partition_point(|&v| v <= want) - 1;
                if let Some(g) = ground_point(self.tile, col, row) {
                    out.push(g);
                }
                k += step;
            }
            a += n;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile() -> Tile {
        let g = GeoGrid {
            crs: Crs::Epsg(32617),
            x0: 1000.0,
            y0: 2000.0,
            res: 0.5,
            width: 8,
            height: 6,
        };
        let mut refl = Raster::filled(g, 100u8, Some(0));
        let mut h = Raster::filled(g, 10.0f32, Some(-9999.0));
        for (i, v) in refl.data.iter_mut().enumerate() {
            *v = 1 + i as u8;
        }
        refl.data[g.width * 2 + 3] = 0; // nodata reflectivity
        h.data[g.width * 3 + 4] = f32::NAN; // NaN height
        h.data[g.width * 3 + 3] = -9999.0; // nodata height
        Tile {
            id: "t".into(),
            satellite: Some(Raster::filled(g, [0, 0, 0], None)),
            reflectivity: refl,
            height: h,
            control_points: vec![],
        }
    }

    #[test]
    fn ground_points_brute_force() {
        let t = tile();
        let g = t.reflectivity.grid;
        for (c, rad) in [
            ((1002.0, 1998.5), 1.2),
            ((1000.0, 2000.0), 0.4),
            ((990.0, 1990.0), 100.0),
        ] {
            let pts = ground_points(&t, c, rad);
            // Brute force over every cell.
            let mut want = Vec::new();
            for row in 0..g.height {
                for col in 0..g.width {
                    let (x, y) = g.pixel_center(col, row);
                    let i = row * g.width + col;
                    let (r, z) = (t.reflectivity.data[i], t.height.data[i]);
                    if (x - c.0).hypot(y - c.1) <= rad && r != 0 && z.is_finite() && z != -9999.0 {
                        want.push((x, y, r));
                    }
                }
            }
            let got: Vec<_> = pts.iter().map(|p| (p.x, p.y, p.reflectivity)).collect();
            assert_eq!(got, want, "centre {c:?} radius {rad}");
        }
        assert_eq!(ground_points(&t, (1002.0, 1998.5), 100.0).len(), 48 - 3);
    }

    /// A 0.1 m tile of 300 × 200 cells with scattered holes in either layer.
    fn holey_tile(seed: u64) -> Tile {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let g = GeoGrid {
            crs: Crs::Local,
            x0: -15.03,
            y0: 10.07,
            res: 0.1,
            width: 300,
            height: 200,
        };
        let mut refl = Raster::filled(g, 1u8, Some(0));
        let mut h = Raster::filled(g, 0.5f32, Some(-9999.0));
        for i in 0..g.len() {
            refl.data[i] = rng.random_range(0..=255u8);
            match rng.random_range(0..20) {
                0 => h.data[i] = f32::NAN,
                1 => h.data[i] = -9999.0,
                _ => {}
            }
        }
        Tile {
            id: "holey".into(),
            satellite: Some(Raster::filled(g, [0, 0, 0], None)),
            reflectivity: refl,
            height: h,
            control_points: vec![],
        }
    }

    #[test]
    fn the_ground_index_picks_the_walks_points() {
        use rand::{Rng, SeedableRng};
        let t = holey_tile(3);
        // The whole tile, a window around its centre (discs leaving it are walked), and none.
        let indexes = [
            GroundIndex::new(&t, (0.0, 0.0), 100.0),
            GroundIndex::new(&t, (1.0, -2.0), 12.0),
            GroundIndex::new(&t, (0.0, 0.0), -1.0),
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut cases: Vec<((f64, f64), f64)> = vec![
            ((0.0, 0.0), 0.0),       // one cell centre at most
            ((-14.98, 10.02), 0.05), // the corner cell
            ((-15.03, 10.07), 0.3),  // the grid's corner itself
            ((0.0, 0.0), 100.0),     // the whole tile
            ((40.0, 0.0), 10.0),     // beyond the tile
            ((20.0, 0.0), 5.2),      // overlapping its east edge
            ((0.0, 0.0), -1.0),      // no disc
        ];
        for _ in 0..200 {
            let c = (rng.random_range(-18.0..18.0), rng.random_range(-13.0..13.0));
            // Radii on and off the cell lattice's distances.
            let r = if rng.random_bool(0.3) {
                0.1 * rng.random_range(0..120) as f64
            } else {
                rng.random_range(0.0..12.0)
            };
            cases.push((c, r));
        }
        let mut kept = 0;
        let mut indexed = [0; 3];
        for (c, r) in cases {
            for (n, index) in indexed.iter_mut().zip(&indexes) {
                *n += usize::from(index.indexes(c, r));
            }
            let all = ground_points(&t, c, r);
            for keep in [1usize, 7, 100, 5000] {
                let step = (all.len() / keep).max(1);
                let want: Vec<GroundPoint> = all.iter().copied().step_by(step).collect();
                for (i, index) in indexes.iter().enumerate() {
                    let mut seen = None;
                    let got = index.disc_strided(c, r, |n| {
                        seen = Some(n);
                        (n / keep).max(1)
                    });
                    let case = format!("index {i}, centre {c:?} radius {r} keep {keep}");
                    assert_eq!(seen, Some(all.len()), "count, {case}");
                    assert_eq!(got, want, "{case}");
                    kept += got.len();
                }
            }
        }
        assert!(kept > 10_000, "the discs held points ({kept})");
        // The whole tile's index counts every disc that touches the tile, the window's some of
        // them, the empty one none.
        assert!(
            indexed[0] > indexed[1] && indexed[1] >= 10 && indexed[2] == 0,
            "{indexed:?}"
        );
        // A tile whose layers' grids differ has no ground points, as the walk says.
        let mut odd = holey_tile(5);
        odd.height.grid.res = 0.2;
        let index = GroundIndex::new(&odd, (0.0, 0.0), 100.0);
        assert!(index.disc_strided((0.0, 0.0), 5.0, |n| n.max(1)).is_empty());
        assert_eq!(ground_points(&odd, (0.0, 0.0), 5.0).len(), 0);
    }
}
