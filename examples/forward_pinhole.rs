//! Study: MI refinement with a forward-looking pinhole (Mei ξ = 0), the geometry of issue 3's
//! real-data check (a vehicle camera and a spinning LiDAR's ground returns), on synthetic scenes.
//!
//! ```sh
//! cargo run --release --example forward_pinhole -- --seeds 1..50 [--grid-only | --polish] [--budget N] [--clutter F]
//!     [--height M] [--down DEG]
//! ```
//!
//! A KITTI-like camera (1242×375, f = 721.5 px) 1.65 m above a procedural ground, looking
//! horizontally along a random heading; LiDAR ground returns on the rings of a 64-beam scanner
//! 1.73 m up (elevations −24.8° … −2°, 0.09° azimuth steps, ±50° around the heading). Starts
//! perturbed uniformly by ±0.8 m in x/y, ±0.4 m in z and ±2.5° in yaw (issue 3's study), true
//! roll and pitch.
//! Refines as `infraloc refine` does (grid search + 4-DoF polish; `--grid-only`: the grid's cell;
//! `--polish`: the 6-DoF polish and search rounds; `--budget`: the coarsest survey's pose budget;
//! `--clutter F`: F × as many extra points on two facades, reflectivity unrelated to the image;
//! `--height M` (default 1.65, the LiDAR 8 cm above it) and `--down DEG` (below the horizon,
//! default 0) for other mountings).
//! Prints per seed the error along and across the view, height and yaw errors and the gate's
//! verdict, then medians.

use infraloc::camera::{Camera, CameraModel, Mei};
use infraloc::localize::mi::objective::View;
use infraloc::localize::mi::space::SearchConfig;
use infraloc::localize::refine::quality::QualityConfig;
use infraloc::localize::refine::{refine_polished, PolishedSearch};
use infraloc::localize::synth::{forward_view, lidar_rings, render, Texture};
use infraloc::pose::{offsets_between, CamFromMap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mut seeds = 1..=50u64;
    // As `infraloc refine`: the 4-DoF polish after the search unless told otherwise.
    let mut finish = Some(PolishedSearch::four_dof());
    let mut cfg = SearchConfig::default();
    let mut clutter = 0.0f64;
    let (mut height, mut down) = (1.65f64, 0.0f64);
    let mut i = 1;
    while i < args.len() {
        match args[i].as_str() {
            "--seeds" => {
                let s = &args[i + 1];
                let (a, b) = s.split_once("..").expect("--seeds A..B");
                seeds = a.parse().expect("seed")..=b.parse().expect("seed");
                i += 1;
            }
            "--polish" => finish = Some(PolishedSearch::default()),
            "--grid-only" => finish = None,
            "--height" => {
                height = args[i + 1].parse().expect("--height M");
                i += 1;
            }
            "--down" => {
                down = args[i + 1].parse().expect("--down DEG");
                i += 1;
            }
            "--clutter" => {
                clutter = args[i + 1].parse().expect("--clutter FRACTION");
                i += 1;
            }
            "--budget" => {
                cfg.coarse_budget = args[i + 1].parse().expect("--budget N");
                i += 1;
            }
            other => panic!("unknown argument {other}"),
        }
        i += 1;
    }
    let cam = Camera::Mei(Mei::pinhole(1242, 375, 721.5, 721.5, 609.6, 172.9));
    let mask = cam.valid_mask();
    println!("seed  start m  start °   along m  acros m  err z m  err yaw °  accepted  reason");
    let (mut eh, mut ez, mut ey) = (Vec::new(), Vec::new(), Vec::new());
    let mut ok = 0;
    let mut n = 0;
    for seed in seeds {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let tex = Texture::new(seed);
        let heading: f64 = rng.random::<f64>() * std::f64::consts::TAU;
        let c = (rng.random::<f64>() * 50.0, rng.random::<f64>() * 50.0);
        let truth = forward_view(c, height, heading, down.to_radians());
        let (gray, _) = render(&tex, &cam, &truth, 0.0, 4.0, seed + 100);
        let mut points = lidar_rings(&tex, c, heading, height + 0.08, seed + 200);
        // Clutter: returns from two facades 8 m either side of the road (0.2–4 m up, 3–40 m
        // ahead) with reflectivity unrelated to the image (the simulator renders only the
        // ground, so these points land on road or sky pixels): a worst case for real scans.
        let n_clutter = (points.len() as f64 * clutter) as usize;
        let (sin, cos) = heading.sin_cos();
        for k in 0..n_clutter {
            let s: f64 = rng.random_range(3.0..40.0);
            let side = if k % 2 == 0 { 8.0 } else { -8.0 };
            points.push(infraloc::localize::mi::points::GroundPoint {
                x: c.0 + s * sin + side * cos,
                y: c.1 + s * cos - side * sin,
                z: rng.random_range(0.2..4.0),
                reflectivity: rng.random_range(0..=255u8),
            });
        }
        let d = [
            rng.random_range(-0.8..0.8),
            rng.random_range(-0.8..0.8),
            rng.random_range(-0.4..0.4),
            rng.random_range(-2.5..2.5),
        ];
        let init =
            infraloc::localize::mi::space::pose_at(&truth, &[d[0], d[1], d[2], d[3], 0.0, 0.0]);
        let pivot = |_: &CamFromMap| None;
        let r = refine_polished(
            &cam,
            &[View {
                gray: &gray,
                mask: &mask,
                points: &points,
            }],
            &init,
            &cfg,
            &QualityConfig::default(),
            finish.as_ref(),
            &pivot,
        );
        n += 1;
        match r {
            Ok((r, _)) => {
                let o = offsets_between(&truth, &r.pose);
                let acc = r.quality.precise();
                // Along / across the viewing direction.
                let along = o[0] * heading.sin() + o[1] * heading.cos();
                let across = o[0] * heading.cos() - o[1] * heading.sin();
                println!(
                    "{seed:4}  {:7.3}  {:7.2}   {:7.4}  {:7.4}  {:7.4}  {:8.4}  {:8}  {}",
                    (d[0] * d[0] + d[1] * d[1]).sqrt(),
                    d[3],
                    along,
                    across,
                    o[2],
                    o[3],
                    acc,
                    r.quality.grade
                );
                eh.push((o[0] * o[0] + o[1] * o[1]).sqrt());
                ez.push(o[2].abs());
                ey.push(o[3].abs());
                if acc
                    && (o[0] * o[0] + o[1] * o[1]).sqrt() < 0.1
                    && o[2].abs() < 0.1
                    && o[3].abs() < 0.2
                {
                    ok += 1;
                }
            }
            Err(e) => println!("{seed:4}  error: {e}"),
        }
    }
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    println!(
        "medians: horizontal {:.4} m, height {:.4} m, yaw {:.4}°; within 10 cm / 0.2° and accepted: {ok}/{n}",
        med(eh),
        med(ez),
        med(ey)
    );
}
