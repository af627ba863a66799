//! Georeferencing accuracy on simulated scenes (issue 38's acceptance), through the poses
//! `pipeline_accuracy` accepted.
//!
//! ```sh
//! cargo run --release --features __internal-test --example pipeline_accuracy -- --preset small --seeds 1..50 --json small.json
//! cargo run --release --example georef_accuracy -- --preset small --runs small.json [--json out.json]
//! ```
//!
//! For every seed of the run whose pose the quality gate accepted, the scene is generated again
//! (`hard`, Mei lens, calibrated intrinsics: what `pipeline_accuracy` localized by default), its
//! camera and tile read back as `infraloc localize` reads them, and each control point's true
//! pixel (truth.json) georeferenced through the accepted pose with its covariance
//! ([`infraloc::geo::georef`]) on the tile's height layer. Per distance band (0–10, 10–20,
//! 20–30 m from the camera's foot) it prints the horizontal error's median and 95th percentile,
//! beside the "ground error" of docs/accuracy.md for the same points (the ray met with the
//! plane at the point's true height), and the share of points inside their 3σ ellipse (the
//! pose's covariance propagated, and the height layer's noise as estimated from the layer;
//! `--sigma-px` adds pixel noise, default 0 since the pixels are exact). Beside them: the same
//! pixels georeferenced on the plane at each point's true height (which is the ground error's
//! own construction, so the two columns must agree to rounding), the height layer's error under
//! each hit, and the coverage the pose's covariance alone would give.

use infraloc::eval::truth_eval;
use infraloc::geo::georef::{
    self, Ellipse, HeightSurface, Params, PoseWithCovariance, Status, Surface,
};
use infraloc::posefile::pose_covariance_of;
use infraloc::sim::GivenIntrinsics;
use serde_json::{json, Value};
use std::path::PathBuf;

#[path = "common/mod.rs"]
mod common;
use common::{hard_settings, parse_preset, pose_of, scene_inputs, scene_truth};

const BANDS: [(f64, f64); 3] = [(0.0, 10.0), (10.0, 20.0), (20.0, 30.0)];

fn usage() -> ! {
    eprintln!(
        "usage: georef_accuracy --preset small|5mp --runs PIPELINE_ACCURACY.json [--json OUT] [--sigma-px S]"
    );
    std::process::exit(2)
}

/// One control point's figures.
struct Hit {
    range_m: f64,
    georef_m: f64,
    ground_m: f64,
    /// Horizontal error of the georeference on the plane at the point's true height.
    plane_m: f64,
    /// The height layer's height at the hit minus the point's true height.
    dh_m: f64,
    mahalanobis: f64,
    /// Mahalanobis distance with the pose's covariance alone (no height term).
    mahalanobis_pose: f64,
    sigma_major_m: f64,
}

/// The command line: preset, runs file, JSON output and pixel σ.
fn args() -> (infraloc::sim::Preset, PathBuf, Option<PathBuf>, f64) {
    let mut preset = None;
    let mut runs = None;
    let mut out: Option<PathBuf> = None;
    let mut sigma_px = 0.0;
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut val = || it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--preset" => preset = Some(parse_preset(&val()).unwrap_or_else(|| usage())),
            "--runs" => runs = Some(PathBuf::from(val())),
            "--json" => out = Some(PathBuf::from(val())),
            "--sigma-px" => sigma_px = val().parse().unwrap_or_else(|_| usage()),
            _ => usage(),
        }
    }
    let (Some(preset), Some(runs)) = (preset, runs) else {
        usage()
    };
    (preset, runs, out, sigma_px)
}

