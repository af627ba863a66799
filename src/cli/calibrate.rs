//! `infraloc calibrate --model mei|equidistant --corners FILE --out CAM.yaml [--report JSON]
//! [--coverage PNG]` (docs/interfaces.md, "Command line and exit codes"): read the corners, run [`crate::calib`], write the intrinsics
//! (OpenCV FileStorage YAML that `load_camera` reads back), the report and the coverage picture.

use crate::calib::{self, corners, Calibration, LensModel};
use crate::error::{Error, Result};
use image::{Rgb, RgbImage};
use std::path::{Path, PathBuf};

/// Lens model argument.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ModelArg {
    /// Mei unified model (OpenCV omnidir): fx fy cx cy skew k1 k2 p1 p2 ξ.
    Mei,
    /// Equidistant fisheye (OpenCV fisheye): fx fy cx cy k1..k4.
    Equidistant,
}

/// Arguments of `calibrate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Lens model to fit.
    #[arg(long, value_enum)]
    pub model: ModelArg,
    /// Corner detections: OpenCV FileStorage (XML or YAML) with `objectPoints` / `imagePoints`
    /// sequences and `imageSize` (opencv_contrib's omni_calib_data.xml layout).
    #[arg(long)]
    pub corners: PathBuf,
    /// Output intrinsics (OpenCV FileStorage YAML).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write a JSON report: RMS overall and per view, rejected views and why, parameter
    /// standard deviations, view poses.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Also write a PNG of where the corners fell on the sensor, with their residual vectors.
    #[arg(long)]
    pub coverage: Option<PathBuf>,
}

/// Run `calibrate`.
pub(super) fn run(a: Args) -> Result<()> {
    let text = std::fs::read_to_string(&a.corners).map_err(|e| Error::io(&a.corners, e))?;
    let obs = corners::parse_corners(&text, &a.corners)?;
    let model = match a.model {
        ModelArg::Mei => LensModel::Mei,
        ModelArg::Equidistant => LensModel::Equidistant,
    };
    let cal = calib::calibrate(&obs, model).map_err(|e| Error::input(&a.corners, e.0))?;
    write(&a.out, calib::to_yaml(&cal))?;
    if let Some(r) = &a.report {
        let json = serde_json::to_string_pretty(&cal)
            .map_err(|e| Error::Invalid(format!("report: {e}")))?;
        write(r, json + "\n")?;
    }
    if let Some(p) = &a.coverage {
        coverage(&cal, &obs)
            .save(p)
            .map_err(|e| Error::Invalid(format!("{}: {e}", p.display())))?;
    }
    let rejected: Vec<String> = cal
        .views
        .iter()
        .filter_map(|v| v.rejected.as_ref().map(|m| format!("{} ({m})", v.name)))
        .collect();
    println!(
        "calibrate: {} views, {} corners, RMS {:.4} px; wrote {}{}",
        cal.views.iter().filter(|v| v.used).count(),
        cal.corners_used,
        cal.rms,
        a.out.display(),
        if rejected.is_empty() {
            String::new()
        } else {
            format!("; rejected: {}", rejected.join(", "))
        }
    );
    Ok(())
}

fn write(path: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// Longest side of the coverage picture, px.
const COVERAGE_SIDE: u32 = 1024;
/// Residual vectors are drawn this many times their length.
const RESIDUAL_GAIN: f64 = 20.0;

/// The sensor (scaled to [`COVERAGE_SIDE`]) with each used corner as a dot coloured by view, its
/// residual ×[`RESIDUAL_GAIN`] as a red line, rejected views' corners as grey crosses, and the
/// principal point as a cross.
pub(super) fn coverage(cal: &Calibration, obs: &calib::Observations) -> RgbImage {
    let [w, h] = cal.image_size;
    let s = COVERAGE_SIDE as f64 / w.max(h) as f64;
    let (cw, ch) = (
        ((w as f64 * s).round() as u32).max(1),
        ((h as f64 * s).round() as u32).max(1),
    );
    let mut img = RgbImage::from_pixel(cw, ch, Rgb([24, 24, 24]));
    let map = |p: [f64; 2]| ((p[0] + 0.5) * s - 0.5, (p[1] + 0.5) * s - 0.5);
    let palette = |i: usize| -> Rgb<u8> {
        // Evenly spaced hues, bright enough on the dark background.
        let hue = (i as f64 * 0.618_033_988_75).fract() * 6.0;
        let x = 1.0 - (hue % 2.0 - 1.0).abs();
        let (r, g, b) = match hue as u32 {
            0 => (1.0, x, 0.0),
            1 => (x, 1.0, 0.0),
            2 => (0.0, 1.0, x),
            3 => (0.0, x, 1.0),
            4 => (x, 0.0, 1.0),
            _ => (1.0, 0.0, x),
        };
        let c = |v: f64| (90.0 + 165.0 * v) as u8;
        Rgb([c(r), c(g), c(b)])
    };
    for (vi, (vr, v)) in cal.views.iter().zip(&obs.views).enumerate() {
        for (j, p) in v.image.iter().enumerate() {
            let (x, y) = map(*p);
            if !vr.used {
                line(
                    &mut img,
                    (x - 3.0, y - 3.0),
                    (x + 3.0, y + 3.0),
                    Rgb([120, 120, 120]),
                );
                line(
                    &mut img,
                    (x - 3.0, y + 3.0),
                    (x + 3.0, y - 3.0),
                    Rgb([120, 120, 120]),
                );
                continue;
            }
            let color = palette(vi);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    put(&mut img, x + dx as f64, y + dy as f64, color);
                }
            }
            if let Some(r) = vr.residuals.get(j) {
                let end = (x + r[0] * s * RESIDUAL_GAIN, y + r[1] * s * RESIDUAL_GAIN);
                line(&mut img, (x, y), end, Rgb([255, 60, 60]));
            }
        }
    }
    let (px, py) = match &cal.camera {
        crate::camera::Camera::Mei(m) => (m.cx, m.cy),
        crate::camera::Camera::Equidistant(e) => (e.cx, e.cy),
    };
    let (x, y) = map([px, py]);
    line(&mut img, (x - 8.0, y), (x + 8.0, y), Rgb([255, 255, 255]));
    line(&mut img, (x, y - 8.0), (x, y + 8.0), Rgb([255, 255, 255]));
    img
}

fn put(img: &mut RgbImage, x: f64, y: f64, c: Rgb<u8>) {
    let (xi, yi) = (x.round(), y.round());
    if xi >= 0.0 && yi >= 0.0 && xi < img.width() as f64 && yi < img.height() as f64 {
        img.put_pixel(xi as u32, yi as u32, c);
    }
}

fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), c: Rgb<u8>) {
    let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).clamp(1, 4096);
    for i in 0..=n {
        let t = i as f64 / n as f64;
        put(img, a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), c);
    }
}
