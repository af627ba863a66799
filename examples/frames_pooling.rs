//! How should the node use several frames of one view in the MI refinement? Measured on seeded
//! simulated scenes (issue 14, "pooled refinement" for the node):
//! - `median`: the temporal median of the frames, one view (what `localize` has always done);
//! - `pooled`: every frame a view of its own, one joint histogram per pose summed over them;
//! - `median+pooled`: the median and every frame.
//!
//! ```sh
//! cargo run --release --example frames_pooling -- --preset small --seeds 1..30 [--frames 5] [--true-intrinsics] [--json OUT]
//! ```
//!
//! Each seed's scene is simulated as `infraloc simulate --seed N` does; each variant refines from
//! the same start (the truth perturbed by a seeded ±0.3 m, ±0.1 m height, ±1° yaw, ±0.5° tilt,
//! i.e. a start inside the pipeline's basin) with the pipeline's search, 6-DoF polish and
//! uncertainty, and is scored against the oracle (the best pose the given intrinsics allow; the
//! truth itself with `--true-intrinsics`) — error and whether it lies within the reported 3σ.

use infraloc::camera::import::{parse_camera, to_opencv_yaml};
use infraloc::camera::CameraModel;
use infraloc::eval::truth_eval::{oracle_pose, SignedError};
use infraloc::localize::mi::objective::View;
use infraloc::localize::pipeline::{mi_points, Params};
use infraloc::localize::refine::refine_polished;
use infraloc::pose::CamFromMap;
use infraloc::sim::{self, Difficulty, Lens, Preset, Settings};
use rand::{Rng, SeedableRng};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

#[path = "common/mod.rs"]
mod common;
use common::parse_preset;

const VARIANTS: [&str; 3] = ["median", "pooled", "median+pooled"];

fn usage() -> ! {
    eprintln!(
        "usage: frames_pooling [--preset small|5mp] [--difficulty hard|easy] --seeds A..B \
         [--frames N] [--true-intrinsics] [--json OUT]"
    );
    std::process::exit(2)
}

fn main() {
    let (mut preset, mut difficulty, mut seeds, mut frames) =
        (Preset::Small, Difficulty::Hard, Vec::new(), 5u32);
    let (mut true_intrinsics, mut json_out): (bool, Option<PathBuf>) = (false, None);
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut val = || it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--preset" => preset = parse_preset(&val()).unwrap_or_else(|| usage()),
            "--difficulty" => {
                difficulty = match val().as_str() {
                    "hard" => Difficulty::Hard,
                    "easy" => Difficulty::Easy,
                    _ => usage(),
                }
            }
            "--seeds" => {
                let v = val();
                let (a, b) = v.split_once("..").unwrap_or_else(|| usage());
                let (a, b): (u64, u64) = (
                    a.parse().unwrap_or_else(|_| usage()),
                    b.parse().unwrap_or_else(|_| usage()),
                );
                seeds = (a..=b).collect();
            }
            "--frames" => frames = val().parse().unwrap_or_else(|_| usage()),
            "--true-intrinsics" => true_intrinsics = true,
            "--json" => json_out = Some(PathBuf::from(val())),
            _ => usage(),
        }
    }
    if seeds.is_empty() {
        usage()
    }
    println!(
        "{:>5} {:<14} {:>8} {:>8} {:>8} {:>6}  {:>5} {:>4}",
        "seed", "variant", "hor cm", "z cm", "yaw °", "acc", "in3σ", "pts"
    );
    let mut recs = Vec::new();
    for &seed in &seeds {
        let settings = Settings {
            seed,
            preset,
            difficulty,
            lens: Lens::Mei,
            frames,
            intrinsics: Default::default(),
            times: 1,
            low_sun: false,
        };
        match run_seed(&settings, true_intrinsics) {
            Ok(r) => {
                for v in VARIANTS {
                    let e = &r[v];
                    println!(
                        "{:>5} {:<14} {:>8.2} {:>8.2} {:>8.4} {:>6} {:>5} {:>4}",
                        seed,
                        v,
                        100.0 * e["horizontal_m"].as_f64().unwrap_or(f64::NAN),
                        100.0 * e["height_m"].as_f64().unwrap_or(f64::NAN),
                        e["yaw_deg"].as_f64().unwrap_or(f64::NAN),
                        e["accepted"],
                        e["within_3sigma"],
                        e["points"]
                    );
                }
                recs.push(r);
            }
            Err(e) => println!("{seed:>5} failed: {e}"),
        }
        if let Some(p) = &json_out {
            let doc = json!({ "command": std::env::args().collect::<Vec<_>>().join(" "),
                "summary": summary(&recs), "seeds": recs });
            if let Err(e) =
                std::fs::write(p, serde_json::to_string_pretty(&doc).unwrap_or_default())
            {
                eprintln!("{}: {e}", p.display());
            }
        }
    }
    let s = summary(&recs);
    println!("\n{}", serde_json::to_string_pretty(&s).unwrap_or_default());
}

