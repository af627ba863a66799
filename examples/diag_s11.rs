//! Search failure or objective bias? The MI objective of the pipeline's polish at the accepted
//! pose, the truth, the oracle and along the straight 6-DoF lines between them, on one fixed
//! point set, for a scene whose answer was accepted outside its 3σ (the commands below run it on
//! `5mp` `hard` seed 11).
//!
//! ```sh
//! cargo run --release --features __internal-test --example pipeline_accuracy -- --preset 5mp --seeds 11 --json s11.json
//! cargo run --release --example diag_s11 -- --preset 5mp --seed 11 --json s11.json
//! ```
//!
//! The accepted (`mi`) and PnP poses are read from `pipeline_accuracy`'s per-seed record
//! (`poses`); the scene is generated again from the seed, and the inputs are read as
//! `pipeline_accuracy` reads them (camera through its YAML, the tile through the GeoTIFF cache,
//! the temporal median of the frames). The points are the pipeline's (`mi_points` around the PnP
//! pose). Three point sets:
//! - `polish`: the one the pipeline's polish would use centred on the accepted pose (visible from
//!   every lattice pose of its ±15 cm / ±0.5° / ±3° tilt box, tilting about the ground);
//! - `union`: visible from every lattice pose of a box centred on the accepted pose that holds
//!   the truth and the oracle (tilting about the camera centre);
//! - `all`: every point, no fixed set (what each pose sees).

use infraloc::camera::CameraModel;
use infraloc::eval::truth_eval;
use infraloc::localize::mi::kernel::Scratch;
use infraloc::localize::mi::mutual_information;
use infraloc::localize::mi::objective::{Evaluator, View};
use infraloc::localize::mi::space::{pose_at, AxisRange, SearchConfig, SearchSpec};
use infraloc::localize::pipeline::{self, Params};
use infraloc::localize::refine::polish::{polish_pose, PolishParams};
use infraloc::pose::{offsets_between, CamFromMap};
use infraloc::sim::{self, GivenIntrinsics, Preset};

#[path = "common/mod.rs"]
mod common;
use common::{
    hard_settings, parse_preset, polish_box, pose_of, scene_inputs, scene_truth, tilt_pivot,
    SceneInputs,
};

fn usage() -> ! {
    eprintln!(
        "usage: diag_s11 --json PIPELINE_ACCURACY.json [--preset small|5mp] [--seed N] \
         [--offset-intrinsics | --true-intrinsics]"
    );
    std::process::exit(2)
}

fn fmt_off(o: &[f64; 6]) -> String {
    format!(
        "dx {:+.3} dy {:+.3} dz {:+.3} m, dyaw {:+.3} dpitch {:+.3} droll {:+.3} deg",
        o[0], o[1], o[2], o[3], o[4], o[5]
    )
}

/// The command line.
struct Args {
    preset: Preset,
    seed: u64,
    json: String,
    given: GivenIntrinsics,
    true_intr: bool,
}

/// The command line, or the usage and exit 2.
fn args() -> Args {
    let (mut preset, mut seed, mut json, mut given, mut true_intr) = (
        Preset::FiveMp,
        11u64,
        None,
        GivenIntrinsics::Calibrated,
        false,
    );
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut val = || it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--preset" => preset = parse_preset(&val()).unwrap_or_else(|| usage()),
            "--seed" => seed = val().parse().unwrap_or_else(|_| usage()),
            "--json" => json = Some(val()),
            "--offset-intrinsics" => given = GivenIntrinsics::Offset,
            "--true-intrinsics" => true_intr = true,
            _ => usage(),
        }
    }
    let json = json.unwrap_or_else(|| usage());
    Args {
        preset,
        seed,
        json,
        given,
        true_intr,
    }
}

/// The accepted (MI) and PnP poses of `seed`'s record in a `pipeline_accuracy` JSON file.
fn seed_poses(json: &str, seed: u64) -> infraloc::Result<(CamFromMap, CamFromMap)> {
    let doc: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(json).map_err(|e| infraloc::Error::io(json, e))?,
    )
    .map_err(|e| infraloc::Error::Invalid(format!("{json}: {e}")))?;
    let rec = doc["seeds"]
        .as_array()
        .and_then(|s| s.iter().find(|r| r["seed"].as_u64() == Some(seed)))
        .unwrap_or_else(|| usage());
    let accepted = pose_of(&rec["poses"]["mi"]).expect("poses.mi");
    let pnp = pose_of(&rec["poses"]["pnp"]).expect("poses.pnp");
    Ok((accepted, pnp))
}

