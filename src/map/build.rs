//! `infraloc tile build`: a node's tile from point clouds (I/O shell; docs/map.md, "From a survey
//! to a tile").
//!
//! 1. The inputs' headers give the tile's CRS (all must agree; `--crs` for inputs without one).
//! 2. The points in the box, widened by half the ground window, are kept compactly (12 bytes a
//!    point: cell, height, raw intensity, input), one chunk of the input at a time.
//! 3. Ground: an input with LAS class 2 points is taken as classified (its class 2 points are the
//!    ground); for the others, the lowest point of each ground cell, opened (erosion then
//!    dilation) with a square window wider than a car, is the ground surface, and points at most
//!    the tolerance above it are ground. An opening keeps planes and slopes and removes whatever
//!    is narrower than the window (parked cars, people, trunks; canopy has ground returns under it).
//! 4. Each tile cell with ground points gets the median of their normalised intensities
//!    (reflectivity, rounded half to even, 1..=255; 0 = no data) and the median of their heights.
//!    Intensity is normalised per input: 8-bit inputs (largest ≤ 255) as they are; every wider
//!    input by one shared 255 / (2^b − 1), b the bits of the largest value among all the wider
//!    inputs (12- and 16-bit sensors), so that flight lines of one survey keep one scale whatever
//!    each line's brightest point.
//! 5. Satellite layer: an orthophoto warped bilinearly into the satellite grid (any CRS the geodesy
//!    relates to the tile's), else the colour of the highest point of each cell (the view from
//!    above), 16-bit colours scaled by 1/257 when the input's largest exceeds 255.

use super::cloud::{self, Box2, Cloud, CloudPoint, Kind, CLASS_GROUND};
use super::geotiff::{Image, Pixels};
use super::{Crs, GeoGrid, MapError, Raster, Tile};
use crate::error::{Error, Result};
use crate::geo;
use std::path::{Path, PathBuf};

/// Reflectivity no-data value of built tiles.
const REFLECTIVITY_NODATA: u8 = 0;
/// Largest tile accepted, cells per layer: a 1 km tile at 5 cm. Bounds memory on a mistyped box.
const MAX_CELLS: usize = 1 << 29;
/// High bit of a kept point's `src`: the point is LAS class 2.
const SRC_GROUND_CLASS: u16 = 0x8000;
/// Largest number of inputs (the rest of `src`).
const MAX_INPUTS: usize = 0x7fff;

/// Where the tile is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Area {
    /// `[xmin, ymin, xmax, ymax]`, map CRS.
    Box(Box2),
    /// A square of `size` metres centred on a map point.
    Center { xy: (f64, f64), size: f64 },
    /// A square of `size` metres centred on a WGS84 position (e.g. the node's GPS fix).
    CenterWgs84 { lat: f64, lon: f64, size: f64 },
    /// The clouds' own extent ([`cloud::extent`]).
    Extent,
}

/// Ground filter parameters (inputs without LAS classification).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GroundParams {
    /// Ground cell, metres: an integer multiple of the tile resolution.
    pub cell: f64,
    /// Opening window, metres: wider than the widest object to remove.
    pub window: f64,
    /// Height above the opened surface still counted as ground, metres.
    pub tolerance: f64,
}

/// What `tile build` is asked for.
#[derive(Debug, Clone)]
pub(crate) struct BuildSpec {
    /// Tile id.
    pub id: String,
    /// Point clouds (files, or Autoware map directories).
    pub inputs: Vec<PathBuf>,
    /// The tile's CRS when the inputs do not say (or to confirm what they say).
    pub crs: Option<Crs>,
    /// `crs` replaces whatever CRS the inputs state (a wrong label), with a warning each.
    pub override_crs: bool,
    /// The tile's extent.
    pub area: Area,
    /// LiDAR layer resolution, metres.
    pub res: f64,
    /// Ground filter.
    pub ground: GroundParams,
    /// Orthophoto for the satellite layer (GeoTIFF, or PNG/TIFF + world file in the tile's CRS).
    pub orthophoto: Option<PathBuf>,
    /// Satellite layer resolution, metres (default: `res`).
    pub satellite_res: Option<f64>,
}

