//! Why a calibration or a board detection failed. Each variant renders as the one line a user
//! reads, naming the view, corner or count at fault.

use crate::camera::error::CameraError;

/// Why a view's object points define no board plane.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlaneError {
    /// The points lie on a line or coincide.
    #[error("the object points are collinear or coincide")]
    Collinear,
    /// The points are not on one plane.
    #[error("the object points are not planar (only flat boards are supported)")]
    NotPlanar,
}

/// A calibration failure, one line naming the view or the reason.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibError {
    /// An empty image size.
    #[error("image size {width}×{height} is empty")]
    EmptySize {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
    },
    /// No view has a board.
    #[error("no board found in any view")]
    NoViews,
    /// A view with unequal object and image point counts.
    #[error("{view}: {object} object points but {image} image points")]
    Counts {
        /// The view.
        view: String,
        /// Object points.
        object: usize,
        /// Image points.
        image: usize,
    },
    /// A point with a non-finite coordinate.
    #[error("{view}: point {index} is not finite")]
    NotFinite {
        /// The view.
        view: String,
        /// The point.
        index: usize,
    },
    /// A corner outside the image.
    #[error("{view}: corner {index} at ({x:.1}, {y:.1}) lies outside the {width}×{height} image")]
    Outside {
        /// The view.
        view: String,
        /// The corner.
        index: usize,
        /// Its column, px.
        x: f64,
        /// Its row, px.
        y: f64,
        /// The image's width.
        width: u32,
        /// The image's height.
        height: u32,
    },
    /// A view's board is not a plane.
    #[error("{view}: {reason}")]
    Plane {
        /// The view.
        view: String,
        /// Why.
        reason: PlaneError,
    },
    /// Too few views left, with the rejected ones' reasons (`view: why`).
    #[error("{usable} usable view(s), need at least {min}{}", rejected_note(.rejected))]
    TooFewViews {
        /// Views left.
        usable: usize,
        /// The fewest accepted.
        min: usize,
        /// Each rejected view and its reason.
        rejected: Vec<String>,
    },
    /// No starting focal length reprojects the boards.
    #[error("no starting focal length reprojects the boards")]
    NoStart,
    /// All boards are fronto-parallel.
    #[error(
        "degenerate views: all {views} boards are fronto-parallel (largest tilt {max_tilt_deg:.1}° < {min_tilt_deg}°), so the focal length is not observable; tilt the board"
    )]
    FrontoParallel {
        /// Views used.
        views: usize,
        /// The largest tilt, degrees.
        max_tilt_deg: f64,
        /// The least tilt that makes the focal length observable, degrees.
        min_tilt_deg: f64,
    },
    /// The optimisation left the model's domain.
    #[error("the optimisation left the model's domain")]
    Domain,
    /// The fitted camera fails its own check.
    #[error("the fitted camera is invalid: {0}")]
    InvalidCamera(CameraError),
    /// A corner projects where the fitted model cannot be inverted.
    #[error("{view}: corner {index} falls where the fitted model is not invertible ({reason})")]
    NotInvertible {
        /// The view.
        view: String,
        /// The corner.
        index: usize,
        /// The projection's refusal.
        reason: String,
    },
}

/// Why no board was found in an image.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DetectError {
    /// An image too small to hold a board (or not its stated size).
    #[error("image {width}×{height} is too small")]
    TooSmall {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
    },
    /// No saddle point at all.
    #[error("no corner-like points")]
    NoCandidates,
    /// Too few corners.
    #[error("{found} checkerboard corners found, the board needs {needed}")]
    TooFewCorners {
        /// Corners found.
        found: usize,
        /// Corners of the board.
        needed: usize,
    },
    /// No grid could be grown, or the best one was too small or too large (`why`); with
    /// `partial_min`, the best grid was not even a partial board of that many corners.
    #[error("{why}{}", partial_note(.partial_min))]
    NoGrid {
        /// Why the grids grown do not make a board.
        why: GridProblem,
        /// The corners a partial board needs, when the best grid fell short of one.
        partial_min: Option<usize>,
    },
}

fn rejected_note(rejected: &[String]) -> String {
    if rejected.is_empty() {
        String::new()
    } else {
        format!(" (rejected: {})", rejected.join("; "))
    }
}

fn partial_note(partial_min: &Option<usize>) -> String {
    partial_min.map_or(String::new(), |n| {
        format!(" (a partial board needs {n} corners, 3 each way)")
    })
}

/// What the grids grown from the seed corners lacked.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GridProblem {
    /// No seed had two neighbours.
    #[error("no seed corner has two neighbours along its edges")]
    NoSeed,
    /// A grid larger than the pattern.
    #[error("a grid of {nx}×{ny} corners, larger than the {cols}×{rows} pattern")]
    TooLarge {
        /// Corners across.
        nx: usize,
        /// Corners down.
        ny: usize,
        /// The pattern's columns.
        cols: usize,
        /// The pattern's rows.
        rows: usize,
    },
    /// Part of the board.
    #[error("only {found} of {needed} corners in a grid")]
    Partial {
        /// Corners in the grid.
        found: usize,
        /// Corners of the board.
        needed: usize,
    },
}
