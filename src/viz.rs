//! Pictures a technician can trust at a glance: LiDAR ground points projected onto the fisheye
//! frame (cyan at the final pose, as in the seed's figures; red at an earlier stage's pose).

use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::map::GroundPoint;
use crate::pose::CamFromMap;
use image::{GrayImage, Rgb, RgbImage};

/// Final-pose colour.
pub const CYAN: [u8; 3] = [0, 255, 255];
/// Earlier-stage colour.
pub const RED: [u8; 3] = [255, 48, 48];
/// Only points at least this bright (percentile of the set's reflectivity) are drawn: the paint,
/// whose alignment is what the eye checks; drawing every point would hide the image.
pub const DRAW_PERCENTILE: f64 = 0.96;

/// The frame in gray with each pose's projections of the brightest ground points drawn on it.
pub fn overlay(
    image: &GrayImage,
    cam: &dyn CameraModel,
    layers: &[(&CamFromMap, [u8; 3])],
    points: &[GroundPoint],
) -> RgbImage {
    let mut out = RgbImage::from_fn(image.width(), image.height(), |x, y| {
        let v = image.get_pixel(x, y)[0] / 2 + 40; // dimmed so the points stand out
        Rgb([v, v, v])
    });
    let mut refl: Vec<u8> = points.iter().map(|p| p.reflectivity).collect();
    if refl.is_empty() {
        return out;
    }
    let k = ((refl.len() - 1) as f64 * DRAW_PERCENTILE) as usize;
    let thr = *refl.select_nth_unstable(k).1;
    for (pose, colour) in layers {
        // Re-centre: UTM coordinates in f64 are fine, but the rotation is applied once per point.
        for p in points.iter().filter(|p| p.reflectivity >= thr.max(1)) {
            let pc = pose.transform(&nalgebra::Point3::new(p.x, p.y, p.z)).coords;
            if let Ok(px) = cam.project_visible(&pc) {
                let (u, v) = (px.x.round() as i64, px.y.round() as i64);
                if u >= 0 && v >= 0 && (u as u32) < out.width() && (v as u32) < out.height() {
                    out.put_pixel(u as u32, v as u32, Rgb(*colour));
                }
            }
        }
    }
    out
}

/// [`overlay`] encoded as PNG bytes.
pub fn overlay_png(
    image: &GrayImage,
    cam: &dyn CameraModel,
    layers: &[(&CamFromMap, [u8; 3])],
    points: &[GroundPoint],
) -> Result<Vec<u8>> {
    let img = overlay(image, cam, layers, points);
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)
        .map_err(|e| Error::Invalid(format!("overlay PNG encoding: {e}")))?;
    Ok(buf.into_inner())
}