/// A kept point: 12 bytes, so that a dense box fits in little memory.
#[derive(Debug, Clone, Copy)]
struct Kept {
    /// Cell of the read grid.
    cell: u32,
    /// Height.
    z: f32,
    /// Raw intensity.
    intensity: u16,
    /// Input index, high bit = LAS class 2.
    src: u16,
}

/// Per-input facts gathered while reading.
#[derive(Debug, Clone, Copy, Default)]
struct InputFacts {
    stats: cloud::ReadStats,
    /// Kept points of class 2.
    ground_class: u64,
}

/// A north-up grid snapped to multiples of `res` covering `b`.
fn snapped_grid(crs: Crs, b: &Box2, res: f64, what: &str) -> Result<GeoGrid> {
    let x0 = (b[0] / res).floor() * res;
    let y0 = (b[3] / res).ceil() * res;
    let width = ((b[2] - x0) / res - 1e-9).ceil().max(1.0);
    let height = ((y0 - b[1]) / res - 1e-9).ceil().max(1.0);
    if width * height > MAX_CELLS as f64 {
        return Err(MapError::TooManyCells {
            what: what.to_string(),
            width,
            height,
            res,
            max: MAX_CELLS,
        }
        .into());
    }
    Ok(GeoGrid {
        crs,
        x0,
        y0,
        res,
        width: width as usize,
        height: height as usize,
    })
}

/// The inputs' CRS, checked against `--crs` and the geodesy.
fn tile_crs(clouds: &[Cloud], flag: Option<Crs>) -> Result<Crs> {
    let mut crs = flag;
    let mut from: Option<&Path> = None;
    for c in clouds {
        let Some(k) = c.crs else { continue };
        geo::check_crs(k).map_err(|e| Error::input(&c.path, format!("CRS: {e}")))?;
        match crs {
            Some(t) if t != k => {
                let other = from.map_or("--crs".to_string(), |p| p.display().to_string());
                return Err(Error::input(
                    &c.path,
                    format!(
                        "is in {k} but {other} is {t}; reproject (e.g. pdal translate with filters.reprojection) or build in {k}"
                    ),
                ));
            }
            _ => {
                if crs.is_none() {
                    from = Some(&c.path);
                }
                crs = Some(k);
            }
        }
    }
    let crs = match crs {
        Some(c) => c,
        None => {
            let first = clouds
                .first()
                .map(|c| c.path.as_path())
                .unwrap_or(Path::new("-"));
            return Err(Error::input(
                first,
                "has no CRS (no GeoTIFF keys or WKT; PCD never has one); give --crs EPSG:<code>",
            ));
        }
    };
    if flag == Some(crs) || from.is_none() {
        geo::check_crs(crs).map_err(|source| {
            // Name the cloud that takes --crs, so that the line says whose CRS it is.
            match clouds.iter().find(|c| c.crs.is_none()) {
                Some(c) => Error::input(&c.path, format!("--crs {crs}: {source}")),
                None => MapError::Flag {
                    flag: "--crs",
                    source,
                }
                .into(),
            }
        })?;
    }
    Ok(crs)
}

/// The box of the tile in its CRS.
fn resolve_area(area: Area, crs: Crs, clouds: &[Cloud]) -> Result<Box2> {
    let square = |(x, y): (f64, f64), size: f64| -> Result<Box2> {
        if !(size > 0.0) || !size.is_finite() {
            return Err(MapError::NotPositive {
                flag: "--size",
                value: size,
            }
            .into());
        }
        let h = size / 2.0;
        Ok([x - h, y - h, x + h, y + h])
    };
    let b = match area {
        Area::Box(b) => b,
        Area::Center { xy, size } => square(xy, size)?,
        Area::CenterWgs84 { lat, lon, size } => {
            let xy = geo::wgs84_to_map(crs, lat, lon).map_err(|source| MapError::Flag {
                flag: "--center-wgs84",
                source,
            })?;
            square(xy, size)?
        }
        Area::Extent => cloud::extent(clouds)?,
    };
    if !b.iter().all(|v| v.is_finite()) || !(b[2] > b[0]) || !(b[3] > b[1]) {
        return Err(MapError::BadBox { bbox: b }.into());
    }
    Ok(b)
}

