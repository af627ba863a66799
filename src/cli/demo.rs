//! `infraloc demo`: simulate a scene in a temporary directory, localize it exactly as a node would
//! (through the scene's config), print the errors against truth, exit non-zero past the thresholds.

use super::simulate::{DifficultyArg, LensArg, PresetArg};
use crate::error::{Error, Result};
use std::io::IsTerminal;
use std::path::PathBuf;

/// Horizontal error the demo accepts, metres (the refinement's 99th-percentile goal).
pub const MAX_HORIZONTAL_M: f64 = 0.10;
/// Height error the demo accepts, metres.
pub const MAX_HEIGHT_M: f64 = 0.10;
/// Yaw error the demo accepts, degrees.
pub const MAX_YAW_DEG: f64 = 0.2;

/// Arguments of `demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scene size: `small` (≈1 MP) or `5mp` (2448×2048, 185° lens).
    #[arg(long, value_enum, default_value = "small")]
    pub preset: PresetArg,
    /// Scene seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Difficulty.
    #[arg(long, value_enum, default_value = "hard")]
    pub difficulty: DifficultyArg,
    /// Keep the scene and outputs in this directory instead of a temporary one.
    #[arg(long)]
    pub keep: Option<PathBuf>,
}

/// Run the demo.
pub fn run(a: Args) -> Result<()> {
    let tmp;
    let dir = match &a.keep {
        Some(d) => {
            std::fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
            d.clone()
        }
        None => {
            tmp = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
            tmp.path().to_path_buf()
        }
    };
    let t0 = std::time::Instant::now();
    let sim_args = super::simulate::Args {
        out: dir.clone(),
        seed: a.seed,
        preset: a.preset,
        difficulty: a.difficulty,
        lens: LensArg::Mei,
        frames: 5,
        montage: None,
    };
    // Simulating takes as long as localizing: the terminal shows it as a stage too.
    let stderr = std::io::stderr();
    let tty = stderr.is_terminal();
    super::progress::with_progress(stderr, tty, |progress| {
        progress("simulate");
        let scene = crate::sim::generate(&sim_args.settings())?;
        super::simulate::write_scene(&scene, &dir)
    })?;
    let t_sim = t0.elapsed().as_secs_f64();
    println!(
        "scene: {} (seed {}, {:?}, {:?}) in {:.1} s",
        dir.display(),
        a.seed,
        a.preset,
        a.difficulty,
        t_sim
    );
    let la = super::localize::Args {
        config: dir.join("infraloc.toml"),
        camera: None,
        images: Vec::new(),
        gps_nmea: None,
        prior_wgs84: None,
        tiles: None,
        out: Some(dir.join("pose.json")),
        overlay: Some(dir.join("overlay.png")),
        report: Some(dir.join("report.json")),
        truth: Some(dir.join("truth.json")),
        threads: None,
    };
    let run = super::localize::run_pipeline(&la)?;
    let t = &run.report["truth"];
    println!(
        "{:<6} {:>12} {:>10} {:>9} {:>16} {:>9}",
        "stage", "horizontal", "height", "yaw", "control pts", "seconds"
    );
    for (name, secs) in [
        ("pnp", run.outcome.stages[1].seconds),
        ("mi", run.outcome.stages[2].seconds),
    ] {
        let e = &t[name];
        println!(
            "{:<6} {:>10.3} m {:>8.3} m {:>7.3} ° {:>13.2} px {:>9.2}",
            name,
            e["horizontal_m"].as_f64().unwrap_or(f64::NAN),
            e["height_m"].as_f64().unwrap_or(f64::NAN),
            e["yaw_deg"].as_f64().unwrap_or(f64::NAN),
            e["control_points_mean_px"].as_f64().unwrap_or(f64::NAN),
            secs
        );
    }
    println!("overlay: {}", dir.join("overlay.png").display());
    let mi = &t["mi"];
    let (h, z, y) = (
        mi["horizontal_m"].as_f64().unwrap_or(f64::INFINITY),
        mi["height_m"].as_f64().unwrap_or(f64::INFINITY),
        mi["yaw_deg"].as_f64().unwrap_or(f64::INFINITY),
    );
    if h > MAX_HORIZONTAL_M || z > MAX_HEIGHT_M || y > MAX_YAW_DEG {
        return Err(Error::stage(
            "demo",
            format!("errors {h:.3} m / {z:.3} m / {y:.3}° exceed {MAX_HORIZONTAL_M} m / {MAX_HEIGHT_M} m / {MAX_YAW_DEG}°"),
        ));
    }
    println!("demo OK: within {MAX_HORIZONTAL_M} m horizontal, {MAX_HEIGHT_M} m height, {MAX_YAW_DEG}° yaw");
    Ok(())
}