fn main() -> infraloc::Result<()> {
    let Args {
        preset,
        seed,
        json,
        given,
        true_intr,
    } = args();
    let (accepted, pnp) = seed_poses(&json, seed)?;

    let scene = sim::generate(&hard_settings(seed, preset, given))?;
    let SceneInputs {
        camera,
        image,
        tile,
        ..
    } = scene_inputs(&scene, true_intr)?;

    let truth = scene_truth(&scene)?;
    let oracle = truth_eval::oracle_pose(&camera, &truth).expect("oracle");
    let params = Params::default();
    let points = pipeline::mi_points(&tile, &pnp, &params);
    let mask = camera.valid_mask();
    let views = [View {
        gray: image.as_raw(),
        mask: &mask,
        points: &points,
    }];
    let ax = |half: f64| AxisRange {
        half,
        step: half / 2.0,
    };
    let off_t = offsets_between(&accepted, &truth.pose);
    let off_o = offsets_between(&accepted, &oracle);
    // pose_at(from, offsets_between(from, to)) must give `to` (the line below relies on it).
    let back = pose_at(&accepted, &off_t);
    let back_err = (back.center() - truth.pose.center()).norm()
        + infraloc::pose::rotation_angle_between(&back.rotation, &truth.pose.rotation);
    println!(
        "seed {seed}: {} points (mi_points around PnP); pose_at round trip error {back_err:.1e}",
        points.len()
    );
    println!("truth  - accepted: {}", fmt_off(&off_t));
    println!("oracle - accepted: {}", fmt_off(&off_o));
    println!(
        "pnp    - accepted: {}",
        fmt_off(&offsets_between(&accepted, &pnp))
    );

    let pp = PolishParams::default();
    let polish_cfg = polish_box(&pp, &params.search, tilt_pivot(&tile, &accepted));
    let half = |i: usize| {
        off_t[i].abs().max(off_o[i].abs()) * 1.1 + [0.01, 0.01, 0.01, 0.02, 0.02, 0.02][i]
    };
    let union_cfg = SearchConfig {
        spec: SearchSpec {
            x: ax(half(0)),
            y: ax(half(1)),
            z: ax(half(2)),
            yaw: ax(half(3)),
            pitch: Some(ax(half(4))),
            roll: Some(ax(half(5))),
            tilt_pivot_m: None,
        },
        ..params.search
    };
    let all_cfg = SearchConfig {
        fixed_point_set: false,
        ..polish_cfg
    };
    let sets = [
        (
            "polish",
            Evaluator::pooled(&camera, &views, &accepted, &polish_cfg, 0)?,
        ),
        (
            "union",
            Evaluator::pooled(&camera, &views, &accepted, &union_cfg, 0)?,
        ),
        (
            "all",
            Evaluator::pooled(&camera, &views, &accepted, &all_cfg, 0)?,
        ),
    ];
    let mut scratch = Scratch::default();
    let mut score = |ev: &Evaluator, p: &CamFromMap| {
        let h = ev.histogram_at(0, p, &mut scratch);
        let lost: u64 = (0..h.rows)
            .map(|r| h.counts[r * h.stride() + h.cols] as u64)
            .sum();
        (mutual_information(&h, true).mi, lost)
    };
    for (name, ev) in &sets {
        println!("\npoint set `{name}`: {} points", ev.n_points);
        for (label, p) in [
            ("accepted", accepted),
            ("truth", truth.pose),
            ("oracle", oracle),
            ("pnp", pnp),
        ] {
            let (v, lost) = score(ev, &p);
            println!("  {label:9} MI {v:.5}  (lost {lost})");
        }
        for (target, off) in [("truth", off_t), ("oracle", off_o)] {
            println!("  line accepted -> {target} (t = 0 accepted, 1 {target}):");
            for k in 0..=10 {
                let t = k as f64 / 10.0;
                let p = pose_at(&accepted, &off.map(|v| v * t));
                let (v, lost) = score(ev, &p);
                println!("    t {t:.1}  MI {v:.5}  (lost {lost})");
            }
        }
    }

    // The local optimum near the truth and near the accepted pose: the pipeline's polish (five
    // tilt starts, its own point set) from each, scored on the `union` set as well.
    println!("\npolish (default params, 5 tilt starts) from each pose:");
    for (label, p) in [
        ("accepted", accepted),
        ("truth", truth.pose),
        ("oracle", oracle),
    ] {
        let (end, rec) = polish_pose(
            &camera,
            &views,
            &p,
            tilt_pivot(&tile, &p),
            &params.search,
            &pp,
        )?;
        let e = offsets_between(&truth.pose, &end);
        let (vu, _) = score(&sets[1].1, &end);
        println!(
            "  from {label:9}: own set MI {:.5} -> {:.5} ({} evals); end - truth: {}; union-set MI {vu:.5}",
            rec.start_value,
            rec.value,
            rec.evaluations,
            fmt_off(&e)
        );
    }
    Ok(())
}
