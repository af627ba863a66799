//! `infraloc refine`: MI refinement alone, from any initial pose (docs/interfaces.md, "Command line and exit codes").

use crate::camera::load_camera;
use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::localize::mi::objective::View;
use crate::localize::mi::points::GroundPoint;
use crate::localize::mi::smooth::Pooling;
use crate::localize::mi::space::{Mode, SearchConfig, SearchSpec};
use crate::localize::mi::MiValue;
use crate::localize::refine::local::{refine_smooth, SmoothRefinement};
use crate::localize::refine::optima::{
    disagreement as disagreement_of, self_check_starts, SEPARATION, START_SPREAD,
};
use crate::localize::refine::quality::QualityConfig;
use crate::localize::refine::verdict::{Grade, Stop};
use crate::localize::refine::{finish_name, refine_polished, Refinement};
use crate::map::{cache, Crs};
use crate::points_io::read_points;
use crate::pose::{offsets_between, CamFromMap};
use crate::posefile::{format_utc, read_pose, PoseFile, PoseQuality, ReadPose};
use std::path::{Path, PathBuf};

/// Default radius (m) of tile ground points around the camera's nadir: at 6 m height that is
/// 76° off-axis; points further out occupy few pixels and add aliasing more than information.
pub(crate) const DEFAULT_RADIUS_M: f64 = 25.0;

/// Arguments of `refine`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("source").required(true).multiple(true).args(["tiles", "points", "pairs"])))]
pub struct Args {
    /// Camera intrinsics (OpenCV/Kalibr/KITTI-360 YAML or TOML).
    #[arg(long)]
    pub camera: PathBuf,
    /// The image (any format `image` reads; converted to gray). Repeat it to pool several frames
    /// that share the pose: with --points, each --image pairs with the --points at the same
    /// position; with --tiles, every image sees the one tile.
    #[arg(long, required_unless_present = "pairs")]
    pub image: Vec<PathBuf>,
    /// Tile cache: ground points within --radius of the camera come from the tile covering it.
    #[arg(long, conflicts_with_all = ["points", "pairs"])]
    pub tiles: Option<PathBuf>,
    /// Point file: CSV (x,y,z,reflectivity header; reflectivity 0–255, or 0–1 normalised), PCD,
    /// LAS or a Velodyne .bin sweep; all points used as given. Repeat it, once per --image, to pool
    /// image/point-set pairs.
    #[arg(long)]
    pub points: Vec<PathBuf>,
    /// Pairs file: more image/point-file pairs to pool, one `IMAGE<TAB>POINTS` a line (relative
    /// paths from the file's directory), after any --image/--points given; `kitti import
    /// --drive … --pairs-out` writes one for a drive's frames.
    #[arg(long)]
    pub pairs: Option<PathBuf>,
    /// Initial pose (pose-like JSON: rotation_cam_from_map + translation_cam_from_map).
    #[arg(long)]
    pub init: PathBuf,
    /// Search box: x=HALF:STEP,y=HALF:STEP,z=HALF:STEP,yaw=HALF:STEP (m, deg; STEP = finest);
    /// adding pitch=HALF:STEP and/or roll=HALF:STEP grid-searches those axes too (6-DoF grid,
    /// tilts about the ground under the camera), off by default.
    #[arg(long, default_value = "x=1:0.02,y=1:0.02,z=0.5:0.02,yaw=3:0.05")]
    pub search: String,
    /// tiled (coarse-to-fine, default) or exhaustive (every cell).
    #[arg(long, default_value = "tiled")]
    pub mode: String,
    /// Radius (m) of tile ground points around the camera (with --tiles).
    #[arg(long, default_value_t = DEFAULT_RADIUS_M)]
    pub radius: f64,
    /// Write the refined pose here (docs/interfaces.md, "Pose file"); only when the quality gate accepts.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write a JSON report (search counters, quality) here, accepted or not.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Write a PNG here, accepted or not: the points (cyan) over the image at the --init pose
    /// (left, "before") and at the refined pose (right, "after"), twice the image's width.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// After the grid search, the smooth stage's gradient ascent and its information over all
    /// six pose parameters (roll and pitch too; docs/refine.md "Estimator"): for an initial pose
    /// whose roll/pitch are not trusted. Without it (and without --grid-only) the ascent moves
    /// x, y, z and yaw only, the tilt held.
    #[arg(long, conflicts_with = "grid_only")]
    pub polish: bool,
    /// Answer the grid search's cell, with no local stage after it (the seed's method: the
    /// exhaustive argmax at the grid's step, on the point set the whole search box sees), judged
    /// by the grid's checks alone. A diagnostic of the global search: it has no σ, and its pose
    /// file carries none.
    #[arg(long)]
    pub grid_only: bool,
    /// Largest accepted σ per axis group: xy=M,z=M,yaw=DEG,tilt=DEG (any subset; the rest keep
    /// the node's defaults, 0.05 m, 0.05 m, 0.15°, 0.5°). The result is refused, and no pose
    /// written, when its marginal σ exceeds one of them.
    #[arg(long)]
    pub max_sigma: Option<String>,
    /// The MI estimator (bins, objective, binning, Parzen smoothing).
    #[command(flatten)]
    pub estimator: super::estimator::EstimatorArgs,
    /// A truth-free self-check: refine from N starts, `--init` and N − 1 spread around it
    /// (`--start-spread`), and report whether the accepted answers agree within their combined
    /// 3σ. Answers that disagree refuse the result; otherwise the accepted answer of the highest
    /// MI is the result.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub starts: usize,
    /// The spread of `--starts`: xy=M (radius of the circle the starts stand on), z=M (their
    /// heights, alternately up and down), yaw=DEG (their yaws, alternately) [default: xy=0.2,
    /// z=0.1,yaw=1].
    #[arg(long, value_name = "xy=M,z=M,yaw=DEG")]
    pub start_spread: Option<String>,
    /// With several pairs: `per-pair` (each pair its own histogram, the objective the
    /// point-weighted sum of their MI: frames under different light need not share one
    /// gray–reflectivity relation) or `joint` (one histogram of all pairs), in the grid search
    /// and the smooth stage alike. One pair is the same either way.
    #[arg(long, value_name = "per-pair|joint", default_value = "per-pair")]
    pub pooling: String,
}

