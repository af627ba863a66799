//! Accuracy of the whole pipeline on seeded simulated scenes (issue 4's acceptance).
//!
//! ```sh
//! cargo run --release --features __internal-test --example pipeline_accuracy -- --preset small --seeds 1..100 --json out.json
//! ```
//!
//! For each seed it generates the scene `infraloc simulate --seed N` writes (hard, Mei lens,
//! 5 frames unless told otherwise), hands the localizer the same inputs `infraloc localize` reads
//! from that scene directory (camera through its YAML, the temporal median of the frames, the
//! tile through the GeoTIFF cache in a temporary directory, the prior from the NMEA log with the
//! default `[gps]` settings), runs `localize_ungated` (`infraloc::__internal`) with the default parameters and
//! applies [`pipeline::quality_gate`] — exactly `localize`, except that a run the gate rejects
//! still shows its stages — and scores each stage with [`truth_eval::truth_errors`], the function
//! behind `infraloc localize --truth`. A failing seed is reproduced with
//! `infraloc simulate --seed N --preset P --out DIR` and `infraloc localize --config DIR/infraloc.toml`.
//!
//! `--top-k N` and `--no-early-stop` change the initializer's candidate list for before/after
//! comparisons on the same seeds; `--no-verify` turns off the LiDAR-MI verification of the
//! initializer's hypotheses (the satellite-only initializer before it). The JSON (per-seed records and the summary) is rewritten after
//! every seed, so an interrupted run keeps what it measured.
//!
//! `--offset-intrinsics` generates `hard` scenes with `simulate --given-intrinsics offset` (a
//! drawn intrinsics offset, what `hard` was before the calibrator) instead of the default
//! calibrated intrinsics.

use infraloc::eval::truth_eval;
use infraloc::localize::frame::{Frame, MapLayers};
use infraloc::localize::init::SearchArea;
use infraloc::localize::pipeline::{self, Params, PnpDetail, PriorDetail, StageDetail};
use infraloc::pose::CamFromMap;
use infraloc::sim::{self, Difficulty, GivenIntrinsics, Lens, Preset, Settings};
use infraloc::stage::StageName;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{gap_free_image, parse_preset, scene_inputs, scene_truth, SceneInputs};

/// Initialization inside the MI search basin (issue 4): horizontal and yaw error bounds.
const BASIN_M: f64 = 1.0;
const BASIN_DEG: f64 = 5.0;
/// Final pose "within": horizontal and height, metres; yaw, degrees (as `infraloc demo`).
const WITHIN_M: f64 = 0.10;
const WITHIN_DEG: f64 = 0.2;

struct Opts {
    preset: Preset,
    difficulty: Difficulty,
    seeds: Vec<u64>,
    frames: u32,
    json: Option<PathBuf>,
    threads: Option<usize>,
    top_k: Option<usize>,
    no_early_stop: bool,
    no_verify: bool,
    init_only: bool,
    mi_off_nadir: Option<f64>,
    true_intrinsics: bool,
    offset_intrinsics: bool,
    search_rounds: Option<usize>,
    fine_off_nadir: Option<f64>,
    gap_free: bool,
}

fn usage() -> ! {
    eprintln!(
        "usage: pipeline_accuracy [--preset small|5mp] [--difficulty hard|easy] --seeds A..B|A,B,C \
         [--frames N] [--json OUT] [--threads N] [--top-k N] [--no-early-stop] [--no-verify] [--init-only]\n  \
         [--mi-off-nadir DEG] [--true-intrinsics] [--offset-intrinsics] [--search-rounds N] [--fine-off-nadir DEG]\n  \
         [--gap-free]\n  \
         A..B is inclusive: 1..100 is 100 seeds"
    );
    std::process::exit(2)
}

fn parse_seeds(s: &str) -> Option<Vec<u64>> {
    if let Some((a, b)) = s.split_once("..") {
        let (a, b): (u64, u64) = (a.parse().ok()?, b.trim_start_matches('=').parse().ok()?);
        return (a <= b).then(|| (a..=b).collect());
    }
    s.split(',').map(|t| t.trim().parse().ok()).collect()
}

