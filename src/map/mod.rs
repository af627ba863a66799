//! The map model of the core ([`infraloc_core::map`]: grids, rasters, tiles, ground points) and its
//! file I/O: the GeoTIFF reader and writer ([`geotiff`]), the tile cache ([`cache`]),
//! `tile import` ([`import`]) and `tile build` from point clouds ([`build`], [`cloud`]).

pub use error::MapError;
pub use infraloc_core::map::*;

pub(crate) mod build;
pub mod cache;
pub(crate) mod cloud;
pub mod error;
pub mod geotiff;
pub(crate) mod import;
pub mod las_header;
