//! The on-disk tile cache (docs/interfaces.md, "Tile cache"), I/O shell.
//!
//! ```text
//! <cache>/<tile-id>/tile.toml            manifest: crs, layers (file, grid, nodata), provenance
//! <cache>/<tile-id>/satellite.tif        u8 RGB GeoTIFF (gray accepted on read); absent from a
//!                                        LiDAR-only tile (no `[layers.satellite]` in its manifest)
//! <cache>/<tile-id>/reflectivity.tif     u8 GeoTIFF + GDAL_NODATA
//! <cache>/<tile-id>/height.tif           f32 GeoTIFF + GDAL_NODATA (NaN is no-data too)
//! <cache>/<tile-id>/control_points.csv   optional: id,x,y,z (map CRS)
//! ```
//!
//! [`write_tile`] builds the tile in a hidden sibling directory and renames it into place, so a
//! crash leaves either the previous tile or the new one, never half of one. [`find_tile`] reads only
//! manifests (small TOML files), so a lookup over a large cache does not decode rasters.

use super::{geotiff, ControlPoint, Crs, GeoGrid, MapError, Raster, Tile};
use crate::error::{Error, Result};
use crate::geo;
use serde::{Deserialize, Serialize};
use std::fs;
use std::path::{Path, PathBuf};

/// Manifest file name inside a tile directory.
pub(crate) const MANIFEST: &str = "tile.toml";
/// Satellite layer file name.
pub(crate) const SATELLITE_FILE: &str = "satellite.tif";
/// Reflectivity layer file name.
pub(crate) const REFLECTIVITY_FILE: &str = "reflectivity.tif";
/// Height layer file name.
pub(crate) const HEIGHT_FILE: &str = "height.tif";
/// Control points file name.
pub(crate) const CONTROL_POINTS_FILE: &str = "control_points.csv";
/// Manifest format tag.
pub(crate) const FORMAT: &str = "infraloc.tile.v1";
/// Header line of `control_points.csv`.
pub(crate) const CONTROL_POINTS_HEADER: &str = "id,x,y,z";
/// How far (degrees of longitude) from a tile zone's central meridian a position is still placed in
/// that zone's plane for [`find_tile`]: the range `tests/it/geo_reference.rs` checks against pyproj.
/// Farther positions get a great-circle distance to the tile centre instead, because transverse
/// Mercator far outside its zone returns finite but meaningless coordinates.
const PLANAR_LON_RANGE_DEG: f64 = 9.0;
/// Distance from a tile in a CRS other than UTM within which planar distances are used, metres
/// (national grids span up to about a thousand kilometres).
const PLANAR_RANGE_M: f64 = 1.0e6;
/// Tolerance when comparing a layer's GeoTIFF georeference with the manifest, metres. Far below
/// any pixel size, far above f64 round-off of UTM coordinates (~1e-9 m).
const GRID_TOL_M: f64 = 1e-6;

/// `tile.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Manifest {
    /// Always `FORMAT`.
    pub format: String,
    /// Tile id = directory name.
    pub id: String,
    /// Map CRS of every layer, `EPSG:N`.
    pub crs: String,
    /// The three raster layers.
    pub layers: Layers,
    /// File name of the control points, if the tile has any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub control_points: Option<String>,
    /// Where the data came from.
    pub provenance: Provenance,
}

/// The layers of a manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Layers {
    /// Satellite/aerial image; `None` (no `[layers.satellite]` table) for a LiDAR-only tile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub satellite: Option<Layer>,
    /// LiDAR ground reflectivity.
    pub reflectivity: Layer,
    /// LiDAR ground height.
    pub height: Layer,
}

/// One layer entry of a manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Layer {
    /// File name inside the tile directory.
    pub file: String,
    /// Its grid.
    pub grid: GridSpec,
    /// Its no-data value (omitted = none; f32 layers treat NaN as no-data regardless).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nodata: Option<f64>,
}

