//! `infraloc plot mi-surface` (docs/interfaces.md, "Command line and exit codes"): the seed's 1-D MI-vs-perturbation curves and the 2-D
//! x–y MI surface around a pose, as one PNG; and the chart drawing shared with `infraloc study`.
//!
//! Charts are drawn with `plotters` into an RGB buffer and encoded with `image`; text uses the
//! DejaVu Sans embedded from `assets/` (Bitstream Vera licence, `assets/DejaVuSans-LICENSE.txt`)
//! so no system font is needed on the node.

use super::parse_size;
use crate::error::{Error, Result};
use crate::eval::study::{
    mi_surface, mi_surface_pooled, offsets_from, Perturbation, PointSelection, Summary, Surface,
    Trial, SUCCESS_HEIGHT_M, SUCCESS_HORIZONTAL_M, SUCCESS_YAW_DEG,
};
use crate::localize::mi::smooth::{Pooling, Sampling};
use crate::localize::mi::space::{SearchConfig, SearchSpec};
use crate::points_io::read_points;
use crate::posefile::read_pose;
use crate::scene::{load_scene, SceneFiles};
use image::RgbImage;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

use crate::viz::FAMILY;

/// `plot` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// MI along x, y, z, yaw, over the x–y plane and over yaw × lateral shift around a pose: on a
    /// simulated scene (--scene) or on real inputs (--camera, --image, --points or --tiles, --pose).
    MiSurface(MiSurfaceArgs),
}

/// Arguments of `plot mi-surface`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("inputs").required(true).args(["scene", "camera"])))]
pub struct MiSurfaceArgs {
    /// Simulated scene directory (`infraloc simulate --out DIR`): its camera, frames' median, tile
    /// and truth.
    #[arg(long, conflicts_with_all = ["camera", "image", "points", "tiles"])]
    pub scene: Option<PathBuf>,
    /// Real inputs: camera intrinsics (any format `refine --camera` reads).
    #[arg(long, requires = "image")]
    pub camera: Option<PathBuf>,
    /// Real inputs: the image (converted to gray), paired with --points; repeat both (in the
    /// same order) to pool several pairs that share the pose, as `refine` does.
    #[arg(long)]
    pub image: Vec<PathBuf>,
    /// Real inputs: point file (CSV, PCD, LAS, Velodyne .bin), all points used as given.
    #[arg(long, conflicts_with = "tiles")]
    pub points: Vec<PathBuf>,
    /// Real inputs: tile cache; ground points within --radius of the camera (the pose's crs
    /// finds the tile), as `refine --tiles`.
    #[arg(long)]
    pub tiles: Option<PathBuf>,
    /// Radius (m) of tile ground points around the camera (with --tiles).
    #[arg(long, default_value_t = 25.0)]
    pub radius: f64,
    /// Centre pose (pose-like JSON, e.g. the served pose.json); default with --scene: the truth.
    /// A `quality.covariance` in it (docs/interfaces.md, "Pose file") is drawn as 1σ and 3σ ellipses.
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// A reference pose to mark (green), e.g. a calibration; default with --scene: the truth.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Output PNG; default: DIR/mi-surface.png with --scene (required otherwise).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Ranges and steps: x=HALF:STEP,y=…,z=…,yaw=… (m, deg), as `refine --search`.
    #[arg(long, default_value = "x=1:0.02,y=1:0.02,z=0.5:0.02,yaw=3:0.05")]
    pub search: String,
    /// The x–y and yaw–lateral surfaces take every N-th step.
    #[arg(long, default_value_t = 2)]
    pub xy_stride: i64,
    /// Image size W,H in pixels.
    #[arg(long, default_value = "2000,900")]
    pub size: String,
    /// Also write the curves and the surfaces as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// The MI estimator (bins, objective, binning, Parzen smoothing), as `refine`'s.
    #[command(flatten)]
    pub estimator: super::estimator::EstimatorArgs,
    /// How a point samples the image: `nearest` (the search's nearest pixel) or `pv` (the
    /// partial-volume histogram of `refine --sampling pv`).
    #[arg(long, value_name = "nearest|pv", default_value = "nearest")]
    pub sampling: String,
    /// With `--sampling pv` and several pairs: `joint` or `per-pair` (as `refine --pooling`).
    #[arg(long, value_name = "joint|per-pair", default_value = "joint")]
    pub pooling: String,
}

/// Run a `plot` subcommand.
pub(super) fn run(c: Command) -> Result<()> {
    match c {
        Command::MiSurface(a) => mi_surface_cmd(a),
    }
}

