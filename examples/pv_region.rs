//! The confidence region of the partial-volume objective (`--sampling pv`) around one pose on
//! real pairs, by test inversion as `refine`'s region (docs/refine.md "Uncertainty"), but on the
//! smooth objective: along every axis and every pair of axes, the first probe whose drop from
//! the answer exceeds z = 2 jackknife standard errors (32 Morton patches). Prints each ray's
//! boundary (or "open") and the σ the boundary implies (its reach over 2z).
//!
//! ```sh
//! cargo run --release --example pv_region -- CAM POSE[@DX,DY,DZ,DYAW] joint|per-pair PAIRS
//! ```
//! POSE, moved by the offsets when given (m, m, m, deg; as `refine`'s report `offsets`), is the
//! pose probed around; PAIRS is a pairs file (`IMAGE<TAB>POINTS` per line, paths relative to its
//! directory, as `kitti import --pairs-out` writes it and `refine --pairs` reads it).

use infraloc::camera::load_camera;
use infraloc::localize::mi::objective::Evaluator;
use infraloc::localize::mi::smooth::{Pooling, Smooth};
use infraloc::localize::mi::space::{pose_at, SearchConfig};
use std::path::Path;

#[path = "common/mod.rs"]
mod common;

/// Patches of the jackknife.
const K: usize = 32;
/// The test's z.
const Z: f64 = 2.0;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() != 4 {
        return Err("usage: pv_region CAM POSE[@DX,DY,DZ,DYAW] joint|per-pair PAIRS".into());
    }
    let cam = load_camera(Path::new(&a[0]))?;
    let answer = common::pose_arg(&a[1])?;
    let pooling: Pooling = a[2].parse()?;
    let listed = Path::new(&a[3]);
    let pairs = infraloc::cli::pairs::parse(&std::fs::read_to_string(listed)?, listed)?;
    let real = common::RealPairs::read(&cam, &pairs)?;
    let views = real.views();
    // The region's box (±30 cm, ±0.9°): its fixed point set is what every probe sees.
    let cfg = SearchConfig {
        spec: "x=0.3:0.02,y=0.3:0.02,z=0.3:0.02,yaw=0.9:0.05".parse()?,
        ..Default::default()
    };
    let ev = Evaluator::pooled(&cam, &views, &answer, &cfg, 0)?;
    let est = Smooth::of_evaluator(&cam, &ev, pooling);
    let unit = [0.02, 0.02, 0.02, 0.05];
    let bound = [0.3, 0.3, 0.3, 0.9];
    let names = ["x", "y", "z", "yaw"];
    let base_h = est.cluster_histograms(&answer, K);
    let value_without = |h: &[Vec<Vec<f64>>], left: Option<usize>| -> f64 {
        let mut sum: Vec<Vec<f64>> = h[0].iter().map(|v| vec![0.0; v.len()]).collect();
        for (j, hk) in h.iter().enumerate() {
            if Some(j) != left {
                for (s, x) in sum.iter_mut().zip(hk) {
                    s.iter_mut().zip(x).for_each(|(a, b)| *a += b);
                }
            }
        }
        est.value_of(&sum)
    };
    let v0 = value_without(&base_h, None);
    println!("N {} objective {v0:.6} at the answer", est.n());
    let mut rays: Vec<[f64; 4]> = Vec::new();
    for i in 0..4 {
        for s in [1.0, -1.0] {
            let mut u = [0.0; 4];
            u[i] = s;
            rays.push(u);
        }
    }
    for i in 0..4 {
        for j in i + 1..4 {
            for (si, sj) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                let mut u = [0.0; 4];
                u[i] = si;
                u[j] = sj;
                rays.push(u);
            }
        }
    }
    let radii = [1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0];
    for u in &rays {
        let reach = (0..4)
            .filter(|&i| u[i] != 0.0)
            .map(|i| bound[i] / unit[i])
            .fold(f64::INFINITY, f64::min);
        let name: String = (0..4)
            .filter(|&i| u[i] != 0.0)
            .map(|i| format!("{}{}", if u[i] > 0.0 { '+' } else { '-' }, names[i]))
            .collect();
        let mut found = None;
        let mut trace = String::new();
        for t in radii.iter().copied().filter(|&t| t < reach).chain([reach]) {
            let o: Vec<f64> = (0..4).map(|i| t * u[i] * unit[i]).collect();
            let p = pose_at(&answer, &[o[0], o[1], o[2], o[3], 0.0, 0.0]);
            let h = est.cluster_histograms(&p, K);
            let drop = v0 - value_without(&h, None);
            let loo: Vec<f64> = (0..K)
                .map(|j| value_without(&base_h, Some(j)) - value_without(&h, Some(j)))
                .collect();
            let mean = loo.iter().sum::<f64>() / K as f64;
            let se = ((K as f64 - 1.0) / K as f64
                * loo.iter().map(|v| (v - mean).powi(2)).sum::<f64>())
            .sqrt();
            let r = drop / (Z * se);
            trace.push_str(&format!(" {t}:{r:+.2}"));
            if r >= 1.0 {
                found = Some(t);
                break;
            }
        }
        let describe = |t: f64| -> String {
            (0..4)
                .filter(|&i| u[i] != 0.0)
                .map(|i| {
                    let v = t * unit[i] / (2.0 * Z);
                    if i < 3 {
                        format!("σ {} ≈ {:.1} cm", names[i], 100.0 * v)
                    } else {
                        format!("σ yaw ≈ {v:.3}°")
                    }
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        match found {
            Some(t) => println!(
                "{name:>10}: told apart at {t} steps ({});{trace}",
                describe(t)
            ),
            None => println!(
                "{name:>10}: open to {reach} steps ({} at least);{trace}",
                describe(reach)
            ),
        }
    }
    Ok(())
}