/// A grid as written in a manifest (the CRS is the manifest's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct GridSpec {
    /// x of the west edge of column 0 (PixelIsArea corner), metres.
    pub x0: f64,
    /// y of the north edge of row 0, metres.
    pub y0: f64,
    /// Pixel size, metres.
    pub res: f64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl GridSpec {
    fn of(g: &GeoGrid) -> Self {
        GridSpec {
            x0: g.x0,
            y0: g.y0,
            res: g.res,
            width: g.width,
            height: g.height,
        }
    }

    fn with_crs(&self, crs: Crs) -> GeoGrid {
        GeoGrid {
            crs,
            x0: self.x0,
            y0: self.y0,
            res: self.res,
            width: self.width,
            height: self.height,
        }
    }
}

/// Provenance of a tile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Provenance {
    /// The program that wrote the tile.
    pub software: String,
    /// Source files or generator description, one entry each.
    #[serde(default)]
    pub sources: Vec<String>,
    /// Free text (e.g. the height datum).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

impl Default for Provenance {
    fn default() -> Self {
        Provenance {
            software: concat!("infraloc ", env!("CARGO_PKG_VERSION")).to_string(),
            sources: Vec::new(),
            note: None,
        }
    }
}

/// What [`find_tile`] returns: a tile located from its manifest alone.
#[derive(Debug, Clone, PartialEq)]
pub struct TileRef {
    /// Tile id.
    pub id: String,
    /// Tile directory (pass to [`load_tile`]).
    pub dir: PathBuf,
    /// The tile's map CRS.
    pub crs: Crs,
    /// The queried position in the tile's CRS (easting, northing).
    pub position: (f64, f64),
    /// Covered extent `(xmin, ymin, xmax, ymax)`: where the satellite and LiDAR layers overlap
    /// (the LiDAR layers' extent for a LiDAR-only tile).
    pub extent: (f64, f64, f64, f64),
    /// Other tile directories of the cache that were skipped as unreadable.
    pub skipped: Vec<SkippedTile>,
}

fn check_id(id: &str) -> Result<()> {
    let ok = !id.is_empty()
        && !id.starts_with('.')
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(())
    } else {
        Err(MapError::BadId { id: id.to_string() }.into())
    }
}

/// Consistency checks shared by writing and loading.
fn check_tile(t: &Tile) -> Result<Crs> {
    check_id(&t.id)?;
    let crs = t.reflectivity.grid.crs;
    geo::check_crs(crs).map_err(|source| MapError::TileCrs {
        id: t.id.clone(),
        source,
    })?;
    if t.reflectivity.grid != t.height.grid {
        return Err(MapError::GridsDiffer {
            id: t.id.clone(),
            reflectivity: t.reflectivity.grid,
            height: t.height.grid,
        }
        .into());
    }
    if let Some(sat) = t.satellite.as_ref().filter(|s| s.grid.crs != crs) {
        return Err(MapError::CrsDiffer {
            id: t.id.clone(),
            satellite: sat.grid.crs,
            lidar: crs,
        }
        .into());
    }
    if let Some(sat) = t
        .satellite
        .as_ref()
        .filter(|s| s.data.len() != s.grid.len())
    {
        return Err(MapError::Samples {
            id: t.id.clone(),
            layer: "satellite",
            samples: sat.data.len(),
            grid: sat.grid.len(),
        }
        .into());
    }
    for (name, n, want) in [
        (
            "reflectivity",
            t.reflectivity.data.len(),
            t.reflectivity.grid.len(),
        ),
        ("height", t.height.data.len(), t.height.grid.len()),
    ] {
        if n != want {
            return Err(MapError::Samples {
                id: t.id.clone(),
                layer: name,
                samples: n,
                grid: want,
            }
            .into());
        }
    }
    Ok(crs)
}

/// Write `tile` into `cache_dir/<tile.id>/` with default provenance. See `write_tile_with`.
pub fn write_tile(cache_dir: &Path, tile: &Tile) -> Result<()> {
    write_tile_with(cache_dir, tile, &Provenance::default())
}

