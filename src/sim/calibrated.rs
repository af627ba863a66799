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
/// fitted camera and the σ it states ([`calib::Calibration::stated_sigma`]).
/// `Err` names the stage that failed (no board found, the fit).
pub(crate) fn calibrated_camera(
    truth: &Camera,
    seed: u64,
) -> Result<(Camera, IntrinsicsSigma), String> {
    let (w, h) = (truth.width(), truth.height());
    let views = render(truth, &BOARD, VIEWS, seed);
    // Views without a board are dropped, as `calibrate --images` lists and skips them.
    let views: Vec<calib::View> = views
        .par_iter()
        .enumerate()
        .filter_map(|(i, v)| {
            detect::detect(&v.image, w, h, BOARD.cols, BOARD.rows, BOARD.square)
                .ok()
                .map(|f| calib::View {
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
    let sigma = c.stated_sigma();
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
    Ok((camera, sigma))
}
