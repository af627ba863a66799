//! The application's error: what the core can refuse ([`infraloc_core::Error`], wrapped as it
//! is) and what only the application does — configuration, files and devices, a command's own
//! verdict, storing the served pose, a service job that panicked, a flag's value or a command
//! line that cannot run, an output that cannot be produced, the service's refusal. Every variant
//! renders as a single line that names the file, key, flag, device or stage at fault, because
//! that line is what a technician sees; [`Error::exit_code`] is the process's exit code.

use crate::stage::StageName;
use std::path::Path;

/// The core's error, which [`Error::Core`] wraps.
pub use infraloc_core::Error as CoreError;

/// Exit code for configuration errors (sysexits.h `EX_CONFIG`).
pub const EXIT_CONFIG: i32 = 78;
/// Exit code for any other failure.
pub(crate) const EXIT_FAILURE: i32 = 1;
/// `refine` and `localize`: a result served graded `coarse` (its σ beyond the precise limits,
/// within the coarse ones); the pose is written, flagged `quality.grade = "coarse"`.
pub const EXIT_COARSE: i32 = 5;

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
    /// A command-line flag whose value cannot be used: its range, syntax or kind.
    #[error("{flag} {value}: {reason}")]
    Arg {
        /// The flag (`--size`).
        flag: &'static str,
        /// The value as the line shows it: quoted ([`Error::arg_quoted`]) when it is text the
        /// user typed, so that spaces and empty values are visible.
        value: String,
        /// What is wrong with it, or what is expected.
        reason: String,
    },
    /// A command line that cannot run as given: flags that do not go together, a flag that
    /// another one (or the command) needs, values that are refused together; the line names the
    /// flags and says what to give.
    #[error("{0}")]
    Usage(String),
    /// An output that could not be produced: a report, chart, image or man page that failed to
    /// encode, draw or save.
    #[error("{what}: {source}")]
    Output {
        /// The output: its path, or the product (`report`, `plot`).
        what: String,
        /// The encoder's, renderer's or writer's error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Data that did not encode (a request, a history, a man page's text); the line is the
    /// encoder's own, as there is no file to name.
    #[error(transparent)]
    Encode(Box<dyn std::error::Error + Send + Sync>),
    /// The operating system refused the service a thread or its signal handlers.
    #[error("cannot {what}: {source}")]
    System {
        /// What the service could not do (`start the drift thread`).
        what: &'static str,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The service declined a request; its reason, as it sent it.
    #[error("{reason}")]
    Refused {
        /// The service's reason.
        reason: String,
    },
    /// An answer of the service that lacks what the command shows.
    #[error("the daemon's {what}: {reason}")]
    Answer {
        /// The answer (`georef answer`).
        what: &'static str,
        /// What is missing or malformed.
        reason: String,
    },
    /// No connection to the service, with why the socket path was the default one.
    #[error("{source} ({note})")]
    Connect {
        /// Why the connection failed.
        source: Box<Error>,
        /// Why the default socket was used (the config problem that hid the configured one).
        note: String,
    },
    /// A `[camera]` table that does not make a frame source; the line names the key.
    /// `Config::load` refuses such a table first (exit 78); this is the same line for a table
    /// built elsewhere.
    #[error("{0}")]
    FrameSource(String),
    /// A scene the simulator cannot make with these settings.
    #[error(transparent)]
    Sim(#[from] crate::sim::error::SimError),
    /// An argument a library call cannot use (an empty burst, a zero stride), or an embedded
    /// asset that is broken.
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

    /// [`Error::Arg`] for a value shown as it displays (a number).
    pub fn arg(
        flag: &'static str,
        value: impl std::fmt::Display,
        reason: impl Into<String>,
    ) -> Self {
        Error::Arg {
            flag,
            value: value.to_string(),
            reason: reason.into(),
        }
    }

    /// [`Error::Arg`] for text the user typed, shown quoted.
    pub fn arg_quoted(flag: &'static str, value: &str, reason: impl Into<String>) -> Self {
        Error::Arg {
            flag,
            value: format!("{value:?}"),
            reason: reason.into(),
        }
    }

    /// Shorthand for [`Error::Output`].
    pub fn output(
        what: impl Into<String>,
        source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
    ) -> Self {
        Error::Output {
            what: what.into(),
            source: source.into(),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::error::MapError;
    use crate::sim::error::SimError;

    /// Each variant's line as a technician reads it, and its exit code.
    #[test]
    fn variants_render_their_lines() {
        let refused = std::io::Error::other("Resource temporarily unavailable");
        let cases: Vec<(Error, &str)> = vec![
            (
                Error::arg("--radius", -2.5, "must be positive"),
                "--radius -2.5: must be positive",
            ),
            (
                Error::arg_quoted("--frames", "9-3", "\"9-3\" runs backwards"),
                "--frames \"9-3\": \"9-3\" runs backwards",
            ),
            (
                Error::Usage("plot mi-surface: give --out PNG".into()),
                "plot mi-surface: give --out PNG",
            ),
            (
                Error::output("truth.json", "key must be a string"),
                "truth.json: key must be a string",
            ),
            (
                Error::Encode("invalid utf-8 sequence of 1 bytes from index 3".into()),
                "invalid utf-8 sequence of 1 bytes from index 3",
            ),
            (
                Error::System {
                    what: "start the drift thread",
                    source: refused,
                },
                "cannot start the drift thread: Resource temporarily unavailable",
            ),
            (
                Error::Refused {
                    reason: "busy: a localization is running".into(),
                },
                "busy: a localization is running",
            ),
            (
                Error::Answer {
                    what: "georef answer",
                    reason: "no points".into(),
                },
                "the daemon's georef answer: no points",
            ),
            (
                Error::Connect {
                    source: Box::new(Error::io(
                        "/run/infraloc/control.sock",
                        std::io::Error::from(std::io::ErrorKind::NotFound),
                    )),
                    note: "the default socket: config x.toml does not load".into(),
                },
                "/run/infraloc/control.sock: entity not found (the default socket: config x.toml does not load)",
            ),
            (
                Error::FrameSource("[camera] source = \"file\" needs frames".into()),
                "[camera] source = \"file\" needs frames",
            ),
            (
                SimError::Count {
                    flag: "--times",
                    value: 0,
                    max: 24,
                }
                .into(),
                "simulate: --times 0 must be 1..=24",
            ),
            (
                SimError::FewSunMinutes {
                    lo: 8.0,
                    hi: 25.0,
                    minutes: 30,
                    times: 12,
                }
                .into(),
                "simulate: the sun is 8–25° up for 30 minutes of the day, too few for --times 12",
            ),
            (
                SimError::Intrinsics {
                    reason: "3 views, need 4".into(),
                }
                .into(),
                "simulate: given intrinsics: 3 views, need 4",
            ),
            (
                SimError::Checkerboard {
                    views: 0,
                    square: 0.04,
                }
                .into(),
                "--checkerboard 0 --square 0.04: need at least one view and a positive square",
            ),
            (
                MapError::NoHeights { id: "n12".into() }.into(),
                "tile n12: the height layer has no valid heights",
            ),
        ];
        for (e, line) in cases {
            assert_eq!(e.lines(), vec![line.to_string()]);
            assert_eq!(e.exit_code(), EXIT_FAILURE, "{line}");
        }
    }
}
