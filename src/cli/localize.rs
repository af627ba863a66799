//! `infraloc localize`: the full two-step pipeline, one shot (docs/interfaces.md, "Command line and exit codes"). The run itself is
//! [`crate::app`]; this file turns the flags into its overrides and prints the result.

use crate::app::{Outputs, Overrides, Run};
use crate::config::Config;
use crate::error::{Error, Result};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

/// Arguments of `localize`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Configuration file (a simulated scene's `infraloc.toml` localizes it with no other flags).
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Intrinsics file (overrides the config's camera).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Frame(s) to use instead of capturing; several are median-filtered.
    #[arg(long = "image")]
    pub images: Vec<PathBuf>,
    /// NMEA log for the prior (overrides the config's GPS source).
    #[arg(long, conflicts_with = "prior_wgs84")]
    pub gps_nmea: Option<PathBuf>,
    /// Prior position `LAT,LON` (overrides the config's GPS source).
    #[arg(long)]
    pub prior_wgs84: Option<String>,
    /// Tile cache (overrides `[map] tiles`).
    #[arg(long)]
    pub tiles: Option<PathBuf>,
    /// Pose file to write (overrides `[output] pose`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Overlay PNG: LiDAR points (cyan) over the frame at the PnP pose (left) and at the final
    /// pose (right).
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Report JSON: per-stage poses, timings, evaluation counts, errors vs truth.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Ground truth (a simulator `truth.json`) to report errors against.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

impl Args {
    /// The flags that replace parts of the config, checked (`--prior-wgs84` must be a WGS84
    /// position).
    pub(crate) fn overrides(&self) -> Result<Overrides> {
        let prior_wgs84 = match &self.prior_wgs84 {
            None => None,
            Some(s) => {
                let [lat, lon] = super::parse_list::<2>("--prior-wgs84", s)?;
                if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
                    return Err(Error::arg("--prior-wgs84", s, "not a WGS84 position"));
                }
                Some((lat, lon))
            }
        };
        Ok(Overrides {
            camera: self.camera.clone(),
            images: self.images.clone(),
            gps_nmea: self.gps_nmea.clone(),
            prior_wgs84,
            tiles: self.tiles.clone(),
            truth: self.truth.clone(),
        })
    }

    /// The flags that replace the config's `[output]` paths.
    pub(crate) fn outputs(&self) -> Outputs {
        Outputs {
            pose: self.out.clone(),
            report: self.report.clone(),
            overlay: self.overlay.clone(),
        }
    }
}

/// Run the node's localization for `a` ([`crate::app::run`]) and write its outputs.
fn run_pipeline(a: &Args) -> Result<Run> {
    if let Some(n) = a.threads {
        // Only the first call in a process can size the global pool; later calls keep it.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global();
    }
    let cfg = Config::load(&a.config)?;
    run_and_write(&cfg, &a.config, &a.overrides()?, &a.outputs())
}

/// [`crate::app::run`] with the stages shown on stderr while they run when stderr is a
/// terminal, then the pose, report and overlay written (`localize` and `demo`).
pub(crate) fn run_and_write(
    cfg: &Config,
    cfg_path: &Path,
    ov: &Overrides,
    out: &Outputs,
) -> Result<Run> {
    // Every output writable before anything is captured.
    out.check(cfg, cfg_path)?;
    let stderr = std::io::stderr();
    let tty = stderr.is_terminal();
    let run = super::progress::with_progress(stderr, tty, |progress| {
        crate::app::run(cfg, cfg_path, ov, &|s| progress(s.name()))
    })?;
    run.write_outputs(cfg, out)?;
    Ok(run)
}

/// Run `localize`: write the outputs and print a one-line summary; the exit code of the
/// served grade (0 precise, [`crate::error::EXIT_COARSE`] coarse).
pub(super) fn run(a: Args) -> Result<i32> {
    let r = run_pipeline(&a)?;
    let (y, p, ro) = r.outcome.pose.yaw_pitch_roll();
    let c = r.outcome.pose.center();
    let q = &r.outcome.refinement.quality;
    println!(
        "pose {}: tile {} centre ({:.3}, {:.3}, {:.3}) yaw {:.3}° pitch {:.3}° roll {:.3}°  NMI {:.4}",
        q.grade.name(), r.tile.id, c.x, c.y, c.z, y.to_degrees(), p.to_degrees(), ro.to_degrees(), q.nmi
    );
    if let crate::localize::refine::verdict::Grade::Coarse(o) = &q.grade {
        println!("coarse: {o} (precise)");
    }
    if let Some(i) = &q.initializer {
        println!(
            "the initializer's pose, {}: the refinement refused: {}",
            q.sigma.map_or_else(|| "σ unknown".into(), |s| s.describe()),
            i.0
        );
    }
    if let Some(t) = r.report.get("truth") {
        println!("vs truth: {t}");
    }
    Ok(if q.precise() {
        0
    } else {
        crate::error::EXIT_COARSE
    })
}
