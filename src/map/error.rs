//! Why a tile cannot be built, imported or stored. Each variant renders as the one line a user
//! reads, naming the tile, layer, flag or count at fault.

use infraloc_core::map::{Crs, GeoGrid};
use infraloc_core::Error as CoreError;
use std::path::PathBuf;

/// A map error of the application: a tile that fails its consistency checks, or a build or
/// import whose parameters do not make a tile.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// A tile id that is not a safe directory name.
    #[error("tile id {id:?}: use letters, digits, '-', '_', '.' (not leading '.')")]
    BadId {
        /// The id.
        id: String,
    },
    /// A tile whose CRS the core refuses.
    #[error("tile {id}: {source}")]
    TileCrs {
        /// The tile.
        id: String,
        /// The core's refusal.
        source: CoreError,
    },
    /// A tile whose LiDAR layers are on different grids.
    #[error("tile {id}: reflectivity grid {reflectivity:?} and height grid {height:?} differ")]
    GridsDiffer {
        /// The tile.
        id: String,
        /// The reflectivity layer's grid.
        reflectivity: GeoGrid,
        /// The height layer's grid.
        height: GeoGrid,
    },
    /// A tile whose satellite layer is in another CRS than its LiDAR layers.
    #[error("tile {id}: satellite CRS {satellite} differs from LiDAR CRS {lidar}")]
    CrsDiffer {
        /// The tile.
        id: String,
        /// The satellite layer's CRS.
        satellite: Crs,
        /// The LiDAR layers' CRS.
        lidar: Crs,
    },
    /// A tile whose height layer has no valid height to georeference on.
    #[error("tile {id}: the height layer has no valid heights")]
    NoHeights {
        /// The tile.
        id: String,
    },
    /// A layer whose samples do not fill its grid.
    #[error("tile {id}: {layer} has {samples} samples for a grid of {grid}")]
    Samples {
        /// The tile.
        id: String,
        /// The layer.
        layer: &'static str,
        /// Samples it has.
        samples: usize,
        /// Cells of its grid.
        grid: usize,
    },
    /// A control point id that would break the CSV it is written to.
    #[error("tile {id}: control point id {point:?} contains a comma or newline")]
    ControlPointId {
        /// The tile.
        id: String,
        /// The control point's id.
        point: String,
    },
    /// A manifest that could not be serialised.
    #[error("tile {id}: manifest: {reason}")]
    Manifest {
        /// The tile.
        id: String,
        /// The serialiser's words.
        reason: String,
    },
    /// A command-line value the core refuses (`--crs`, `--center-wgs84`).
    #[error("{flag}: {source}")]
    Flag {
        /// The flag.
        flag: &'static str,
        /// The core's refusal.
        source: CoreError,
    },
    /// A size or resolution that is not a positive number.
    #[error("{flag} {value}: must be > 0")]
    NotPositive {
        /// The flag.
        flag: &'static str,
        /// Its value.
        value: f64,
    },
    /// A grid with too many cells.
    #[error(
        "{what}: {width}x{height} cells at {res} m exceed {max}; build a smaller box or a coarser grid"
    )]
    TooManyCells {
        /// The grid (`tile`, `satellite`).
        what: String,
        /// Cells across.
        width: f64,
        /// Cells down.
        height: f64,
        /// Cell size, m.
        res: f64,
        /// The most cells a grid may have.
        max: usize,
    },
    /// A box that is empty or not finite.
    #[error("box {bbox:?}: need finite xmin < xmax and ymin < ymax")]
    BadBox {
        /// xmin, ymin, xmax, ymax.
        bbox: [f64; 4],
    },
    /// `tile build` without input.
    #[error("tile build: no point cloud given")]
    NoInputs,
    /// `tile build` with more inputs than it takes.
    #[error("tile build: {inputs} inputs, at most {max}")]
    TooManyInputs {
        /// Inputs given.
        inputs: usize,
        /// The most it takes.
        max: usize,
    },
    /// A ground cell that is not a whole number of tile cells.
    #[error("--ground-cell {cell}: must be a whole multiple of --res {res}")]
    GroundCell {
        /// `--ground-cell`.
        cell: f64,
        /// `--res`.
        res: f64,
    },
    /// A ground window smaller than its cell, or a negative tolerance.
    #[error(
        "--ground-window {window} must be ≥ --ground-cell and --ground-tolerance {tolerance} ≥ 0"
    )]
    GroundWindow {
        /// `--ground-window`.
        window: f64,
        /// `--ground-tolerance`.
        tolerance: f64,
    },
    /// A read grid too large for 32-bit cell indices.
    #[error("tile build: the box and its ground margin exceed 2^32 cells")]
    MarginTooLarge,
    /// A world file given for a GeoTIFF that has its own georeference.
    #[error(
        "{}: is a GeoTIFF with its own georeference; drop {flag}-world {}",
        .image.display(),
        .world.display()
    )]
    WorldWithGeoTiff {
        /// The image.
        image: PathBuf,
        /// Its layer's flag (`--satellite`).
        flag: String,
        /// The world file.
        world: PathBuf,
    },
}