/// Check the inputs' count and the grid and ground parameters; returns ground cell ÷ `--res`.
fn check_params(spec: &BuildSpec) -> Result<usize> {
    if spec.inputs.is_empty() {
        return Err(MapError::NoInputs.into());
    }
    if spec.inputs.len() > MAX_INPUTS {
        return Err(MapError::TooManyInputs {
            inputs: spec.inputs.len(),
            max: MAX_INPUTS,
        }
        .into());
    }
    let res = spec.res;
    if !(res > 0.0) || !res.is_finite() {
        return Err(MapError::NotPositive {
            flag: "--res",
            value: res,
        }
        .into());
    }
    let gp = spec.ground;
    let ratio = (gp.cell / res).round();
    if !(ratio >= 1.0) || (gp.cell - ratio * res).abs() > 1e-9 * gp.cell.max(1.0) {
        return Err(MapError::GroundCell { cell: gp.cell, res }.into());
    }
    if !(gp.window >= gp.cell) || !(gp.tolerance >= 0.0) {
        return Err(MapError::GroundWindow {
            window: gp.window,
            tolerance: gp.tolerance,
        }
        .into());
    }
    Ok(ratio as usize)
}

/// The read grid: the tile widened on every side by `margin_cells` cells (whole ground cells
/// covering half the ground window), and its box.
fn read_grid(tile_grid: &GeoGrid, margin_cells: usize) -> Result<(GeoGrid, Box2)> {
    let margin = margin_cells as f64 * tile_grid.res;
    let (tx0, ty0, tx1, ty1) = tile_grid.bounds();
    let read_box = [tx0 - margin, ty0 - margin, tx1 + margin, ty1 + margin];
    let read_grid = GeoGrid {
        x0: tx0 - margin,
        y0: ty1 + margin,
        width: tile_grid.width + 2 * margin_cells,
        height: tile_grid.height + 2 * margin_cells,
        ..*tile_grid
    };
    if read_grid.len() > u32::MAX as usize {
        return Err(MapError::MarginTooLarge.into());
    }
    Ok((read_grid, read_box))
}

/// Read every cloud's points in `read_box` onto `read_grid`, feeding the highest-colour grid
/// `top` when there is one; the kept points and each input's facts.
fn read_points(
    clouds: &[Cloud],
    read_box: &Box2,
    read_grid: &GeoGrid,
    mut top: Option<&mut TopColour>,
) -> Result<(Vec<Kept>, Vec<InputFacts>)> {
    let res = read_grid.res;
    let mut kept: Vec<Kept> = Vec::new();
    let mut facts = vec![InputFacts::default(); clouds.len()];
    for (i, c) in clouds.iter().enumerate() {
        let mut ground_class = 0u64;
        let mut top_here = top.as_deref_mut();
        let stats = cloud::read(c, read_box, |p: &CloudPoint| {
            let [x, y, z] = p.xyz;
            let col = ((x - read_grid.x0) / res).floor();
            let row = ((read_grid.y0 - y) / res).floor();
            if !(col >= 0.0 && row >= 0.0) {
                return;
            }
            let (col, row) = (col as usize, row as usize);
            if col >= read_grid.width || row >= read_grid.height || !z.is_finite() {
                return;
            }
            let is_ground = p.class == CLASS_GROUND;
            ground_class += u64::from(is_ground);
            kept.push(Kept {
                cell: (row * read_grid.width + col) as u32,
                z: z as f32,
                intensity: p.intensity,
                src: i as u16 | if is_ground { SRC_GROUND_CLASS } else { 0 },
            });
            if let (Some(t), Some(rgb)) = (top_here.as_deref_mut(), p.rgb) {
                t.offer(x, y, z, rgb, i);
            }
        })?;
        facts[i].stats = stats;
        facts[i].ground_class = ground_class;
    }
    Ok((kept, facts))
}

