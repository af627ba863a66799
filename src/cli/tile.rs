//! `infraloc tile …`: tile cache operations (docs/interfaces.md, "Tile cache" and "Command line").

use crate::error::{Error, Result};
use crate::map::cache::write_tile_with;
use crate::map::import::{import_tile, Source};
use crate::map::Crs;
use std::path::PathBuf;

/// Tile subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Build CACHE/TILE_ID/ from GeoTIFFs (georeference from their tags) or PNG/TIFF + world
    /// files (.pgw/.tfw/.wld, centre-of-pixel convention; found beside the image if not given).
    Import(Box<ImportArgs>),
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
    /// Map CRS, EPSG:326zz / EPSG:327zz (GeoTIFF inputs must be in it).
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

/// Run a tile subcommand.
pub(super) fn run(c: Command) -> Result<()> {
    match c {
        Command::Import(a) => import(a),
    }
}

fn import(a: Box<ImportArgs>) -> Result<()> {
    import_with(&a)
}

fn import_with<'a>(a: &'a ImportArgs) -> Result<()> {
    let crs: Crs = a
        .crs
        .parse()
        .map_err(|e: String| Error::Invalid(format!("--crs: {e}")))?;
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
    let g = tile.reflectivity.grid;
    let (xmin, ymin, xmax, ymax) = g.bounds();
    println!(
        "tile {} written to {}: {crs}, LiDAR {}x{} at {} m/px, extent x {xmin}..{xmax}, y {ymin}..{ymax}; \
         satellite {}x{} at {} m/px; {} control points",
        tile.id,
        a.out.join(&tile.id).display(),
        g.width,
        g.height,
        g.res,
        tile.satellite.grid.width,
        tile.satellite.grid.height,
        tile.satellite.grid.res,
        tile.control_points.len()
    );
    Ok(())
}
