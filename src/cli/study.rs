//! `infraloc study` (docs/interfaces.md, "Command line and exit codes"): the seed's robustness study on a simulated scene — MI
//! refinement from seeded random initializations around the truth, a summary on stdout, a scatter
//! plot PNG and a JSON file with every trial. The computation is [`crate::eval::study`]; this
//! file reads the scene and writes the outputs.

use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::eval::study::{
    attitude_from_control_points, run_trial, Ground, Perturbation, PointSelection, Scene, Summary,
    SUCCESS_HEIGHT_M, SUCCESS_HORIZONTAL_M, SUCCESS_YAW_DEG,
};
use crate::localize::mi::space::{SearchConfig, SearchSpec};
use crate::localize::refine::quality::QualityConfig;
use crate::localize::refine::{finish_name, PolishedSearch};
use crate::scene::{load_perspective, load_perspective_times, load_scene, load_times};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `study`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Simulated scene directory (`infraloc simulate --out DIR`: truth.json, camera.yaml, frames/,
    /// tiles/).
    #[arg(long)]
    pub scene: PathBuf,
    /// Number of random initializations.
    #[arg(long, default_value_t = 100)]
    pub trials: usize,
    /// Seed of the initializations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Largest x and y perturbation of the start, metres (uniform in ±value).
    #[arg(long, default_value_t = 0.8)]
    pub perturb_xy: f64,
    /// Largest z perturbation, metres.
    #[arg(long, default_value_t = 0.4)]
    pub perturb_z: f64,
    /// Largest yaw perturbation, degrees.
    #[arg(long, default_value_t = 2.5)]
    pub perturb_yaw: f64,
    /// Search box around each start, as `refine --search`.
    #[arg(long, default_value = "x=1:0.02,y=1:0.02,z=0.5:0.02,yaw=3:0.05")]
    pub search: String,
    /// Scatter plot PNG; default DIR/study.png.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// JSON with the summary and every trial; default DIR/study.json.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Roll and pitch of the starts: `truth`, or `control-points` (the least-squares fit of
    /// truth.json's control points under camera.yaml's intrinsics, what a perfect PnP would give).
    #[arg(long, value_enum, default_value = "truth")]
    pub attitude: Attitude,
    /// Plot size W,H in pixels.
    #[arg(long, default_value = "1400,1200")]
    pub size: String,
    /// Each trial answers the grid search's cell, with no continuous 4-DoF polish after it (as
    /// `refine --grid-only`).
    #[arg(long)]
    pub grid_only: bool,
    /// Which camera and LiDAR the trials refine: the fisheye against the map tile, or (a
    /// `--preset gantry` scene) the perspective camera's first frame against the first LiDAR
    /// sweep, with the truth in the LiDAR frame.
    #[arg(long, value_enum, default_value = "fisheye")]
    pub sensor: Sensor,
    /// Pool every time of day of the scene (`simulate --times K`), one histogram each (as
    /// `refine --pooling per-pair`): the fisheye's burst medians times/NN.png against the tile,
    /// or the perspective camera's first frame of each time against the sweep taken with it
    /// (perspective/pairs_times.tsv). Without it the trials refine the first time alone.
    #[arg(long)]
    pub times: bool,
    /// The MI estimator, as `refine`'s flags.
    #[command(flatten)]
    pub estimator: super::estimator::EstimatorArgs,
}

/// The camera and LiDAR a study refines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sensor {
    /// The fisheye (temporal median of frames/) against the map tile.
    Fisheye,
    /// The gantry's perspective camera against its LiDAR sweep (perspective/, lidar/).
    Perspective,
}

/// Where the starts' roll and pitch come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Attitude {
    /// The true roll and pitch.
    Truth,
    /// The 6-DoF fit of the control points under the given intrinsics.
    ControlPoints,
}

