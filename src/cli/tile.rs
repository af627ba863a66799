//! `infraloc tile …`: tile cache operations (docs/interfaces.md, "Tile cache" and "Command line").

use crate::error::{Error, Result};
use crate::map::cache::write_tile_with;
use crate::map::import::{import_tile, Source};
use crate::map::{Crs, MapError};
use std::path::PathBuf;

/// Tile subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Build CACHE/TILE_ID/ from GeoTIFFs (georeference from their tags) or PNG/TIFF + world
    /// files (.pgw/.tfw/.wld, centre-of-pixel convention; found beside the image if not given).
    Import(Box<ImportArgs>),
    /// Build CACHE/TILE_ID/ from point clouds (LAS/LAZ/COPC/PCD, Autoware split maps): ground
    /// reflectivity and height rasterised in the clouds' CRS, satellite layer from an orthophoto
    /// or the points' RGB (docs/map.md, "From a survey to a tile").
    Build(Box<BuildArgs>),
}

/// Arguments of `tile build`.
#[derive(Debug, clap::Args)]
pub struct BuildArgs {
    /// Point clouds: .las, .laz, .copc.laz, .pcd, or an Autoware split-map directory.
    #[arg(required = true, value_name = "CLOUD")]
    pub inputs: Vec<PathBuf>,
    /// Tile cache directory (created if missing).
    #[arg(long, value_name = "CACHE")]
    pub out: PathBuf,
    /// Tile id (the tile's directory name).
    #[arg(long, value_name = "TILE_ID")]
    pub id: String,
    /// The tile's CRS, for clouds that carry none (PCD); must match the clouds' own.
    #[arg(long, value_name = "EPSG:N")]
    pub crs: Option<String>,
    /// Take --crs instead of the CRS the clouds state (a wrong label), with a warning per cloud.
    #[arg(long)]
    pub override_crs: bool,
    /// Tile box in the map CRS (default: the clouds' extent, at most 2000 m a side).
    #[arg(long, value_name = "XMIN,YMIN,XMAX,YMAX", value_parser = floats::<4>,
          allow_hyphen_values = true, conflicts_with_all = ["center", "center_wgs84"])]
    pub bbox: Option<[f64; 4]>,
    /// Tile centre in the map CRS (a square of --size).
    #[arg(long, value_name = "X,Y", value_parser = floats::<2>, allow_hyphen_values = true,
          conflicts_with = "center_wgs84")]
    pub center: Option<[f64; 2]>,
    /// Tile centre as WGS84 latitude,longitude, e.g. the node's GPS fix (a square of --size).
    #[arg(long, value_name = "LAT,LON", value_parser = floats::<2>, allow_hyphen_values = true)]
    pub center_wgs84: Option<[f64; 2]>,
    /// Side of the square tile around --center / --center-wgs84, metres.
    #[arg(long, value_name = "M", default_value_t = 200.0)]
    pub size: f64,
    /// LiDAR layer resolution, metres.
    #[arg(long, value_name = "M", default_value_t = 0.1)]
    pub res: f64,
    /// Satellite layer from this orthophoto (GeoTIFF in any supported CRS, or PNG/TIFF + world
    /// file in the tile's CRS), warped bilinearly; default: the points' RGB.
    #[arg(long, value_name = "FILE")]
    pub orthophoto: Option<PathBuf>,
    /// Satellite layer resolution, metres (default: --res).
    #[arg(long, value_name = "M")]
    pub satellite_res: Option<f64>,
    /// Ground filter cell (clouds without LAS class 2), metres; a whole multiple of --res.
    #[arg(long, value_name = "M", default_value_t = 0.5)]
    pub ground_cell: f64,
    /// Ground filter window: wider than the widest object to remove (cars, kiosks), metres.
    #[arg(long, value_name = "M", default_value_t = 12.0)]
    pub ground_window: f64,
    /// Height above the filtered ground surface still counted as ground, metres.
    #[arg(long, value_name = "M", default_value_t = 0.2)]
    pub ground_tolerance: f64,
    /// Surveyed control points, CSV `id,x,y,z` in the map CRS.
    #[arg(long, value_name = "CSV")]
    pub control_points: Option<PathBuf>,
}

