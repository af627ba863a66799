//! Why a localization input is refused, why a stage's step failed, and why the quality gate
//! refused a result. Each renders as the one line a user reads; the fields are what the line
//! names (the axis, the σ, the limit), so code reacts to the variant, never to the text.

use serde::{Serialize, Serializer};
use std::fmt;

/// An input or setting the localization cannot work with: a command-line choice, a search box,
/// a point set or a frame that does not fit the camera.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LocalizeError {
    /// A named choice outside its set (`--objective`, `--binning`, …).
    #[error("--{flag} {given:?}: expected {expected}")]
    Choice {
        /// The option, without its dashes.
        flag: &'static str,
        /// The text given.
        given: String,
        /// The choices, in words.
        expected: &'static str,
    },
    /// A `--search` item that is not `AXIS=HALF:STEP`.
    #[error(
        "--search {item:?}: expected AXIS=HALF:STEP with AXIS one of x, y, z, yaw, pitch, roll"
    )]
    SearchSyntax {
        /// The item as given.
        item: String,
    },
    /// A `--search` item with a zero half range.
    #[error("--search {item}: half range and step must be positive")]
    SearchZero {
        /// The item as given.
        item: String,
    },
    /// A search axis whose half range or step is not a positive number.
    #[error("--search {axis}={half}:{step}: half range and step must be positive")]
    SearchNotPositive {
        /// The axis.
        axis: &'static str,
        /// Its half range.
        half: f64,
        /// Its step.
        step: f64,
    },
    /// A search axis wider than a refinement.
    #[error("--search {axis}: half range {half} exceeds the limit {limit} (not a refinement)")]
    SearchTooWide {
        /// The axis.
        axis: &'static str,
        /// Its half range.
        half: f64,
        /// The largest half range of this axis.
        limit: f64,
    },
    /// A search axis whose step is larger than its half range.
    #[error("--search {axis}: step {step} larger than the half range {half}")]
    SearchStep {
        /// The axis.
        axis: &'static str,
        /// Its step.
        step: f64,
        /// Its half range.
        half: f64,
    },
    /// Every search axis is held.
    #[error("--search: every axis is held: nothing to search")]
    SearchHeld,
    /// A grid with too many cells.
    #[error("--search: {cells} grid cells, more than the limit {limit}")]
    SearchCells {
        /// Cells of the grid.
        cells: u64,
        /// The largest number of cells.
        limit: u64,
    },
    /// A histogram bin count outside its range.
    #[error("mi: {what} {bins} outside 2..={max}")]
    Bins {
        /// `bins-reflectivity` or `bins-gray`.
        what: &'static str,
        /// The count given.
        bins: usize,
        /// The largest count.
        max: usize,
    },
    /// An empty point set.
    #[error("{what}: no ground points")]
    NoPoints {
        /// The point set's source.
        what: String,
    },
    /// A point with a non-finite coordinate.
    #[error("{what}: point {index} has a non-finite coordinate ({x}, {y}, {z})")]
    NonFinitePoint {
        /// The point set's source.
        what: String,
        /// The point's index.
        index: usize,
        /// Its x.
        x: f64,
        /// Its y.
        y: f64,
        /// Its z.
        z: f64,
    },
    /// A refinement with no image/point-set pair.
    #[error("no image/point-set pair to refine on")]
    NoPairs,
    /// A frame whose size is not the camera's.
    #[error("image has {pixels} pixels but the camera is {width}×{height}")]
    ImageSize {
        /// Pixels of the frame.
        pixels: usize,
        /// The camera's width.
        width: usize,
        /// The camera's height.
        height: usize,
    },
    /// A frame with no valid pixel in the image circle.
    #[error("image: no valid pixel in the camera's image circle")]
    NoValidPixel,
    /// The fixed point set is empty.
    #[error(
        "points: none is visible from every pose of the search box (wrong pose, tile or camera?)"
    )]
    NoFixedPoints,
    /// No point is visible from the start.
    #[error("points: none is visible from the initial pose")]
    NoVisiblePoints,
    /// One pair of a pooled refinement failed (`index` 1-based, as given).
    #[error("pair {index} of {of}: {source}")]
    Pair {
        /// The pair, 1-based.
        index: usize,
        /// The number of pairs.
        of: usize,
        /// What is wrong with it.
        source: Box<LocalizeError>,
    },
}