fn load_gray(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let g = crate::capture::load_gray(path)?;
    Ok((g.width(), g.height(), g.into_raw()))
}

/// The `KEY=VALUE` items of `flag`'s comma-separated `spec`, each KEY one of `keys` and each
/// VALUE finite and positive (or ≥ 0 with `zero_ok`); one line naming the item otherwise.
fn key_values(
    flag: &'static str,
    spec: Option<&str>,
    keys: &[&'static str],
    zero_ok: bool,
) -> Result<Vec<(&'static str, f64)>> {
    let mut out = Vec::new();
    for item in spec
        .unwrap_or("")
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
    {
        let bad = || {
            Error::arg_quoted(
                flag,
                item,
                format!(
                    "expected KEY=VALUE with KEY one of {} and a {}",
                    keys.join(", "),
                    if zero_ok {
                        "finite number ≥ 0"
                    } else {
                        "positive number"
                    }
                ),
            )
        };
        let (k, v) = item.split_once('=').ok_or_else(bad)?;
        let v: f64 = v.trim().parse().map_err(|_| bad())?;
        let key = keys.iter().find(|c| **c == k.trim()).ok_or_else(bad)?;
        if !(v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0))) {
            return Err(bad());
        }
        out.push((*key, v));
    }
    Ok(out)
}

/// The quality gate with `--max-sigma`'s limits.
fn quality_config(spec: Option<&str>) -> Result<QualityConfig> {
    let mut q = QualityConfig::default();
    for (k, v) in key_values("--max-sigma", spec, &["xy", "z", "yaw", "tilt"], false)? {
        match k {
            "xy" => q.max_sigma_xy_m = v,
            "z" => q.max_sigma_z_m = v,
            "yaw" => q.max_sigma_yaw_deg = v,
            _ => q.max_sigma_tilt_deg = v,
        }
    }
    Ok(q)
}

