//! Pictures a technician can trust at a glance: LiDAR ground points projected onto the fisheye
//! frame in cyan, as in the seed's figures; [`before_after`] puts the initial pose's picture and
//! the final pose's side by side, so neither hides the other.
//!
//! Text (panel labels here, the `study` and `plot` charts' labels) is drawn with `plotters`'
//! `ab_glyph` backend and the DejaVu Sans embedded from `assets/` (Bitstream Vera licence,
//! `assets/DejaVuSans-LICENSE.txt`), so no system font is needed on the node.

use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::map::GroundPoint;
use crate::pose::CamFromMap;
use image::{GrayImage, Rgb, RgbImage};
use plotters::prelude::*;

/// Point colour.
pub(crate) const CYAN: [u8; 3] = [0, 255, 255];

/// The embedded font (DejaVu Sans 2.37, Bitstream Vera licence).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// Font family name every picture and chart uses.
pub(crate) const FAMILY: &str = "sans-serif";

/// Register the embedded font under [`FAMILY`], once per process.
pub(crate) fn register_font() -> Result<()> {
    static ONCE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *ONCE
        .get_or_init(|| plotters::style::register_font(FAMILY, FontStyle::Normal, FONT).is_ok());
    if ok {
        Ok(())
    } else {
        Err(Error::Invalid("embedded font is unreadable".into()))
    }
}
/// Only points at least this bright (percentile of the set's reflectivity) are drawn: the paint,
/// whose alignment is what the eye checks; drawing every point would hide the image.
pub(crate) const DRAW_PERCENTILE: f64 = 0.96;

/// The frame in gray with each pose's projections of the brightest ground points drawn on it.
pub(crate) fn overlay(
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

/// Labels of [`before_after`]'s panels, left to right.
pub(crate) const PANEL_LABELS: [&str; 2] = ["before: initial pose", "after: final pose"];

/// Two [`overlay`] panels side by side, 2·W × H: left the points at `before` (the initial pose),
/// right at `after` (the final pose), both cyan, each labelled in its top-left corner. Drawn on
/// one image the final pose's points hid the initial pose's wherever they overlapped.
pub(crate) fn before_after(
    image: &GrayImage,
    cam: &dyn CameraModel,
    before: &CamFromMap,
    after: &CamFromMap,
    points: &[GroundPoint],
) -> Result<RgbImage> {
    let (w, h) = (image.width(), image.height());
    let mut out = RgbImage::new(2 * w, h);
    for (i, pose) in [before, after].into_iter().enumerate() {
        let panel = overlay(image, cam, &[(pose, CYAN)], points);
        image::imageops::replace(&mut out, &panel, i as i64 * w as i64, 0);
    }
    register_font()?;
    let err = |e: &dyn std::fmt::Display| Error::output("overlay labels", e.to_string());
    // Label size follows the frame (a 5 MP frame needs larger text than a 320 px test frame).
    let size = (h / 28).clamp(12, 64);
    {
        let (bw, bh) = (out.width(), out.height());
        let root = BitMapBackend::with_buffer(&mut out, (bw, bh)).into_drawing_area();
        let style = (FAMILY, size).into_font().color(&WHITE);
        for (i, label) in PANEL_LABELS.iter().enumerate() {
            let x0 = i as i32 * w as i32;
            let (tw, th) = root
                .estimate_text_size(label, &style)
                .map_err(|e| err(&e))?;
            // A black box under the text keeps it readable on bright pavement.
            let pad = (size / 4) as i32;
            root.draw(&Rectangle::new(
                [(x0, 0), (x0 + tw as i32 + 2 * pad, th as i32 + 2 * pad)],
                BLACK.filled(),
            ))
            .map_err(|e| err(&e))?;
            root.draw_text(label, &style, (x0 + pad, pad))
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}

/// [`before_after`] encoded as PNG bytes.
pub(crate) fn before_after_png(
    image: &GrayImage,
    cam: &dyn CameraModel,
    before: &CamFromMap,
    after: &CamFromMap,
    points: &[GroundPoint],
) -> Result<Vec<u8>> {
    let img = before_after(image, cam, before, after, points)?;
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)
        .map_err(|e| Error::output("overlay PNG encoding", e))?;
    Ok(buf.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Camera, Mei};
    use nalgebra::{Point3, Vector3};

    #[test]
    fn before_after_panels_show_each_pose_s_projection() {
        let cam = Camera::Mei(Mei {
            width: 320,
            height: 240,
            fx: 150.0,
            fy: 150.0,
            cx: 160.0,
            cy: 120.0,
            skew: 0.0,
            xi: 1.2,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        });
        let after = CamFromMap::from_center_ypr(&Point3::new(10.0, 20.0, 6.0), 0.3, 0.0, 0.0);
        // 0.8 m and 2° away: the point lands tens of pixels from where `after` puts it.
        let before = after.perturbed(&Vector3::new(0.8, -0.5, 0.0), 2f64.to_radians());
        let p = GroundPoint {
            x: 11.0,
            y: 21.5,
            z: 0.0,
            reflectivity: 200,
        };
        let pixel = |pose: &CamFromMap| {
            let pc = pose.transform(&Point3::new(p.x, p.y, p.z)).coords;
            let px = cam.project_visible(&pc).unwrap();
            (px.x.round() as u32, px.y.round() as u32)
        };
        let (ub, vb) = pixel(&before);
        let (ua, va) = pixel(&after);
        assert!(
            ub.abs_diff(ua) + vb.abs_diff(va) > 10,
            "{ub},{vb} {ua},{va}"
        );
        // Clear of the labels in the top-left corners.
        assert!(vb > 40 && va > 40, "{vb} {va}");
        let frame = GrayImage::from_pixel(320, 240, image::Luma([100]));
        let png = before_after_png(&frame, &cam, &before, &after, &[p]).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (640, 240));
        let cyan = Rgb(CYAN);
        // Right panel: the point at the final pose; left: at the initial pose.
        assert_eq!(*img.get_pixel(320 + ua, va), cyan);
        assert_eq!(*img.get_pixel(ub, vb), cyan);
        // Each panel has only its own pose's point.
        assert_ne!(*img.get_pixel(320 + ub, vb), cyan);
        assert_ne!(*img.get_pixel(ua, va), cyan);
        let n_cyan = img.pixels().filter(|&&px| px == cyan).count();
        assert_eq!(n_cyan, 2);
        // The labels are drawn: white text inside each panel's top-left box.
        for x0 in [0, 320] {
            let white = (x0..x0 + 150)
                .flat_map(|x| (0..30).map(move |y| (x, y)))
                .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c > 200))
                .count();
            assert!(white > 20, "panel at {x0}: {white} label pixels");
        }
    }
}
