//! The map model of the core ([`infraloc_core::map`]: grids, rasters, tiles, ground points) and its
//! file I/O: the GeoTIFF reader and writer ([`geotiff`]), the tile cache ([`cache`]) and
//! `tile import` ([`import`]).

pub use infraloc_core::map::*;

pub mod cache;
pub mod geotiff;
pub(crate) mod import;