/// The point sets of `refine`: one per image (--points), or the tile's one set shared by every
/// image (--tiles, the tile covering `init`'s camera); with the map CRS and the tile's id.
fn point_sets(a: &Args, init: &ReadPose) -> Result<(Vec<Vec<GroundPoint>>, Crs, String)> {
    let c = init.pose.center();
    match &a.tiles {
        Some(dir) => {
            if !(a.radius > 0.0 && a.radius.is_finite()) {
                return Err(Error::arg("--radius", a.radius, "must be positive"));
            }
            let crs = init.crs.ok_or_else(|| {
                Error::input(&a.init, "no \"crs\": needed to find the tile in --tiles")
            })?;
            let (lat, lon) = crate::geo::map_to_wgs84(crs, c.x, c.y)?;
            let (tile, tref) = cache::load_covering(dir, lat, lon, a.radius, a.radius)?;
            if tref.crs != crs {
                return Err(Error::input(
                    &a.init,
                    format!(
                        "pose CRS {crs} differs from tile {} CRS {}",
                        tref.id, tref.crs
                    ),
                ));
            }
            let pts = crate::map::ground_points(&tile, (c.x, c.y), a.radius);
            if pts.is_empty() {
                return Err(Error::input(
                    &tref.dir,
                    format!("no valid ground point within {} m of the camera", a.radius),
                ));
            }
            Ok((vec![pts], crs, tref.id))
        }
        None => {
            let mut sets = Vec::with_capacity(a.points.len());
            for p in &a.points {
                sets.push(read_points(p)?);
            }
            Ok((sets, init.crs.unwrap_or(Crs::Local), String::new()))
        }
    }
}

/// What `refine` prints of an accepted result: the move, the MI, the uncertainty, the competing
/// optima and the smooth stage's ascents.
fn print_result(r: &Refinement, smooth: Option<&SmoothRefinement>) {
    let o = r.offsets;
    // Pitch and roll only move when the grid searches them or a 6-DoF polish ran.
    let tilt = if o[4] != 0.0 || o[5] != 0.0 {
        format!(", pitch {:+.3}°, roll {:+.3}°", o[4], o[5])
    } else {
        String::new()
    };
    let pairs = if r.views.len() > 1 {
        format!(" ({} pairs pooled)", r.views.len())
    } else {
        String::new()
    };
    println!(
        "mi: moved ({:+.3}, {:+.3}, {:+.3}) m, yaw {:+.3}°{tilt}; MI {:.4} nats on {} points{pairs}; {:.0}× fewer point-pose evaluations than exhaustive",
        o[0],
        o[1],
        o[2],
        o[3],
        r.quality.mi,
        r.points.1,
        r.stats.exhaustive_point_evaluations as f64 / r.stats.point_evaluations.max(1) as f64
    );
    if let Some(sig) = &r.quality.sigma {
        println!("uncertainty: {}", sig.describe());
    }
    if let Some(o) = &r.quality.optima {
        let told = o.found.iter().filter(|f| f.separated).count();
        println!(
            "optima: {} climbs found {} other optim{}, {told} told apart from the answer{}",
            o.starts,
            o.found.len(),
            if o.found.len() == 1 { "um" } else { "a" },
            o.describe().map_or(String::new(), |d| format!("; {d}"))
        );
    }
    if let Some(sm) = smooth {
        if let Ok(info) = &sm.information {
            println!("information: {}", info.describe());
        }
        for (i, asc) in sm.ascents.iter().enumerate() {
            println!(
                "gradient ascent {}: {} iterations, {} evaluations, stopped on {}, objective {:.5} -> {:.5}",
                i + 1,
                asc.iterations,
                asc.evaluations,
                asc.stop,
                asc.value_start,
                asc.value
            );
        }
    }
}

