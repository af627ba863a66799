//! Objective or search: where does the ground error come from? Over many seeds, the pipeline's
//! accepted pose, the oracle (the least-squares pose of the truth's control points under the given
//! intrinsics) and a single-start polish from the oracle, all scored by the pipeline's polish MI
//! on one fixed point set and by the ground error of the control points.
//!
//! ```sh
//! cargo run --release --features __internal-test --example pipeline_accuracy -- --preset small --seeds 1..30 --json s.json
//! cargo run --release --example diag_ground -- --preset small --json s.json
//! ```
//!
//! If the polish from the oracle stays near the oracle and outscores the accepted pose, the
//! accepted pose is a search failure; if it walks off as far as the accepted pose is, the
//! objective's optimum itself is that far from the truth (estimator-limited).
//!
//! The same question for the smooth estimator (partial-volume sampling, `--sampling pv`): its
//! L-BFGS ascent (4-DoF, tilt held) from the oracle and from the accepted pose, and a 6-DoF
//! ascent from the accepted pose, on the same point set; their ground errors and PV objective
//! values beside the others'.
//!
//! And whether an offset is the estimator's or the simulator's modality gap: a gap-free image,
//! each pixel the tile's reflectivity (bilinear) where the pixel's ray meets the height layer at
//! the true pose through the given camera, so the image and the LiDAR raster agree exactly at
//! the truth. The PV ascent and the nearest-pixel polish start at the truth on it; how far they
//! walk is the estimator's own offset.

use infraloc::camera::Camera;
use infraloc::camera::CameraModel;
use infraloc::eval::truth_eval;
use infraloc::localize::mi::kernel::Scratch;
use infraloc::localize::mi::mutual_information;
use infraloc::localize::mi::objective::{Evaluator, View};
use infraloc::localize::mi::smooth::{Pooling, Smooth};
use infraloc::localize::pipeline::{self, Params};
use infraloc::localize::refine::ascent::{ascend, AscentConfig};
use infraloc::localize::refine::polish::{polish_pose, PolishParams};
use infraloc::map::Tile;
use infraloc::pose::CamFromMap;
use infraloc::sim::{self, GivenIntrinsics, Preset};

#[path = "common/mod.rs"]
mod common;
use common::{
    gap_free_image, hard_settings, parse_preset, polish_box, pose_of, scene_inputs, scene_truth,
    tilt_pivot, SceneInputs,
};

fn usage() -> ! {
    eprintln!("usage: diag_ground --json PIPELINE_ACCURACY.json [--preset small|5mp]");
    std::process::exit(2)
}

/// One seed's scores: ground error medians (cm) and polish MI of the accepted pose, the oracle
/// and the polish from the oracle.
struct Row {
    ground: [f64; 3],
    mi: [f64; 3],
    /// Ground error medians (cm) of the PV ascents: from the oracle, from the accepted pose
    /// (4-DoF) and from the accepted pose (6-DoF).
    pv_ground: [f64; 3],
    /// PV value at the oracle and at the end of the ascent from it.
    pv: [f64; 2],
    /// Gap-free image: PV ascent's drift from the truth (cm, horizontal) and the nearest-pixel
    /// polish's.
    gap_free: [f64; 2],
}

