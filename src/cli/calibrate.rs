//! `infraloc calibrate --model mei|equidistant (--images DIR --pattern COLSxROWS --square M |
//! --corners FILE) --out CAM.yaml [--report JSON] [--coverage PNG]` (docs/interfaces.md, "Command
//! line and exit codes"): detect or read the corners, run [`crate::calib`], write the intrinsics
//! (OpenCV FileStorage YAML that `load_camera` reads back), the report and the coverage picture.

use crate::calib::{self, corners, detect, Calibration, LensModel, NotFound};
use crate::error::{Error, Result};
use image::{Rgb, RgbImage};
use rayon::prelude::*;
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
    #[arg(long, required_unless_present = "images", conflicts_with = "images")]
    pub corners: Option<PathBuf>,
    /// Directory of checkerboard images (PNG, JPEG, TIFF; all the same size), detected here.
    #[arg(long, requires_all = ["pattern", "square"])]
    pub images: Option<PathBuf>,
    /// Inner corners of the board as COLSxROWS (OpenCV's pattern size), e.g. 9x6.
    #[arg(long, value_parser = parse_pattern)]
    pub pattern: Option<(usize, usize)>,
    /// Side of a board square, metres.
    #[arg(long)]
    pub square: Option<f64>,
    /// With --images: also write the detected corners here, in the --corners layout (so OpenCV,
    /// or a later run, can use the same detections).
    #[arg(long, requires = "images")]
    pub save_corners: Option<PathBuf>,
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

/// `COLSxROWS` → (cols, rows), each at least 2.
pub(super) fn parse_pattern(s: &str) -> std::result::Result<(usize, usize), String> {
    let bad = || format!("{s:?}: expected COLSxROWS inner corners, e.g. 9x6");
    let (c, r) = s.split_once(['x', 'X', '×']).ok_or_else(bad)?;
    let (c, r): (usize, usize) = (
        c.trim().parse().map_err(|_| bad())?,
        r.trim().parse().map_err(|_| bad())?,
    );
    // A board of more than 100 000 inner corners is a typing error, and bounding it keeps the
    // corner counts and the rendered board's allocations far from overflow.
    if c < 2 || r < 2 || c > 1000 || r > 1000 || c * r > 100_000 {
        return Err(bad());
    }
    Ok((c, r))
}

/// Image files of a directory, by name.
fn image_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|x| x.to_str())
                .map(|x| {
                    matches!(
                        x.to_ascii_lowercase().as_str(),
                        "png" | "jpg" | "jpeg" | "tif" | "tiff" | "pgm" | "bmp"
                    )
                })
                .unwrap_or(false)
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::input(
            dir,
            "no images (.png, .jpg, .tif, .pgm, .bmp)",
        ));
    }
    Ok(files)
}

/// Detect the board in every image of `dir`: the views found, and the images without a board
/// and why. Images are decoded and searched in parallel.
fn detect_dir(
    dir: &Path,
    (cols, rows): (usize, usize),
    square: f64,
) -> Result<(calib::Observations, Vec<NotFound>)> {
    if !(square.is_finite() && square > 0.0) {
        return Err(Error::arg(
            "--square",
            square,
            "expected a positive size in metres",
        ));
    }
    let files = image_files(dir)?;
    let name = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    type Outcome = (
        u32,
        u32,
        std::result::Result<detect::Found, calib::DetectError>,
    );
    let found: Vec<Result<Outcome>> = files
        .par_iter()
        .map(|p| {
            let img = image::open(p)
                .map_err(|e| Error::input(p, format!("cannot read the image: {e}")))?
                .into_luma8();
            let (w, h) = img.dimensions();
            Ok((w, h, detect::detect(img.as_raw(), w, h, cols, rows, square)))
        })
        .collect();
    let mut size: Option<(u32, u32, &Path)> = None;
    let mut views = Vec::new();
    let mut missing = Vec::new();
    for (p, f) in files.iter().zip(found) {
        let (w, h, f) = f?;
        match size {
            Some((w0, h0, first)) if (w0, h0) != (w, h) => {
                return Err(Error::input(
                    p,
                    format!(
                        "image is {w}×{h} but {} is {w0}×{h0}: one camera, one size",
                        name(first)
                    ),
                ))
            }
            Some(_) => {}
            None => size = Some((w, h, p)),
        }
        match f {
            Ok(f) => views.push(calib::View {
                name: name(p),
                object: f.object,
                image: f.image,
            }),
            Err(reason) => missing.push(NotFound {
                name: name(p),
                reason: reason.to_string(),
            }),
        }
    }
    let list = |m: &[NotFound]| {
        m.iter()
            .map(|n| format!("{}: {}", n.name, n.reason))
            .collect::<Vec<_>>()
            .join("; ")
    };
    let (width, height) = size.map(|(w, h, _)| (w, h)).unwrap_or((0, 0));
    if views.is_empty() {
        return Err(Error::input(
            dir,
            format!(
                "no {cols}x{rows} board found in any of {} image(s) ({})",
                files.len(),
                list(&missing)
            ),
        ));
    }
    if views.len() < calib::MIN_VIEWS {
        return Err(Error::input(
            dir,
            format!(
                "a board in {} image(s), need at least {} (not found: {})",
                views.len(),
                calib::MIN_VIEWS,
                list(&missing)
            ),
        ));
    }
    Ok((
        calib::Observations {
            width,
            height,
            views,
        },
        missing,
    ))
}

/// Run `calibrate`.
pub(super) fn run(a: Args) -> Result<()> {
    let (obs, not_found, origin) = match (&a.corners, &a.images) {
        (Some(c), _) => {
            let text = std::fs::read_to_string(c).map_err(|e| Error::io(c, e))?;
            (corners::parse_corners(&text, c)?, Vec::new(), c.clone())
        }
        (None, Some(dir)) => {
            let (pattern, square) = a.pattern.zip(a.square).ok_or_else(|| {
                Error::Usage("--images needs --pattern COLSxROWS and --square METRES".into())
            })?;
            let (obs, nf) = detect_dir(dir, pattern, square)?;
            (obs, nf, dir.clone())
        }
        (None, None) => {
            return Err(Error::Usage(
                "give --corners FILE or --images DIR --pattern COLSxROWS --square METRES".into(),
            ))
        }
    };
    if let Some(p) = &a.save_corners {
        write(p, corners::to_corners_yaml(&obs))?;
    }
    let model = match a.model {
        ModelArg::Mei => LensModel::Mei,
        ModelArg::Equidistant => LensModel::Equidistant,
    };
    let mut cal =
        calib::calibrate(&obs, model).map_err(|e| Error::input(&origin, e.to_string()))?;
    cal.not_found = not_found;
    write(&a.out, calib::to_yaml(&cal))?;
    if let Some(r) = &a.report {
        let json = serde_json::to_string_pretty(&cal).map_err(|e| Error::output("report", e))?;
        write(r, json + "\n")?;
    }
    if let Some(p) = &a.coverage {
        coverage(&cal, &obs)
            .save(p)
            .map_err(|e| Error::output(p.display().to_string(), e))?;
    }
    let rejected: Vec<String> = cal
        .views
        .iter()
        .filter_map(|v| v.rejected.as_ref().map(|m| format!("{} ({m})", v.name)))
        .chain(
            cal.not_found
                .iter()
                .map(|n| format!("{} (no board: {})", n.name, n.reason)),
        )
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