/// Write `tile` into `cache_dir/<tile.id>/`, replacing any previous tile of that id.
///
/// Everything is written and fsynced in `cache_dir/.tmp-<id>-<pid>/` first, then renamed into place
/// (a previous tile is first renamed aside and deleted afterwards). A crash therefore leaves only a
/// hidden temporary directory, which [`find_tile`] ignores and the next write removes.
pub(crate) fn write_tile_with(
    cache_dir: &Path,
    tile: &Tile,
    provenance: &Provenance,
) -> Result<()> {
    let crs = check_tile(tile)?;
    fs::create_dir_all(cache_dir).map_err(|e| Error::io(cache_dir, e))?;
    let pid = std::process::id();
    let tmp = cache_dir.join(format!(".tmp-{}-{pid}", tile.id));
    let old = cache_dir.join(format!(".old-{}-{pid}", tile.id));
    let dest = cache_dir.join(&tile.id);
    for stale in [&tmp, &old] {
        if stale.exists() {
            fs::remove_dir_all(stale).map_err(|e| Error::io(stale, e))?;
        }
    }
    fs::create_dir(&tmp).map_err(|e| Error::io(&tmp, e))?;
    let result = write_tile_files(&tmp, tile, crs, provenance);
    if let Err(e) = result {
        let _ = fs::remove_dir_all(&tmp);
        return Err(e);
    }
    if dest.exists() {
        fs::rename(&dest, &old).map_err(|e| Error::io(&dest, e))?;
    }
    fs::rename(&tmp, &dest).map_err(|e| Error::io(&dest, e))?;
    if old.exists() {
        fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))?;
    }
    sync_path(cache_dir)?;
    Ok(())
}

fn sync_path(p: &Path) -> Result<()> {
    fs::File::open(p)
        .and_then(|f| f.sync_all())
        .map_err(|e| Error::io(p, e))
}

fn write_tile_files(dir: &Path, t: &Tile, crs: Crs, provenance: &Provenance) -> Result<()> {
    let mut files = Vec::new();
    if let Some(sat) = &t.satellite {
        geotiff::write_rgb8(&dir.join(SATELLITE_FILE), sat)?;
        files.push(SATELLITE_FILE);
    }
    geotiff::write_gray8(&dir.join(REFLECTIVITY_FILE), &t.reflectivity)?;
    geotiff::write_f32(&dir.join(HEIGHT_FILE), &t.height)?;
    files.extend([REFLECTIVITY_FILE, HEIGHT_FILE]);
    let control_points = if t.control_points.is_empty() {
        None
    } else {
        let mut s = format!("{CONTROL_POINTS_HEADER}\n");
        for cp in &t.control_points {
            if cp.id.contains([',', '\n', '\r']) {
                return Err(MapError::ControlPointId {
                    id: t.id.clone(),
                    point: cp.id.clone(),
                }
                .into());
            }
            let [x, y, z] = cp.xyz;
            s.push_str(&format!("{},{x},{y},{z}\n", cp.id));
        }
        let p = dir.join(CONTROL_POINTS_FILE);
        fs::write(&p, s).map_err(|e| Error::io(&p, e))?;
        files.push(CONTROL_POINTS_FILE);
        Some(CONTROL_POINTS_FILE.to_string())
    };
    let layer = |file: &str, g: &GeoGrid, nodata: Option<f64>| Layer {
        file: file.to_string(),
        grid: GridSpec::of(g),
        nodata,
    };
    let manifest = Manifest {
        format: FORMAT.into(),
        id: t.id.clone(),
        crs: crs.to_string(),
        layers: Layers {
            satellite: t
                .satellite
                .as_ref()
                .map(|s| layer(SATELLITE_FILE, &s.grid, None)),
            reflectivity: layer(
                REFLECTIVITY_FILE,
                &t.reflectivity.grid,
                t.reflectivity.nodata.map(f64::from),
            ),
            height: layer(
                HEIGHT_FILE,
                &t.height.grid,
                Some(t.height.nodata.map(f64::from).unwrap_or(f64::NAN)),
            ),
        },
        control_points,
        provenance: provenance.clone(),
    };
    let text = toml::to_string(&manifest).map_err(|e| MapError::Manifest {
        id: t.id.clone(),
        reason: e.to_string(),
    })?;
    let p = dir.join(MANIFEST);
    fs::write(&p, text).map_err(|e| Error::io(&p, e))?;
    files.push(MANIFEST);
    for f in files {
        sync_path(&dir.join(f))?;
    }
    sync_path(dir)
}

