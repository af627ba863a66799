//! The application's error: what the core can refuse ([`infraloc_core::Error`], wrapped as it
//! is) and what only the application does — configuration, files and devices, a command's own
//! verdict, storing the served pose, a service job that panicked, an invalid argument. Every
//! variant renders as a single line that names the file, key, device or stage at fault, because
//! that line is what a technician sees; [`Error::exit_code`] is the process's exit code.

use crate::stage::StageName;
use std::path::Path;

/// The core's error, which [`Error::Core`] wraps.
pub use infraloc_core::Error as CoreError;

/// Exit code for configuration errors (sysexits.h `EX_CONFIG`).
pub const EXIT_CONFIG: i32 = 78;
/// Exit code for any other failure.
pub(crate) const EXIT_FAILURE: i32 = 1;

/// The application's error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// What the core refused (an input's content, a stage, a CRS, a camera, a localization
    /// setting).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// The configuration (file or a value in it) is unusable. Exit code 78.
    #[error("config {path}: {msg}")]
    Config {
        /// Config file (or `<command line>`).
        path: String,
        /// What is wrong, naming the key.
        msg: String,
    },
    /// Several configuration problems at once, each naming its key. Exit code 78. Renders as one
    /// line (problems separated by "; ") for logs and the service's status; [`Error::lines`]
    /// gives one line per problem for a terminal.
    #[error("config {path}: {}", problems.join("; "))]
    ConfigList {
        /// Config file.
        path: String,
        /// What is wrong, one entry per problem, each naming its key.
        problems: Vec<String>,
    },
    /// An operating-system I/O error on a named path or device.
    #[error("{path}: {source}")]
    Io {
        /// The path or device.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A command's own verdict on its run (`demo`'s error thresholds, a `study` trial, the
    /// service's answer to `relocalize`, the kernel's `self-test`).
    #[error("{command}: {msg}")]
    Command {
        /// The command's name.
        command: &'static str,
        /// What failed.
        msg: String,
    },
    /// The served pose or its history could not be stored.
    #[error("persist: {0}")]
    Persist(String),
    /// A job of the service (`localize`, `drift`) panicked; the service goes on.
    #[error("{job}: internal error: {what}")]
    Internal {
        /// The job.
        job: &'static str,
        /// The panic's message.
        what: String,
    },
    /// A tile that cannot be built, imported or stored.
    #[error(transparent)]
    Map(#[from] crate::map::error::MapError),
    /// Invalid argument on the command line or to a library call.
    #[error("{0}")]
    Invalid(String),
}

/// The core's domain errors lift through [`infraloc_core::Error`], as in the core.
macro_rules! through_core {
    ($($t:ty),*) => {$(
        impl From<$t> for Error {
            fn from(e: $t) -> Self {
                Error::Core(e.into())
            }
        }
    )*};
}
through_core!(
    infraloc_core::geo::error::GeoError,
    infraloc_core::camera::error::CameraError,
    infraloc_core::localize::error::LocalizeError
);

impl Error {
    /// Process exit code for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Config { .. } | Error::ConfigList { .. } => EXIT_CONFIG,
            _ => EXIT_FAILURE,
        }
    }

    /// Shorthand for the core's [`infraloc_core::Error::Input`]: a file whose content is
    /// unusable.
    pub fn input(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Core(CoreError::input(path, msg))
    }

    /// Shorthand for the core's [`infraloc_core::Error::Stage`].
    pub fn stage(stage: StageName, msg: impl Into<String>) -> Self {
        Error::Core(CoreError::stage(stage, msg))
    }

    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }

    /// Shorthand for [`Error::Config`].
    pub fn config(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Config {
            path: path.as_ref().display().to_string(),
            msg: msg.into(),
        }
    }

    /// `Ok` without problems, [`Error::Config`] for one, [`Error::ConfigList`] for several.
    pub fn config_problems(path: impl AsRef<Path>, mut problems: Vec<String>) -> Result<()> {
        let path = path.as_ref().display().to_string();
        match problems.len() {
            0 => Ok(()),
            1 => Err(Error::Config {
                path,
                msg: problems.remove(0),
            }),
            _ => Err(Error::ConfigList { path, problems }),
        }
    }

    /// The error as a technician reads it on a terminal: one line, or one line per problem of
    /// an [`Error::ConfigList`] (each `config PATH: problem`).
    pub fn lines(&self) -> Vec<String> {
        match self {
            Error::ConfigList { path, problems } => problems
                .iter()
                .map(|p| format!("config {path}: {p}"))
                .collect(),
            e => vec![e.to_string()],
        }
    }

    /// Shorthand for [`Error::Command`].
    pub fn command(command: &'static str, msg: impl Into<String>) -> Self {
        Error::Command {
            command,
            msg: msg.into(),
        }
    }
}

/// The application's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;