/// The marginal covariance of x, y and yaw (m, m, deg) a pose file's `quality.covariance`
/// carries (docs/interfaces.md, "Pose file"): a matrix over [x, y, z, yaw(, pitch, roll)], or the
/// object refine and the service write, with that `matrix` and the `axes` it is ordered by.
/// `None` when the file has none.
pub(crate) fn pose_covariance(
    doc: &serde_json::Value,
) -> std::result::Result<Option<[[f64; 3]; 3]>, String> {
    let Some(c) = doc.get("quality").and_then(|q| q.get("covariance")) else {
        return Ok(None);
    };
    if c.is_null() {
        return Ok(None);
    }
    let (matrix, axes) = match c {
        serde_json::Value::Object(o) => (
            o.get("matrix").ok_or("quality.covariance: no \"matrix\"")?,
            o.get("axes").and_then(|a| a.as_array()).map(|a| {
                a.iter()
                    .map(|n| n.as_str().unwrap_or("").to_string())
                    .collect::<Vec<_>>()
            }),
        ),
        other => (other, None),
    };
    let rows: Vec<Vec<f64>> = matrix
        .as_array()
        .ok_or("quality.covariance: not a matrix")?
        .iter()
        .map(|r| {
            r.as_array()
                .map(|r| r.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect())
                .unwrap_or_default()
        })
        .collect();
    let n = rows.len();
    if n < 4 || rows.iter().any(|r| r.len() != n) {
        return Err(format!(
            "quality.covariance: expected a square matrix over x, y, z, yaw(, pitch, roll), found {n} rows"
        ));
    }
    if rows.iter().flatten().any(|v| !v.is_finite()) {
        return Err("quality.covariance: not finite".into());
    }
    let names = axes.unwrap_or_else(|| {
        ["x", "y", "z", "yaw", "pitch", "roll"][..n.min(6)]
            .iter()
            .map(|s| s.to_string())
            .collect()
    });
    let at = |axis: &str| {
        names
            .iter()
            .position(|a| a == axis)
            .filter(|&i| i < n)
            .ok_or_else(|| format!("quality.covariance: no axis {axis}"))
    };
    let idx = [at("x")?, at("y")?, at("yaw")?];
    let m: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| rows[idx[i]][idx[j]]));
    // A covariance is symmetric with non-negative variances.
    if m[0][0] < 0.0 || m[1][1] < 0.0 || m[2][2] < 0.0 {
        return Err("quality.covariance: negative variance".into());
    }
    Ok(Some(m))
}

/// The gray image at the camera's size.
fn load_gray(path: &Path, cam: &crate::camera::Camera) -> Result<Vec<u8>> {
    use crate::camera::CameraModel;
    let img = crate::capture::load_gray(path)?;
    if (img.width(), img.height()) != (cam.width(), cam.height()) {
        return Err(Error::input(
            path,
            format!(
                "image is {}×{} but the camera is {}×{}",
                img.width(),
                img.height(),
                cam.width(),
                cam.height()
            ),
        ));
    }
    Ok(img.into_raw())
}

/// Ground points of the tile covering the camera, within `radius` m of it.
fn tile_points(
    dir: &Path,
    pose_path: &Path,
    crs: Option<crate::map::Crs>,
    c: &nalgebra::Point3<f64>,
    radius: f64,
) -> Result<Vec<crate::map::GroundPoint>> {
    use crate::map::cache;
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(Error::arg("--radius", radius, "must be positive"));
    }
    let crs = crs
        .ok_or_else(|| Error::input(pose_path, "no \"crs\": needed to find the tile in --tiles"))?;
    let (lat, lon) = crate::geo::map_to_wgs84(crs, c.x, c.y)?;
    let (tile, tref) = cache::load_covering(dir, lat, lon, radius, radius)?;
    let pts = crate::map::ground_points(&tile, (c.x, c.y), radius);
    if pts.is_empty() {
        return Err(Error::input(
            &tref.dir,
            format!("no valid ground point within {radius} m of the camera"),
        ));
    }
    Ok(pts)
}

/// What a surface is drawn around and against.
struct Marks {
    /// Whether the plotted pose is the scene's truth.
    at_truth: bool,
    /// The reference pose's offsets from the plotted pose (x, y, z m, yaw °).
    truth: Option<[f64; 4]>,
    /// Marginal covariance of x, y, yaw at the plotted pose.
    cov: Option<[[f64; 3]; 3]>,
}

/// `--sampling` and `--pooling` as [`mi_surface`] takes them: the pooling of the partial-volume
/// estimator, or `None` for the nearest pixel.
fn pv_pooling(sampling: &str, pooling: &str) -> Result<Option<Pooling>> {
    let pooling: Pooling = pooling.parse()?;
    Ok(match sampling.parse::<Sampling>()? {
        Sampling::Nearest => None,
        Sampling::Pv => Some(pooling),
    })
}