/// Read and parse `tile_dir/tile.toml` (no rasters). Errors name the manifest file.
pub fn read_manifest(tile_dir: &Path) -> Result<Manifest> {
    let path = tile_dir.join(MANIFEST);
    let text = match fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(Error::input(
                &path,
                "missing tile manifest (not a tile directory?)",
            ))
        }
        Err(e) => return Err(Error::io(&path, e)),
    };
    let m: Manifest = toml::from_str(&text).map_err(|e| {
        // toml's Display is multi-line; keep the one-line message with its line number.
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1))
            .unwrap_or(0);
        Error::input(&path, format!("line {line}: {}", e.message().trim()))
    })?;
    if m.format != FORMAT {
        return Err(Error::input(
            &path,
            format!("format {:?}, expected {FORMAT:?}", m.format),
        ));
    }
    Ok(m)
}

fn manifest_crs(m: &Manifest, path: &Path) -> Result<Crs> {
    let crs: Crs = m
        .crs
        .parse()
        .map_err(|e: geo::GeoError| Error::input(path, format!("crs: {e}")))?;
    geo::check_crs(crs).map_err(|e| Error::input(path, format!("crs: {e}")))?;
    Ok(crs)
}

/// A layer file name must stay inside the tile directory.
fn layer_path(tile_dir: &Path, manifest: &Path, key: &str, file: &str) -> Result<PathBuf> {
    if file.is_empty() || file.contains(['/', '\\']) || file == "." || file == ".." {
        return Err(Error::input(
            manifest,
            format!("{key} file {file:?} must be a plain file name inside the tile directory"),
        ));
    }
    let p = tile_dir.join(file);
    if !p.is_file() {
        return Err(Error::input(
            &p,
            format!("missing layer {key} (listed in {MANIFEST})"),
        ));
    }
    Ok(p)
}

fn same_grid(a: &GeoGrid, b: &GeoGrid) -> bool {
    a.crs == b.crs
        && a.width == b.width
        && a.height == b.height
        && (a.x0 - b.x0).abs() <= GRID_TOL_M
        && (a.y0 - b.y0).abs() <= GRID_TOL_M
        && (a.res - b.res).abs() * (a.width.max(a.height) as f64) <= GRID_TOL_M
}

fn describe(g: &GeoGrid) -> String {
    format!(
        "{} {}x{} at ({}, {}) res {} m",
        g.crs, g.width, g.height, g.x0, g.y0, g.res
    )
}

fn check_layer_grid(file: &Path, got: &GeoGrid, want: &GeoGrid) -> Result<()> {
    if same_grid(got, want) {
        Ok(())
    } else {
        Err(Error::input(
            file,
            format!(
                "grid {} differs from {MANIFEST} ({})",
                describe(got),
                describe(want)
            ),
        ))
    }
}

fn same_nodata(a: Option<f64>, b: Option<f64>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(x), Some(y)) => x == y || (x.is_nan() && y.is_nan()),
        _ => false,
    }
}