/// Run `study`.
pub(super) fn run(a: Args) -> Result<()> {
    if a.trials == 0 {
        return Err(Error::arg("--trials", 0, "need at least one trial"));
    }
    let pert = Perturbation {
        xy_m: a.perturb_xy,
        z_m: a.perturb_z,
        yaw_deg: a.perturb_yaw,
    };
    pert.validate()?;
    let spec: SearchSpec = a.search.parse()?;
    let mi = crate::localize::mi::MiConfig {
        pooling: crate::localize::mi::smooth::Pooling::PerPair,
        ..a.estimator.config()?
    };
    let size = super::parse_size(&a.size)?;
    let cfg = SearchConfig {
        spec,
        mi,
        ..Default::default()
    };
    let sel = PointSelection::default();
    let (camera_yaml, truth_json) = match a.sensor {
        Sensor::Fisheye => (a.scene.join("camera.yaml"), a.scene.join("truth.json")),
        Sensor::Perspective => (
            a.scene.join("perspective").join("camera.yaml"),
            PathBuf::new(),
        ),
    };
    let (camera, grays, truth, control, tile, points) = match a.sensor {
        Sensor::Fisheye => {
            let s = load_scene(&a.scene)?;
            let grays = match a.times {
                true => load_times(&a.scene, &s.camera)?,
                false => vec![s.gray],
            };
            (
                s.camera,
                grays,
                s.truth,
                Some(s.control),
                Some(s.tile),
                Vec::new(),
            )
        }
        Sensor::Perspective => {
            let p = load_perspective(&a.scene)?;
            let (grays, points) = match a.times {
                true => load_perspective_times(&a.scene, &p.camera)?
                    .into_iter()
                    .unzip(),
                false => (vec![p.gray], vec![p.points]),
            };
            (p.camera, grays, p.truth, None, None, points)
        }
    };
    // The σ the node would report: with the given intrinsics' stated uncertainty.
    let qcfg = QualityConfig {
        intrinsics_sigma: crate::camera::load_intrinsics_sigma(&camera_yaml)?,
        ..QualityConfig::default()
    };
    let ground_truth = match control {
        Some(_) => Some(crate::eval::truth::read_truth(&truth_json)?),
        None => None,
    };
    let ground = match &tile {
        Some(t) => Ground::Tile(t),
        None => Ground::Points(&points),
    };
    let gray_refs: Vec<&[u8]> = grays.iter().map(|g| g.as_raw().as_slice()).collect();
    let camera = &camera;
    let base = match (a.attitude, control) {
        (Attitude::Truth, _) => truth,
        (Attitude::ControlPoints, Some(control)) => {
            attitude_from_control_points(camera, &truth, &control)
                .map_err(|e| Error::input(a.scene.join("truth.json"), e.to_string()))?
        }
        (Attitude::ControlPoints, None) => {
            return Err(Error::Usage(
                "--attitude control-points with --sensor perspective: the perspective camera has no control points; use --attitude truth".into(),
            ))
        }
    };
    let mask = camera.valid_mask();
    let sc = Scene {
        camera,
        grays: &gray_refs,
        mask: &mask,
        ground,
        truth: &truth,
        base: &base,
        control: ground_truth.as_ref(),
    };
    let (_, bp, br) = base.yaw_pitch_roll();
    let (_, tp, tr) = truth.yaw_pitch_roll();
    println!(
        "study: starts' pitch/roll differ from the truth by {:+.3}°/{:+.3}° ({:?})",
        (bp - tp).to_degrees(),
        (br - tr).to_degrees(),
        a.attitude
    );
    let t0 = Instant::now();
    let now = move || t0.elapsed().as_secs_f64();
    let starts = pert.starts(a.trials, a.seed);
    let finish = (!a.grid_only).then(PolishedSearch::four_dof);
    let mut trials = Vec::with_capacity(a.trials);
    for (i, s) in starts.iter().enumerate() {
        let t = run_trial(&sc, i, *s, &sel, &cfg, &qcfg, finish.as_ref(), &now)?;
        print_trial(i, a.trials, s, &t);
        trials.push(t);
    }
    let sum = Summary::of(&trials);
    print_summary(&a.scene, &sum, &trials);
    let doc = json!({
        "scene": a.scene,
        "seed": a.seed,
        "attitude": a.attitude,
        "sensor": a.sensor,
        "images_pooled": grays.len(),
        "perturbation": pert,
        "search": a.search,
        "finish": finish_name(finish.as_ref()),
        "estimator": mi,
        "success_bounds": {
            "horizontal_m": SUCCESS_HORIZONTAL_M,
            "height_m": SUCCESS_HEIGHT_M,
            "yaw_deg": SUCCESS_YAW_DEG,
        },
        "summary": sum,
        "trials": trials,
    });
    let jpath = a.json.unwrap_or_else(|| a.scene.join("study.json"));
    let text = serde_json::to_string_pretty(&doc)
        .map_err(|e| Error::output(jpath.display().to_string(), e))?;
    crate::persist::write_atomic(&jpath, (text + "\n").as_bytes())?;
    let png = a.out.unwrap_or_else(|| a.scene.join("study.png"));
    let note = format!(
        "seed {}, start roll/pitch: {}",
        a.seed,
        match a.attitude {
            Attitude::Truth => "truth",
            Attitude::ControlPoints => "control-point fit",
        }
    );
    let img = super::plot::study_chart(&trials, &sum, &pert, &note, size)?;
    super::plot::save_png(&img, &png)?;
    println!("study: wrote {} and {}", png.display(), jpath.display());
    Ok(())
}

/// One trial's line: its start, its errors, the gate's reason when it refused.
fn print_trial(i: usize, n: usize, s: &[f64; 4], t: &crate::eval::study::Trial) {
    println!(
        "trial {:>3}/{n}: start ({:+.3}, {:+.3}, {:+.3}) m {:+.2}° → error {:.1} cm horizontal, {:.1} cm height, {:.3}° yaw{} ({:.1} s)",
        i + 1,
        s[0],
        s[1],
        s[2],
        s[3],
        t.horizontal_m * 100.0,
        t.height_m * 100.0,
        t.yaw_deg,
        match &t.reason {
            Some(r) if !t.accepted => format!("; gate: {r}"),
            _ => String::new(),
        },
        t.seconds
    );
}

/// The study's summary for people: the spread of each error and the fraction within bounds.
fn print_summary(scene: &std::path::Path, sum: &Summary, trials: &[crate::eval::study::Trial]) {
    let row = |name: &str, s: &crate::eval::study::Spread, scale: f64, unit: &str| {
        println!(
            "{name:<11} median {:>7.3} {unit}  p95 {:>7.3} {unit}  max {:>7.3} {unit}",
            s.median * scale,
            s.p95 * scale,
            s.max * scale
        );
    };
    println!("study: {} trials on {}", sum.trials, scene.display());
    row("horizontal", &sum.horizontal_m, 100.0, "cm");
    row("height", &sum.height_m, 100.0, "cm");
    row("yaw", &sum.yaw_deg, 1.0, "° ");
    println!(
        "within {:.0} cm horizontal, {:.0} cm height and {}° yaw: {:.1} % ({} of {}); gate rejections: {}; time {:.1} s ({:.2} s median per trial)",
        SUCCESS_HORIZONTAL_M * 100.0,
        SUCCESS_HEIGHT_M * 100.0,
        SUCCESS_YAW_DEG,
        sum.success_fraction * 100.0,
        trials.iter().filter(|t| t.success).count(),
        sum.trials,
        sum.gate_rejections,
        sum.seconds_total,
        sum.seconds_median
    );
}
