//! The core's error. Every variant renders as a single line that names the file, field or stage
//! at fault, because that line is what a technician sees. The domains' own errors
//! ([`crate::geo::error::GeoError`], [`crate::camera::error::CameraError`],
//! [`crate::localize::error::LocalizeError`]) are wrapped as they are, so `?` lifts them and
//! their line is the one rendered. What only the application does (configuration, files,
//! commands, the service) has its own variants in the application's error, which wraps this one.

use crate::stage::StageName;
use std::path::Path;

/// The core's error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An input (file or stream) the caller read has content the core cannot use.
    #[error("{path}: {msg}")]
    Input {
        /// The file (or stream) at fault.
        path: String,
        /// What is wrong, naming the key/field/offset where possible.
        msg: String,
    },
    /// A stage of a localization could not produce a trustworthy result.
    #[error("{}: {msg}", stage.name())]
    Stage {
        /// The stage.
        stage: StageName,
        /// The numbers that made it fail.
        msg: String,
    },
    /// A CRS or a position that geodesy refuses.
    #[error(transparent)]
    Geo(#[from] crate::geo::error::GeoError),
    /// A camera, calibration projection or rectification that cannot be used.
    #[error(transparent)]
    Camera(#[from] crate::camera::error::CameraError),
    /// A localization input or setting that cannot be used.
    #[error(transparent)]
    Localize(#[from] crate::localize::error::LocalizeError),
}

impl Error {
    /// Shorthand for [`Error::Input`].
    pub fn input(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Input {
            path: path.as_ref().display().to_string(),
            msg: msg.into(),
        }
    }

    /// Shorthand for [`Error::Stage`].
    pub fn stage(stage: StageName, msg: impl Into<String>) -> Self {
        Error::Stage {
            stage,
            msg: msg.into(),
        }
    }
}

/// The core's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;