/// Load and check a tile directory: manifest present and valid, CRS known, every listed file
/// present, each layer's GeoTIFF georeference and nodata equal to the manifest's, reflectivity and
/// height on one grid, control points parse. Errors name the file at fault.
pub fn load_tile(tile_dir: &Path) -> Result<Tile> {
    let m = read_manifest(tile_dir)?;
    let mpath = tile_dir.join(MANIFEST);
    let crs = manifest_crs(&m, &mpath)?;
    if let Some(name) = tile_dir.file_name().and_then(|n| n.to_str()) {
        if name != m.id {
            return Err(Error::input(
                &mpath,
                format!("id {:?} differs from the directory name {name:?}", m.id),
            ));
        }
    }
    check_id(&m.id).map_err(|e| Error::input(&mpath, e.to_string()))?;

    let sp = m
        .layers
        .satellite
        .as_ref()
        .map(|l| Ok::<_, Error>((layer_path(tile_dir, &mpath, "satellite", &l.file)?, l.grid)))
        .transpose()?;
    let rp = layer_path(
        tile_dir,
        &mpath,
        "reflectivity",
        &m.layers.reflectivity.file,
    )?;
    let hp = layer_path(tile_dir, &mpath, "height", &m.layers.height.file)?;

    // The three layers decode in parallel (tens of milliseconds each for a 5 MP scene's tile);
    // their errors are reported in the order a serial read would meet them.
    let (satellite, (reflectivity, height)) = rayon::join(
        || sp.as_ref().map(|(p, _)| geotiff::read_rgb8(p)),
        || rayon::join(|| geotiff::read_gray8(&rp), || geotiff::read_f32(&hp)),
    );
    let satellite = satellite.transpose()?;
    if let (Some(s), Some((p, g))) = (&satellite, &sp) {
        check_layer_grid(p, &s.grid, &g.with_crs(crs))?;
    }
    let reflectivity = reflectivity?;
    check_layer_grid(
        &rp,
        &reflectivity.grid,
        &m.layers.reflectivity.grid.with_crs(crs),
    )?;
    let height = height?;
    check_layer_grid(&hp, &height.grid, &m.layers.height.grid.with_crs(crs))?;
    if !same_grid(&reflectivity.grid, &height.grid) {
        return Err(Error::input(
            &hp,
            format!(
                "height grid {} differs from reflectivity grid {} ({}); they must share one grid",
                describe(&height.grid),
                describe(&reflectivity.grid),
                rp.display()
            ),
        ));
    }
    if !same_nodata(
        reflectivity.nodata.map(f64::from),
        m.layers.reflectivity.nodata,
    ) {
        return Err(Error::input(
            &rp,
            format!(
                "nodata {:?} differs from {MANIFEST} ({:?})",
                reflectivity.nodata, m.layers.reflectivity.nodata
            ),
        ));
    }
    // Height: the manifest's NaN and "none" both mean "NaN only".
    let hm = m.layers.height.nodata.filter(|v| !v.is_nan());
    if !same_nodata(height.nodata.map(f64::from), hm) {
        return Err(Error::input(
            &hp,
            format!(
                "nodata {:?} differs from {MANIFEST} ({:?})",
                height.nodata, m.layers.height.nodata
            ),
        ));
    }
    // One grid for both LiDAR layers, bit-identical, as the model promises.
    let height = Raster {
        grid: reflectivity.grid,
        ..height
    };
    let control_points = match &m.control_points {
        None => Vec::new(),
        Some(f) => {
            let p = layer_path(tile_dir, &mpath, "control-points", f)?;
            let text = fs::read_to_string(&p).map_err(|e| Error::io(&p, e))?;
            parse_control_points(&text, &p)?
        }
    };
    Ok(Tile {
        id: m.id,
        satellite,
        reflectivity,
        height,
        control_points,
    })
}

/// Parse a control points CSV (`id,x,y,z` header, then one point per line). `path` is for errors.
pub(crate) fn parse_control_points(text: &str, path: &Path) -> Result<Vec<ControlPoint>> {
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
    let cols: Vec<String> = header
        .split(',')
        .map(|c| c.trim().to_ascii_lowercase())
        .collect();
    if cols != ["id", "x", "y", "z"] {
        return Err(Error::input(
            path,
            format!("line 1: header {header:?}, expected {CONTROL_POINTS_HEADER:?}"),
        ));
    }
    let mut out = Vec::new();
    for (i, line) in lines {
        let l = line.trim();
        if l.is_empty() {
            continue;
        }
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if f.len() != 4 || f[0].is_empty() {
            return Err(Error::input(
                path,
                format!("line {}: expected id,x,y,z, got {l:?}", i + 1),
            ));
        }
        let mut xyz = [0.0; 3];
        for (k, v) in f[1..].iter().enumerate() {
            xyz[k] = v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    Error::input(
                        path,
                        format!(
                            "line {}: {} {v:?} is not a finite number",
                            i + 1,
                            ["x", "y", "z"][k]
                        ),
                    )
                })?;
        }
        out.push(ControlPoint {
            id: f[0].to_string(),
            xyz,
        });
    }
    Ok(out)
}

/// Extent where the satellite and LiDAR layers of a manifest overlap (a LiDAR-only tile: its
/// LiDAR layers' extent).
fn coverage(m: &Manifest) -> (f64, f64, f64, f64) {
    let b = |g: &GridSpec| g.with_crs(Crs::Local).bounds();
    let r = b(&m.layers.reflectivity.grid);
    let a = m.layers.satellite.as_ref().map_or(r, |s| b(&s.grid));
    (a.0.max(r.0), a.1.max(r.1), a.2.min(r.2), a.3.min(r.3))
}

