//! # infraloc
//!
//! Self-localization of a pole-mounted, downward-looking fisheye camera in the prior map that
//! autonomous vehicles navigate by: GPS prior → satellite matching + PnP → mutual-information
//! refinement against LiDAR ground reflectivity.
//!
//! Layout: pure core modules ([`camera`], [`pose`], [`geo`], [`map`] model, [`gnss`] parsing,
//! [`sim`] maths) do no I/O; the shell ([`cli`], [`capture`], map cache I/O, serial) does.
#![deny(missing_docs)]
// `!(x > 0.0)` is how this crate rejects NaN together with out-of-range values; keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod app;
pub mod calib;
pub mod camera;
pub mod capture;
pub mod cli;
pub mod config;
pub mod control;
pub mod daemon;
pub mod error;
pub mod geo;
pub mod gnss;
pub mod gps_serial;
pub mod localize;
pub mod map;
pub mod orthonormal;
pub mod persist;
pub mod pose;
pub mod posefile;
pub(crate) mod preflight;
pub mod scene;
pub mod sim;
pub mod stage;
pub mod store;
pub(crate) mod viz;

pub use error::{Error, Result};
