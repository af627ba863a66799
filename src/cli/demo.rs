//! `infraloc demo`: simulate a scene in a temporary directory, localize it exactly as a node would
//! (through the scene's config), print the errors against truth, exit non-zero past the thresholds.

use super::simulate::{DifficultyArg, LensArg, PresetArg};
use crate::app::{Outputs, Overrides};
use crate::config::Config;
use crate::error::{Error, Result};
use serde_json::Value;
use std::io::IsTerminal;
use std::path::PathBuf;

/// Horizontal error the demo accepts, metres (the refinement's 99th-percentile goal).
pub(crate) const MAX_HORIZONTAL_M: f64 = 0.10;
/// Height error the demo accepts, metres.
pub(crate) const MAX_HEIGHT_M: f64 = 0.10;
/// Yaw error the demo accepts, degrees.
pub(crate) const MAX_YAW_DEG: f64 = 0.2;

/// The thresholds as `infraloc demo --help` states them (README "Start here" repeats them).
pub(crate) fn thresholds_help() -> String {
    format!(
        "Passes when the final (MI) pose is within {MAX_HORIZONTAL_M} m horizontally, \
         {MAX_HEIGHT_M} m in height and {MAX_YAW_DEG}° in yaw of the simulated truth; \
         exits 1 otherwise."
    )
}

/// The demo's judgement of the MI stage's errors against truth (`report["truth"]["mi"]`): an
/// error naming the errors and the thresholds when one exceeds its threshold or is missing (a
/// report without the number cannot show the pose is good).
fn verdict(mi: &Value) -> Result<()> {
    let err = |key: &str| mi[key].as_f64().unwrap_or(f64::INFINITY);
    let (h, z, y) = (err("horizontal_m"), err("height_m"), err("yaw_deg"));
    // `!(e <= max)` also fails a NaN error.
    if !(h <= MAX_HORIZONTAL_M && z <= MAX_HEIGHT_M && y <= MAX_YAW_DEG) {
        return Err(Error::command(
            "demo",
            format!("errors {h:.3} m / {z:.3} m / {y:.3}° exceed {MAX_HORIZONTAL_M} m / {MAX_HEIGHT_M} m / {MAX_YAW_DEG}°"),
        ));
    }
    Ok(())
}

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
    /// Write the overlay PNG (LiDAR points over the frame, before | after) here. Default:
    /// overlay.png in the --keep directory, else infraloc-demo-overlay.png in the system's
    /// temporary directory, which outlives the demo's scene.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
}

/// Run the demo.
pub(super) fn run(a: Args) -> Result<()> {
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
        times: 1,
        low_sun: false,
        given_intrinsics: super::simulate::IntrinsicsArg::Calibrated,
        montage: None,
        lidar_laz: None,
        board: Default::default(),
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
    let place = match &a.keep {
        Some(d) => d.display().to_string(),
        None => "temporary directory".to_string(),
    };
    println!(
        "scene: {} (seed {}, {:?}, {:?}) in {:.1} s",
        place, a.seed, a.preset, a.difficulty, t_sim
    );
    // The picture is the demo's point (docs/interfaces.md, "Command line and exit codes"): it goes where it survives the scene.
    let overlay = match (&a.overlay, &a.keep) {
        (Some(p), _) => p.clone(),
        (None, Some(d)) => d.join("overlay.png"),
        (None, None) => std::env::temp_dir().join("infraloc-demo-overlay.png"),
    };
    let cfg_path = dir.join("infraloc.toml");
    let cfg = Config::load(&cfg_path)?;
    cfg.validate(&cfg_path)?;
    let ov = Overrides {
        truth: Some(dir.join("truth.json")),
        ..Overrides::default()
    };
    let out = Outputs {
        pose: Some(dir.join("pose.json")),
        report: Some(dir.join("report.json")),
        overlay: Some(overlay.clone()),
    };
    let run = super::localize::run_and_write(&cfg, &cfg_path, &ov, &out)?;
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
    print_ground_table(t);
    println!("overlay: {}", overlay.display());
    if a.keep.is_none() {
        // The temporary scene directory is removed when the demo returns.
        println!("scene, pose and report: not kept (--keep DIR keeps them)");
    }
    verdict(&t["mi"])?;
    println!("demo OK: within {MAX_HORIZONTAL_M} m horizontal, {MAX_HEIGHT_M} m height, {MAX_YAW_DEG}° yaw");
    Ok(())
}

/// What the detection pipeline inherits (docs/accuracy.md): each pose against the oracle — the
/// best pose the given intrinsics allow — and the ground error of the control points, overall
/// and by distance from the pole, in centimetres.
fn print_ground_table(t: &serde_json::Value) {
    let cm = |v: &serde_json::Value| {
        v.as_f64()
            .map_or("—".to_string(), |x| format!("{:.1}", 100.0 * x))
    };
    let pair = |g: &serde_json::Value| format!("{}/{}", cm(&g["median"]), cm(&g["p95"]));
    println!(
        "{:<6} {:>22} {:>12} {:>12} {:>12} {:>12}",
        "vs oracle", "Δhor/Δz cm, Δyaw °", "ground cm", "0–10 m", "10–20 m", "20–30 m"
    );
    for name in ["oracle", "pnp", "mi"] {
        let e = &t[name];
        if e.is_null() {
            continue;
        }
        let d = &e["vs_oracle"];
        let offs = if name == "oracle" {
            "—".to_string()
        } else {
            format!(
                "{}/{} {:.3}",
                cm(&d["horizontal_m"]),
                cm(&d["height_m"]),
                d["yaw_deg"].as_f64().unwrap_or(f64::NAN)
            )
        };
        let b = |i: usize| pair(&e["ground"]["bands"][i]["error"]);
        println!(
            "{:<9} {:>19} {:>12} {:>12} {:>12} {:>12}",
            name,
            offs,
            pair(&e["ground"]["all"]),
            b(0),
            b(1),
            b(2)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn verdict_passes_within_the_thresholds_and_fails_past_any_of_them() {
        let within = json!({"horizontal_m": 0.05, "height_m": 0.02, "yaw_deg": 0.1});
        assert!(verdict(&within).is_ok());
        for (key, value) in [
            ("horizontal_m", MAX_HORIZONTAL_M + 0.01),
            ("height_m", MAX_HEIGHT_M + 0.01),
            ("yaw_deg", MAX_YAW_DEG + 0.01),
        ] {
            let mut over = within.clone();
            over[key] = json!(value);
            let e = verdict(&over).expect_err(key);
            assert_ne!(e.exit_code(), 0, "{key}");
            assert!(e.to_string().starts_with("demo: errors "), "{key}: {e}");
        }
        // A report without an error (truth unreadable, stage missing) is no proof of accuracy.
        let e = verdict(&json!({"horizontal_m": 0.05, "height_m": 0.02})).expect_err("no yaw");
        assert!(e.to_string().contains("inf°"), "{e}");
    }

    #[test]
    fn help_states_the_thresholds() {
        let h = thresholds_help();
        for v in [MAX_HORIZONTAL_M, MAX_HEIGHT_M, MAX_YAW_DEG] {
            assert!(h.contains(&format!("{v}")), "{v} not in {h:?}");
        }
    }
}