fn opts() -> Opts {
    let mut o = Opts {
        preset: Preset::Small,
        difficulty: Difficulty::Hard,
        seeds: Vec::new(),
        frames: 5,
        json: None,
        threads: None,
        top_k: None,
        no_early_stop: false,
        no_verify: false,
        init_only: false,
        mi_off_nadir: None,
        true_intrinsics: false,
        offset_intrinsics: false,
        search_rounds: None,
        fine_off_nadir: None,
        gap_free: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut val = || it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--preset" => o.preset = parse_preset(&val()).unwrap_or_else(|| usage()),
            "--difficulty" => {
                o.difficulty = match val().as_str() {
                    "hard" => Difficulty::Hard,
                    "easy" => Difficulty::Easy,
                    _ => usage(),
                }
            }
            "--seeds" => o.seeds = parse_seeds(&val()).unwrap_or_else(|| usage()),
            "--frames" => o.frames = val().parse().unwrap_or_else(|_| usage()),
            "--json" => o.json = Some(PathBuf::from(val())),
            "--threads" => o.threads = Some(val().parse().unwrap_or_else(|_| usage())),
            "--top-k" => o.top_k = Some(val().parse().unwrap_or_else(|_| usage())),
            "--no-early-stop" => o.no_early_stop = true,
            "--no-verify" => o.no_verify = true,
            "--init-only" => o.init_only = true,
            "--true-intrinsics" => o.true_intrinsics = true,
            "--offset-intrinsics" => o.offset_intrinsics = true,
            "--fine-off-nadir" => {
                o.fine_off_nadir = Some(val().parse().unwrap_or_else(|_| usage()))
            }
            "--search-rounds" => o.search_rounds = Some(val().parse().unwrap_or_else(|_| usage())),
            "--mi-off-nadir" => o.mi_off_nadir = Some(val().parse().unwrap_or_else(|_| usage())),
            "--gap-free" => o.gap_free = true,
            _ => usage(),
        }
    }
    if o.seeds.is_empty() {
        usage()
    }
    o
}

/// The scene settings of `seed` under the options.
fn settings(o: &Opts, seed: u64) -> Settings {
    Settings {
        seed,
        preset: o.preset,
        difficulty: o.difficulty,
        lens: Lens::Mei,
        frames: o.frames,
        intrinsics: if o.offset_intrinsics {
            GivenIntrinsics::Offset
        } else {
            GivenIntrinsics::Calibrated
        },
        times: 1,
        low_sun: false,
    }
}

/// A pose as the record's `poses` hold it: `[x, y, z, yaw, pitch, roll]` (map metres, degrees).
fn pose_record(pose: &CamFromMap) -> Value {
    let (y, p, r) = pose.yaw_pitch_roll();
    json!([
        pose.center().x,
        pose.center().y,
        pose.center().z,
        y.to_degrees(),
        p.to_degrees(),
        r.to_degrees()
    ])
}