/// The provenance line of each input.
fn source_lines(
    clouds: &[Cloud],
    facts: &[InputFacts],
    classified: &[bool],
    full: &[f64],
) -> Vec<String> {
    clouds
        .iter()
        .zip(facts)
        .zip(classified)
        .zip(full)
        .map(|(((c, f), cl), full)| {
            format!(
                "point cloud: {} ({}, {} of {} points in the box and margin, ground {}, intensity full scale {})",
                c.path.display(),
                match c.kind {
                    Kind::Las => "LAS/LAZ",
                    Kind::Copc => "COPC",
                    Kind::Pcd(_) => "PCD",
                },
                f.stats.kept,
                f.stats.decoded,
                if *cl { "LAS class 2" } else { "lowest-surface filter" },
                full
            )
        })
        .collect()
}

/// The satellite layer: the orthophoto warped onto `sat_grid`, else the highest point's colour
/// per cell; its provenance line is added to `sources`.
fn satellite_layer(
    ortho: Option<(&Path, (Image, GeoGrid))>,
    top: Option<TopColour>,
    facts: &[InputFacts],
    sat_grid: &GeoGrid,
    names: &str,
    sources: &mut Vec<String>,
) -> Result<Raster<[u8; 3]>> {
    match (ortho, top) {
        (Some((path, img)), _) => {
            sources.push(format!("satellite: {} warped bilinearly", path.display()));
            warp_rgb(&img, path, sat_grid)
        }
        (None, Some(t)) => {
            let scale: Vec<f64> = facts
                .iter()
                .map(|f| {
                    if f.stats.max_rgb > 255 {
                        1.0 / 257.0
                    } else {
                        1.0
                    }
                })
                .collect();
            if t.filled == 0 {
                return Err(Error::input(
                    names,
                    "no satellite layer: the points in the box carry no RGB; give --orthophoto",
                ));
            }
            sources.push("satellite: RGB of the highest point per cell".into());
            Ok(t.into_raster(&scale))
        }
        (None, None) => unreachable!("the top colour is kept whenever there is no orthophoto"),
    }
}

