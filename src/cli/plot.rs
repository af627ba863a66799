//! `infraloc plot mi-surface` (contracts §6): the seed's 1-D MI-vs-perturbation curves and the 2-D
//! x–y MI surface around a pose, as one PNG; and the chart drawing shared with `infraloc study`.
//!
//! Charts are drawn with `plotters` into an RGB buffer and encoded with `image`; text uses the
//! DejaVu Sans embedded from `assets/` (Bitstream Vera licence, `assets/DejaVuSans-LICENSE.txt`)
//! so no system font is needed on the node.

use super::parse_size;
use crate::error::{Error, Result};
use crate::localize::search::{SearchConfig, SearchSpec};
use crate::localize::study::{
    mi_surface, offsets_from, Perturbation, PointSelection, Summary, Surface, Trial,
    SUCCESS_HEIGHT_M, SUCCESS_HORIZONTAL_M, SUCCESS_YAW_DEG,
};
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
    /// MI along x, y, z, yaw and over the x–y plane around a pose (default: the truth).
    MiSurface(MiSurfaceArgs),
}

/// Arguments of `plot mi-surface`.
#[derive(Debug, clap::Args)]
pub struct MiSurfaceArgs {
    /// Simulated scene directory (`infraloc simulate --out DIR`).
    #[arg(long)]
    pub scene: PathBuf,
    /// Centre pose (pose-like JSON); default: the scene's truth.json.
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// Output PNG; default: DIR/mi-surface.png.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Ranges and steps: x=HALF:STEP,y=…,z=…,yaw=… (m, deg), as `refine --search`.
    #[arg(long, default_value = "x=1:0.02,y=1:0.02,z=0.5:0.02,yaw=3:0.05")]
    pub search: String,
    /// The x–y surface takes every N-th x and y step.
    #[arg(long, default_value_t = 2)]
    pub xy_stride: i64,
    /// Image size W,H in pixels.
    #[arg(long, default_value = "1600,900")]
    pub size: String,
    /// Also write the curves and the surface as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Run a `plot` subcommand.
pub fn run(c: Command) -> Result<()> {
    match c {
        Command::MiSurface(a) => mi_surface_cmd(a),
    }
}

fn mi_surface_cmd(a: MiSurfaceArgs) -> Result<()> {
    let spec: SearchSpec = a.search.parse()?;
    let size = parse_size(&a.size)?;
    let scene: SceneFiles = load_scene(&a.scene)?;
    let pose = match &a.pose {
        Some(p) => read_pose(p)?.pose,
        None => scene.truth,
    };
    let cfg = SearchConfig {
        spec,
        ..Default::default()
    };
    let points = PointSelection::default().points(&scene.tile, &pose);
    let surf = mi_surface(
        &scene.camera,
        scene.gray.as_raw(),
        &points,
        &pose,
        &cfg,
        a.xy_stride,
    )
    .map_err(|e| Error::input(&a.scene, e.to_string()))?;
    // Where the truth lies relative to the plotted pose (none when plotting around the truth).
    let truth = offsets_from(&pose, &scene.truth);
    let truth = if truth.iter().all(|v| v.abs() < 1e-9) {
        None
    } else {
        Some(truth)
    };
    let img = surface_chart(&surf, truth, size)?;
    let out = a.out.unwrap_or_else(|| a.scene.join("mi-surface.png"));
    save_png(&img, &out)?;
    if let Some(j) = &a.json {
        let text = serde_json::to_string_pretty(&surf)
            .map_err(|e| Error::Invalid(format!("{}: {e}", j.display())))?;
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
    println!("plot: wrote {} ({} points)", out.display(), surf.points);
    Ok(())
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

fn pe<E: std::fmt::Display>(e: E) -> Error {
    Error::Invalid(format!("plot: {e}"))
}

/// Draw into a white W×H RGB image.
fn draw(
    (w, h): (u32, u32),
    f: impl FnOnce(&DrawingArea<BitMapBackend, Shift>) -> Result<()>,
) -> Result<RgbImage> {
    crate::viz::register_font().map_err(|e| Error::Invalid(format!("plot: {e}")))?;
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        f(&root)?;
        root.present().map_err(pe)?;
    }
    RgbImage::from_raw(w, h, buf).ok_or_else(|| Error::Invalid("plot: buffer size".into()))
}

/// Encode and write a PNG atomically.
pub(crate) fn save_png(img: &RgbImage, path: &Path) -> Result<()> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| Error::Invalid(format!("{}: PNG encoding: {e}", path.display())))?;
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

/// The 1-D curves (2×2, left) and the x–y heat map with its colour bar (right).
pub(crate) fn surface_chart(
    s: &Surface,
    truth: Option<[f64; 4]>,
    size: (u32, u32),
) -> Result<RgbImage> {
    draw(size, |root| {
        let title = match truth {
            None => format!(
                "MI (nats) around the true pose, {} LiDAR points (fixed set); red: maximum",
                s.points
            ),
            Some(_) => format!(
                "MI (nats) around the given pose, {} LiDAR points (fixed set); red: maximum, green: truth",
                s.points
            ),
        };
        let root = root.titled(&title, text(22)).map_err(pe)?;
        let (left, right) = root.split_horizontally(size.0 * 55 / 100);
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

        let (map_area, bar_area) = right.split_horizontally(size.0 * 45 / 100 - 150);
        let (lo, hi) = min_max(s.grid_mi.iter().copied());
        let (nx, ny) = (s.grid_x.len(), s.grid_y.len());
        let half = |v: &[f64]| {
            if v.len() > 1 {
                (v[1] - v[0]) / 2.0
            } else {
                0.01
            }
        };
        let (hx, hy) = (half(&s.grid_x), half(&s.grid_y));
        let best = argmax(&s.grid_mi);
        let (bx, by) = (s.grid_x[best % nx], s.grid_y[best / nx]);
        let map_area = square(&map_area);
        let mut chart = panel(
            &map_area,
            &format!("x–y surface (z, yaw fixed): max at ({bx:+.2}, {by:+.2}) m"),
            (s.grid_x[0] - hx)..(s.grid_x[nx - 1] + hx),
            (s.grid_y[0] - hy)..(s.grid_y[ny - 1] + hy),
            ("x offset (m)", "y offset (m)"),
        )?;
        let norm = |v: f64| (v - lo) / (hi - lo).max(1e-12);
        chart
            .draw_series(s.grid_mi.iter().enumerate().map(|(k, &v)| {
                let (x, y) = (s.grid_x[k % nx], s.grid_y[k / nx]);
                Rectangle::new([(x - hx, y - hy), (x + hx, y + hy)], ramp(norm(v)).filled())
            }))
            .map_err(pe)?;
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
        if let Some(t) = truth {
            chart
                .draw_series(std::iter::once(TriangleMarker::new(
                    (t[0], t[1]),
                    8,
                    DARK_GREEN.filled(),
                )))
                .map_err(pe)?;
        }

        // Colour bar: the ramp against the MI values it stands for, as tall as the map.
        let (_, mh) = map_area.dim_in_pixel();
        let (_, bh) = bar_area.dim_in_pixel();
        let top = (bh.saturating_sub(mh)) / 2;
        let mut bar = ChartBuilder::on(&bar_area)
            .margin_top(top + 34)
            .margin_bottom(top + 48)
            .margin_right(8)
            .margin_left(30)
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