/// Run `refine`; the exit code of a served result (0 precise, [`crate::error::EXIT_COARSE`]
/// coarse).
pub(super) fn run(mut a: Args) -> Result<i32> {
    if let Some(file) = &a.pairs {
        for (image, points) in super::pairs::read(file)? {
            a.image.push(image);
            a.points.push(points);
        }
    }
    let spec: SearchSpec = a.search.parse()?;
    let qcfg = quality_config(a.max_sigma.as_deref())?;
    let mode: Mode = a.mode.parse()?;
    let pooling: Pooling = a.pooling.parse()?;
    let mi = crate::localize::mi::MiConfig {
        pooling,
        ..a.estimator.config()?
    };
    let spread = start_spread(a.starts, a.start_spread.as_deref())?;
    if !a.points.is_empty() && a.points.len() != a.image.len() {
        return Err(Error::Usage(format!(
            "--image given {} times but --points {} times: pooled pairs need one point file per image, paired in order",
            a.image.len(),
            a.points.len()
        )));
    }
    let cam = load_camera(&a.camera)?;
    let qcfg = QualityConfig {
        intrinsics_sigma: crate::camera::load_intrinsics_sigma(&a.camera)?,
        ..qcfg
    };
    let grays = load_grays(&a, &cam)?;
    let (w, h) = (cam.width(), cam.height());
    let init = read_pose(&a.init)?;
    if let Some(n) = &init.note {
        super::note(n);
    }
    let (point_sets, crs, tile_id) = point_sets(&a, &init)?;
    let cfg = SearchConfig {
        spec,
        mode,
        mi,
        ..Default::default()
    };
    // Computed once for the search and the polish (the image size was checked above).
    let mask = cam.valid_mask();
    let views: Vec<View<'_>> = grays
        .iter()
        .enumerate()
        .map(|(i, gray)| View {
            gray,
            mask: &mask,
            points: &point_sets[i.min(point_sets.len() - 1)],
        })
        .collect();
    // The smooth estimator's stage after the grid search; `--grid-only` stops at the grid's
    // cell, with its checks and no σ.
    let refine_from = |start: &CamFromMap| -> Result<Run> {
        Ok(if a.grid_only {
            let (r, _) = refine_polished(&cam, &views, start, &cfg, &qcfg, None, &|_| None)?;
            (r, None)
        } else {
            let (r, s) = refine_smooth(&cam, &views, start, &cfg, &qcfg, a.polish)?;
            (r, Some(s))
        })
    };
    let starts = self_check_starts(&init.pose, a.starts, spread);
    let mut runs = Vec::with_capacity(starts.len());
    for s in &starts {
        runs.push(refine_from(s)?);
    }
    let check = (starts.len() > 1).then(|| SelfCheck::of(&init.pose, &starts, &runs));
    if let Some(c) = &check {
        c.print();
    }
    let pick = check.as_ref().map_or(0, |c| c.answer);
    let (mut r, smooth) = runs.swap_remove(pick);
    if let Some(stop) = check.as_ref().and_then(|c| c.disagreement.clone()) {
        r.quality.grade = Grade::Refused(stop);
    }
    let finish_label = match (&smooth, a.polish) {
        (Some(_), true) => "6-dof-gradient",
        (Some(_), false) => "4-dof-gradient",
        (None, _) => finish_name(None),
    };
    if let Some(path) = &a.report {
        let head = ReportHead {
            mode,
            mi,
            finish_label,
            note: init.note.as_deref(),
        };
        write_report(path, &r, smooth.as_ref(), &head, check.as_ref())?;
    }
    if let Some(path) = &a.overlay {
        // `gray` is the camera's size (checked above), so this cannot fail; the error is kept
        // one line all the same.
        // The first pair: one picture, the frame a technician names first.
        let frame = image::GrayImage::from_raw(w, h, grays[0].clone())
            .ok_or_else(|| Error::input(&a.image[0], "overlay: image buffer size"))?;
        let png = crate::viz::before_after_png(&frame, &cam, &init.pose, &r.pose, &point_sets[0])?;
        crate::persist::write_atomic(path, &png)?;
    }
    if let Grade::Refused(stop) = &r.quality.grade {
        return Err(Error::stage(
            crate::stage::StageName::Mi,
            format!("result refused: {stop}"),
        ));
    }
    print_result(&r, smooth.as_ref());
    println!("grade: {}", r.quality.grade);
    if let Some(path) = &a.out {
        write_pose_out(
            path,
            &a,
            &r,
            crs,
            &tile_id,
            smooth.as_ref(),
            finish_label,
            pooling,
        )?;
    }
    Ok(match r.quality.grade {
        Grade::Coarse(_) => crate::error::EXIT_COARSE,
        _ => 0,
    })
}

/// What the report names beside the refinement: the settings and the start's note.
struct ReportHead<'a> {
    mode: Mode,
    mi: crate::localize::mi::MiConfig,
    finish_label: &'a str,
    note: Option<&'a str>,
}