/// Build the tile. Returns it and the provenance lines (sources, note).
pub(crate) fn build_tile(spec: &BuildSpec) -> Result<(Tile, super::cache::Provenance)> {
    let ratio = check_params(spec)?;
    let (res, gp) = (spec.res, spec.ground);
    // An Autoware map directory's files are chosen by the box, which needs the CRS first: no
    // directory has a CRS, so a provisional everything-box is fine for choosing, then refined.
    let everything = [f64::MIN, f64::MIN, f64::MAX, f64::MAX];
    let mut probe: Vec<Cloud> = spec
        .inputs
        .iter()
        .map(|p| cloud::open(p, &everything))
        .collect::<Result<_>>()?;
    cloud::settle_crs(&mut probe, spec.override_crs, spec.crs)?;
    let crs = tile_crs(&probe, spec.crs)?;
    let bx = resolve_area(spec.area, crs, &probe)?;
    let tile_grid = snapped_grid(crs, &bx, res, "tile")?;
    let margin_cells = (gp.window / 2.0 / gp.cell).ceil() as usize * ratio;
    let (read_grid, read_box) = read_grid(&tile_grid, margin_cells)?;
    let clouds: Vec<Cloud> = spec
        .inputs
        .iter()
        .zip(probe)
        .map(|(p, c)| match c.kind {
            Kind::Pcd(_) if p.is_dir() => cloud::open(p, &read_box),
            _ => Ok(c),
        })
        .collect::<Result<_>>()?;
    let sat_grid = match spec.satellite_res {
        Some(r) if !(r > 0.0) || !r.is_finite() => {
            return Err(MapError::NotPositive {
                flag: "--satellite-res",
                value: r,
            }
            .into())
        }
        Some(r) => snapped_grid(crs, &bx, r, "satellite")?,
        None => tile_grid,
    };
    // The orthophoto is read before the clouds so that a bad one fails fast.
    let ortho = match &spec.orthophoto {
        Some(p) => Some((p.as_path(), read_orthophoto(p, crs)?)),
        None => None,
    };
    let mut top = ortho.is_none().then(|| TopColour::new(sat_grid));
    let (mut kept, facts) = read_points(&clouds, &read_box, &read_grid, top.as_mut())?;
    let names = spec
        .inputs
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ");
    // Inputs whose intensity is all zero have none (LAS makes the field optional by zeroing it).
    for (c, f) in clouds.iter().zip(&facts) {
        if f.stats.kept > 0 && f.stats.max_intensity == 0 {
            return Err(Error::input(
                c.path.clone(),
                format!(
                    "no intensity: all {} points read have intensity 0; reflectivity needs it",
                    f.stats.decoded
                ),
            ));
        }
    }
    let classified: Vec<bool> = facts.iter().map(|f| f.ground_class > 0).collect();
    let surface = ground_surface(&kept, &classified, &read_grid, ratio, gp);
    let full = full_scales(facts.iter().map(|f| f.stats.max_intensity));
    let (refl, height, n_ground) = rasterize(
        &mut kept,
        &classified,
        &full,
        surface.as_ref(),
        &read_grid,
        &tile_grid,
        margin_cells,
        ratio,
        gp.tolerance,
    );
    drop(kept);
    if n_ground == 0 {
        let (a, b, c, d) = tile_grid.bounds();
        let read: u64 = facts.iter().map(|f| f.stats.kept).sum();
        return Err(Error::input(
            names,
            format!(
                "no ground points in the box x {a}..{c}, y {b}..{d} ({crs}; {read} points within the box and its margin)"
            ),
        ));
    }
    let mut sources = source_lines(&clouds, &facts, &classified, &full);
    let satellite = satellite_layer(ortho, top, &facts, &sat_grid, &names, &mut sources)?;
    let note = format!(
        "tile build: {res} m grid; ground cell {} m, window {} m, tolerance {} m; reflectivity = \
         median normalised ground intensity, height = median ground height ({n_ground} cells)",
        gp.cell, gp.window, gp.tolerance
    );
    let tile = Tile {
        id: spec.id.clone(),
        satellite,
        reflectivity: refl,
        height,
        control_points: Vec::new(),
    };
    let provenance = super::cache::Provenance {
        sources,
        note: Some(note),
        ..Default::default()
    };
    Ok((tile, provenance))
}

/// The intensity that maps to 255, per input from its largest intensity: 255 for 8-bit inputs
/// (largest ≤ 255); for all wider inputs one value, the smallest 2^b − 1 that holds the largest
/// intensity among them. Sharing it keeps the flight lines of one survey on one scale: a line
/// whose brightest point is below half the sensor's range would otherwise come out twice as
/// bright as its neighbour.
fn full_scales(maxima: impl Iterator<Item = u16> + Clone) -> Vec<f64> {
    let wide = maxima.clone().filter(|&m| m > 255).max().unwrap_or(0);
    let wide_full = if wide == 0 {
        255.0
    } else {
        f64::from(((1u32 << (16 - wide.leading_zeros())) - 1) as u16)
    };
    maxima
        .map(|m| if m <= 255 { 255.0 } else { wide_full })
        .collect()
}

/// The opened lowest surface on the ground cells of the read grid (`None` when every input is
/// classified): `+∞` where no unclassified point lies within the window.
fn ground_surface(
    kept: &[Kept],
    classified: &[bool],
    read: &GeoGrid,
    ratio: usize,
    gp: GroundParams,
) -> Option<Vec<f32>> {
    if classified.iter().all(|&c| c) {
        return None;
    }
    let (gw, gh) = (read.width.div_ceil(ratio), read.height.div_ceil(ratio));
    let mut low = vec![f32::INFINITY; gw * gh];
    for k in kept {
        if classified[usize::from(k.src & !SRC_GROUND_CLASS)] {
            continue;
        }
        let (row, col) = (k.cell as usize / read.width, k.cell as usize % read.width);
        let g = (row / ratio) * gw + col / ratio;
        low[g] = low[g].min(k.z);
    }
    let r = (gp.window / 2.0 / gp.cell).round() as usize;
    // Erosion ignores empty cells (+∞); dilation of the eroded surface must ignore them too.
    let eroded = filter2(&low, gw, gh, r, f32::INFINITY, f32::min);
    let opened = filter2(&eroded, gw, gh, r, f32::NEG_INFINITY, |a, b| {
        if b.is_finite() {
            a.max(b)
        } else {
            a
        }
    });
    Some(
        opened
            .into_iter()
            .map(|v| if v.is_finite() { v } else { f32::INFINITY })
            .collect(),
    )
}