/// One seed: simulate, localize as `infraloc localize` does, score against truth.
fn run_seed(o: &Opts, seed: u64, params: &Params) -> infraloc::Result<Value> {
    let t0 = Instant::now();
    let scene = sim::generate(&settings(o, seed))?;
    let sim_s = t0.elapsed().as_secs_f64();
    // The scene directory's files `localize` reads, read back as it reads them (the frames are
    // PNG, lossless: kept in memory). `--true-intrinsics`: hand the localizer the camera's true
    // intrinsics (in `hard` it gets deliberately wrong ones), to separate the intrinsics' bias
    // from the method's.
    let t1 = Instant::now();
    let SceneInputs {
        camera,
        mut image,
        tile,
        prior_xy: xy,
        prior_sigma_m: sigma,
        dir: tmp,
    } = scene_inputs(&scene, o.true_intrinsics)?;
    let dir = tmp.path();
    // `--gap-free`: the frame is the tile's reflectivity seen at the true pose through the
    // given camera (docs/accuracy.md, "Where the ground error comes from").
    if o.gap_free {
        let truth = scene_truth(&scene)?;
        let gray = gap_free_image(&camera, &tile, &truth.pose);
        image = image::GrayImage::from_raw(image.width(), image.height(), gray)
            .ok_or_else(|| infraloc::Error::Invalid("gap-free image size".into()))?;
    }
    // The given intrinsics' stated uncertainty reaches the covariance, as camera.yaml's does.
    let mut params = params.clone();
    if !o.true_intrinsics {
        params.quality.intrinsics_sigma = scene.camera_sigma;
    }
    let params = &params;
    let inputs_s = t1.elapsed().as_secs_f64();
    let clock = Instant::now();
    if o.init_only {
        return init_only(
            &scene,
            &Frame::new(&camera, image.as_raw())?,
            &tile,
            xy,
            sigma,
            params,
            sim_s,
        );
    }
    let now = || clock.elapsed().as_secs_f64();
    let outcome = infraloc::__internal::localize_ungated(
        &Frame::new(&camera, image.as_raw())?,
        &tile,
        xy,
        sigma,
        params,
        &now,
        &|_| {},
    );
    let acq = &scene.acquisition;
    let mut rec = json!({
        "seed": seed,
        "scene": {
            "camera_height_m": acq.camera_height_above_ground_m,
            "approaches": acq.approaches,
            "overcast": acq.camera_overcast,
            "traffic": acq.traffic_vehicles_pedestrians,
            "gps_sigma_bias_noise_m": acq.gps_sigma_bias_noise_m,
            "prior_sigma_m": sigma,
        },
        "seconds": { "simulate": sim_s, "inputs": inputs_s },
    });
    let truth_text = serde_json::to_string(&scene.truth_json())
        .map_err(|e| infraloc::Error::Invalid(format!("truth: {e}")))?;
    let truth_path = dir.join("truth.json");
    match outcome {
        Err(e) => {
            rec["failure"] = json!(e.to_string());
            // The prior alone can still be scored.
            let prior_stage = pipeline::Stage {
                name: StageName::Prior,
                pose: None,
                seconds: 0.0,
                detail: StageDetail::Prior(PriorDetail::new(xy, sigma, params)),
            };
            rec["errors"] =
                truth_eval::truth_errors(&truth_text, &truth_path, &camera, &[prior_stage])?;
        }
        Ok(out) => {
            if let Err(e) = pipeline::quality_gate(&out) {
                rec["failure"] = json!(e.to_string());
            }
            // The oracle: the 6-DoF least-squares fit of the truth's control points under the
            // given (in `hard`, wrong) intrinsics — the best pose these intrinsics allow.
            let stages = out.stages.clone();
            let truth = infraloc::eval::truth::parse_truth(&truth_text, &truth_path)?;
            let floor = truth_eval::oracle_pose(&camera, &truth);
            rec["errors"] = truth_eval::truth_errors(&truth_text, &truth_path, &camera, &stages)?;
            // Every control point's ground error, for figures pooled over all scenes.
            let hits = |p: &CamFromMap| -> Vec<[f64; 2]> {
                truth_eval::ground_hits(&camera, &truth, p)
                    .iter()
                    .map(|h| [h.range_m, h.error_m])
                    .collect()
            };
            rec["ground_hits"]["mi"] = json!(hits(&out.pose));
            if let Some(f) = &floor {
                rec["ground_hits"]["oracle"] = json!(hits(f));
            }
            // The MI objective at each stage's pose and at the oracle, on one point set: whether
            // a miss is the search's (the oracle scores higher) or the objective's (it doesn't).
            let pts = pipeline::mi_points(&tile, &out.pose, params);
            let mask = infraloc::camera::CameraModel::valid_mask(&camera);
            let named = stages
                .iter()
                .filter_map(|st| Some((st.name.name(), st.pose?)))
                .chain(floor.map(|f| ("oracle", f)));
            for (name, pose) in named {
                {
                    let pose = &pose;
                    rec["objective"][name] = json!(objective_at(
                        &camera,
                        image.as_raw(),
                        &mask,
                        &pts,
                        pose,
                        params
                    ));
                    rec["poses"][name] = pose_record(pose);
                }
            }
            rec["seconds"]["init"] = json!(out.stages[1].seconds);
            rec["seconds"]["mi"] = json!(out.stages[2].seconds);
            rec["seconds"]["localize"] =
                json!(inputs_s + out.stages[2].seconds + out.stages[1].seconds);
            rec["init"] = json!(out.stages[1].detail);
            if let StageDetail::Mi(d) = &out.stages[2].detail {
                rec["rounds"] = json!(d.rounds);
                if let Some(h) = &d.other_hypothesis {
                    rec["other_hypothesis"] = json!(h);
                }
            }
            rec["mi_quality"] =
                serde_json::to_value(&out.refinement.quality).unwrap_or(Value::Null);
        }
    }
    Ok(rec)
}