fn main() {
    let (preset, runs, out, sigma_px) = args();
    let text = std::fs::read_to_string(&runs).unwrap_or_else(|e| {
        eprintln!("{}: {e}", runs.display());
        std::process::exit(1)
    });
    let doc: Value = serde_json::from_str(&text).unwrap_or_else(|e| {
        eprintln!("{}: {e}", runs.display());
        std::process::exit(1)
    });
    let seeds = doc["seeds"].as_array().cloned().unwrap_or_default();
    let params = Params {
        sigma_px,
        wgs84: false,
        height_sigma_m: None,
        ..Params::default()
    };
    let mut hits: Vec<Hit> = Vec::new();
    let mut statuses = std::collections::BTreeMap::<&str, usize>::new();
    let mut used = 0;
    let mut sigma_h: Vec<f64> = Vec::new();
    println!(
        "{:>5} {:>4} {:>10} {:>10} {:>8}",
        "seed", "pts", "georef cm", "ground cm", "in 3σ"
    );
    for rec in &seeds {
        let seed = rec["seed"].as_u64().unwrap_or(0);
        if rec.get("failure").is_some() {
            continue;
        }
        let Some(pose) = pose_of(&rec["poses"]["mi"]) else {
            continue;
        };
        let covariance = match pose_covariance_of(&rec["mi_quality"]) {
            Ok(Some(c)) => c,
            other => {
                let other = other.map_err(|e| e.to_string());
                eprintln!("seed {seed}: no usable covariance ({other:?})");
                continue;
            }
        };
        let scene =
            infraloc::sim::generate(&hard_settings(seed, preset, GivenIntrinsics::Calibrated))
                .expect("simulate");
        let inputs = scene_inputs(&scene, false).expect("scene inputs");
        let truth = scene_truth(&scene).expect("truth");
        let surface = Surface::Heights(HeightSurface::new(&inputs.tile.height).expect("heights"));
        let pc = PoseWithCovariance {
            pose,
            covariance: Some(covariance),
        };
        let crs = inputs.tile.height.grid.crs;
        let pixels: Vec<[f64; 2]> = truth.control_points.iter().map(|c| c.pixel).collect();
        let points = georef::georef_batch(&inputs.camera, &pc, &surface, crs, &pixels, &params);
        let pose_only = Params {
            height_sigma_m: Some(0.0),
            ..params
        };
        let bare = georef::georef_batch(&inputs.camera, &pc, &surface, crs, &pixels, &pose_only);
        sigma_h.push(surface.height_sigma_m(&params));
        let ground = truth_eval::ground_hits(&inputs.camera, &truth, &pose);
        let foot = truth.pose.center();
        let (mut n, mut inside) = (0, 0);
        let (mut e_sum, mut g_sum) = (0.0, 0.0);
        for ((cp, m), b) in truth.control_points.iter().zip(&points).zip(&bare) {
            *statuses.entry(m.status.name()).or_default() += 1;
            if m.status != Status::Ok {
                continue;
            }
            let (de, dn) = (m.enh[0] - cp.map[0], m.enh[1] - cp.map[1]);
            let range_m = (cp.map[0] - foot.x).hypot(cp.map[1] - foot.y);
            // The same point's ground error (ground_hits keeps the points it can score, in order).
            let ground_m = ground
                .iter()
                .find(|h| (h.range_m - range_m).abs() < 1e-9)
                .map_or(f64::NAN, |h| h.error_m);
            let mahalanobis = Ellipse::mahalanobis(&m.covariance, de, dn);
            let on_plane = georef::georef(
                &inputs.camera,
                &pc,
                &Surface::Plane(cp.map[2]),
                crs,
                cp.pixel,
                &params,
            );
            let plane_m = (on_plane.enh[0] - cp.map[0]).hypot(on_plane.enh[1] - cp.map[1]);
            n += 1;
            inside += usize::from(mahalanobis <= 3.0);
            e_sum += de.hypot(dn);
            g_sum += ground_m;
            hits.push(Hit {
                range_m,
                georef_m: de.hypot(dn),
                ground_m,
                plane_m,
                dh_m: m.enh[2] - cp.map[2],
                mahalanobis,
                mahalanobis_pose: Ellipse::mahalanobis(&b.covariance, de, dn),
                sigma_major_m: m.ellipse().sigma_major_m,
            });
        }
        used += 1;
        println!(
            "{seed:>5} {n:>4} {:>10.2} {:>10.2} {:>7.1}%",
            100.0 * e_sum / n.max(1) as f64,
            100.0 * g_sum / n.max(1) as f64,
            100.0 * inside as f64 / n.max(1) as f64
        );
    }
    let mut bands: Vec<Value> = BANDS.iter().map(|&(a, b)| band(&hits, a, b)).collect();
    bands.push(band(&hits, 0.0, f64::INFINITY));
    let summary = json!({
        "runs": runs.display().to_string(),
        "scenes": used,
        "statuses": statuses,
        "sigma_px": sigma_px,
        "height_sigma_m": truth_eval::median_p95(&sigma_h),
        "bands": bands,
    });
    print_bands(&summary);
    println!("statuses: {}", summary["statuses"]);
    println!(
        "height layer σ estimated from each tile: median {:.2} cm",
        100.0
            * summary["height_sigma_m"]["median"]
                .as_f64()
                .unwrap_or(f64::NAN)
    );
    if let Some(p) = out {
        let text = serde_json::to_string_pretty(&summary).unwrap_or_default();
        if let Err(e) = std::fs::write(&p, text) {
            eprintln!("{}: {e}", p.display());
        }
    }
}