/// Distance from (x, y) to a rectangle (0 inside), and how far inside it is (≤ 0 outside).
fn rect_distance(x: f64, y: f64, e: (f64, f64, f64, f64)) -> (f64, f64) {
    let dx = (e.0 - x).max(x - e.2).max(0.0);
    let dy = (e.1 - y).max(y - e.3).max(0.0);
    let inside = (x - e.0).min(e.2 - x).min(y - e.1).min(e.3 - y);
    (dx.hypot(dy), inside)
}

/// A tile directory of the cache that could not be used, and why (shown in the report and in
/// `infraloc status`; the search goes on without it).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SkippedTile {
    /// The tile directory.
    pub dir: PathBuf,
    /// Why it was skipped: the error naming its file.
    pub reason: String,
}

impl std::fmt::Display for SkippedTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.reason)
    }
}

/// What a search of the cache found.
struct Scan {
    /// Tiles covering the position with the margin, deepest first (ties: smallest id).
    covering: Vec<TileRef>,
    /// Tiles whose manifest could not be read.
    skipped: Vec<SkippedTile>,
    /// (distance, id, depth) of the nearest tile.
    nearest: Option<(f64, String, f64)>,
    /// A tile whose extent holds the position only in the prior's own UTM zone: its manifest's
    /// CRS is wrong. (id, manifest CRS, the prior's CRS).
    crs_mismatch: Option<(String, Crs, Crs)>,
}

fn scan(cache_dir: &Path, lat: f64, lon: f64, margin_m: f64) -> Result<Scan> {
    let tile_err = |msg: String| {
        Error::stage(
            crate::stage::StageName::Tile,
            format!("{}: {msg}", cache_dir.display()),
        )
    };
    let entries = fs::read_dir(cache_dir).map_err(|e| tile_err(e.to_string()))?;
    let mut dirs: Vec<PathBuf> = Vec::new();
    for e in entries {
        let e = e.map_err(|e| Error::io(cache_dir, e))?;
        let name = e.file_name();
        if name.to_string_lossy().starts_with('.') || !e.path().is_dir() {
            continue;
        }
        dirs.push(e.path());
    }
    dirs.sort();
    let prior_crs =
        (lat.abs() <= 90.0 && lon.is_finite()).then(|| Crs::Epsg(geo::utm_epsg_for(lat, lon)));
    let mut found = Scan {
        covering: Vec::new(),
        skipped: Vec::new(),
        nearest: None,
        crs_mismatch: None,
    };
    let mut depths: Vec<f64> = Vec::new();
    for dir in dirs {
        let manifest = read_manifest(&dir).and_then(|m| {
            let crs = manifest_crs(&m, &dir.join(MANIFEST))?;
            Ok((m, crs))
        });
        let (m, crs) = match manifest {
            Ok(v) => v,
            Err(e) => {
                found.skipped.push(SkippedTile {
                    dir: dir.clone(),
                    reason: e.to_string(),
                });
                continue;
            }
        };
        let extent = coverage(&m);
        geo::check_crs(crs).map_err(|e| Error::input(dir.join(MANIFEST), e.to_string()))?;
        let centre_wgs84 = || {
            geo::map_to_wgs84(
                crs,
                0.5 * (extent.0 + extent.2),
                0.5 * (extent.1 + extent.3),
            )
            .map_err(|e| Error::input(dir.join(MANIFEST), e.to_string()))
        };
        // Planar distances only where the CRS is meant to be used: a UTM zone's longitudes, or
        // (other projections) within a national grid's reach of the tile.
        let planar = match geo::utm_zone(crs) {
            Some(zone) => {
                let dlon = (lon - geo::central_meridian(zone) + 180.0).rem_euclid(360.0) - 180.0;
                dlon.abs() <= PLANAR_LON_RANGE_DEG
            }
            None => {
                let (clat, clon) = centre_wgs84()?;
                geo::great_circle_m(lat, lon, clat, clon) <= PLANAR_RANGE_M
            }
        };
        let (dist, inside) = if planar {
            let (x, y) = geo::wgs84_to_map(crs, lat, lon)
                .map_err(|e| Error::input(dir.join(MANIFEST), e.to_string()))?;
            let (dist, inside) = rect_distance(x, y, extent);
            if inside >= margin_m {
                let at = depths.partition_point(|d| *d >= inside);
                depths.insert(at, inside);
                found.covering.insert(
                    at,
                    TileRef {
                        id: m.id.clone(),
                        dir: dir.clone(),
                        crs,
                        position: (x, y),
                        extent,
                        skipped: Vec::new(),
                    },
                );
            }
            (dist, inside)
        } else {
            let (clat, clon) = centre_wgs84()?;
            (geo::great_circle_m(lat, lon, clat, clon), f64::NEG_INFINITY)
        };
        if found.nearest.as_ref().is_none_or(|(d, _, _)| dist < *d) {
            found.nearest = Some((dist, m.id.clone(), inside));
        }
        // A manifest written with the wrong zone: the extent holds the position in the prior's
        // own zone, not in the zone the manifest claims.
        if let Some(pc) = prior_crs.filter(|pc| *pc != crs && inside < 0.0) {
            if let Ok((x, y)) = geo::wgs84_to_map(pc, lat, lon) {
                if rect_distance(x, y, extent).1 >= 0.0 && found.crs_mismatch.is_none() {
                    found.crs_mismatch = Some((m.id.clone(), crs, pc));
                }
            }
        }
    }
    Ok(found)
}