/// Separable square min/max filter of radius `r` cells (rows, then columns).
fn filter2(
    v: &[f32],
    w: usize,
    h: usize,
    r: usize,
    init: f32,
    op: fn(f32, f32) -> f32,
) -> Vec<f32> {
    let pass = |src: &[f32], len: usize, n: usize, stride: usize, step: usize| -> Vec<f32> {
        let mut out = vec![init; src.len()];
        for line in 0..n {
            let base = line * stride;
            for i in 0..len {
                let (a, b) = (i.saturating_sub(r), (i + r).min(len - 1));
                let mut acc = init;
                for j in a..=b {
                    acc = op(acc, src[base + j * step]);
                }
                out[base + i * step] = acc;
            }
        }
        out
    };
    let rows = pass(v, w, h, w, 1);
    pass(&rows, h, w, 1, w)
}

/// Reflectivity and height of the tile from the kept points; the number of cells with ground.
#[allow(clippy::too_many_arguments)]
fn rasterize(
    kept: &mut [Kept],
    classified: &[bool],
    full: &[f64],
    surface: Option<&Vec<f32>>,
    read: &GeoGrid,
    tile: &GeoGrid,
    margin: usize,
    ratio: usize,
    tolerance: f64,
) -> (Raster<u8>, Raster<f32>, usize) {
    let gw = read.width.div_ceil(ratio);
    let is_ground = |k: &Kept| -> bool {
        let src = usize::from(k.src & !SRC_GROUND_CLASS);
        if classified[src] {
            return k.src & SRC_GROUND_CLASS != 0;
        }
        let (row, col) = (k.cell as usize / read.width, k.cell as usize % read.width);
        let s = surface.map_or(f32::INFINITY, |s| s[(row / ratio) * gw + col / ratio]);
        f64::from(k.z) <= f64::from(s) + tolerance
    };
    // The tile's cell of a read-grid cell, if inside the tile.
    let tile_cell = |cell: u32| -> Option<u32> {
        let (row, col) = (cell as usize / read.width, cell as usize % read.width);
        let (r, c) = (row.checked_sub(margin)?, col.checked_sub(margin)?);
        (r < tile.height && c < tile.width).then(|| (r * tile.width + c) as u32)
    };
    // Keep the tile's ground points, renumbered to tile cells, and group them by cell.
    let mut n = 0;
    for i in 0..kept.len() {
        let k = kept[i];
        if !is_ground(&k) {
            continue;
        }
        if let Some(c) = tile_cell(k.cell) {
            kept[n] = Kept { cell: c, ..k };
            n += 1;
        }
    }
    let ground = &mut kept[..n];
    ground.sort_unstable_by_key(|k| k.cell);
    let mut refl = Raster::filled(*tile, REFLECTIVITY_NODATA, Some(REFLECTIVITY_NODATA));
    let mut height = Raster::filled(*tile, f32::NAN, Some(f32::NAN));
    let (mut vals, mut zs) = (Vec::new(), Vec::new());
    let mut cells = 0;
    for run in ground.chunk_by(|a, b| a.cell == b.cell) {
        vals.clear();
        zs.clear();
        for k in run {
            let src = usize::from(k.src & !SRC_GROUND_CLASS);
            vals.push(f64::from(k.intensity) * 255.0 / full[src]);
            zs.push(f64::from(k.z));
        }
        let c = run[0].cell as usize;
        let r = median(&mut vals).round_ties_even().clamp(1.0, 255.0);
        refl.data[c] = r as u8;
        height.data[c] = median(&mut zs) as f32;
        cells += 1;
    }
    (refl, height, cells)
}