/// The refinement's JSON report at `path`.
fn write_report(
    path: &Path,
    r: &Refinement,
    smooth: Option<&SmoothRefinement>,
    head: &ReportHead<'_>,
    check: Option<&SelfCheck>,
) -> Result<()> {
    let (mode, mi, finish_label) = (head.mode, head.mi, head.finish_label);
    let mut report =
        serde_json::to_value(r.report(mode)).map_err(|e| Error::output("report", e))?;
    report["finish"] = finish_label.into();
    if let Some(sm) = smooth {
        report["smooth"] = serde_json::to_value(sm).unwrap_or_default();
    }
    report["estimator"] = serde_json::to_value(mi).unwrap_or_default();
    // The value the search maximised, named: quality.mi and quality.nmi are both reported
    // whatever the objective, so a reader cannot tell from them which one was optimised.
    report["score"] = serde_json::json!({
        "objective": mi.objective,
        "value": MiValue { mi: r.quality.mi, nmi: r.quality.nmi, n: r.quality.points }.get(mi.objective),
    });
    if let Some(n) = head.note {
        report["notes"] = serde_json::json!([n]);
    }
    if let Some(c) = check {
        report["self_check"] = serde_json::to_value(c).unwrap_or_default();
    }
    let text = serde_json::to_string_pretty(&report).map_err(|e| Error::output("report", e))?;
    crate::persist::write_atomic(path, (text + "\n").as_bytes())
}

/// The refined pose as a pose file at `path`, with the smooth stage's information and settings
/// when it ran.
#[allow(clippy::too_many_arguments)]
fn write_pose_out(
    path: &Path,
    a: &Args,
    r: &Refinement,
    crs: Crs,
    tile_id: &str,
    smooth: Option<&SmoothRefinement>,
    finish_label: &str,
    pooling: Pooling,
) -> Result<()> {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let mut pf = PoseFile::new(&r.pose, crs, tile_id, format_utc(now, None));
    pf.quality = PoseQuality::from_value(serde_json::to_value(&r.quality).unwrap_or_default());
    pf.stages = vec![
        serde_json::json!({ "name": "mi", "mode": a.mode, "search": a.search, "polish": a.polish, "finish": finish_label }),
    ];
    if smooth.is_some() || a.image.len() > 1 {
        pf.stages[0]["pooling"] = pooling.name().into();
    }
    crate::persist::write_atomic(path, pf.to_json().as_bytes())
}

/// One refinement's outcome: the result and the smooth stage's record (none with
/// `--grid-only`).
type Run = (Refinement, Option<SmoothRefinement>);

/// `--start-spread`'s xy, z (m) and yaw (deg), defaults [`START_SPREAD`], for `starts` starts
/// (at least one).
fn start_spread(starts: usize, spec: Option<&str>) -> Result<[f64; 3]> {
    if starts == 0 {
        return Err(Error::arg("--starts", 0, "at least one start"));
    }
    let mut s = START_SPREAD;
    for (k, v) in key_values("--start-spread", spec, &["xy", "z", "yaw"], true)? {
        match k {
            "xy" => s[0] = v,
            "z" => s[1] = v,
            _ => s[2] = v,
        }
    }
    Ok(s)
}

/// One start of `--starts` as the report lists it.
#[derive(Debug, Clone, serde::Serialize)]
struct StartOutcome {
    /// The start's offset from `--init`: x, y, z (m), yaw, pitch, roll (deg).
    start: [f64; 6],
    /// The answer's offset from `--init`.
    offsets: [f64; 6],
    /// Its grade, and why it is not precise.
    #[serde(flatten)]
    grade: Grade,
    /// The answer's σ when it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    sigma: Option<crate::pose::Sigma>,
    /// MI at the answer (nats).
    mi: f64,
}

/// The truth-free self-check of `--starts`: every start's outcome and whether the served
/// answers (precise or coarse) agree within their combined 3σ, and each lies within a served
/// answer's 3σ of a refused one whose MI is at least its own.
#[derive(Debug, Clone, serde::Serialize)]
struct SelfCheck {
    /// Per start, in order (the first is `--init`).
    starts: Vec<StartOutcome>,
    /// Served answers.
    served: usize,
    /// The served answers agree pairwise within their combined 3σ (vacuous below two).
    agree: bool,
    /// Why not: the axis that disagrees most, between the starts `pair`.
    #[serde(skip)]
    disagreement: Option<Stop>,
    /// The two starts (1-based) that disagree.
    #[serde(skip_serializing_if = "Option::is_none")]
    pair: Option<(usize, usize)>,
    /// The start whose answer is the result: the served one of the best grade and then the
    /// highest MI, else the first.
    answer: usize,
}