/// `--init-only`: the pipeline's initialization step alone (same search radius, seed and
/// parameters), scored like the full run; for comparing initializer variants cheaply.
fn init_only(
    scene: &sim::Scene,
    frame: &Frame<'_>,
    tile: &infraloc::map::Tile,
    xy: (f64, f64),
    sigma: f64,
    p: &Params,
    sim_s: f64,
) -> infraloc::Result<Value> {
    let (camera, image) = (frame.camera(), frame.gray());
    use rand::SeedableRng;
    let t = Instant::now();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed);
    // As the pipeline does: the LiDAR map verifies the hypotheses.
    let verifier = p.fine.verify.enabled.then(|| {
        infraloc::localize::init::verify::MiVerifier::new(
            camera,
            image,
            tile,
            p.fine.verify.mi.clone(),
        )
        .for_search_area(xy, p.search_radius_m(sigma))
    });
    let init = infraloc::localize::init::initialize(
        frame,
        MapLayers {
            satellite: tile
                .satellite
                .as_ref()
                .expect("the tile has a satellite layer"),
            heights: &tile.height,
        },
        SearchArea {
            center: xy,
            radius_m: p.search_radius_m(sigma),
        },
        &p.coarse,
        &p.fine,
        verifier.as_ref(),
        &mut rng,
    );
    let secs = t.elapsed().as_secs_f64();
    let truth_text = serde_json::to_string(&scene.truth_json())
        .map_err(|e| infraloc::Error::Invalid(format!("truth: {e}")))?;
    let prior = pipeline::Stage {
        name: StageName::Prior,
        pose: None,
        seconds: 0.0,
        detail: StageDetail::Prior(PriorDetail::new(xy, sigma, p)),
    };
    let mut rec =
        json!({ "seed": scene.settings.seed, "seconds": { "simulate": sim_s, "init": secs } });
    let stages = match init {
        Ok(r) => {
            rec["init"] = json!(PnpDetail::new(
                &r,
                "dense-sweep",
                p.quality.orthophoto_sigma_m
            ));
            vec![
                prior,
                pipeline::Stage {
                    name: StageName::Pnp,
                    pose: Some(r.pose),
                    seconds: secs,
                    detail: StageDetail::Pnp(PnpDetail::new(
                        &r,
                        "dense-sweep",
                        p.quality.orthophoto_sigma_m,
                    )),
                },
            ]
        }
        Err(e) => {
            rec["failure"] = json!(e.to_string());
            vec![prior]
        }
    };
    rec["errors"] = truth_eval::truth_errors(
        &truth_text,
        std::path::Path::new("truth.json"),
        camera,
        &stages,
    )?;
    Ok(rec)
}

fn f(v: &Value, stage: &str, key: &str) -> Option<f64> {
    v["errors"][stage][key].as_f64().filter(|x| x.is_finite())
}

/// Median, 95th percentile (nearest rank) and maximum.
fn stats(mut xs: Vec<f64>) -> Option<[f64; 3]> {
    if xs.is_empty() {
        return None;
    }
    xs.sort_by(f64::total_cmp);
    let n = xs.len();
    let med = if n % 2 == 1 {
        xs[n / 2]
    } else {
        0.5 * (xs[n / 2 - 1] + xs[n / 2])
    };
    let p95 = xs[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1];
    Some([med, p95, xs[n - 1]])
}

fn in_basin(r: &Value) -> bool {
    f(r, "pnp", "horizontal_m").is_some_and(|x| x <= BASIN_M)
        && f(r, "pnp", "yaw_deg").is_some_and(|x| x <= BASIN_DEG)
}

