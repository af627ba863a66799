//! # infraloc-core
//!
//! The pure core of infraloc: self-localization of a pole-mounted, downward-looking fisheye
//! camera in the prior map that autonomous vehicles navigate by. Data in, data out: nothing here
//! opens a file or a socket, reads a clock or depends on the simulator, so every result is a
//! deterministic function of its inputs (docs/architecture.md).
//!
//! - [`camera`]: one `CameraModel` over bearings (Mei = OpenCV omnidir, equidistant = OpenCV
//!   fisheye), intrinsics parsing, rectification;
//! - [`pose`]: frame-typed poses; [`posefile`]: the `infraloc.pose.v1` document;
//! - [`geo`]: WGS84 ↔ UTM and the CRS; [`map`]: grids, rasters, tiles, ground points;
//! - [`gnss`]: NMEA framing and parsing, the position prior;
//! - [`calib`]: intrinsic calibration from checkerboards; [`imageops`]: shared image operations;
//! - [`localize`]: initialization (satellite matching + PnP) and MI refinement;
//! - [`error`]: the one error type; [`stage`]: the stage names.
#![deny(missing_docs)]
// `!(x > 0.0)` is how this crate rejects NaN together with out-of-range values; keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod calib;
pub mod camera;
pub mod error;
pub mod geo;
pub mod gnss;
pub mod imageops;
pub mod localize;
pub mod map;
pub mod orthonormal;
pub mod pose;
pub mod posefile;
pub mod stage;

pub use error::{Error, Result};

/// Entry points for the application's examples and tests, not part of the API: they exist
/// only with the cargo feature `__internal-test` (which `--all-features` turns on).
#[cfg(feature = "__internal-test")]
#[doc(hidden)]
pub mod __internal {
    use crate::localize::frame::Frame;
    use crate::localize::pipeline::{Outcome, Params};
    use crate::map::Tile;
    use crate::stage::StageName;

    /// `localize::pipeline::localize` without the quality gate: the outcome whatever the gate
    /// would say, so that an evaluation can still see the stages of a refused run.
    pub fn localize_ungated(
        frame: &Frame<'_>,
        tile: &Tile,
        prior_xy: (f64, f64),
        prior_sigma_m: f64,
        p: &Params,
        now: &dyn Fn() -> f64,
        progress: &dyn Fn(StageName),
    ) -> crate::Result<Outcome> {
        crate::localize::pipeline::localize_ungated(
            frame,
            &[],
            tile,
            prior_xy,
            prior_sigma_m,
            p,
            now,
            progress,
        )
    }
}
