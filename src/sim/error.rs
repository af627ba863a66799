//! Why the simulator cannot make a scene with the settings given. Each variant renders as the one
//! line a user reads, naming the flag at fault.

/// A scene the simulator cannot make.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A count flag (`--frames`, `--times`) outside `1..=max`.
    #[error("simulate: {flag} {value} must be 1..={max}")]
    Count {
        /// The flag.
        flag: &'static str,
        /// Its value.
        value: u32,
        /// The largest value it takes.
        max: u32,
    },
    /// A day whose sun is in the elevation band for too few minutes to spread `--times` over.
    #[error(
        "simulate: the sun is {lo}–{hi}° up for {minutes} minutes of the day, too few for --times {times}"
    )]
    FewSunMinutes {
        /// Lowest sun elevation of the band, degrees.
        lo: f64,
        /// Highest sun elevation of the band, degrees.
        hi: f64,
        /// Minutes of the day with the sun in the band.
        minutes: usize,
        /// `--times`.
        times: u32,
    },
    /// The calibration that gives the hard preset its intrinsics failed.
    #[error("simulate: given intrinsics: {reason}")]
    Intrinsics {
        /// The calibration's words.
        reason: String,
    },
    /// `--checkerboard` without a view or with a square that is not a positive size.
    #[error(
        "--checkerboard {views} --square {square}: need at least one view and a positive square"
    )]
    Checkerboard {
        /// `--checkerboard`: views to render.
        views: usize,
        /// `--square`, metres.
        square: f64,
    },
}