fn final_within(r: &Value) -> bool {
    r.get("failure").is_none()
        && f(r, "mi", "horizontal_m").is_some_and(|x| x <= WITHIN_M)
        && f(r, "mi", "height_m").is_some_and(|x| x <= WITHIN_M)
        && f(r, "mi", "yaw_deg").is_some_and(|x| x <= WITHIN_DEG)
}

fn summary(recs: &[Value]) -> Value {
    let n = recs.len();
    let mut s = json!({ "seeds": n });
    for stage in ["prior", "pnp", "mi", "oracle"] {
        for key in [
            "horizontal_m",
            "height_m",
            "yaw_deg",
            "rotation_deg",
            "control_points_mean_px",
        ] {
            let xs: Vec<f64> = recs.iter().filter_map(|r| f(r, stage, key)).collect();
            if let Some([m, p, x]) = stats(xs.clone()) {
                s[stage][key] = json!({ "median": m, "p95": p, "max": x, "n": xs.len(),
                    "mean": xs.iter().sum::<f64>() / xs.len() as f64 });
            }
        }
    }
    for key in ["init", "mi", "localize", "simulate"] {
        let xs: Vec<f64> = recs
            .iter()
            .filter_map(|r| r["seconds"][key].as_f64())
            .collect();
        if let Some([m, p, x]) = stats(xs) {
            s["seconds"][key] = json!({ "median": m, "p95": p, "max": x });
        }
    }
    s["vs_oracle"] = vs_oracle(recs);
    s["ground"] = pooled_ground(recs);
    s["coverage"] = coverage(recs);
    let count = |p: &dyn Fn(&Value) -> bool| recs.iter().filter(|r| p(r)).count();
    s["init_in_basin"] = json!(count(&in_basin));
    s["final_within"] = json!(count(&final_within));
    s["failures"] = recs
        .iter()
        .filter_map(|r| Some(json!({ "seed": r["seed"], "reason": r.get("failure")? })))
        .collect();
    s
}

fn print_summary(s: &Value) {
    let n = s["seeds"].as_u64().unwrap_or(0);
    println!(
        "\n{:<6} {:<22} {:>10} {:>10} {:>10} {:>5}",
        "stage", "error", "median", "p95", "max", "n"
    );
    for stage in ["prior", "pnp", "mi", "oracle"] {
        for key in [
            "horizontal_m",
            "height_m",
            "yaw_deg",
            "control_points_mean_px",
        ] {
            let v = &s[stage][key];
            if v.is_null() {
                continue;
            }
            let g = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
            println!(
                "{:<6} {:<22} {:>10.4} {:>10.4} {:>10.4} {:>5}",
                stage,
                key,
                g("median"),
                g("p95"),
                g("max"),
                v["n"]
            );
        }
    }
    for key in ["init", "mi", "localize"] {
        let v = &s["seconds"][key];
        if !v.is_null() {
            println!(
                "seconds {:<9} median {:.2}  p95 {:.2}  max {:.2}",
                key,
                v["median"].as_f64().unwrap_or(f64::NAN),
                v["p95"].as_f64().unwrap_or(f64::NAN),
                v["max"].as_f64().unwrap_or(f64::NAN)
            );
        }
    }
    let pct = |k: &str| {
        let c = s[k].as_u64().unwrap_or(0);
        format!("{c}/{n} ({:.1} %)", 100.0 * c as f64 / n.max(1) as f64)
    };
    println!(
        "init in basin (≤ {BASIN_M} m, ≤ {BASIN_DEG}°): {}",
        pct("init_in_basin")
    );
    println!(
        "final within {WITHIN_M} m horizontal and height, {WITHIN_DEG}° yaw, gate passed: {}",
        pct("final_within")
    );
    let g = |v: &Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    let vo = &s["vs_oracle"];
    println!(
        "mi vs oracle, median/p95: horizontal {:.2}/{:.2} cm, height {:.2}/{:.2} cm, yaw {:.4}/{:.4}°",
        100.0 * g(&vo["horizontal_m"], "median"),
        100.0 * g(&vo["horizontal_m"], "p95"),
        100.0 * g(&vo["height_m"], "median"),
        100.0 * g(&vo["height_m"], "p95"),
        g(&vo["yaw_deg"], "median"),
        g(&vo["yaw_deg"], "p95"),
    );
    for who in ["mi", "oracle"] {
        let gr = &s["ground"][who];
        let band = |i: usize| {
            let b = &gr["bands"][i]["error"];
            format!("{:.2}/{:.2}", 100.0 * g(b, "median"), 100.0 * g(b, "p95"))
        };
        println!(
            "ground error {who:<6} median/p95 cm: all {:.2}/{:.2} (n {}), 0–10 m {}, 10–20 m {}, 20–30 m {}",
            100.0 * g(&gr["all"], "median"),
            100.0 * g(&gr["all"], "p95"),
            gr["all"]["n"],
            band(0),
            band(1),
            band(2)
        );
    }
    for set in ["all", "accepted"] {
        for against in ["truth", "oracle"] {
            let c = &s["coverage"][set][against];
            let n = c["n"].as_u64().unwrap_or(0).max(1) as f64;
            let p = |k: &str| 100.0 * c[k].as_u64().unwrap_or(0) as f64 / n;
            println!(
                "3σ coverage ({set} results with σ, n {}) vs {against}: x {:.1} %, y {:.1} %, z {:.1} %, yaw {:.1} %, every axis {:.1} %",
                c["n"], p("x"), p("y"), p("z"), p("yaw"), p("every_axis")
            );
        }
    }
    for fl in s["failures"].as_array().into_iter().flatten() {
        println!("failure seed {}: {}", fl["seed"], fl["reason"]);
    }
}

