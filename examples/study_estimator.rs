//! Estimator study (a measurement, not a pass/fail test; run on demand):
//! `cargo run --release --example study_estimator`
//!
//! For each estimator setting, 1-D profiles of the objective through the true pose along x and yaw
//! on several synthetic scenes, including an under-exposed image (gray squeezed into 0–63) and a
//! forward-looking pinhole (Mei ξ = 0). Reports the argmax error and the peak's prominence over the
//! profile's noise: (peak − median) / MAD(second differences). Results: docs/refine.md.

use infraloc::camera::{Camera, Mei};
use infraloc::localize::mi::kernel::Scratch;
use infraloc::localize::mi::objective::Evaluator;
use infraloc::localize::mi::space::{AxisRange, SearchConfig, SearchSpec};
use infraloc::localize::mi::{Binning, MiConfig, Objective};
use infraloc::localize::synth::{ground_points, render, Texture};
use infraloc::pose::CamFromMap;
use nalgebra::Point3;

fn truth() -> CamFromMap {
    CamFromMap::from_center_ypr(&Point3::new(3.0, 4.0, 6.0), 0.3, 0.0, 0.0)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[allow(clippy::type_complexity)]
fn main() {
    let fisheye = Camera::Mei(Mei {
        width: 768,
        height: 768,
        fx: 450.0,
        fy: 450.0,
        cx: 383.5,
        cy: 383.5,
        skew: 0.0,
        xi: 1.2,
        k1: -0.04,
        k2: 0.008,
        p1: 0.0,
        p2: 0.0,
        fov_deg: Some(185.0),
    });
    let pinhole = Camera::Mei(Mei::pinhole(800, 600, 500.0, 500.0, 399.5, 299.5));
    let settings = settings();
    // Render every scene once.
    let scenes: Vec<(
        &str,
        u64,
        &Camera,
        Vec<u8>,
        Vec<u8>,
        Vec<infraloc::localize::mi::points::GroundPoint>,
    )> = [
        ("fisheye", 1u64),
        ("fisheye", 2),
        ("fisheye dark", 3),
        ("pinhole", 4),
    ]
    .into_iter()
    .map(|(scene, seed)| {
        let cam = if scene == "pinhole" {
            &pinhole
        } else {
            &fisheye
        };
        let tex = Texture::new(seed);
        let (mut gray, mask) = render(&tex, cam, &truth(), 0.0, 8.0, seed);
        if scene.ends_with("dark") {
            gray.iter_mut().for_each(|g| *g /= 4);
        }
        let points = ground_points(&tex, (3.0, 4.0), 14.0, 0.1, 0.0, 8.0, seed + 9);
        (scene, seed, cam, gray, mask, points)
    })
    .collect();
    println!("| setting | scene | x err (m) | x prominence | yaw err (°) | yaw prominence |");
    println!("|---|---|---|---|---|---|");
    for (name, mi) in &settings {
        for (scene, seed, cam, gray, mask, points) in &scenes {
            let spec = SearchSpec {
                x: AxisRange {
                    half: 0.6,
                    step: 0.02,
                },
                y: AxisRange {
                    half: 0.02,
                    step: 0.02,
                },
                z: AxisRange {
                    half: 0.02,
                    step: 0.02,
                },
                yaw: AxisRange {
                    half: 3.0,
                    step: 0.1,
                },
                pitch: None,
                roll: None,
                tilt_pivot_m: None,
            };
            let cfg = SearchConfig {
                spec,
                mi: *mi,
                ..Default::default()
            };
            let ev = Evaluator::new(cam, gray, mask, points, &truth(), &cfg, 0).unwrap();
            let g = *ev.grid();
            let mut s = Scratch::default();
            let mut row = format!("| {name} | {scene} {seed} |");
            for axis in [0usize, 3] {
                let prof: Vec<(f64, f64)> = (-g.m[axis]..=g.m[axis])
                    .map(|k| {
                        let mut c = [0i64; 6];
                        c[axis] = k;
                        (
                            k as f64 * g.step[axis],
                            ev.score(0, g.index(&c), &mut s).score,
                        )
                    })
                    .collect();
                let (arg, peak) =
                    prof.iter().fold(
                        (0.0, f64::MIN),
                        |a, &(x, v)| if v > a.1 { (x, v) } else { a },
                    );
                let med = median(prof.iter().map(|p| p.1).collect());
                let d2: Vec<f64> = prof
                    .windows(3)
                    .map(|w| (w[0].1 - 2.0 * w[1].1 + w[2].1).abs())
                    .collect();
                let noise = median(d2).max(1e-12);
                row += &format!(" {:.3} | {:.0} |", arg.abs(), (peak - med) / noise);
            }
            println!("{row}");
        }
    }
}

/// The estimator settings compared, by name.
fn settings() -> Vec<(&'static str, MiConfig)> {
    vec![
        (
            "256 uniform (seed)",
            MiConfig {
                bins_reflectivity: 256,
                bins_gray: 255,
                binning: Binning::Uniform,
                objective: Objective::Mi,
                parzen: false,
                ..MiConfig::default()
            },
        ),
        (
            "64 uniform",
            MiConfig {
                bins_reflectivity: 64,
                bins_gray: 64,
                binning: Binning::Uniform,
                objective: Objective::Mi,
                parzen: false,
                ..MiConfig::default()
            },
        ),
        (
            "32 uniform",
            MiConfig {
                bins_reflectivity: 32,
                bins_gray: 32,
                binning: Binning::Uniform,
                objective: Objective::Mi,
                parzen: false,
                ..MiConfig::default()
            },
        ),
        (
            "32 equalized",
            MiConfig {
                bins_reflectivity: 32,
                bins_gray: 32,
                binning: Binning::Equalized,
                objective: Objective::Mi,
                parzen: false,
                ..MiConfig::default()
            },
        ),
        ("32 equalized+parzen", MiConfig::default()),
        (
            "16 equalized+parzen",
            MiConfig {
                bins_reflectivity: 16,
                bins_gray: 16,
                ..MiConfig::default()
            },
        ),
        (
            "64 equalized+parzen",
            MiConfig {
                bins_reflectivity: 64,
                bins_gray: 64,
                ..MiConfig::default()
            },
        ),
        (
            "32 eq+parzen NMI",
            MiConfig {
                objective: Objective::Nmi,
                ..MiConfig::default()
            },
        ),
    ]
}