/// Why the observed information gives no covariance at the answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InformationError {
    /// A matrix of the computation is not finite.
    #[error("information: the {what} is not finite")]
    NotFinite {
        /// `MI Hessian`, `covariance`, `sandwich covariance` or `frame-clustered covariance`.
        what: &'static str,
    },
    /// The Hessian has no basin over the free axes.
    #[error(
        "information: the MI Hessian is not negative definite over the free axes (no basin along {along}; largest curvature {curvature:.3e})"
    )]
    NoBasin {
        /// The upward direction, in words.
        along: String,
        /// The largest curvature (positive: upward).
        curvature: f64,
    },
    /// The free parameters do not match the reported axes.
    #[error("information: {free} free parameters but {axes} reported axes")]
    Axes {
        /// Free parameters.
        free: usize,
        /// Reported axes.
        axes: usize,
    },
    /// The axes' Jacobian has no inverse.
    #[error("information: the axes' Jacobian is singular")]
    SingularAxes,
    /// The ascent never left its box's edge, so there is no answer to take it at.
    #[error("the gradient ascent still ended on its box's edge after {rounds} rounds")]
    OnEdge {
        /// Rounds run.
        rounds: usize,
    },
}

/// Reports carry the reason as its one line.
impl Serialize for InformationError {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// A value of `[quality]` out of its range; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum QualityConfigError {
    /// A σ limit that is not a positive number.
    #[error("{key} = {value}: must be a positive finite number")]
    NotPositive {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// A coarse σ limit below its precise one (or not a finite number).
    #[error("{key} = {value}: must be a finite number at least {precise_key} = {precise}")]
    CoarseBelowPrecise {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
        /// The precise limit's key.
        precise_key: &'static str,
        /// The precise limit.
        precise: f64,
    },
    /// A fraction outside 0..1.
    #[error("{key} = {value}: must lie in 0..1")]
    NotFraction {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// Profile and fit half-widths out of order or range.
    #[error(
        "profile-half-steps = {profile} / fit-half-steps = {fit}: need 1 <= fit <= profile <= 1000"
    )]
    HalfSteps {
        /// `profile-half-steps`.
        profile: i64,
        /// `fit-half-steps`.
        fit: i64,
    },
    /// `min-basin-steps` out of range.
    #[error("min-basin-steps = {value}: must lie in 0..1000")]
    BasinSteps {
        /// Its value.
        value: i64,
    },
}

/// Why the grid search's checks refused a result (the smooth stage's verdict is
/// [`crate::localize::refine::verdict::Grade`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Refusal {
    /// Too few points seen from every pose of the box.
    TooFewPoints {
        /// Points seen.
        points: usize,
        /// The least accepted.
        min: usize,
    },
    /// Too much of the fixed point set left the image at some pose.
    PointsLost {
        /// The largest fraction lost.
        lost: f64,
        /// The largest accepted.
        max: f64,
    },
    /// The optimum sits on the box's edge.
    OnEdge {
        /// The axis.
        axis: String,
    },
    /// The objective rises again too close to the optimum.
    NoBasin {
        /// The axis.
        axis: String,
        /// Steps from the optimum to the rise.
        cells: i64,
        /// The fewest accepted.
        min: i64,
    },
    /// No negative curvature along an axis.
    NoPeak {
        /// The axis.
        axis: String,
        /// Its curvature, nats per unit².
        curvature: f64,
        /// The axis's unit.
        unit: String,
    },
    /// A separate second peak reaches too close to the optimum's height.
    Ambiguous {
        /// The optimum's offsets from the start (m, m, m, deg).
        optimum: [f64; 4],
        /// The second peak's offsets from the optimum (m, m, m, deg).
        second: [f64; 4],
        /// Its height above background over the optimum's.
        contrast: f64,
        /// The largest accepted.
        max: f64,
    },
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::TooFewPoints { points, min } => write!(
                f,
                "only {points} points seen from every pose of the search box (< {min})"
            ),
            Refusal::PointsLost { lost, max } => write!(
                f,
                "{:.1}% of the fixed point set left the image at some pose (> {:.1}%)",
                100.0 * lost,
                100.0 * max
            ),
            Refusal::OnEdge { axis } => write!(
                f,
                "optimum on the search box's {axis} edge: the true optimum may lie outside; widen --search"
            ),
            Refusal::NoBasin { axis, cells, min } => write!(
                f,
                "no basin along {axis}: the objective rises again {cells} step(s) from the optimum (< {min}), a spike rather than an alignment peak"
            ),
            Refusal::NoPeak {
                axis,
                curvature,
                unit,
            } => write!(
                f,
                "no peak along {axis}: MI curvature {curvature:.3e} nats/{unit}² is not negative-definite"
            ),
            Refusal::Ambiguous {
                optimum: a,
                second: o,
                contrast,
                max,
            } => write!(
                f,
                "ambiguous: two separate peaks, the optimum at ({:+.2} m, {:+.2} m, {:+.2} m, {:+.2}°) from the start and a second at ({:+.2} m, {:+.2} m, {:+.2} m, {:+.2}°), offset ({:.2} m, {:.2} m, {:.2} m, {:.2}°) from it, reaching {:.0}% of the optimum's height above background (> {:.0}%)",
                a[0], a[1], a[2], a[3],
                a[0] + o[0], a[1] + o[1], a[2] + o[2], a[3] + o[3],
                o[0], o[1], o[2], o[3], 100.0 * contrast, 100.0 * max
            ),
        }
    }
}