/// Arguments of `tile import`.
#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// Tile cache directory (created if missing).
    #[arg(long, value_name = "CACHE")]
    pub out: PathBuf,
    /// Tile id (the tile's directory name).
    #[arg(long, value_name = "TILE_ID")]
    pub id: String,
    /// Map CRS: WGS84 UTM or another supported projected CRS (docs/map.md); GeoTIFF inputs in it.
    #[arg(long, value_name = "EPSG:N")]
    pub crs: String,
    /// Satellite/aerial image: u8 RGB or gray.
    #[arg(long, value_name = "FILE")]
    pub satellite: PathBuf,
    /// World file of the satellite image.
    #[arg(long, value_name = "FILE")]
    pub satellite_world: Option<PathBuf>,
    /// LiDAR ground reflectivity: u8 gray (GeoTIFF GDAL_NODATA is kept).
    #[arg(long, value_name = "FILE")]
    pub reflectivity: PathBuf,
    /// World file of the reflectivity image.
    #[arg(long, value_name = "FILE")]
    pub reflectivity_world: Option<PathBuf>,
    /// LiDAR ground height: f32 TIFF/GeoTIFF, metres (NaN / GDAL_NODATA = no data).
    #[arg(long, value_name = "FILE")]
    pub height: PathBuf,
    /// World file of the height raster.
    #[arg(long, value_name = "FILE")]
    pub height_world: Option<PathBuf>,
    /// Surveyed control points, CSV `id,x,y,z` in the map CRS.
    #[arg(long, value_name = "CSV")]
    pub control_points: Option<PathBuf>,
}

/// `N` comma-separated finite numbers.
fn floats<const N: usize>(s: &str) -> std::result::Result<[f64; N], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| format!("{s:?}: expected {N} comma-separated numbers"))?;
    v.try_into()
        .map_err(|_| format!("{s:?}: expected {N} comma-separated numbers"))
}

/// Run a tile subcommand.
pub(super) fn run(c: Command) -> Result<()> {
    match c {
        Command::Import(a) => import(a),
        Command::Build(a) => build(&a),
    }
}

/// `--crs` text the core cannot read, as the error that names the flag.
fn crs_flag(e: crate::geo::GeoError) -> MapError {
    MapError::Flag {
        flag: "--crs",
        source: e.into(),
    }
}

fn build(a: &BuildArgs) -> Result<()> {
    use crate::map::build::{build_tile, Area, BuildSpec, GroundParams};
    let crs = a
        .crs
        .as_deref()
        .map(|c| c.parse::<Crs>().map_err(crs_flag))
        .transpose()?;
    let area = match (&a.bbox, &a.center, &a.center_wgs84) {
        (Some(b), _, _) => Area::Box(*b),
        (_, Some(c), _) => Area::Center {
            xy: (c[0], c[1]),
            size: a.size,
        },
        (_, _, Some(c)) => Area::CenterWgs84 {
            lat: c[0],
            lon: c[1],
            size: a.size,
        },
        _ => Area::Extent,
    };
    let spec = BuildSpec {
        id: a.id.clone(),
        inputs: a.inputs.clone(),
        crs,
        override_crs: a.override_crs,
        area,
        res: a.res,
        ground: GroundParams {
            cell: a.ground_cell,
            window: a.ground_window,
            tolerance: a.ground_tolerance,
        },
        orthophoto: a.orthophoto.clone(),
        satellite_res: a.satellite_res,
    };
    let (mut tile, mut provenance) = build_tile(&spec)?;
    if let Some(p) = &a.control_points {
        let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
        tile.control_points = crate::map::cache::parse_control_points(&text, p)?;
        provenance
            .sources
            .push(format!("control points: {}", p.display()));
    }
    write_tile_with(&a.out, &tile, &provenance)?;
    report(&tile, &a.out);
    Ok(())
}

fn import(a: Box<ImportArgs>) -> Result<()> {
    import_with(&a)
}

fn import_with<'a>(a: &'a ImportArgs) -> Result<()> {
    let crs: Crs = a.crs.parse().map_err(crs_flag)?;
    let source = |image: &'a PathBuf, world: &'a Option<PathBuf>| Source {
        image: image.as_path(),
        world: world.as_deref(),
    };
    let (tile, provenance) = import_tile(
        &a.id,
        crs,
        source(&a.satellite, &a.satellite_world),
        source(&a.reflectivity, &a.reflectivity_world),
        source(&a.height, &a.height_world),
        a.control_points.as_deref(),
    )?;
    write_tile_with(&a.out, &tile, &provenance)?;
    report(&tile, &a.out);
    Ok(())
}

/// The one-line summary of a written tile.
fn report(tile: &crate::map::Tile, out: &std::path::Path) {
    let g = tile.reflectivity.grid;
    let (xmin, ymin, xmax, ymax) = g.bounds();
    println!(
        "tile {} written to {}: {}, LiDAR {}x{} at {} m/px, extent x {xmin}..{xmax}, y {ymin}..{ymax}; \
         satellite {}x{} at {} m/px; {} control points",
        tile.id,
        out.join(&tile.id).display(),
        g.crs,
        g.width,
        g.height,
        g.res,
        tile.satellite.grid.width,
        tile.satellite.grid.height,
        tile.satellite.grid.res,
        tile.control_points.len()
    );
}
