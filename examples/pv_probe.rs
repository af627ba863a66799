//! Probe the partial-volume objective (`--sampling pv`) at one pose on real pairs: its value, its
//! gradient and its Hessian's eigen-structure at several central-difference steps, i.e. whether
//! the data has a basin there and how wide (docs/refine.md "Estimator").
//!
//! ```sh
//! cargo run --release --example pv_probe -- CAM.yaml POSE.json joint|per-pair IMG BIN [IMG BIN …]
//! ```

use infraloc::camera::{load_camera, CameraModel};
use infraloc::localize::mi::objective::{Evaluator, View};
use infraloc::localize::mi::smooth::{Pooling, Smooth};
use infraloc::localize::mi::space::SearchConfig;
use infraloc::points_io::read_points;
use infraloc::posefile::read_pose;
use nalgebra::DMatrix;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 5 || (a.len() - 3) % 2 != 0 {
        return Err("usage: pv_probe CAM POSE joint|per-pair IMG BIN [IMG BIN …]".into());
    }
    let cam = load_camera(Path::new(&a[0]))?;
    let pose = read_pose(Path::new(&a[1]))?.pose;
    let pooling: Pooling = a[2].parse()?;
    let mask = cam.valid_mask();
    let mut grays = Vec::new();
    let mut sets = Vec::new();
    for pair in a[3..].chunks(2) {
        grays.push(image::open(&pair[0])?.to_luma8().into_raw());
        sets.push(read_points(Path::new(&pair[1]))?);
    }
    let views: Vec<View<'_>> = grays
        .iter()
        .zip(&sets)
        .map(|(g, p)| View {
            gray: g,
            mask: &mask,
            points: p,
        })
        .collect();
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
    for (m, deg) in [(0.01, 0.05), (0.02, 0.1), (0.04, 0.2), (0.08, 0.4)] {
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
        match infraloc::localize::refine::gradient::information_with_step(
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
