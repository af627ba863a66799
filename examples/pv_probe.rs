//! Probe the partial-volume objective (`--sampling pv`) at one pose on real pairs: its value, its
//! gradient and its Hessian's eigen-structure at several central-difference steps, i.e. whether
//! the data has a basin there and how wide (docs/refine.md "Estimator").
//!
//! ```sh
//! cargo run --release --example pv_probe -- CAM.yaml POSE.json[@DX,DY,DZ,DYAW] joint|per-pair IMG BIN [IMG BIN …]
//! ```

use infraloc::camera::load_camera;
use infraloc::localize::mi::objective::Evaluator;
use infraloc::localize::mi::smooth::{Pooling, Smooth};
use infraloc::localize::mi::space::SearchConfig;
use nalgebra::DMatrix;
use std::path::{Path, PathBuf};

#[path = "common/mod.rs"]
mod common;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 5 || (a.len() - 3) % 2 != 0 {
        return Err(
            "usage: pv_probe CAM POSE[@DX,DY,DZ,DYAW] joint|per-pair IMG BIN [IMG BIN …]".into(),
        );
    }
    let cam = load_camera(Path::new(&a[0]))?;
    let pose = common::pose_arg(&a[1])?;
    let pooling: Pooling = a[2].parse()?;
    let pairs: Vec<_> = a[3..]
        .chunks(2)
        .map(|p| (PathBuf::from(&p[0]), PathBuf::from(&p[1])))
        .collect();
    let real = common::RealPairs::read(&cam, &pairs)?;
    let views = real.views();
    let cfg = SearchConfig {
        spec: "x=0.15:0.01,y=0.15:0.01,z=0.15:0.01,yaw=0.5:0.05".parse()?,
        ..Default::default()
    };
    let ev = Evaluator::pooled(&cam, &views, &pose, &cfg, 0)?;
    let est = Smooth::of_evaluator(&cam, &ev, pooling);
    let v = est.evaluate(&pose, true);
    println!(
        "N {} valid {:.0}; objective {:.6}; gradient {:?}",
        v.n, v.valid, v.value, v.grad
    );
    let free = [true, true, true, false, false, true];
    let names = ["x", "y", "z", "yaw"];
    for (m, deg) in [
        (0.01, 0.05),
        (0.02, 0.1),
        (0.04, 0.2),
        (0.08, 0.4),
        (0.16, 0.8),
    ] {
        let r = f64::to_radians(deg);
        let h = est.hessian(&pose, &free, &[m, m, m, r, r, r]);
        // Unitless: per (step)² so the eigen-directions compare the axes fairly.
        let idx = [0usize, 1, 2, 5];
        let sc = [m, m, m, r];
        let hm = DMatrix::from_fn(4, 4, |i, j| {
            (v.n as f64) * h[idx[i]][idx[j]] * sc[i] * sc[j]
        });
        let e = hm.clone().symmetric_eigen();
        print!("step {m} m / {deg}°: N·H per step² eigenvalues");
        for k in 0..4 {
            let dir: Vec<String> = (0..4)
                .map(|i| format!("{} {:+.2}", names[i], e.eigenvectors[(i, k)]))
                .collect();
            print!(" | {:+.2} along ({})", e.eigenvalues[k], dir.join(", "));
        }
        println!();
        match infraloc::localize::refine::information::information_with_step(
            &est,
            &pose,
            &free,
            &[m, m, m, r, r, r],
        ) {
            Ok(i) => println!("  {}", i.describe()),
            Err(e) => println!("  {e}"),
        }
    }
    Ok(())
}
