//! Why a camera, a calibration's projection or a rectification is refused. Each variant renders
//! as the one line a user reads, naming the parameter, key or size at fault.

/// Upper bound of a field of view, degrees.
pub(crate) const FULL_TURN_DEG: f64 = 360.0;

/// A camera error: unusable intrinsics, a KITTI projection that is not a rectified camera, or a
/// rectification whose sizes do not fit.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A zero image size.
    #[error("image size {width}×{height}: width and height must be positive")]
    EmptySize {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
    },
    /// A parameter that is not finite.
    #[error("{name} = {value} is not finite")]
    NotFinite {
        /// The parameter (`fx`, `k1`, …).
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A focal length that is not positive.
    #[error("{name} = {value}: focal length must be positive")]
    Focal {
        /// `fx` or `fy`.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A negative mirror parameter.
    #[error("xi = {value}: the mirror parameter must be ≥ 0")]
    NegativeXi {
        /// ξ.
        value: f64,
    },
    /// A field of view outside (0°, 360°].
    #[error("fov-deg = {value}: must be in (0, {}]", FULL_TURN_DEG)]
    FieldOfView {
        /// The field of view, degrees.
        value: f64,
    },
    /// A KITTI projection the file does not have.
    #[error("missing key {name} (has {})", have.join(", "))]
    MissingProjection {
        /// The key asked for (`P2`).
        name: String,
        /// The keys the file has.
        have: Vec<String>,
    },
    /// A KITTI projection whose left 3×3 is not a camera matrix.
    #[error(
        "{name}: left 3×3 is not upper-triangular with K[2][2] = 1 (rows 2–3: {row2:?}, {row3:?})"
    )]
    NotRectified {
        /// The projection's key.
        name: String,
        /// Its second row of `K`.
        row2: [f64; 3],
        /// Its third row of `K`.
        row3: [f64; 3],
    },
    /// A KITTI projection with a focal length that is not positive.
    #[error("{name}: focal lengths {fx} and {fy} must be positive")]
    ProjectionFocal {
        /// The projection's key.
        name: String,
        /// K₀₀.
        fx: f64,
        /// K₁₁.
        fy: f64,
    },
    /// A KITTI projection whose `K` has no inverse.
    #[error("{name}: K is singular")]
    SingularK {
        /// The projection's key.
        name: String,
    },
    /// KITTI's `R0_rect · Tr_velo_to_cam` is not a rotation.
    #[error(
        "R0_rect · Tr_velo_to_cam: not a rotation (|RᵀR−I| = {deviation:.2e}, det = {det:.4})"
    )]
    VeloNotRotation {
        /// `|RᵀR − I|` (Frobenius).
        deviation: f64,
        /// The determinant.
        det: f64,
    },
    /// A KITTI-360 camera that needs a file the caller did not give.
    #[error("KITTI-360 camera {camera:02}: {what} not given")]
    Kitti360Missing {
        /// The camera, 0–3.
        camera: u8,
        /// The file.
        what: String,
    },
    /// A KITTI-360 camera number outside 0–3.
    #[error("KITTI-360 camera {camera}: expected 0–3 (00, 01 perspective; 02, 03 fisheye)")]
    Kitti360Camera {
        /// The number asked for.
        camera: u8,
    },
    /// A rectified view of no pixels.
    #[error("rectify: output size {width}x{height} is empty")]
    RectifyEmpty {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// A rectification whose `P·R` has no inverse.
    #[error("rectify: P·R is singular (check --k and --rotation)")]
    RectifySingular,
    /// Gray bytes that do not fill their size.
    #[error("gray image: {bytes} bytes is not {width}x{height}")]
    GraySize {
        /// Bytes given.
        bytes: usize,
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// Map planes that do not match the map's size.
    #[error("remap: map planes ({map_x}, {map_y}) do not match {width}x{height}")]
    MapPlanes {
        /// Length of the x plane.
        map_x: usize,
        /// Length of the y plane.
        map_y: usize,
        /// The map's width.
        width: usize,
        /// The map's height.
        height: usize,
    },
    /// A source image too small to interpolate.
    #[error("remap: source {width}x{height} is smaller than 2x2")]
    SourceTooSmall {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// A source image too large for the table's offsets.
    #[error("remap: source {width}x{height} exceeds 2^32 pixels")]
    SourceTooLarge {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// An image of another size than the remap table's source.
    #[error("remap: image is {width}x{height}, table was built for {table_width}x{table_height}")]
    RemapSource {
        /// The image's width.
        width: usize,
        /// The image's height.
        height: usize,
        /// The table's source width.
        table_width: usize,
        /// The table's source height.
        table_height: usize,
    },
    /// An output buffer of another size than the remap table's.
    #[error("remap: output buffer has {bytes} bytes, expected {width}x{height}")]
    RemapOutput {
        /// Bytes given.
        bytes: usize,
        /// The table's width.
        width: usize,
        /// The table's height.
        height: usize,
    },
    /// A height raster whose samples do not fill its grid.
    #[error("orthorectify: height raster has {samples} samples, grid is {width}x{height}")]
    HeightSize {
        /// Samples given.
        samples: usize,
        /// The grid's width.
        width: usize,
        /// The grid's height.
        height: usize,
    },
    /// A height raster with no valid cell.
    #[error("orthorectify: height raster has no valid cell")]
    HeightEmpty,
    /// An image of another size than the camera's.
    #[error("orthorectify: image is {width}x{height}, camera is {camera_width}x{camera_height}")]
    OrthoImage {
        /// The image's width.
        width: usize,
        /// The image's height.
        height: usize,
        /// The camera's width.
        camera_width: u32,
        /// The camera's height.
        camera_height: u32,
    },
    /// An empty image or output grid.
    #[error("orthorectify: empty image or grid")]
    OrthoEmpty,
}