fn main() -> infraloc::Result<()> {
    let (mut preset, mut json) = (Preset::Small, None);
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut val = || it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--preset" => preset = parse_preset(&val()).unwrap_or_else(|| usage()),
            "--json" => json = Some(val()),
            _ => usage(),
        }
    }
    let json = json.unwrap_or_else(|| usage());
    let doc: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&json).map_err(|e| infraloc::Error::io(&json, e))?,
    )
    .map_err(|e| infraloc::Error::Invalid(format!("{json}: {e}")))?;
    let params = Params::default();
    let pp = PolishParams {
        tilt_starts_deg: 0.0,
        ..PolishParams::default()
    };
    println!(
        "seed  ground median cm: accepted oracle from-oracle | MI: accepted oracle from-oracle | from-oracle - oracle: dxy cm, tilt deg"
    );
    let mut rows = Vec::new();
    for rec in doc["seeds"].as_array().unwrap_or_else(|| usage()) {
        let seed = rec["seed"].as_u64().unwrap_or_else(|| usage());
        let (Some(accepted), Some(pnp)) =
            (pose_of(&rec["poses"]["mi"]), pose_of(&rec["poses"]["pnp"]))
        else {
            continue;
        };
        let scene = sim::generate(&hard_settings(seed, preset, GivenIntrinsics::Calibrated))?;
        let SceneInputs {
            camera,
            image,
            tile,
            ..
        } = scene_inputs(&scene, false)?;
        let truth = scene_truth(&scene)?;
        let Some(oracle) = truth_eval::oracle_pose(&camera, &truth) else {
            continue;
        };
        let points = pipeline::mi_points(&tile, &pnp, &params);
        let mask = camera.valid_mask();
        let views = [View {
            gray: image.as_raw(),
            mask: &mask,
            points: &points,
        }];
        let cfg = polish_box(&pp, &params.search, tilt_pivot(&tile, &accepted));
        let ev = Evaluator::pooled(&camera, &views, &accepted, &cfg, 0)?;
        let mut scratch = Scratch::default();
        let mut score =
            |p: &CamFromMap| mutual_information(&ev.histogram_at(0, p, &mut scratch), true).mi;
        let (end, _) = polish_pose(
            &camera,
            &views,
            &oracle,
            tilt_pivot(&tile, &oracle),
            &params.search,
            &pp,
        )?;
        let g = |p: &CamFromMap| {
            truth_eval::ground_error(&truth_eval::ground_hits(&camera, &truth, p))
                .all
                .map_or(f64::NAN, |q| q.median * 100.0)
        };
        let (ga, go, ge) = (g(&accepted), g(&oracle), g(&end));
        let est = Smooth::of_evaluator(&camera, &ev, Pooling::Joint);
        let four = AscentConfig::four_dof();
        let pv_oracle = ascend(&est, &oracle, &four);
        let pv_acc = ascend(&est, &accepted, &four);
        let pv_acc6 = ascend(&est, &accepted, &AscentConfig::six_dof());
        let pv_ground = [g(&pv_oracle.pose), g(&pv_acc.pose), g(&pv_acc6.pose)];
        let pv = [est.evaluate(&oracle, false).value, pv_oracle.value];
        let drift = (pv_oracle.pose.center() - oracle.center()).norm() * 100.0;
        println!(
            "      pv ground cm: from-oracle {:.2} from-accepted {:.2} 6dof {:.2} | pv oracle {:.5} end {:.5} | drift {drift:.2} cm ({} , {} evals)",
            pv_ground[0], pv_ground[1], pv_ground[2], pv[0], pv[1], pv_oracle.stop, pv_oracle.evaluations
        );
        let (ma, mo, me) = (score(&accepted), score(&oracle), score(&end));
        let dxy = (end.center() - oracle.center()).xy().norm() * 100.0;
        let tilt =
            infraloc::pose::rotation_angle_between(&end.rotation, &oracle.rotation).to_degrees();
        let shift = |p: &CamFromMap| {
            let (mut su, mut sv, mut sr, mut n) = (0.0, 0.0, 0.0, 0.0);
            let (cx, cy) = (camera.width() as f64 / 2.0, camera.height() as f64 / 2.0);
            for cp in &truth.control_points {
                let pc = p.rotation * nalgebra::Vector3::new(cp.map[0], cp.map[1], cp.map[2])
                    + p.translation;
                if let Ok(px) = camera.project(&pc) {
                    let (du, dv) = (px.x - cp.pixel[0], px.y - cp.pixel[1]);
                    let (rx, ry) = (cp.pixel[0] - cx, cp.pixel[1] - cy);
                    let rn = rx.hypot(ry).max(1e-9);
                    su += du;
                    sv += dv;
                    sr += (du * rx + dv * ry) / rn;
                    n += 1.0;
                }
            }
            format!("{:+.3} {:+.3} r{:+.3}", su / n, sv / n, sr / n)
        };
        println!(
            "      px shift accepted {} from-oracle {} oracle {}",
            shift(&accepted),
            shift(&end),
            shift(&oracle)
        );
        println!(
            "{seed:4}  {ga:6.2} {go:6.2} {ge:6.2} | {ma:.5} {mo:.5} {me:.5} | {dxy:5.2} {tilt:.4}"
        );
        let gap_free = gap_free_drift(&camera, &tile, &truth.pose, &points, &params, &pp)?;
        println!(
            "      gap-free image, drift from the truth: pv {:.2} cm, nearest polish {:.2} cm",
            gap_free[0], gap_free[1]
        );
        rows.push(Row {
            ground: [ga, go, ge],
            mi: [ma, mo, me],
            pv_ground,
            pv,
            gap_free,
        });
    }
    summary(&rows);
    Ok(())
}