impl SelfCheck {
    fn of(init: &CamFromMap, starts: &[CamFromMap], runs: &[Run]) -> Self {
        let outcomes: Vec<StartOutcome> = starts
            .iter()
            .zip(runs)
            .map(|(s, (r, _))| StartOutcome {
                start: offsets_between(init, s),
                offsets: offsets_between(init, &r.pose),
                grade: r.quality.grade.clone(),
                sigma: r.quality.sigma,
                mi: r.quality.mi,
            })
            .collect();
        let ok: Vec<usize> = (0..runs.len())
            .filter(|&i| runs[i].0.quality.served() && runs[i].0.quality.sigma.is_some())
            .collect();
        let mut disagreement = None;
        let mut pair = None;
        'pairs: for (n, &i) in ok.iter().enumerate() {
            for &j in &ok[n + 1..] {
                let (a, b) = (&runs[i].0, &runs[j].0);
                let (Some(sa), Some(sb)) = (a.quality.sigma, b.quality.sigma) else {
                    continue;
                };
                if let Some((axis, d, z)) = disagreement_of(&a.pose, &sa, &b.pose, &sb) {
                    disagreement = Some(Stop::Disagree {
                        axis,
                        difference: d,
                        sigmas: z,
                    });
                    pair = Some((i + 1, j + 1));
                    break 'pairs;
                }
            }
        }
        // A refused answer is an answer too: one the data scores as high as a served one must
        // agree with it within their combined 3σ (the served one's alone where the refused one
        // has none).
        if disagreement.is_none() {
            let answers: Vec<Answer> = runs
                .iter()
                .enumerate()
                .map(|(i, (r, _))| Answer {
                    pose: r.pose,
                    sigma: r.quality.sigma,
                    mi: r.quality.mi,
                    tolerance: tolerance_of(r),
                    served: ok.contains(&i),
                })
                .collect();
            if let Some((i, j, stop)) = refused_disagreement(&answers) {
                disagreement = Some(stop);
                pair = Some((i + 1, j + 1));
            }
        }
        let key = |i: usize| (runs[i].0.quality.precise(), runs[i].0.quality.mi);
        let answer = ok
            .iter()
            .copied()
            .max_by(|&i, &j| {
                let (a, b) = (key(i), key(j));
                a.0.cmp(&b.0).then(a.1.total_cmp(&b.1))
            })
            .unwrap_or(0);
        SelfCheck {
            starts: outcomes,
            served: ok.len(),
            agree: disagreement.is_none(),
            disagreement,
            pair,
            answer,
        }
    }

    /// One line per start, then the verdict.
    fn print(&self) {
        for (k, s) in self.starts.iter().enumerate() {
            let o = &s.offsets;
            let verdict = match (&s.grade, s.sigma) {
                (Grade::Refused(_), _) | (_, None) => s.grade.to_string(),
                (g, Some(sig)) => format!("{}, {}", g.name(), sig.describe()),
            };
            println!(
                "start {} at ({:+.2}, {:+.2}, {:+.2}) m, yaw {:+.2}°: answer ({:+.3}, {:+.3}, {:+.3}) m, yaw {:+.3}°, MI {:.4}; {verdict}",
                k + 1,
                s.start[0],
                s.start[1],
                s.start[2],
                s.start[3],
                o[0],
                o[1],
                o[2],
                o[3],
                s.mi
            );
        }
        match (&self.disagreement, self.pair) {
            (Some(d), Some((i, j))) => println!("self-check: starts {i} and {j}: {d}"),
            _ => println!(
                "self-check: {} of {} starts served; {}",
                self.served,
                self.starts.len(),
                if self.served >= 2 {
                    "their answers agree within their combined 3σ"
                } else {
                    "fewer than two served answers to compare"
                }
            ),
        }
    }
}

/// One start's answer as the self-check weighs it against a refused one.
#[derive(Debug, Clone, Copy)]
struct Answer {
    pose: CamFromMap,
    sigma: Option<crate::pose::Sigma>,
    mi: f64,
    /// How much lower an MI still scores "as high" as this answer's (nats).
    tolerance: f64,
    served: bool,
}

/// "As high" within what the data can tell: [`SEPARATION`] standard errors of the answer's own
/// test against its competing optima (the median of theirs), 0 without any.
fn tolerance_of(r: &Refinement) -> f64 {
    let mut se: Vec<f64> = r
        .quality
        .optima
        .iter()
        .flat_map(|o| o.found.iter().map(|f| f.se))
        .filter(|v| v.is_finite())
        .collect();
    se.sort_by(f64::total_cmp);
    se.get(se.len() / 2).map_or(0.0, |v| SEPARATION * v)
}

