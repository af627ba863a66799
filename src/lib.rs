//! # infraloc
//!
//! Self-localization of a pole-mounted, downward-looking fisheye camera in the prior map that
//! autonomous vehicles navigate by: GPS prior → satellite matching + PnP → mutual-information
//! refinement against LiDAR ground reflectivity.
//!
//! This crate is the application over the pure core [`infraloc_core`] (re-exported here module by
//! module): the node's job ([`app`]), the service ([`daemon`], [`control`], [`store`]), the
//! command line ([`cli`]), frame capture ([`capture`]), the serial GNSS reader, file I/O of
//! cameras, poses, points and tiles, the simulator ([`sim`]) and evaluation against its truth
//! ([`eval`]).
#![deny(missing_docs)]
// `!(x > 0.0)` is how this crate rejects NaN together with out-of-range values; keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub use infraloc_core::{calib, geo, gnss, imageops, localize, orthonormal, pose, stage};

pub mod app;
pub mod camera;
pub mod capture;
pub mod cli;
pub mod config;
pub mod control;
pub mod daemon;
pub mod error;
pub mod eval;
pub mod frames;
pub mod georef;
pub mod gps_serial;
pub mod map;
pub mod persist;
pub mod points_io;
pub mod posefile;
pub(crate) mod preflight;
pub mod scene;
pub mod sim;
pub mod store;
pub(crate) mod viz;

pub use error::{Error, Result};

/// The core's test-only entry points (cargo feature `__internal-test`), for the examples.
#[cfg(feature = "__internal-test")]
#[doc(hidden)]
pub use infraloc_core::__internal;