/// The medians over the seeds.
fn summary(rows: &[Row]) {
    let n = rows.len();
    let med = |f: &dyn Fn(&Row) -> f64| {
        let mut v: Vec<f64> = rows.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.get(n / 2).copied().unwrap_or(f64::NAN)
    };
    println!(
        "n {n}: median ground cm accepted {:.2}, oracle {:.2}, from-oracle {:.2}; oracle scores above accepted on {} seeds, from-oracle above accepted on {}",
        med(&|r| r.ground[0]),
        med(&|r| r.ground[1]),
        med(&|r| r.ground[2]),
        rows.iter().filter(|r| r.mi[1] > r.mi[0]).count(),
        rows.iter().filter(|r| r.mi[2] > r.mi[0]).count()
    );
    println!(
        "pv: median ground cm from-oracle {:.2}, from-accepted {:.2}, 6-DoF from-accepted {:.2}; the ascent from the oracle gains on {} of {n} seeds",
        med(&|r| r.pv_ground[0]),
        med(&|r| r.pv_ground[1]),
        med(&|r| r.pv_ground[2]),
        rows.iter().filter(|r| r.pv[1] > r.pv[0] + 1e-9).count()
    );
    println!(
        "gap-free image: median drift from the truth cm: pv {:.2}, nearest polish {:.2}",
        med(&|r| r.gap_free[0]),
        med(&|r| r.gap_free[1])
    );
}

/// On the gap-free image at the truth: the PV ascent's (4-DoF) and the nearest-pixel polish's
/// horizontal drift from the truth, cm.
fn gap_free_drift(
    camera: &Camera,
    tile: &Tile,
    truth: &CamFromMap,
    points: &[infraloc::map::GroundPoint],
    params: &Params,
    pp: &PolishParams,
) -> infraloc::Result<[f64; 2]> {
    let gray = gap_free_image(camera, tile, truth);
    let mask = camera.valid_mask();
    let views = [View {
        gray: &gray,
        mask: &mask,
        points,
    }];
    let cfg = polish_box(pp, &params.search, tilt_pivot(tile, truth));
    let ev = Evaluator::pooled(camera, &views, truth, &cfg, 0)?;
    let est = Smooth::of_evaluator(camera, &ev, Pooling::Joint);
    let a = ascend(&est, truth, &AscentConfig::four_dof());
    let (end, _) = polish_pose(
        camera,
        &views,
        truth,
        tilt_pivot(tile, truth),
        &params.search,
        pp,
    )?;
    let d = |p: &CamFromMap| (p.center() - truth.center()).xy().norm() * 100.0;
    Ok([d(&a.pose), d(&end)])
}