fn run_seed(settings: &Settings, true_intrinsics: bool) -> infraloc::Result<Value> {
    let scene = sim::generate(settings)?;
    let cam_text = to_opencv_yaml(if true_intrinsics {
        &scene.camera_true
    } else {
        &scene.camera_given
    });
    let camera = parse_camera(&cam_text, Path::new("camera.yaml"))?;
    let frames = scene.frame_images();
    let median = infraloc::capture::temporal_median(&frames)?;
    let truth_text = serde_json::to_string(&scene.truth_json())
        .map_err(|e| infraloc::Error::Invalid(format!("truth: {e}")))?;
    let truth = infraloc::eval::truth::parse_truth(&truth_text, Path::new("truth.json"))?;
    let reference = if true_intrinsics {
        truth.pose
    } else {
        oracle_pose(&camera, &truth)
            .ok_or_else(|| infraloc::Error::Invalid("no oracle: too few control points".into()))?
    };
    // The start: the truth perturbed, seeded per scene.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed ^ 0x5eed_f00d);
    let mut u = |a: f64| rng.random_range(-a..=a);
    let c = truth.pose.center();
    let (y, p, r) = truth.pose.yaw_pitch_roll();
    let start = CamFromMap::from_center_ypr(
        &nalgebra::Point3::new(c.x + u(0.3), c.y + u(0.3), c.z + u(0.1)),
        y + u(1.0).to_radians(),
        p + u(0.5).to_radians(),
        r + u(0.5).to_radians(),
    );
    let mut params = Params::default();
    if !true_intrinsics {
        params.quality.intrinsics_sigma = scene.camera_sigma;
    }
    let tile = &scene.tile;
    let points = mi_points(tile, &start, &params);
    let mask = camera.valid_mask();
    let pivot = |pose: &CamFromMap| {
        let c = pose.center();
        infraloc::localize::init::ground::height_at(&tile.height, c.x, c.y)
            .map(|g| (c.z - g).max(1.0))
    };
    let mut rec = json!({ "seed": settings.seed });
    for v in VARIANTS {
        let mut grays: Vec<&[u8]> = Vec::new();
        if v != "pooled" {
            grays.push(median.as_raw());
        }
        if v != "median" {
            grays.extend(frames.iter().map(|f| f.as_raw().as_slice()));
        }
        let views: Vec<View> = grays
            .iter()
            .map(|gray| View {
                gray,
                mask: &mask,
                points: &points,
            })
            .collect();
        let (res, _) = refine_polished(
            &camera,
            &views,
            &start,
            &params.search,
            &params.quality,
            params.polish.as_ref(),
            &pivot,
        )?;
        let e = SignedError::between(&res.pose, &reference);
        let within = res
            .quality
            .sigma
            .map(|s| e.within(&s, 3.0, [0.0; 4]).iter().all(|&b| b));
        rec[v] = json!({
            "horizontal_m": e.horizontal_m(), "height_m": e.z.abs(), "yaw_deg": e.yaw.abs(),
            "signed": e, "sigma": res.quality.sigma, "accepted": res.quality.served(), "grade": res.quality.grade.name(),
            "reason": res.quality.grade.to_string(), "within_3sigma": within, "points": res.points.1,
        });
    }
    Ok(rec)
}

fn summary(recs: &[Value]) -> Value {
    let mut out = json!({ "seeds": recs.len() });
    for v in VARIANTS {
        let get = |k: &str| -> Vec<f64> { recs.iter().filter_map(|r| r[v][k].as_f64()).collect() };
        let pct = |k: &str| infraloc::eval::truth_eval::median_p95(&get(k));
        let count = |f: &dyn Fn(&Value) -> bool| recs.iter().filter(|r| f(&r[v])).count();
        out[v] = json!({
            "horizontal_m": pct("horizontal_m"), "height_m": pct("height_m"), "yaw_deg": pct("yaw_deg"),
            "accepted": count(&|e| e["accepted"] == json!(true)),
            "within_3sigma": count(&|e| e["within_3sigma"] == json!(true)),
            "within_10cm_0.2deg": count(&|e| e["horizontal_m"].as_f64().is_some_and(|x| x <= 0.1)
                && e["height_m"].as_f64().is_some_and(|x| x <= 0.1)
                && e["yaw_deg"].as_f64().is_some_and(|x| x <= 0.2)),
        });
    }
    out
}