/// Find the tile of `cache_dir` that covers WGS84 (`lat`, `lon`) with at least `margin_m` metres
/// to spare on every side (of the area where satellite and LiDAR layers overlap).
///
/// Reads manifests only. Hidden entries (temporaries of [`write_tile`]) are skipped; so is a
/// tile directory whose manifest cannot be read (it is listed in [`TileRef::skipped`], and named
/// in the error if no tile covers the position). If several tiles cover the position the one
/// where it lies deepest inside wins (ties: smallest id). If none does, the error names the
/// nearest tile and its distance in metres: planar in the tile's CRS, or, for positions more
/// than 9° of longitude from the tile's zone, the great-circle distance to the tile centre; a
/// tile whose extent holds the position only in the prior's own UTM zone is named as a CRS
/// mismatch instead. A missing or empty cache and a position no tile covers are errors of the
/// `tile` stage (`tile: CACHE_DIR: …`), as the other stages of a localization name themselves.
pub fn find_tile(cache_dir: &Path, lat: f64, lon: f64, margin_m: f64) -> Result<TileRef> {
    let found = scan(cache_dir, lat, lon, margin_m)?;
    match found.covering.into_iter().next() {
        Some(mut r) => {
            r.skipped = found.skipped;
            Ok(r)
        }
        None => Err(no_cover(
            cache_dir,
            lat,
            lon,
            margin_m,
            found.nearest,
            found.crs_mismatch,
            &found.skipped,
        )),
    }
}

fn no_cover(
    cache_dir: &Path,
    lat: f64,
    lon: f64,
    margin_m: f64,
    nearest: Option<(f64, String, f64)>,
    mismatch: Option<(String, Crs, Crs)>,
    skipped: &[SkippedTile],
) -> Error {
    let where_ = format!("lat {lat:.7}, lon {lon:.7}");
    let skipped_note = match skipped.len() {
        0 => String::new(),
        n => format!(
            " ({n} tile{} skipped: {})",
            if n == 1 { "" } else { "s" },
            skipped
                .iter()
                .map(|s| s.reason.as_str())
                .collect::<Vec<_>>()
                .join("; ")
        ),
    };
    let msg = match (mismatch, nearest) {
        // A tile holds the position in its own CRS, only too near its edge: that is the story,
        // whatever another tile's numbers would mean in another zone.
        (_, Some((0.0, id, inside))) => format!(
            "no tile covers {where_} with a {margin_m} m margin; nearest tile {id:?} has it only {inside:.1} m inside its edge"
        ),
        (Some((id, crs, pc)), _) => format!(
            "CRS mismatch: tile {id:?}'s manifest says {crs}, but its extent holds {where_} only in {pc}, the prior's UTM zone; the manifest's crs is wrong (re-import the tile with the right --crs)"
        ),
        (None, None) if skipped.is_empty() => {
            format!("no tiles in the cache (looking for {where_})")
        }
        (None, None) => format!("no usable tile in the cache (looking for {where_})"),
        (None, Some((dist, id, _))) => format!(
            "no tile covers {where_}; nearest tile {id:?} is {dist:.1} m away (margin {margin_m} m)"
        ),
    };
    Error::stage(
        crate::stage::StageName::Tile,
        format!("{}: {msg}{skipped_note}", cache_dir.display()),
    )
}