/// The figures of the control points of `hits` whose range is at least `lo` and below `hi` metres.
fn band(hits: &[Hit], lo: f64, hi: f64) -> Value {
    let sel: Vec<&Hit> = hits
        .iter()
        .filter(|h| h.range_m >= lo && h.range_m < hi)
        .collect();
    let pct = |xs: Vec<f64>| truth_eval::median_p95(&xs);
    let inside = sel.iter().filter(|h| h.mahalanobis <= 3.0).count();
    let inside_pose = sel.iter().filter(|h| h.mahalanobis_pose <= 3.0).count();
    json!({
        "band_m": [lo, hi],
        "points": sel.len(),
        "georef_m": pct(sel.iter().map(|h| h.georef_m).collect()),
        "ground_error_m": pct(sel.iter().map(|h| h.ground_m).collect()),
        "largest_difference_m": sel.iter().map(|h| (h.georef_m - h.ground_m).abs()).fold(0.0, f64::max),
        "sigma_major_m": pct(sel.iter().map(|h| h.sigma_major_m).collect()),
        "plane_vs_ground_largest_m": sel.iter().map(|h| (h.plane_m - h.ground_m).abs()).fold(0.0, f64::max),
        "height_error_abs_m": pct(sel.iter().map(|h| h.dh_m.abs()).collect()),
        "inside_3sigma_pose_only": inside_pose as f64 / sel.len().max(1) as f64,
        "inside_3sigma": inside as f64 / sel.len().max(1) as f64,
    })
}

/// The bands of `summary` as a table.
fn print_bands(summary: &Value) {
    println!("\nband        pts  georef med/p95 cm   ground err med/p95 cm  |diff| max cm  σmaj med cm  in 3σ   |δh| med/p95 cm  plane−ground max cm  in 3σ pose only");
    for b in summary["bands"].as_array().into_iter().flatten() {
        let p = |k: &str, q: &str| 100.0 * b[k][q].as_f64().unwrap_or(f64::NAN);
        let r = &b["band_m"];
        println!(
            "{:>4}–{:<5} {:>5}  {:>7.2} / {:<7.2}    {:>7.2} / {:<7.2}       {:>8.3}    {:>8.2}   {:>5.1}%  {:>5.2} / {:<5.2}      {:>10.6}        {:>5.1}%",
            r[0].as_f64().unwrap_or(0.0),
            r[1].as_f64().map_or("∞".to_string(), |v| v.to_string()),
            b["points"],
            p("georef_m", "median"),
            p("georef_m", "p95"),
            p("ground_error_m", "median"),
            p("ground_error_m", "p95"),
            100.0 * b["largest_difference_m"].as_f64().unwrap_or(f64::NAN),
            p("sigma_major_m", "median"),
            100.0 * b["inside_3sigma"].as_f64().unwrap_or(f64::NAN),
            p("height_error_abs_m", "median"),
            p("height_error_abs_m", "p95"),
            100.0 * b["plane_vs_ground_largest_m"].as_f64().unwrap_or(f64::NAN),
            100.0 * b["inside_3sigma_pose_only"].as_f64().unwrap_or(f64::NAN),
        );
    }
}
