//! Map tiles: georeferenced grids and layers (this pure model) and the on-disk tile cache.
//!
//! A [`GeoGrid`] is north-up and square-pixelled: pixel (col, row) has its *centre* at
//! `x = x0 + (col + 0.5)·res`, `y = y0 − (row + 0.5)·res`, where (x0, y0) is the outer corner of the
//! top-left pixel (GeoTIFF "PixelIsArea" convention).

use serde::{Deserialize, Serialize};

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
    pub fn pixel_center(&self, col: usize, row: usize) -> (f64, f64) {
        (
            self.x0 + (col as f64 + 0.5) * self.res,
            self.y0 - (row as f64 + 0.5) * self.res,
        )
    }

    /// Continuous pixel coordinates of a map point, pixel centres at integers.
    #[inline]
    pub fn to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
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
    pub fn contains(&self, x: f64, y: f64, margin: f64) -> bool {
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
    /// BEV satellite/aerial image, RGB (gray sources are replicated), on its own grid.
    pub satellite: Raster<[u8; 3]>,
    /// LiDAR ground reflectivity 0..255.
    pub reflectivity: Raster<u8>,
    /// LiDAR ground height, metres; NaN = no data. Same grid as `reflectivity`.
    pub height: Raster<f32>,
    /// Optional surveyed control points.
    pub control_points: Vec<ControlPoint>,
}