/// The final pose against the oracle, over the seeds that have both: median and p95 of the
/// horizontal, height and yaw offsets (issue 15's first figure).
fn vs_oracle(recs: &[Value]) -> Value {
    let mut out = json!({});
    for key in ["horizontal_m", "height_m", "yaw_deg"] {
        let xs: Vec<f64> = recs
            .iter()
            .filter_map(|r| r["errors"]["mi"]["vs_oracle"][key].as_f64())
            .collect();
        out[key] = json!(truth_eval::median_p95(&xs));
    }
    out
}

/// Ground error pooled over every control point of every scene, for the final pose and the
/// oracle, overall and per distance band (issue 15's second figure).
fn pooled_ground(recs: &[Value]) -> Value {
    let mut out = json!({});
    for who in ["mi", "oracle"] {
        let hits: Vec<truth_eval::GroundHit> = recs
            .iter()
            .filter_map(|r| r["ground_hits"][who].as_array())
            .flatten()
            .filter_map(|h| {
                Some(truth_eval::GroundHit {
                    range_m: h[0].as_f64()?,
                    error_m: h[1].as_f64()?,
                })
            })
            .collect();
        out[who] = json!(truth_eval::ground_error(&hits));
    }
    out
}

/// How often the true error lies within 3σ of the reported marginal σ, per axis and on all four
/// at once: against the truth, and against the oracle (the reference when the given intrinsics
/// are wrong on purpose), over every result that carries a σ and over the accepted ones.
fn coverage(recs: &[Value]) -> Value {
    let mut out = json!({});
    for (set, accepted_only) in [("all", false), ("accepted", true)] {
        for (against, path) in [
            ("truth", &["signed"][..]),
            ("oracle", &["vs_oracle", "signed"][..]),
        ] {
            let mut n = 0usize;
            let mut hit = [0usize; 5];
            for r in recs {
                if accepted_only && r.get("failure").is_some() {
                    continue;
                }
                let sigma: Option<infraloc::localize::refine::quality::Sigma> =
                    serde_json::from_value(r["mi_quality"]["sigma"].clone()).ok();
                let mut e = &r["errors"]["mi"];
                for k in path {
                    e = &e[*k];
                }
                let err: Option<truth_eval::SignedError> = serde_json::from_value(e.clone()).ok();
                let (Some(sigma), Some(err)) = (sigma, err) else {
                    continue;
                };
                n += 1;
                let w = err.within(&sigma, 3.0, [0.0; 4]);
                for (i, ok) in w.iter().enumerate() {
                    hit[i] += usize::from(*ok);
                }
                hit[4] += usize::from(w.iter().all(|&b| b));
            }
            out[set][against] = json!({ "n": n, "x": hit[0], "y": hit[1], "z": hit[2],
                "yaw": hit[3], "every_axis": hit[4] });
        }
    }
    out
}