fn mi_surface_cmd(a: MiSurfaceArgs) -> Result<()> {
    let spec: SearchSpec = a.search.parse()?;
    let size = parse_size(&a.size)?;
    let mi = a.estimator.config()?;
    let pv = pv_pooling(&a.sampling, &a.pooling)?;
    let cfg = SearchConfig {
        spec,
        mi,
        ..Default::default()
    };
    let read_doc = |p: &Path| -> Result<(crate::posefile::ReadPose, Option<[[f64; 3]; 3]>)> {
        let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
        let read = crate::posefile::parse_pose(&text, p)?;
        if let Some(n) = &read.note {
            super::note(n);
        }
        let doc: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| Error::input(p, e.to_string()))?;
        let cov = pose_covariance(&doc).map_err(|m| Error::input(p, m))?;
        Ok((read, cov))
    };
    let reference = a.truth.as_deref().map(read_pose).transpose()?.map(|r| {
        if let Some(n) = &r.note {
            super::note(n);
        }
        r.pose
    });
    let (surf, pose, cov, out) = if let Some(dir) = &a.scene {
        let scene: SceneFiles = load_scene(dir)?;
        let (pose, cov) = match &a.pose {
            Some(p) => {
                let (r, c) = read_doc(p)?;
                (r.pose, c)
            }
            None => (scene.truth, None),
        };
        let points = PointSelection::default().points(&scene.tile, &pose);
        let surf = mi_surface(
            &scene.camera,
            scene.gray.as_raw(),
            &points,
            &pose,
            &cfg,
            a.xy_stride,
            pv,
        )
        .map_err(|e| Error::input(dir, e.to_string()))?;
        let out = a.out.clone().unwrap_or_else(|| dir.join("mi-surface.png"));
        (
            surf,
            pose,
            cov,
            (out, Some(reference.unwrap_or(scene.truth))),
        )
    } else {
        let (Some(camera), Some(pose_path)) = (&a.camera, &a.pose) else {
            return Err(Error::Usage(
                "plot mi-surface: give --scene DIR, or --camera, --image, --points or --tiles, and --pose".into(),
            ));
        };
        let out = a
            .out
            .clone()
            .ok_or_else(|| Error::Usage("plot mi-surface: give --out PNG".into()))?;
        let cam = crate::camera::load_camera(camera)?;
        let (read, cov) = read_doc(pose_path)?;
        let pose = read.pose;
        // Pairs as `refine` takes them: each --image with the --points in the same place, or
        // every --image with the one --tiles' points.
        if a.image.is_empty() || (a.tiles.is_none() && a.points.len() != a.image.len()) {
            return Err(Error::Usage(format!(
                "plot mi-surface: --image and --points pair up in order (or several --image with one --tiles): got {} and {}",
                a.image.len(),
                a.points.len()
            )));
        }
        let point_sets = match &a.tiles {
            Some(dir) => vec![tile_points(
                dir,
                pose_path,
                read.crs,
                &pose.center(),
                a.radius,
            )?],
            None => a
                .points
                .iter()
                .map(|p| read_points(p))
                .collect::<Result<Vec<_>>>()?,
        };
        let grays = a
            .image
            .iter()
            .map(|i| load_gray(i, &cam))
            .collect::<Result<Vec<_>>>()?;
        let pairs: Vec<(&[u8], &[crate::map::GroundPoint])> = grays
            .iter()
            .enumerate()
            .map(|(i, g)| {
                (
                    g.as_slice(),
                    point_sets[i.min(point_sets.len() - 1)].as_slice(),
                )
            })
            .collect();
        let surf = mi_surface_pooled(&cam, &pairs, &pose, &cfg, a.xy_stride, pv)?;
        (surf, pose, cov, (out, reference))
    };
    let (out, reference) = out;
    // Where the reference lies relative to the plotted pose (none when it is the plotted pose).
    let truth = reference
        .map(|r| offsets_from(&pose, &r))
        .filter(|t| t.iter().any(|v| v.abs() >= 1e-9));
    let at_truth = a.scene.is_some() && a.pose.is_none();
    let img = surface_chart(
        &surf,
        &Marks {
            at_truth,
            truth,
            cov,
        },
        size,
    )?;
    save_png(&img, &out)?;
    if let Some(j) = &a.json {
        let text = serde_json::to_string_pretty(&surf)
            .map_err(|e| Error::output(j.display().to_string(), e))?;
        crate::persist::write_atomic(j, (text + "\n").as_bytes())?;
    }
    for (name, off, mi) in &surf.profiles {
        let k = argmax(mi);
        println!(
            "{name}: MI max {:.4} nats at offset {:+.3} {}",
            mi[k],
            off[k],
            unit(name)
        );
    }
    let v = valley(&surf);
    println!(
        "yaw–lateral: MI max at lateral {:+.3} m, yaw {:+.3}°; the top 10 % of the surface runs \
         {:+.3} m per degree of yaw (correlation {:+.2})",
        v.best.0, v.best.1, v.slope_m_per_deg, v.correlation
    );
    println!("plot: wrote {} ({} points)", out.display(), surf.points);
    Ok(())
}

/// The yaw–lateral surface's maximum and the shape of its high region.
struct Valley {
    /// (lateral m, yaw °) of the maximum.
    best: (f64, f64),
    /// Regression slope of lateral on yaw over the cells in the top 10 % of the MI range, m/°.
    slope_m_per_deg: f64,
    /// Their lateral–yaw correlation (−1..1; ±1 = a straight valley, 0 = a round peak).
    correlation: f64,
}

