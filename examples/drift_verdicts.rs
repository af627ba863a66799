//! The service's drift check judged on seeded simulated scenes: does it say "moved" exactly when
//! the camera moved past the thresholds, how far off is the optimum it reports, and what does it
//! cost — for the shipped thinning and for candidate ones, on the same inputs in the same run.
//!
//! ```sh
//! RAYON_NUM_THREADS=2 cargo run --release --features __internal-test --example drift_verdicts -- --preset small --seeds 1..20 \
//!     [--variant THIN:COARSE_MIN_POINTS ...]
//! ```
//!
//! For each seed it generates the `hard` scene `infraloc simulate --seed N` writes (calibrated
//! intrinsics), takes the temporal median of its frames and the tile through the GeoTIFF cache,
//! and localizes as `infraloc localize` does (gated). The served pose is that result. Then the
//! camera is "knocked": the served pose is moved away from where the frames say the camera is,
//! by a seeded amount per case (the camera moved; the served pose did not), and
//! [`drift_search_with`] runs for each variant:
//!
//! | case | knock | the check must say |
//! |---|---|---|
//! | steady | none | not moved |
//! | nudged | 0.04 m, random direction | not moved |
//! | twisted | 0.1° yaw, random sign | not moved |
//! | knocked | 0.2 m, random direction | moved |
//! | turned | 0.5° yaw, random sign | moved |
//! | struck | 0.35 m and 1.0° | moved |
//!
//! With the default thresholds (0.1 m, 0.3°). The optimum's error is taken against the
//! unknocked served pose (where the frames put the camera, as the full refinement found it).
//! CPU-seconds are the process's, around each `drift_search_with` call alone (the frames and the
//! tile are loaded once per seed; `examples/drift_cost.rs` times a whole check).
//! The first variant is the shipped one ([`DriftParams::default`]). Each line also shows the
//! optimum's NMI, and the steady line the localization's own NMI (on every cell), for the
//! cross-check's NMI comparison (docs/benchmarks.md "Drift check").

use infraloc::config::Config;
use infraloc::localize::frame::Frame;
use infraloc::localize::pipeline::{self, Params};
use infraloc::localize::refine::drift::{drift_search_with, DriftParams, DriftThresholds};
use infraloc::pose::{angle_difference, CamFromMap};
use infraloc::sim::{self, GivenIntrinsics, Preset};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{cpu_s, hard_settings, parse_preset, scene_inputs, SceneInputs};

/// One knock: horizontal move (m), yaw turn (deg), whether the check must say "moved".
struct Case {
    name: &'static str,
    shift_m: f64,
    yaw_deg: f64,
    moved: bool,
}

const CASES: [Case; 6] = [
    Case {
        name: "steady",
        shift_m: 0.0,
        yaw_deg: 0.0,
        moved: false,
    },
    Case {
        name: "nudged",
        shift_m: 0.04,
        yaw_deg: 0.0,
        moved: false,
    },
    Case {
        name: "twisted",
        shift_m: 0.0,
        yaw_deg: 0.1,
        moved: false,
    },
    Case {
        name: "knocked",
        shift_m: 0.2,
        yaw_deg: 0.0,
        moved: true,
    },
    Case {
        name: "turned",
        shift_m: 0.0,
        yaw_deg: 0.5,
        moved: true,
    },
    Case {
        name: "struck",
        shift_m: 0.35,
        yaw_deg: 1.0,
        moved: true,
    },
];

/// What one variant did over all seeds and cases.
#[derive(Default)]
struct Tally {
    right: usize,
    false_alarms: Vec<String>,
    misses: Vec<String>,
    horiz_err_m: Vec<f64>,
    yaw_err_deg: Vec<f64>,
    cpu_s: f64,
    wall_s: f64,
    checks: usize,
}

fn parse_seeds(s: &str) -> Result<Vec<u64>, String> {
    match s.split_once("..") {
        Some((a, b)) => {
            let a: u64 = a.parse().map_err(|_| format!("--seeds: bad start {a:?}"))?;
            let b: u64 = b.parse().map_err(|_| format!("--seeds: bad end {b:?}"))?;
            Ok((a..=b).collect())
        }
        None => s
            .split(',')
            .map(|v| v.parse().map_err(|_| format!("--seeds: bad seed {v:?}")))
            .collect(),
    }
}

fn parse_variant(s: &str) -> Result<DriftParams, String> {
    let (t, c) = s
        .split_once(':')
        .ok_or_else(|| format!("--variant {s:?}: want THIN:COARSE_MIN_POINTS"))?;
    Ok(DriftParams {
        thin: t
            .parse()
            .map_err(|_| format!("--variant: bad thin {t:?}"))?,
        coarse_min_points: c
            .parse()
            .map_err(|_| format!("--variant: bad coarse-min-points {c:?}"))?,
    })
}

