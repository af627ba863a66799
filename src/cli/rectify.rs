//! `infraloc rectify`: perspective rectification of a fisheye/omnidirectional image with
//! `cv::omnidir::initUndistortRectifyMap(…, RECTIFY_PERSPECTIVE)` semantics (docs/interfaces.md, "Command line and exit codes").

use super::parse_list;
use crate::camera::load_camera;
use crate::camera::rectify::{perspective_map, GrayView, RectifyMap, RemapTable};
use crate::camera::CameraModel;
use crate::error::{Error, Result};
use nalgebra::Matrix3;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `rectify`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Camera intrinsics file (OpenCV FileStorage, Kalibr camchain, KITTI-360 MEI YAML or TOML).
    #[arg(long, value_name = "CAM")]
    pub camera: PathBuf,
    /// Input image (gray or colour; colour is converted with BT.601 weights like OpenCV).
    #[arg(long, value_name = "IN")]
    pub image: PathBuf,
    /// Output image (gray; format from the extension, e.g. .png).
    #[arg(long, value_name = "OUT")]
    pub out: PathBuf,
    /// Output size `W,H` in pixels.
    #[arg(long, value_name = "W,H")]
    pub size: String,
    /// Intrinsics `FX,FY,CX,CY` of the virtual perspective camera (OpenCV's `P`).
    #[arg(long, value_name = "FX,FY,CX,CY")]
    pub k: String,
    /// Rotation `R` (9 numbers, row-major), as OpenCV's `R` argument; identity if absent.
    #[arg(long, value_name = "R00,…,R22", allow_hyphen_values = true)]
    pub rotation: Option<String>,
    /// Also write the maps: map_x then map_y, f32 little-endian, W·H each.
    #[arg(long, value_name = "FILE")]
    pub map_out: Option<PathBuf>,
}

/// Largest output side accepted (OpenCV's maps use 16-bit coordinates internally too).
const MAX_SIDE: f64 = 32767.0;

/// How far `RᵀR` may be from the identity (per element) and `det R` from 1: a rotation typed
/// with 6 to 9 significant digits passes, a scaled, sheared or mirrored matrix does not.
const ROTATION_TOL: f64 = 1e-5;

/// `--rotation` must be a rotation: orthonormal with determinant +1. A scaled or sheared matrix
/// would silently zoom or skew the output; OpenCV applies it all the same.
fn check_rotation(r: &Matrix3<f64>) -> Result<()> {
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    let det = r.determinant();
    if off > ROTATION_TOL || (det - 1.0).abs() > ROTATION_TOL {
        return Err(Error::Usage(format!(
            "--rotation is not a rotation matrix: RᵀR differs from the identity by up to {off:.3e} and det R = {det:.6} (need an orthonormal matrix with det +1, within {ROTATION_TOL:e})"
        )));
    }
    Ok(())
}

/// Run `rectify`.
pub(super) fn run(a: Args) -> Result<()> {
    let [w, h] = parse_list::<2>("--size", &a.size)?;
    let valid_side = |v: f64| (1.0..=MAX_SIDE).contains(&v) && v.fract() == 0.0;
    if !(valid_side(w) && valid_side(h)) {
        return Err(Error::arg_quoted(
            "--size",
            &a.size,
            format!("expected two whole numbers from 1 to {MAX_SIDE}"),
        ));
    }
    let (w, h) = (w as usize, h as usize);
    let [fx, fy, cx, cy] = parse_list::<4>("--k", &a.k)?;
    let p = Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0);
    let r = match &a.rotation {
        Some(s) => Matrix3::from_row_slice(&parse_list::<9>("--rotation", s)?),
        None => Matrix3::identity(),
    };
    if !(p.iter().chain(r.iter()).all(|v| v.is_finite())) {
        return Err(Error::Usage(
            "--k / --rotation: values must be finite".into(),
        ));
    }
    check_rotation(&r)?;

    let cam = load_camera(&a.camera)?;
    let gray = crate::capture::load_gray(&a.image)?;
    let (iw, ih) = (gray.width() as usize, gray.height() as usize);
    let gray = gray.into_raw();
    if iw != cam.width() as usize || ih != cam.height() as usize {
        return Err(Error::input(
            &a.image,
            format!(
                "image is {iw}x{ih} but the camera {} is calibrated for {}x{}",
                a.camera.display(),
                cam.width(),
                cam.height()
            ),
        ));
    }

    let map = perspective_map(cam.model(), &p, &r, w, h)?;
    let src = GrayView::new(&gray, iw, ih)?;
    let out = RemapTable::new(&map, iw, ih)?.remap(&src)?;
    let img = image::GrayImage::from_raw(w as u32, h as u32, out)
        .ok_or_else(|| Error::output("rectify", "output buffer size mismatch"))?;
    img.save(&a.out)
        .map_err(|e| Error::input(&a.out, format!("cannot write image: {e}")))?;
    if let Some(path) = &a.map_out {
        write_maps(path, &map)?;
    }
    Ok(())
}

/// Write map_x then map_y as f32 little-endian planes.
fn write_maps(path: &Path, map: &RectifyMap) -> Result<()> {
    let f = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut w = std::io::BufWriter::new(f);
    for v in map.map_x.iter().chain(&map.map_y) {
        w.write_all(&v.to_le_bytes())
            .map_err(|e| Error::io(path, e))?;
    }
    w.flush().map_err(|e| Error::io(path, e))
}