fn valley(s: &Surface) -> Valley {
    let n = s.grid_lateral.len();
    let v = &s.grid_lateral_yaw_mi;
    let k = argmax(v);
    let (lo, hi) = min_max(v.iter().copied());
    let cut = hi - 0.1 * (hi - lo);
    let top: Vec<(f64, f64)> = v
        .iter()
        .enumerate()
        .filter(|(_, m)| **m >= cut)
        .map(|(i, _)| (s.grid_lateral[i % n], s.grid_yaw[i / n]))
        .collect();
    let m = top.len().max(1) as f64;
    let (ml, my) = top
        .iter()
        .fold((0.0, 0.0), |(a, b), (l, y)| (a + l / m, b + y / m));
    let (mut sll, mut syy, mut sly) = (0.0, 0.0, 0.0);
    for (l, y) in &top {
        sll += (l - ml) * (l - ml);
        syy += (y - my) * (y - my);
        sly += (l - ml) * (y - my);
    }
    Valley {
        best: (s.grid_lateral[k % n], s.grid_yaw[k / n]),
        slope_m_per_deg: if syy > 0.0 { sly / syy } else { 0.0 },
        correlation: if sll > 0.0 && syy > 0.0 {
            sly / (sll * syy).sqrt()
        } else {
            0.0
        },
    }
}

fn unit(axis: &str) -> &'static str {
    if axis == "yaw" || axis == "pitch" || axis == "roll" {
        "°"
    } else {
        "m"
    }
}

fn argmax(v: &[f64]) -> usize {
    // First of equal maxima, like the search's tie rule (lowest cell).
    v.iter()
        .enumerate()
        .fold(0, |b, (i, x)| if *x > v[b] { i } else { b })
}

fn pe<E: std::error::Error + Send + Sync + 'static>(e: E) -> Error {
    Error::output("plot", e)
}

/// Draw into a white W×H RGB image.
fn draw(
    (w, h): (u32, u32),
    f: impl FnOnce(&DrawingArea<BitMapBackend, Shift>) -> Result<()>,
) -> Result<RgbImage> {
    crate::viz::register_font().map_err(pe)?;
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        f(&root)?;
        root.present().map_err(pe)?;
    }
    RgbImage::from_raw(w, h, buf).ok_or_else(|| Error::output("plot", "buffer size"))
}

/// Encode and write a PNG atomically.
pub(crate) fn save_png(img: &RgbImage, path: &Path) -> Result<()> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| Error::output(format!("{}: PNG encoding", path.display()), e))?;
    crate::persist::write_atomic(path, &bytes.into_inner())
}

/// `lo..hi` padded by `pad` of its width (a flat series gets a unit-free ±1e-6 so the axis exists).
fn padded(lo: f64, hi: f64, pad: f64) -> std::ops::Range<f64> {
    let d = (hi - lo).max(1e-6);
    (lo - pad * d)..(hi + pad * d)
}

fn min_max(v: impl IntoIterator<Item = f64>) -> (f64, f64) {
    v.into_iter()
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        })
}

/// The largest centred sub-area whose plotting region is about square, given the label areas and
/// caption the charts here use, so that equal x and y ranges are drawn to the same scale.
fn square<'a>(a: &DrawingArea<BitMapBackend<'a>, Shift>) -> DrawingArea<BitMapBackend<'a>, Shift> {
    const EXTRA_W: u32 = 80; // y label area + margins
    const EXTRA_H: u32 = 90; // caption + x label area + margins
    let (w, h) = a.dim_in_pixel();
    let s = w
        .saturating_sub(EXTRA_W)
        .min(h.saturating_sub(EXTRA_H))
        .max(50);
    let (bw, bh) = ((s + EXTRA_W).min(w), (s + EXTRA_H).min(h));
    a.clone().shrink(((w - bw) / 2, (h - bh) / 2), (bw, bh))
}

fn text(size: u32) -> TextStyle<'static> {
    (FAMILY, size).into_font().color(&BLACK)
}

/// Viridis-like colour ramp, t in [0, 1] (perceptually ordered, readable in gray print).
fn ramp(t: f64) -> RGBColor {
    const C: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f64;
    let mix = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
    RGBColor(
        mix(C[i].0, C[i + 1].0),
        mix(C[i].1, C[i + 1].1),
        mix(C[i].2, C[i + 1].2),
    )
}

const DARK_GREEN: RGBColor = RGBColor(0, 150, 0);

type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Tick label with `dec` decimals and no "-0.0".
fn tick(v: f64, dec: usize) -> String {
    let t = format!("{v:.dec$}");
    if t.starts_with('-') && t[1..].chars().all(|c| c == '0' || c == '.') {
        t[1..].to_string()
    } else {
        t
    }
}

/// Decimals that tell ticks of a range apart (about 10 ticks).
fn decimals(r: &std::ops::Range<f64>) -> usize {
    let step = ((r.end - r.start) / 10.0).abs().max(1e-9);
    (-step.log10().floor()).clamp(0.0, 6.0) as usize
}