fn median_max(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    (s[s.len() / 2], s[s.len() - 1])
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut preset = Preset::Small;
    let mut seeds: Vec<u64> = (1..=10).collect();
    let mut variants = vec![DriftParams::default()];
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--preset" => {
                let name = val()?;
                preset =
                    parse_preset(&name).ok_or_else(|| format!("--preset: unknown {name:?}"))?;
            }
            "--seeds" => seeds = parse_seeds(&val()?)?,
            "--variant" => variants.push(parse_variant(&val()?)?),
            other => return Err(format!("unknown argument {other:?}").into()),
        }
    }
    let cfg = Config::default();
    let mut tallies: Vec<Tally> = variants.iter().map(|_| Tally::default()).collect();
    for &seed in &seeds {
        let settings = hard_settings(seed, preset, GivenIntrinsics::Calibrated);
        let scene = sim::generate(&settings)?;
        let SceneInputs {
            camera,
            image,
            tile,
            prior_xy: xy,
            prior_sigma_m: sigma,
            dir: _dir,
        } = scene_inputs(&scene, false)?;
        let mut params = Params::default();
        params.quality.intrinsics_sigma = scene.camera_sigma;
        let clock = Instant::now();
        let now = || clock.elapsed().as_secs_f64();
        let (served, served_nmi) = match infraloc::__internal::localize_ungated(
            &Frame::new(&camera, image.as_raw())?,
            &tile,
            xy,
            sigma,
            &params,
            &now,
            &|_| {},
        )
        .and_then(|out| {
            pipeline::quality_gate(&out).map(|_| (out.pose, out.refinement.quality.nmi))
        }) {
            Ok(p) => p,
            Err(e) => {
                println!("seed {seed}: not localized, skipped ({e})");
                continue;
            }
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xd41f7);
        for case in &CASES {
            let dir: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            // The camera moved by (dc, dyaw); the served pose stays: so the served pose lies at
            // the inverse move from where the frames put the camera.
            let dc = Vector3::new(dir.cos(), dir.sin(), 0.0) * case.shift_m;
            let dyaw = (sign * case.yaw_deg).to_radians();
            let knocked = CamFromMap::from_center_ypr(
                &(served.center() - dc),
                served.yaw_pitch_roll().0 - dyaw,
                served.yaw_pitch_roll().1,
                served.yaw_pitch_roll().2,
            );
            let mut line = format!("seed {seed:>3} {:<8}", case.name);
            if case.shift_m == 0.0 && case.yaw_deg == 0.0 {
                line += &format!(" (localize NMI {served_nmi:.4})");
            }
            for (v, t) in variants.iter().zip(tallies.iter_mut()) {
                let (c0, w0) = (cpu_s(), Instant::now());
                let thresholds = DriftThresholds {
                    shift_m: cfg.daemon.drift_threshold_m,
                    yaw_deg: cfg.daemon.drift_threshold_deg,
                };
                let d =
                    drift_search_with(&camera, image.as_raw(), &tile, &knocked, &thresholds, v)?;
                t.cpu_s += cpu_s() - c0;
                t.wall_s += w0.elapsed().as_secs_f64();
                t.checks += 1;
                let oc = d.optimum.camera_center;
                let herr = ((oc[0] - served.center().x).powi(2)
                    + (oc[1] - served.center().y).powi(2))
                .sqrt();
                let yerr = angle_difference(
                    d.optimum.yaw_pitch_roll_deg[0].to_radians(),
                    served.yaw_pitch_roll().0,
                )
                .to_degrees()
                .abs();
                let tag = format!(
                    "seed {seed} {} ({})",
                    case.name,
                    d.verdict.reason.as_deref().unwrap_or("not moved")
                );
                if d.verdict.moved == case.moved {
                    t.right += 1;
                } else if d.verdict.moved {
                    t.false_alarms.push(tag);
                } else {
                    t.misses.push(tag);
                }
                // The optimum's error only where the peak was accepted (a refused peak has no
                // place to be judged by).
                if d.verdict
                    .reason
                    .as_deref()
                    .is_none_or(|r| !r.contains("no acceptable"))
                {
                    t.horiz_err_m.push(herr);
                    t.yaw_err_deg.push(yerr);
                }
                line += &format!(
                    "  | {}:{} {} {:.3} m {:+.3}° err {:.3} m {:.3}° NMI {:.4}",
                    v.thin,
                    v.coarse_min_points,
                    if d.verdict.moved { "MOVED" } else { "steady" },
                    d.verdict.shift_m,
                    d.verdict.yaw_deg,
                    herr,
                    yerr,
                    d.optimum.nmi
                );
            }
            println!("{line}");
        }
    }
    print_summary(&variants, &tallies);
    Ok(())
}

/// Each variant's tally: verdicts right, false alarms, misses, the optimum's error and the cost.
fn print_summary(variants: &[DriftParams], tallies: &[Tally]) {
    println!();
    for (v, t) in variants.iter().zip(tallies) {
        let (hm, hx) = median_max(&t.horiz_err_m);
        let (ym, yx) = median_max(&t.yaw_err_deg);
        println!(
            "thin {} coarse-min {}: {}/{} verdicts right, {} false alarms, {} misses; optimum vs \
             served median/max {:.3}/{:.3} m, {:.3}/{:.3}°; {:.3} CPU-s and {:.3} s wall per check",
            v.thin,
            v.coarse_min_points,
            t.right,
            t.checks,
            t.false_alarms.len(),
            t.misses.len(),
            hm,
            hx,
            ym,
            yx,
            t.cpu_s / t.checks.max(1) as f64,
            t.wall_s / t.checks.max(1) as f64,
        );
        for f in t.false_alarms.iter().chain(&t.misses) {
            println!("    wrong: {f}");
        }
    }
}
