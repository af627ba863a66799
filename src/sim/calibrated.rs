//! Given intrinsics the way a real install gets them: render checkerboard views with the scene's
//! true camera ([`super::checkerboard::render`]), detect the corners ([`crate::calib::detect`]) and
//! calibrate ([`crate::calib::calibrate`]), exactly as `infraloc calibrate --images` would on a
//! technician's board images. The error left in the result is the calibrator's own (corner noise,
//! the focal–ξ trade, the lens edge the boards reached), not an offset drawn from a stated range.

use super::checkerboard::{render, Board};
use crate::calib::{self, detect, LensModel};
use crate::camera::import::IntrinsicsSigma;
use crate::camera::{Camera, CameraModel};
use rayon::prelude::*;

/// The board a technician holds: 9 × 6 inner corners, 4 cm squares (OpenCV's sample pattern).
const BOARD: Board = Board {
    cols: 9,
    rows: 6,
    square: 0.04,
};

/// Views rendered: a short calibration session (the views that miss the board are dropped).
pub(crate) const VIEWS: usize = 16;

/// A calibration of `truth` from [`VIEWS`] rendered board views (deterministic for `seed`): the
/// fitted camera, the σ it states (from the fit's parameter standard deviations: the larger
/// focal's relative σ, the larger principal-point coordinate's σ) and the fit's RMS (px).
/// `Err` names the stage that failed (no board found, the fit).
pub(crate) fn calibrated_camera(
    truth: &Camera,
    seed: u64,
) -> Result<(Camera, IntrinsicsSigma, f64), String> {
    let (w, h) = (truth.width(), truth.height());
    let views = render(truth, &BOARD, VIEWS, seed);
    let found: Vec<(usize, Result<detect::Found, String>)> = views
        .par_iter()
        .enumerate()
        .map(|(i, v)| {
            (
                i,
                detect::detect(&v.image, w, h, BOARD.cols, BOARD.rows, BOARD.square),
            )
        })
        .collect();
    let views: Vec<calib::View> = found
        .into_iter()
        .filter_map(|(i, f)| {
            f.ok().map(|f| calib::View {
                name: format!("view {i}"),
                object: f.object,
                image: f.image,
            })
        })
        .collect();
    let obs = calib::Observations {
        width: w,
        height: h,
        views,
    };
    let model = match truth {
        Camera::Mei(_) => LensModel::Mei,
        Camera::Equidistant(_) => LensModel::Equidistant,
    };
    let c = calib::calibrate(&obs, model).map_err(|e| format!("calibration: {e}"))?;
    let p = |name: &str| c.params.iter().find(|p| p.name == name);
    let rel = |name: &str| p(name).map_or(0.0, |p| (p.std / p.value).abs());
    let std = |name: &str| p(name).map_or(0.0, |p| p.std);
    let sigma = IntrinsicsSigma {
        focal_rel: rel("fx").max(rel("fy")),
        principal_point_px: std("cx").max(std("cy")),
    };
    // The lens's field of view is its datasheet's, not something a board calibration measures:
    // an installer writes it into the camera file as well.
    let mut camera = c.camera;
    match (&mut camera, truth) {
        (Camera::Mei(m), Camera::Mei(t)) => m.fov_deg = t.fov_deg,
        (Camera::Equidistant(m), Camera::Equidistant(t)) => {
            m.fov_deg = t.fov_deg;
            m.cache = Default::default();
        }
        _ => {}
    }
    Ok((camera, sigma, c.rms))
}