/// One chart with the caption, label areas and axis texts every panel here uses.
fn panel<'a, 'b>(
    area: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    caption: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    (x_desc, y_desc): (&str, &str),
) -> Result<Chart<'a, 'b>> {
    let (dx, dy) = (decimals(&x), decimals(&y));
    let mut c = ChartBuilder::on(area)
        .caption(caption, text(16))
        .margin(8)
        .x_label_area_size(40)
        .y_label_area_size(62)
        .build_cartesian_2d(x, y)
        .map_err(pe)?;
    c.configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(text(13))
        .axis_desc_style(text(14))
        .x_label_formatter(&|v| tick(*v, dx))
        .y_label_formatter(&|v| tick(*v, dy))
        .draw()
        .map_err(pe)?;
    Ok(c)
}

/// A vertical line across a chart's y range.
fn vline(c: &mut Chart, x: f64, style: ShapeStyle) -> Result<()> {
    let y = c.y_range();
    c.draw_series(LineSeries::new([(x, y.start), (x, y.end)], style))
        .map_err(pe)?;
    Ok(())
}

/// Points of the ellipse {v : vᵀ C⁻¹ v = k²} of a 2×2 covariance around the origin.
fn ellipse(c: [[f64; 2]; 2], k: f64) -> Vec<(f64, f64)> {
    // Eigen-decomposition of the symmetric 2×2 in closed form.
    let (a, b, d) = (c[0][0], 0.5 * (c[0][1] + c[1][0]), c[1][1]);
    let mean = 0.5 * (a + d);
    let r = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = ((mean + r).max(0.0), (mean - r).max(0.0));
    let t = 0.5 * (2.0 * b).atan2(a - d);
    let (ct, st) = (t.cos(), t.sin());
    (0..=180)
        .map(|i| {
            let u = i as f64 * std::f64::consts::TAU / 180.0;
            let (p, q) = (k * l1.sqrt() * u.cos(), k * l2.sqrt() * u.sin());
            (p * ct - q * st, p * st + q * ct)
        })
        .collect()
}

/// Draw a polyline clipped to the chart's ranges (segments leaving the plot are dropped).
fn clipped_line(c: &mut Chart, pts: &[(f64, f64)], style: ShapeStyle) -> Result<()> {
    let (xr, yr) = (c.x_range(), c.y_range());
    let inside = |p: &(f64, f64)| xr.contains(&p.0) && yr.contains(&p.1);
    let mut run: Vec<(f64, f64)> = Vec::new();
    let mut runs = Vec::new();
    for p in pts {
        if inside(p) {
            run.push(*p);
        } else if !run.is_empty() {
            runs.push(std::mem::take(&mut run));
        }
    }
    runs.push(run);
    for r in runs.into_iter().filter(|r| r.len() > 1) {
        c.draw_series(LineSeries::new(r, style)).map_err(pe)?;
    }
    Ok(())
}

/// A heat map of `mi` over `xs` × `ys` (row-major, y slowest) on `area`, coloured on the shared
/// scale `lo..hi`; the origin (white ×), the maximum (red ○), the reference (green ▲) and the 1σ
/// and 3σ ellipses of `cov` when given. Returns the drawn chart's area for the colour bar.
#[allow(clippy::too_many_arguments)]
fn heat_map(
    area: &DrawingArea<BitMapBackend, Shift>,
    caption: &str,
    (xs, ys, mi): (&[f64], &[f64], &[f64]),
    (lo, hi): (f64, f64),
    desc: (&str, &str),
    reference: Option<(f64, f64)>,
    cov: Option<[[f64; 2]; 2]>,
    square_cells: bool,
) -> Result<()> {
    let (nx, ny) = (xs.len(), ys.len());
    let half = |v: &[f64]| {
        if v.len() > 1 {
            (v[1] - v[0]) / 2.0
        } else {
            0.01
        }
    };
    let (hx, hy) = (half(xs), half(ys));
    let best = argmax(mi);
    let (bx, by) = (xs[best % nx], ys[best / nx]);
    let area = if square_cells {
        square(area)
    } else {
        area.clone()
    };
    let mut chart = panel(
        &area,
        caption,
        (xs[0] - hx)..(xs[nx - 1] + hx),
        (ys[0] - hy)..(ys[ny - 1] + hy),
        desc,
    )?;
    let norm = |v: f64| (v - lo) / (hi - lo).max(1e-12);
    chart
        .draw_series(mi.iter().enumerate().map(|(k, &v)| {
            let (x, y) = (xs[k % nx], ys[k / nx]);
            Rectangle::new([(x - hx, y - hy), (x + hx, y + hy)], ramp(norm(v)).filled())
        }))
        .map_err(pe)?;
    if let Some(c) = cov {
        clipped_line(&mut chart, &ellipse(c, 1.0), WHITE.stroke_width(2))?;
        clipped_line(&mut chart, &ellipse(c, 3.0), WHITE.stroke_width(1))?;
    }
    chart
        .draw_series(std::iter::once(Cross::new(
            (0.0, 0.0),
            7,
            WHITE.stroke_width(2),
        )))
        .map_err(pe)?;
    chart
        .draw_series(std::iter::once(Circle::new(
            (bx, by),
            7,
            RED.stroke_width(2),
        )))
        .map_err(pe)?;
    if let Some(t) = reference {
        chart
            .draw_series(std::iter::once(TriangleMarker::new(
                t,
                8,
                DARK_GREEN.filled(),
            )))
            .map_err(pe)?;
    }
    Ok(())
}