/// Why a match file cannot be read; errors name the line and the column.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MatchFileError {
    /// No header line.
    #[error("no header line (need u,v,x,y[,z])")]
    NoHeader,
    /// A header without a needed column.
    #[error("header {header:?} has no column {column:?} (need u,v,x,y[,z])")]
    NoColumn {
        /// The header line.
        header: String,
        /// The missing column.
        column: &'static str,
    },
    /// A row without a value in a column.
    #[error("line {line}: missing {column}")]
    Missing {
        /// 1-based line.
        line: usize,
        /// The column.
        column: &'static str,
    },
    /// A value that is not a number.
    #[error("line {line}: {column} is not a number")]
    NotANumber {
        /// 1-based line.
        line: usize,
        /// The column.
        column: &'static str,
    },
    /// A value that is not finite.
    #[error("line {line}: {column} is not finite")]
    NotFinite {
        /// 1-based line.
        line: usize,
        /// The column.
        column: &'static str,
    },
    /// A header and no rows.
    #[error("no correspondences after the header")]
    Empty,
}

/// What a kernel self-test found different from the reference on this CPU.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SelfTestError {
    /// The nearest-pixel kernel's histogram or visibility at a pose.
    #[error("pose {pose}: {path} {what} differs from the reference")]
    Kernel {
        /// The pose.
        pose: usize,
        /// The kernel's path (`avx2+fma`, …).
        path: &'static str,
        /// `histogram` or `visibility`.
        what: &'static str,
    },
    /// The all-poses visibility.
    #[error("all-poses visibility differs from the reference")]
    AllPoses,
    /// The partial-volume projection or Jacobian of a point.
    #[error("pose {pose}, point {point}: the {copy} PV {what} differs from the reference")]
    Lanes {
        /// The pose.
        pose: usize,
        /// The point.
        point: usize,
        /// The copy that differs.
        copy: &'static str,
        /// `projection` or `Jacobian`.
        what: &'static str,
    },
    /// The partial-volume estimator's value or gradient.
    #[error(
        "pose {pose}: the PV value or gradient with the {path} projection differs from the reference"
    )]
    LanesEstimator {
        /// The pose.
        pose: usize,
        /// The projection's path.
        path: &'static str,
    },
    /// A scene that does not exercise both outcomes.
    #[error("degenerate scene: {seen} {seen_word}, {lost} {lost_word}")]
    Degenerate {
        /// Samples (or points) seen.
        seen: u64,
        /// `valid` or `visible`.
        seen_word: &'static str,
        /// Samples (or points) not seen.
        lost: u64,
        /// `invalid samples` or `not`.
        lost_word: &'static str,
    },
}