/// Median (mean of the middle two for an even count) of a non-empty slice.
fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let m = n / 2;
    let (lo, mid, _) = v.select_nth_unstable_by(m, f64::total_cmp);
    let mid = *mid;
    if n % 2 == 1 {
        mid
    } else {
        let below = lo.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (below + mid) / 2.0
    }
}

/// The colour of the highest point per satellite cell, streamed.
struct TopColour {
    grid: GeoGrid,
    z: Vec<f32>,
    rgb: Vec<[u16; 3]>,
    src: Vec<u16>,
    filled: usize,
}

impl TopColour {
    fn new(grid: GeoGrid) -> Self {
        TopColour {
            grid,
            z: vec![f32::NEG_INFINITY; grid.len()],
            rgb: vec![[0; 3]; grid.len()],
            src: vec![0; grid.len()],
            filled: 0,
        }
    }

    fn offer(&mut self, x: f64, y: f64, z: f64, rgb: [u16; 3], src: usize) {
        let g = self.grid;
        let col = ((x - g.x0) / g.res).floor();
        let row = ((g.y0 - y) / g.res).floor();
        if !(col >= 0.0 && row >= 0.0 && (col as usize) < g.width && (row as usize) < g.height) {
            return;
        }
        let i = row as usize * g.width + col as usize;
        let z = z as f32;
        if z > self.z[i] {
            self.filled += usize::from(self.z[i] == f32::NEG_INFINITY);
            self.z[i] = z;
            self.rgb[i] = rgb;
            self.src[i] = src as u16;
        }
    }

    fn into_raster(self, scale: &[f64]) -> Raster<[u8; 3]> {
        let data = self
            .rgb
            .iter()
            .zip(&self.src)
            .map(|(c, &s)| {
                let k = scale[usize::from(s)];
                c.map(|v| (f64::from(v) * k).round().min(255.0) as u8)
            })
            .collect();
        Raster {
            grid: self.grid,
            data,
            nodata: None,
        }
    }
}

/// Read an orthophoto: a GeoTIFF (its own CRS), or a PNG/TIFF with a world file in `crs`.
fn read_orthophoto(path: &Path, crs: Crs) -> Result<(Image, GeoGrid)> {
    let (img, grid, _) = super::import::read_source_any_crs(path, crs, "--orthophoto")?;
    match img.pixels {
        Pixels::Gray8(_) | Pixels::Rgb8(_) => Ok((img, grid)),
        Pixels::F32(_) => Err(Error::input(
            path,
            "orthophoto is f32; expected 8-bit RGB or gray",
        )),
    }
}