/// The search's objective (NMI by default) at `pose`, on the points visible from a 1-cell box.
fn objective_at(
    camera: &infraloc::camera::Camera,
    gray: &[u8],
    mask: &[u8],
    pts: &[infraloc::map::GroundPoint],
    pose: &CamFromMap,
    params: &Params,
) -> Option<f64> {
    use infraloc::localize::mi::objective::Evaluator;
    use infraloc::localize::mi::space::{AxisRange, SearchConfig, SearchSpec};
    let held = AxisRange {
        half: 0.0,
        step: 0.01,
    };
    let cfg = SearchConfig {
        spec: SearchSpec {
            x: AxisRange {
                half: 0.01,
                step: 0.01,
            },
            y: held,
            z: held,
            yaw: held,
            pitch: None,
            roll: None,
            tilt_pivot_m: None,
        },
        ..params.search
    };
    let ev = Evaluator::new(camera, gray, mask, pts, pose, &cfg, 0).ok()?;
    let centre = ev.grid().index(&[0; 6]);
    Some(ev.score(0, centre, &mut Default::default()).score)
}

fn main() {
    let o = opts();
    if let Some(n) = o.threads {
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global();
    }
    let mut params = Params::default();
    if let Some(k) = o.top_k {
        params.coarse.top_k = k;
    }
    if o.no_verify {
        params.fine.verify.enabled = false;
    }
    if o.no_early_stop {
        params.fine.convincing_inliers = None;
    }
    if let (Some(n), Some(ps)) = (o.search_rounds, params.polish.as_mut()) {
        ps.search_rounds = n;
    }
    if let Some(d) = o.fine_off_nadir {
        params.fine.max_off_nadir_deg = d;
    }
    if let Some(d) = o.mi_off_nadir {
        params.mi_max_off_nadir_deg = d;
    }
    println!(
        "{:>5} {:>9} {:>8} {:>8} {:>9} {:>8} {:>8} {:>8} {:>6} {:>7} {:>7}  note",
        "seed",
        "prior m",
        "pnp m",
        "pnp °",
        "mi m",
        "mi z m",
        "mi °",
        "mi px",
        "cand",
        "init s",
        "mi s"
    );
    let mut recs = Vec::new();
    for &seed in &o.seeds {
        let rec = run_seed(&o, seed, &params)
            .unwrap_or_else(|e| json!({ "seed": seed, "failure": format!("harness: {e}") }));
        let g = |st: &str, k: &str| f(&rec, st, k).unwrap_or(f64::NAN);
        println!(
            "{:>5} {:>9.2} {:>8.3} {:>8.3} {:>9.4} {:>8.4} {:>8.4} {:>8.2} {:>3}/{:<2} {:>7.1} {:>7.1}  {}",
            seed,
            g("prior", "horizontal_m"),
            g("pnp", "horizontal_m"),
            g("pnp", "yaw_deg"),
            g("mi", "horizontal_m"),
            g("mi", "height_m"),
            g("mi", "yaw_deg"),
            g("mi", "control_points_mean_px"),
            rec["init"]["candidate_rank"].as_u64().map_or(-1, |r| r as i64),
            rec["init"]["candidates"].as_u64().unwrap_or(0),
            rec["seconds"]["init"].as_f64().unwrap_or(f64::NAN),
            rec["seconds"]["mi"].as_f64().unwrap_or(f64::NAN),
            rec.get("failure").and_then(|v| v.as_str()).unwrap_or("")
        );
        recs.push(rec);
        if let Some(p) = &o.json {
            let doc = json!({
                "command": std::env::args().collect::<Vec<_>>().join(" "),
                "summary": summary(&recs),
                "seeds": recs,
            });
            let text = serde_json::to_string_pretty(&doc).unwrap_or_default();
            if let Err(e) = std::fs::write(p, text) {
                eprintln!("{}: {e}", p.display());
            }
        }
    }
    print_summary(&summary(&recs));
}
