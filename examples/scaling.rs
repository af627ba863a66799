//! How the MI refinement's cost grows with the image size and the number of LiDAR points: one
//! configuration per process, so that each peak RSS is its own.
//!
//! `cargo run --release --example scaling -- MEGAPIXELS SPACING_M [THREADS]`
//!
//! Scene (`localize::synth`, seeded, as `benches/refine.rs`): a 185° Mei fisheye with the `5mp`
//! preset's optics scaled to the image size (1 MP = 1224×1024, 5 MP = 2448×2048, 12 MP =
//! 4000×3000: focal length and centre scale with the width), 10.4 m above a textured ground, LiDAR
//! ground points within 25 m on a square grid of `SPACING_M` (0.2 / 0.1 / 0.05 m ≈ 49 k / 196 k /
//! 785 k points), start 0.4 / −0.3 / 0.2 m and 1.5° off. Timed: `localize::refine::refine` (the
//! camera's validity mask, the evaluator, the grid search and its checks, then the smooth stage:
//! ascent, information and competing optima), in a rayon pool of `THREADS` (default 2). Printed: wall and process CPU seconds,
//! the peak RSS of the refinement alone (the peak is reset after the scene is rendered, through
//! `/proc/self/clear_refs`) and the process's peak, and the answer's error.

use infraloc::localize::mi::space::SearchConfig;
use infraloc::localize::refine::quality::QualityConfig;
use infraloc::localize::refine::refine;
use infraloc::localize::synth::{ground_points, render, Texture};
use infraloc::pose::CamFromMap;
use nalgebra::{Point3, Vector3};
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{cpu_s, preset_camera};

/// A `/proc/self/status` field in KiB.
fn status_kib(field: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(field))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: scaling MEGAPIXELS(1|5|12) SPACING_M [THREADS]".into());
    }
    let (w, h) = match args[1].as_str() {
        "1" => (1224, 1024),
        "5" => (2448, 2048),
        "12" => (4000, 3000),
        other => return Err(format!("megapixels: 1, 5 or 12, not {other}").into()),
    };
    let spacing: f64 = args[2].parse()?;
    let threads: usize = args.get(3).map_or(Ok(2), |t| t.parse())?;
    let cam = preset_camera(w, h);
    let tex = Texture::new(2);
    let truth = CamFromMap::from_center_ypr(&Point3::new(50.0, 40.0, 10.4), 1.72, -0.0013, 0.0);
    let (gray, _) = render(&tex, &cam, &truth, 0.0, 4.0, 102);
    let pts = ground_points(&tex, (50.0, 40.0), 25.0, spacing, 0.0, 4.0, 202);
    let init = truth.perturbed(&Vector3::new(0.4, -0.3, 0.2), 1.5f64.to_radians());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let before = status_kib("VmRSS:");
    // Reset the peak (VmHWM) to the current RSS, so the next peak is the refinement's own.
    let reset = std::fs::write("/proc/self/clear_refs", "5").is_ok();
    let (w0, c0) = (Instant::now(), cpu_s());
    let r = pool.install(|| {
        refine(
            &cam,
            &gray,
            &pts,
            &init,
            &SearchConfig::default(),
            &QualityConfig::default(),
        )
    })?;
    let (wall, cpu) = (w0.elapsed().as_secs_f64(), cpu_s() - c0);
    let peak = status_kib("VmHWM:");
    let e = r.pose.center() - truth.center();
    println!(
        "{w}x{h} ({:.1} MP) | {} points ({} used) | {threads} threads | wall {wall:.3} s | cpu {cpu:.3} s | \
         RSS before {:.0} MB, peak during refine {} | poses {} | point-evals {:.3e} | error {:.3} m | accepted {}",
        (w * h) as f64 / 1e6,
        pts.len(),
        r.points.1,
        before as f64 / 1024.0,
        if reset {
            format!("{:.0} MB", peak as f64 / 1024.0)
        } else {
            format!("(process peak, reset refused) {:.0} MB", peak as f64 / 1024.0)
        },
        r.stats.poses,
        r.stats.point_evaluations as f64,
        e.norm(),
        r.quality.precise(),
    );
    Ok(())
}
