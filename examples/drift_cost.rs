//! Cost of the service's drift check (`daemon::drift_check`: fresh frames, the tile, the narrow MI
//! search around the served pose), stage by stage, in process CPU seconds and wall seconds.
//! The service runs exactly these calls on its schedule; the frames come from the config's camera
//! (a simulated scene's `infraloc.toml` reads its `frames/`).
//!
//! `cargo run --release --example drift_cost -- SCENE/infraloc.toml POSE.json [RUNS]`
//! (`RAYON_NUM_THREADS=2` for the node's two cores). Each run is a whole drift check, as the
//! service makes it every `drift-check-interval-min`; the first run includes what a process
//! computes once per camera (the validity mask). Then the search once more, taken apart stage by
//! stage.

use infraloc::app::{camera_and_frame, Overrides};
use infraloc::camera::CameraModel;
use infraloc::config::Config;
use infraloc::localize::mi::objective::{Evaluator, View};
use infraloc::localize::mi::space::{SearchConfig, MAX_LEVEL};
use infraloc::localize::pipeline::{mi_points, Params};
use infraloc::localize::refine::drift::{drift_search, DriftParams, DriftThresholds, DRIFT_SPEC};
use infraloc::localize::refine::quality::{assess, QualityConfig};
use infraloc::localize::refine::search::search;
use infraloc::map::cache::load_tile;
use infraloc::posefile::PoseFile;
use std::path::Path;
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::cpu_s;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: drift_cost CONFIG POSE.json [RUNS]".into());
    }
    let cfg_path = Path::new(&args[1]);
    let served: PoseFile = serde_json::from_str(&std::fs::read_to_string(&args[2])?)?;
    let runs: usize = args.get(3).map_or(Ok(3), |r| r.parse())?;
    let cfg = Config::load(cfg_path)?;
    println!("run  frames cpu/wall  tile cpu/wall  search cpu/wall  total cpu/wall (s)  verdict");
    for run in 0..runs {
        let (c0, w0) = (cpu_s(), Instant::now());
        let (camera, image) = camera_and_frame(&cfg, cfg_path, &Overrides::default(), &|_| {})?;
        let (c1, w1) = (cpu_s(), Instant::now());
        let tile = load_tile(&cfg.map.tiles.join(&served.tile_id))?;
        let (c2, w2) = (cpu_s(), Instant::now());
        let thresholds = DriftThresholds {
            shift_m: cfg.daemon.drift_threshold_m,
            yaw_deg: cfg.daemon.drift_threshold_deg,
        };
        let d = drift_search(&camera, image.as_raw(), &tile, &served.pose(), &thresholds)?;
        let (c3, w3) = (cpu_s(), Instant::now());
        println!(
            "{run:>3}  {:.3}/{:.3}  {:.3}/{:.3}  {:.3}/{:.3}  {:.3}/{:.3}  moved={} shift={:.4} m yaw={:.4}°",
            c1 - c0,
            (w1 - w0).as_secs_f64(),
            c2 - c1,
            (w2 - w1).as_secs_f64(),
            c3 - c2,
            (w3 - w2).as_secs_f64(),
            c3 - c0,
            (w3 - w0).as_secs_f64(),
            d.verdict.moved,
            d.verdict.shift_m,
            d.verdict.yaw_deg,
        );
    }
    let (camera, image) = camera_and_frame(&cfg, cfg_path, &Overrides::default(), &|_| {})?;
    let tile = load_tile(&cfg.map.tiles.join(&served.tile_id))?;
    let pose = served.pose();
    let all_points = mi_points(&tile, &pose, &Params::default());
    let g = tile.reflectivity.grid;
    let drift = DriftParams::default();
    let on_grid = |v: f64| (v.round() as i64).rem_euclid(drift.thin) == 0;
    let points: Vec<_> = all_points
        .iter()
        .filter(|p| {
            let (c, r) = g.to_pixel(p.x, p.y);
            on_grid(c) && on_grid(r)
        })
        .copied()
        .collect();
    let search_cfg = SearchConfig {
        spec: DRIFT_SPEC,
        coarse_min_points: drift.coarse_min_points,
        ..SearchConfig::default()
    };
    let qcfg = QualityConfig::default();
    let c0 = cpu_s();
    let mask = camera.valid_mask();
    let c1 = cpu_s();
    let views = [View {
        gray: image.as_raw(),
        mask: &mask,
        points: &points,
    }];
    let ev = Evaluator::pooled(&camera, &views, &pose, &search_cfg, MAX_LEVEL)?;
    let c2 = cpu_s();
    let res = search(&ev, &search_cfg);
    let c3 = cpu_s();
    let q = assess(&ev, &res, &qcfg);
    let c4 = cpu_s();
    println!(
        "stages (CPU s): mask {:.3}, evaluator {:.3}, search {:.3} ({} poses, {:.3e} point-evaluations), \
         assess {:.3} ({} poses); {} of {} tile points, {} in the fixed set; accepted {}",
        c1 - c0,
        c2 - c1,
        c3 - c2,
        res.stats.poses,
        res.stats.point_evaluations as f64,
        c4 - c3,
        q.poses,
        points.len(),
        all_points.len(),
        ev.n_points,
        q.grid_refusal().is_none(),
    );
    Ok(())
}