/// Below this fraction of valid samples in a LiDAR layer around the prior, the tile is refused:
/// an all-NaN or all-nodata layer would otherwise surface as a PnP or MI failure that points at
/// the camera.
pub(crate) const MIN_VALID_FRACTION: f64 = 0.10;

/// Fraction of valid samples of the reflectivity and height layers within `radius_m` of `(x,
/// y)`; a layer below [`MIN_VALID_FRACTION`] is an error of the `tile` stage naming the layer's
/// file. A disc that misses the grid counts as empty.
pub(crate) fn check_layers_near(
    tile: &Tile,
    dir: &Path,
    (x, y): (f64, f64),
    radius_m: f64,
) -> Result<()> {
    let g = tile.reflectivity.grid;
    let (c, r) = g.to_pixel(x, y);
    let rp = (radius_m / g.res).ceil().max(1.0);
    let (mut n, mut refl_ok, mut height_ok) = (0usize, 0usize, 0usize);
    let r0 = (r - rp).floor() as i64;
    let c0 = (c - rp).floor() as i64;
    for row in r0..=(r + rp).ceil() as i64 {
        for col in c0..=(c + rp).ceil() as i64 {
            let (dc, dr) = (col as f64 - c, row as f64 - r);
            if dc * dc + dr * dr > rp * rp {
                continue;
            }
            n += 1;
            if row < 0 || col < 0 {
                continue;
            }
            let (col, row) = (col as usize, row as usize);
            if let Some(v) = tile.reflectivity.get(col, row) {
                refl_ok += usize::from(Some(v) != tile.reflectivity.nodata);
            }
            if let Some(h) = tile.height.get(col, row) {
                height_ok += usize::from(h.is_finite() && Some(h) != tile.height.nodata);
            }
        }
    }
    let n = n.max(1) as f64;
    for (layer, file, ok) in [
        ("height", HEIGHT_FILE, height_ok),
        ("reflectivity", REFLECTIVITY_FILE, refl_ok),
    ] {
        let frac = ok as f64 / n;
        if frac < MIN_VALID_FRACTION {
            return Err(Error::stage(
                crate::stage::StageName::Tile,
                format!(
                    "{}: {layer} layer has valid data in only {:.1} % of the {radius_m:.0} m around the prior (need {:.0} %): the map tile is damaged or does not cover this ground",
                    dir.join(file).display(),
                    100.0 * frac,
                    100.0 * MIN_VALID_FRACTION
                ),
            ));
        }
    }
    Ok(())
}

/// The tile a localization uses at WGS84 (`lat`, `lon`): the covering tiles ([`find_tile`]'s
/// order) are loaded in turn, each checked with [`check_layers_near`] over `radius_m`; a tile
/// that fails to load is skipped (and listed) in favour of the next one that covers the
/// position. The error, when none is usable, is the first covering tile's (a `tile:` line naming
/// its file and layer), or [`find_tile`]'s when none covers.
pub fn load_covering(
    cache_dir: &Path,
    lat: f64,
    lon: f64,
    margin_m: f64,
    radius_m: f64,
) -> Result<(Tile, TileRef)> {
    let found = scan(cache_dir, lat, lon, margin_m)?;
    let mut skipped = found.skipped;
    let mut first_err = None;
    for mut r in found.covering {
        let loaded = load_tile(&r.dir)
            .map_err(|e| Error::stage(crate::stage::StageName::Tile, e.to_string()))
            .and_then(|t| check_layers_near(&t, &r.dir, r.position, radius_m).map(|_| t));
        match loaded {
            Ok(t) => {
                r.skipped = skipped;
                return Ok((t, r));
            }
            Err(e) => {
                skipped.push(SkippedTile {
                    dir: r.dir.clone(),
                    reason: e.to_string(),
                });
                first_err.get_or_insert(e);
            }
        }
    }
    Err(first_err.unwrap_or_else(|| {
        no_cover(
            cache_dir,
            lat,
            lon,
            margin_m,
            found.nearest,
            found.crs_mismatch,
            &skipped,
        )
    }))
}