/// Warp an orthophoto into `dst` bilinearly (pixel centres at integer coordinates, as GDAL's
/// bilinear warp at the same scale); every target pixel must fall within the source image.
fn warp_rgb((img, src): &(Image, GeoGrid), path: &Path, dst: &GeoGrid) -> Result<Raster<[u8; 3]>> {
    let chans = match &img.pixels {
        Pixels::Rgb8(_) => 3,
        _ => 1,
    };
    let bytes: &[u8] = match &img.pixels {
        Pixels::Rgb8(b) | Pixels::Gray8(b) => b,
        Pixels::F32(_) => unreachable!("read_orthophoto refuses f32"),
    };
    let (w, h) = (src.width, src.height);
    let mut data = Vec::with_capacity(dst.len());
    let mut outside = 0usize;
    let mut first_out = None;
    for row in 0..dst.height {
        for col in 0..dst.width {
            let (x, y) = dst.pixel_center(col, row);
            let (sx, sy) = geo::map_to_map(dst.crs, src.crs, x, y)
                .map_err(|e| Error::input(path, format!("warp: {e}")))?;
            let (fc, fr) = src.to_pixel(sx, sy);
            let inside = fc >= -0.5 && fr >= -0.5 && fc <= w as f64 - 0.5 && fr <= h as f64 - 0.5;
            if !inside {
                outside += 1;
                first_out.get_or_insert((x, y));
                data.push([0; 3]);
                continue;
            }
            // Edge pixels replicate outward over their outer half.
            let fc = fc.clamp(0.0, (w - 1) as f64);
            let fr = fr.clamp(0.0, (h - 1) as f64);
            let (c0, r0) = (fc.floor() as usize, fr.floor() as usize);
            let (c1, r1) = ((c0 + 1).min(w - 1), (r0 + 1).min(h - 1));
            let (ax, ay) = (fc - c0 as f64, fr - r0 as f64);
            let px = |c: usize, r: usize, k: usize| -> f64 {
                let i = (r * w + c) * chans;
                f64::from(bytes[i + k.min(chans - 1)])
            };
            let mut out = [0u8; 3];
            for (k, o) in out.iter_mut().enumerate() {
                let top = px(c0, r0, k) * (1.0 - ax) + px(c1, r0, k) * ax;
                let bot = px(c0, r1, k) * (1.0 - ax) + px(c1, r1, k) * ax;
                *o = (top * (1.0 - ay) + bot * ay).round().clamp(0.0, 255.0) as u8;
            }
            data.push(out);
        }
    }
    if outside > 0 {
        let (x, y) = first_out.unwrap_or_default();
        let (a, b, c, d) = src.bounds();
        return Err(Error::input(
            path,
            format!(
                "orthophoto does not cover the box: {outside} of {} satellite pixels fall outside it \
                 (first at x {x:.2}, y {y:.2} {}); its extent is x {a}..{c}, y {b}..{d} {}",
                dst.len(),
                dst.crs,
                src.crs
            ),
        ));
    }
    Ok(Raster {
        grid: *dst,
        data,
        nodata: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_and_full_scale() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&mut [7.0]), 7.0);
        let fs = |m: &[u16]| full_scales(m.iter().copied());
        assert_eq!(fs(&[200]), [255.0]);
        assert_eq!(fs(&[4000]), [4095.0]);
        assert_eq!(fs(&[65535]), [65535.0]);
        assert_eq!(fs(&[256]), [511.0]);
        // Two flight lines of one 16-bit survey, one of them dark, and an 8-bit file.
        assert_eq!(fs(&[30000, 50000, 200]), [65535.0, 65535.0, 255.0]);
        assert_eq!(fs(&[30000, 4000]), [32767.0, 32767.0]);
    }

    #[test]
    fn opening_removes_narrow_bumps_and_keeps_slopes() {
        // A 1-D ramp (slope 0.1 per cell) with a 3-cell box 1.5 above it, on a 30x1 grid.
        let w = 30;
        let mut v: Vec<f32> = (0..w).map(|i| 0.1 * i as f32).collect();
        for x in &mut v[10..13] {
            *x += 1.5;
        }
        v[20] = f32::INFINITY; // an empty cell
        let e = filter2(&v, w, 1, 3, f32::INFINITY, f32::min);
        let o = filter2(&e, w, 1, 3, f32::NEG_INFINITY, |a, b| {
            if b.is_finite() {
                a.max(b)
            } else {
                a
            }
        });
        for (i, z) in o.iter().enumerate() {
            let want = 0.1 * i as f32;
            // Away from the ends (where the window is cut) the ramp is kept to within the slope
            // times the bump's width, and the bump is gone.
            if (3..w - 3).contains(&i) {
                assert!((z - want).abs() <= 0.3 + 1e-5, "cell {i}: {z} vs {want}");
            }
        }
        // On flat ground the opening is exact: the bump is removed, the empty cell filled.
        let mut v = vec![5.0f32; w];
        v[10..13].fill(6.5);
        v[20] = f32::INFINITY;
        let e = filter2(&v, w, 1, 3, f32::INFINITY, f32::min);
        let o = filter2(&e, w, 1, 3, f32::NEG_INFINITY, |a, b| {
            if b.is_finite() {
                a.max(b)
            } else {
                a
            }
        });
        assert_eq!(o, vec![5.0f32; w]);
    }
}