/// The 1-D curves (2×2, left), the x–y and yaw–lateral heat maps on one colour scale and the
/// colour bar (right); the reference pose and the covariance's ellipses where given.
fn surface_chart(s: &Surface, marks: &Marks, size: (u32, u32)) -> Result<RgbImage> {
    let truth = marks.truth;
    draw(size, |root| {
        let mut title = format!(
            "MI (nats) around the {} pose, {} LiDAR points (fixed set); white ×: the pose, red ○: maximum",
            if marks.at_truth { "true" } else { "given" },
            s.points
        );
        if truth.is_some() {
            title.push_str(", green: reference");
        }
        if marks.cov.is_some() {
            title.push_str("; ellipses: 1σ (thick) and 3σ of the pose's covariance");
        }
        let root = root.titled(&title, text(20)).map_err(pe)?;
        let (left, right) = root.split_horizontally(size.0 * 40 / 100);
        for (k, area) in left.split_evenly((2, 2)).iter().enumerate() {
            let Some((name, off, mi)) = s.profiles.get(k) else {
                continue;
            };
            let u = unit(name);
            let (lo, hi) = min_max(mi.iter().copied());
            let (xlo, xhi) = min_max(off.iter().copied());
            let best = argmax(mi);
            let mut chart = panel(
                area,
                &format!("{name}: max at {:+.3} {u}", off[best]),
                xlo..xhi,
                padded(lo, hi, 0.05),
                (&format!("{name} offset ({u})"), "MI (nats)"),
            )?;
            vline(&mut chart, 0.0, BLACK.mix(0.4).into())?;
            if let Some(t) = truth {
                vline(&mut chart, t[k], DARK_GREEN.stroke_width(2))?;
            }
            chart
                .draw_series(LineSeries::new(
                    off.iter().copied().zip(mi.iter().copied()),
                    BLUE.stroke_width(2),
                ))
                .map_err(pe)?;
            chart
                .draw_series(std::iter::once(Circle::new(
                    (off[best], mi[best]),
                    5,
                    RED.filled(),
                )))
                .map_err(pe)?;
        }

        const BAR_W: u32 = 120;
        let (rw, _) = right.dim_in_pixel();
        let map_w = rw.saturating_sub(BAR_W) / 2;
        let (xy_area, rest) = right.split_horizontally(map_w);
        let (yl_area, bar_area) = rest.split_horizontally(map_w);
        let (lo, hi) = min_max(s.grid_mi.iter().chain(&s.grid_lateral_yaw_mi).copied());

        let best = argmax(&s.grid_mi);
        let nx = s.grid_x.len();
        let (bx, by) = (s.grid_x[best % nx], s.grid_y[best / nx]);
        heat_map(
            &xy_area,
            &format!("x–y (z, yaw fixed): max at ({bx:+.2}, {by:+.2}) m"),
            (&s.grid_x, &s.grid_y, &s.grid_mi),
            (lo, hi),
            ("x offset (m)", "y offset (m)"),
            truth.map(|t| (t[0], t[1])),
            marks.cov.map(|c| [[c[0][0], c[0][1]], [c[1][0], c[1][1]]]),
            true,
        )?;

        // Lateral = d · (x, y) with d the unit vector left of the view.
        let d = s.lateral_direction;
        let lat_cov = marks.cov.map(|c| {
            let var_l = d[0] * d[0] * c[0][0] + 2.0 * d[0] * d[1] * c[0][1] + d[1] * d[1] * c[1][1];
            let cov_ly = d[0] * c[0][2] + d[1] * c[1][2];
            [[var_l, cov_ly], [cov_ly, c[2][2]]]
        });
        let v = valley(s);
        heat_map(
            &yl_area,
            &format!(
                "yaw–lateral (z fixed; lateral: left of a view {}° from map x): max at {:+.2} m, {:+.2}°",
                tick((-d[0]).atan2(d[1]).to_degrees(), 0),
                v.best.0,
                v.best.1
            ),
            (&s.grid_lateral, &s.grid_yaw, &s.grid_lateral_yaw_mi),
            (lo, hi),
            ("lateral offset (m)", "yaw offset (°)"),
            truth.map(|t| (d[0] * t[0] + d[1] * t[1], t[3])),
            lat_cov,
            false,
        )?;

        // Colour bar: the ramp against the MI values it stands for.
        let mut bar = ChartBuilder::on(&bar_area)
            .margin_top(60)
            .margin_bottom(70)
            .margin_right(8)
            .margin_left(20)
            // Labels on the right, away from the heat map and not under the bar.
            .right_y_label_area_size(80)
            .build_cartesian_2d(0.0..1.0, padded(lo, hi, 0.0))
            .map_err(pe)?;
        let dy = decimals(&padded(lo, hi, 0.0));
        bar.configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc("MI (nats)")
            .label_style(text(13))
            .axis_desc_style(text(14))
            .y_label_formatter(&|v| tick(*v, dy))
            .draw()
            .map_err(pe)?;
        let steps = 100;
        bar.draw_series((0..steps).map(|i| {
            let (a, b) = (i as f64 / steps as f64, (i + 1) as f64 / steps as f64);
            let (va, vb) = (lo + a * (hi - lo), lo + b * (hi - lo));
            Rectangle::new([(0.0, va), (1.0, vb)], ramp(a).filled())
        }))
        .map_err(pe)?;
        Ok(())
    })
}