/// A refused answer is an answer too: the first served answer (with a σ) that a refused one
/// scoring as high (its MI at least the served one's less its tolerance) disagrees with beyond
/// their combined 3σ (the served one's alone where the refused one has none), as (served index,
/// refused index, the stop).
fn refused_disagreement(answers: &[Answer]) -> Option<(usize, usize, Stop)> {
    let none = crate::pose::Sigma {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        yaw: 0.0,
        pitch: None,
        roll: None,
    };
    for (i, a) in answers.iter().enumerate().filter(|(_, a)| a.served) {
        let Some(sa) = a.sigma else { continue };
        for (j, b) in answers.iter().enumerate() {
            if b.served || !(b.mi >= a.mi - a.tolerance) {
                continue;
            }
            let sb = b.sigma.unwrap_or(none);
            if let Some((axis, difference, sigmas)) = disagreement_of(&a.pose, &sa, &b.pose, &sb) {
                return Some((
                    i,
                    j,
                    Stop::Disagree {
                        axis,
                        difference,
                        sigmas,
                    },
                ));
            }
        }
    }
    None
}

/// Every `--image` as gray, each checked to be the camera's size.
fn load_grays(a: &Args, cam: &crate::camera::Camera) -> Result<Vec<Vec<u8>>> {
    let mut grays = Vec::with_capacity(a.image.len());
    for path in &a.image {
        let (w, h, gray) = load_gray(path)?;
        if (w, h) != (cam.width(), cam.height()) {
            return Err(Error::input(
                path,
                format!(
                    "image is {w}×{h} but the camera {} is {}×{} (every pooled image must be the camera's size)",
                    a.camera.display(),
                    cam.width(),
                    cam.height()
                ),
            ));
        }
        grays.push(gray);
    }
    Ok(grays)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn answer(x: f64, sigma_x: Option<f64>, mi: f64, served: bool) -> Answer {
        Answer {
            pose: CamFromMap::from_center_ypr(&Point3::new(x, 0.0, 10.0), 0.0, 0.0, 0.0),
            sigma: sigma_x.map(|s| crate::pose::Sigma {
                x: s,
                y: s,
                z: s,
                yaw: 0.1,
                pitch: None,
                roll: None,
            }),
            mi,
            tolerance: 0.002,
            served,
        }
    }

    /// A refused answer the data scores as high must agree with a served one; one it scores
    /// lower, or one within the combined 3σ, is no objection.
    #[test]
    fn a_refused_answer_scoring_as_high_must_agree_with_the_served_one() {
        // Served at 0 (σ 0.1 m); refused 1.5 m away without a σ, at the same MI within the
        // tolerance: they disagree on x by 1.5 m, 15 σ.
        let (i, j, stop) = refused_disagreement(&[
            answer(0.0, Some(0.1), 0.2065, true),
            answer(1.5, None, 0.2060, false),
        ])
        .expect("a disagreement");
        assert_eq!((i, j), (0, 1));
        match stop {
            Stop::Disagree {
                axis,
                difference,
                sigmas,
            } => {
                assert_eq!(axis, crate::localize::mi::space::Axis::X);
                assert!((difference - 1.5).abs() < 1e-9 && (sigmas - 15.0).abs() < 1e-6);
            }
            other => panic!("{other}"),
        }
        // Scored lower than the tolerance: the data tells it apart, no objection.
        assert!(refused_disagreement(&[
            answer(0.0, Some(0.1), 0.2065, true),
            answer(1.5, None, 0.2040, false),
        ])
        .is_none());
        // With a σ of its own (0.5 m): 1.5 m is within 3·√(0.1² + 0.5²) = 1.53 m.
        assert!(refused_disagreement(&[
            answer(0.0, Some(0.1), 0.2065, true),
            answer(1.5, Some(0.5), 0.2070, false),
        ])
        .is_none());
        // Two served answers are the served pairs' check, not this one's.
        assert!(refused_disagreement(&[
            answer(0.0, Some(0.1), 0.2065, true),
            answer(1.5, Some(0.1), 0.2070, true),
        ])
        .is_none());
    }
}
