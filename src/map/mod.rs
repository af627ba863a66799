//! Map tiles: georeferenced grids and layers (this pure model) and the on-disk tile cache
//! ([`cache`], [`geotiff`]: the I/O shell; layout in `docs/map.md`).
//!
//! A [`GeoGrid`] is north-up and square-pixelled: pixel (col, row) has its *centre* at
//! `x = x0 + (col + 0.5)·res`, `y = y0 − (row + 0.5)·res`, where (x0, y0) is the outer corner of the
//! top-left pixel (GeoTIFF "PixelIsArea" convention).

use serde::{Deserialize, Serialize};

pub mod cache;
pub mod geotiff;
pub(crate) mod import;

/// A coordinate reference system of map data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Crs {
    /// An EPSG code (e.g. 32617 = WGS84 / UTM 17N).
    Epsg(u32),
    /// A local metric right-handed frame with z up; no WGS84 lookups.
    Local,
}

impl std::fmt::Display for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Crs::Epsg(c) => write!(f, "EPSG:{c}"),
            Crs::Local => write!(f, "LOCAL"),
        }
    }
}

impl std::str::FromStr for Crs {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("LOCAL") {
            return Ok(Crs::Local);
        }
        let code = t
            .strip_prefix("EPSG:")
            .or_else(|| t.strip_prefix("epsg:"))
            .ok_or_else(|| format!("CRS {s:?}: expected EPSG:<code> or LOCAL"))?;
        code.parse::<u32>()
            .map(Crs::Epsg)
            .map_err(|_| format!("CRS {s:?}: EPSG code is not a number"))
    }
}

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
    pub(crate) fn pixel_center(&self, col: usize, row: usize) -> (f64, f64) {
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
    pub(crate) fn get(&self, col: usize, row: usize) -> Option<T> {
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
    /// BEV satellite/aerial image, RGB (gray sources are replicated), on its own grid.
    pub satellite: Raster<[u8; 3]>,
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
pub(crate) fn ground_points(tile: &Tile, center_xy: (f64, f64), radius_m: f64) -> Vec<GroundPoint> {
    ground_points_iter(tile, center_xy, radius_m).collect()
}

/// [`ground_points`] one at a time, in the same order, without collecting them: a caller that
/// keeps only a stride of them (initialization's verifier) counts them and then walks them again
/// instead of allocating all the disc's points.
pub(crate) fn ground_points_iter(
    tile: &Tile,
    center_xy: (f64, f64),
    radius_m: f64,
) -> impl Iterator<Item = GroundPoint> + '_ {
    let refl = &tile.reflectivity;
    let hgt = &tile.height;
    let g = refl.grid;
    let usable = radius_m >= 0.0 && !g.is_empty() && hgt.grid == g;
    let (cx, cy) = center_xy;
    // Pixel-index window of the circle's bounding box, clamped to the grid (empty when unusable).
    let (pc, pr) = g.to_pixel(cx, cy);
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
    let r2 = radius_m * radius_m;
    (r0..r1).flat_map(move |row| {
        (c0..c1).filter_map(move |col| {
            let (x, y) = g.pixel_center(col, row);
            if (x - cx).powi(2) + (y - cy).powi(2) > r2 {
                return None;
            }
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
        })
    })
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
            satellite: Raster::filled(g, [0, 0, 0], None),
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
}