/// The success bounds drawn in the zoom panels.
const BOUNDS: &str = "10 cm / 0.2°";

/// The study's scatter plot: start offsets (red +) and final offsets (green ●), as the seed's
/// figure, plus zooms of the final offsets against the success bounds. `note` goes in the title
/// (e.g. where the starts' roll and pitch came from).
pub(crate) fn study_chart(
    trials: &[Trial],
    summary: &Summary,
    pert: &Perturbation,
    note: &str,
    size: (u32, u32),
) -> Result<RgbImage> {
    draw(size, |root| {
        let s = summary;
        let title = format!(
            "MI refinement from {} random starts ({note}): median error {:.1} cm horizontal, {:.1} cm height, {:.3}° yaw; \
             p95 {:.1} cm / {:.1} cm / {:.3}°; within {BOUNDS}: {:.0} %; gate rejected {}",
            s.trials,
            s.horizontal_m.median * 100.0,
            s.height_m.median * 100.0,
            s.yaw_deg.median,
            s.horizontal_m.p95 * 100.0,
            s.height_m.p95 * 100.0,
            s.yaw_deg.p95,
            s.success_fraction * 100.0,
            s.gate_rejections
        );
        let root = root.titled(&title, text(15)).map_err(pe)?;
        let areas = root.split_evenly((2, 2));
        let red = RED.stroke_width(2);
        let green = DARK_GREEN.filled();
        let plus = move |c: (i32, i32)| {
            EmptyElement::at(c)
                + PathElement::new(vec![(-6, 0), (6, 0)], red)
                + PathElement::new(vec![(0, -6), (0, 6)], red)
        };
        let start_marker = move |c: (f64, f64)| {
            EmptyElement::at(c)
                + PathElement::new(vec![(-6, 0), (6, 0)], red)
                + PathElement::new(vec![(0, -6), (0, 6)], red)
        };
        let final_marker = move |c: (f64, f64)| Circle::new(c, 3, green);
        let xy = |t: &Trial| (t.result[0] * 100.0, t.result[1] * 100.0);
        let yz = |t: &Trial| (t.result[3], t.result[2] * 100.0);

        // Panel 1: x–y offsets from the truth, start and final (equal scales).
        let r = pert.xy_m.max(0.05) * 1.1;
        let a0 = square(&areas[0]);
        let mut c = panel(
            &a0,
            "horizontal offset from truth: start (+) → final (●)",
            -r..r,
            -r..r,
            ("x offset (m)", "y offset (m)"),
        )?;
        c.draw_series(
            trials
                .iter()
                .map(|t| start_marker((t.start[0], t.start[1]))),
        )
        .map_err(pe)?
        .label("start")
        .legend(plus);
        c.draw_series(
            trials
                .iter()
                .map(|t| final_marker((t.result[0], t.result[1]))),
        )
        .map_err(pe)?
        .label("final")
        .legend(move |p| Circle::new(p, 3, green));
        c.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.85))
            .label_font(text(13))
            .draw()
            .map_err(pe)?;

        // Panel 2: yaw and height offsets, start and final.
        let (ry, rz) = (pert.yaw_deg.max(0.1) * 1.1, pert.z_m.max(0.05) * 1.1);
        let mut c = panel(
            &areas[1],
            "yaw and height offset from truth: start (+) → final (●)",
            -ry..ry,
            -rz..rz,
            ("yaw offset (°)", "z offset (m)"),
        )?;
        c.draw_series(
            trials
                .iter()
                .map(|t| start_marker((t.start[3], t.start[2]))),
        )
        .map_err(pe)?;
        c.draw_series(
            trials
                .iter()
                .map(|t| final_marker((t.result[3], t.result[2]))),
        )
        .map_err(pe)?;

        // Panel 3: final horizontal offsets, cm, with the success circle (equal scales).
        let (lo, hi) = min_max(trials.iter().flat_map(|t| [xy(t).0, xy(t).1]));
        let b = SUCCESS_HORIZONTAL_M * 100.0;
        let r = (lo.abs().max(hi.abs()) * 1.15).max(b * 1.2);
        let a2 = square(&areas[2]);
        let mut c = panel(
            &a2,
            &format!("final horizontal offset (zoom); circle: {b:.0} cm"),
            -r..r,
            -r..r,
            ("x offset (cm)", "y offset (cm)"),
        )?;
        let circle = (0..=72).map(|i| {
            let a = i as f64 * std::f64::consts::TAU / 72.0;
            (b * a.cos(), b * a.sin())
        });
        c.draw_series(LineSeries::new(circle, BLACK.mix(0.5)))
            .map_err(pe)?;
        c.draw_series(trials.iter().map(|t| final_marker(xy(t))))
            .map_err(pe)?;

        // Panel 4: final yaw and height offsets, with the success box.
        let (ylo, yhi) = min_max(trials.iter().map(|t| yz(t).0));
        let (zlo, zhi) = min_max(trials.iter().map(|t| yz(t).1));
        let (by, bz) = (SUCCESS_YAW_DEG, SUCCESS_HEIGHT_M * 100.0);
        let ry = (ylo.abs().max(yhi.abs()) * 1.15).max(by * 1.2);
        let rz = (zlo.abs().max(zhi.abs()) * 1.15).max(bz * 1.2);
        let mut c = panel(
            &areas[3],
            &format!("final yaw and height offset (zoom); box: ±{by}°, ±{bz:.0} cm"),
            -ry..ry,
            -rz..rz,
            ("yaw offset (°)", "z offset (cm)"),
        )?;
        c.draw_series(LineSeries::new(
            [(-by, -bz), (by, -bz), (by, bz), (-by, bz), (-by, -bz)],
            BLACK.mix(0.5),
        ))
        .map_err(pe)?;
        c.draw_series(trials.iter().map(|t| final_marker(yz(t))))
            .map_err(pe)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn covariance_from_a_matrix_or_an_object_with_axes() {
        let m = json!([
            [0.01, 0.002, 0.0, 0.003],
            [0.002, 0.04, 0.0, -0.02],
            [0.0, 0.0, 0.09, 0.0],
            [0.003, -0.02, 0.0, 0.25]
        ]);
        let want = [
            [0.01, 0.002, 0.003],
            [0.002, 0.04, -0.02],
            [0.003, -0.02, 0.25],
        ];
        let bare = json!({ "quality": { "covariance": m } });
        assert_eq!(pose_covariance(&bare).unwrap(), Some(want));
        // An object names its axes: here in another order, with pitch and roll.
        let object = json!({ "quality": { "covariance": {
            "axes": ["yaw", "x", "y", "z", "pitch", "roll"],
            "matrix": [
                [0.25, 0.003, -0.02, 0.0, 0.0, 0.0],
                [0.003, 0.01, 0.002, 0.0, 0.0, 0.0],
                [-0.02, 0.002, 0.04, 0.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, 0.09, 0.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
            ]
        } } });
        assert_eq!(pose_covariance(&object).unwrap(), Some(want));
        assert_eq!(pose_covariance(&json!({ "quality": {} })).unwrap(), None);
        assert_eq!(pose_covariance(&json!({})).unwrap(), None);
        let bad = |v: serde_json::Value| {
            pose_covariance(&json!({ "quality": { "covariance": v } })).unwrap_err()
        };
        assert!(bad(json!([[1.0, 0.0], [0.0, 1.0]])).contains("square matrix"));
        assert!(bad(json!([
            [1, 0, 0, 0],
            [0, 1, 0, 0],
            [0, 0, 1, 0],
            [0, 0, 0, "x"]
        ]))
        .contains("not finite"));
        assert!(bad(json!([
            [1, 0, 0, 0],
            [0, -1, 0, 0],
            [0, 0, 1, 0],
            [0, 0, 0, 1]
        ]))
        .contains("negative"));
    }

    #[test]
    fn ellipse_is_the_mahalanobis_contour() {
        let c = [[0.04, -0.018], [-0.018, 0.25]];
        let inv = {
            let det = c[0][0] * c[1][1] - c[0][1] * c[1][0];
            [
                [c[1][1] / det, -c[0][1] / det],
                [-c[1][0] / det, c[0][0] / det],
            ]
        };
        for k in [1.0, 3.0] {
            for (x, y) in ellipse(c, k) {
                let d2 = x * (inv[0][0] * x + inv[0][1] * y) + y * (inv[1][0] * x + inv[1][1] * y);
                assert!((d2.sqrt() - k).abs() < 1e-9, "{d2}");
            }
        }
        // Its extent along each axis is k·σ of that axis.
        let e = ellipse(c, 3.0);
        let xmax = e.iter().map(|p| p.0).fold(0.0, f64::max);
        assert!((xmax - 3.0 * 0.2).abs() < 1e-3, "{xmax}");
    }
}
