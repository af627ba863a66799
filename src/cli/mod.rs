//! Command line (docs/interfaces.md, "Command line and exit codes"). Each command's handler lives in its own file; this module only
//! parses arguments, dispatches, and turns errors into one stderr line and an exit code.

mod calibrate;
mod demo;
mod estimator;
mod georef;
mod gps;
mod kitti;
mod localize;
pub mod man;
pub mod pairs;
mod plot;
mod progress;
mod project;
mod rectify;
mod refine;
mod selftest;
mod simulate;
mod study;
mod tech;
mod tile;
mod validate;

use crate::error::Error;
use clap::{Parser, Subcommand};

/// infraloc: localize a smart-infrastructure fisheye camera in an AV prior map.
#[derive(Debug, Parser)]
#[command(name = "infraloc", version, about, propagate_version = true)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Simulate a scene, localize it, print the errors against truth (non-zero exit past the
    /// documented thresholds).
    #[command(after_help = demo::thresholds_help())]
    Demo(demo::Args),
    /// Localize the camera: GPS prior → satellite matching + PnP → MI refinement → pose file.
    Localize(localize::Args),
    /// Generate a simulated scene directory (docs/interfaces.md, "Scene directory").
    Simulate(simulate::Args),
    /// Project points through a camera model: CSV x,y,z → CSV u,v on stdout.
    Project(project::Args),
    /// Map pixels to the ground through the served pose: CSV u,v → E, N, h, lat, lon, error
    /// ellipse and status per pixel (docs/georef.md).
    Georef(georef::Args),
    /// Perspective rectification with cv::omnidir RECTIFY_PERSPECTIVE semantics.
    Rectify(rectify::Args),
    /// MI refinement alone, from any initial pose.
    Refine(refine::Args),
    /// Intrinsic calibration from checkerboard corners (Mei or equidistant model).
    Calibrate(calibrate::Args),
    /// The seed's robustness study: MI refinement from random starts around a simulated truth.
    Study(study::Args),
    /// Charts: `plot mi-surface` (MI along each axis and over x–y around a pose).
    #[command(subcommand)]
    Plot(plot::Command),
    /// Tile cache operations.
    #[command(subcommand)]
    Tile(tile::Command),
    /// GPS tools.
    #[command(subcommand)]
    Gps(gps::Command),
    /// KITTI data: `kitti import` turns a frame's calibration into a camera file and a
    /// Velodyne-frame pose (real LiDAR + camera inputs for `refine` and `plot mi-surface`).
    #[command(subcommand)]
    Kitti(kitti::Command),
    /// Check a configuration file: prints "config OK" or the problem (exit 78).
    Validate(validate::Args),
    /// The node service: serve the stored pose, localize at boot and on request, control socket,
    /// watchdog (run by infraloc.service).
    Daemon(tech::DaemonArgs),
    /// The service's state, served pose, last run and schedules (exit 3 degraded, 4 failed).
    Status(tech::StatusArgs),
    /// Ask the service to localize now (`--wait`: show progress and the result).
    Relocalize(tech::RelocalizeArgs),
    /// Print the pose the service serves (docs/interfaces.md, "Pose file").
    Pose(tech::Target),
    /// Drop the service's stored frames of earlier runs, which later runs pool (after moving
    /// the camera, or when its frames are not to be trusted).
    ClearFrames(tech::Target),
    /// Save the LiDAR-over-image overlay of the service's latest run as PNG.
    Overlay(tech::OverlayArgs),
    /// Write the manual pages (infraloc.1 from these definitions, infraloc.toml.5) into a
    /// directory; the package build and tests use it.
    #[command(hide = true)]
    Man(man::Args),
    /// Check the MI kernel's SIMD copy against the reference loop on this CPU (run by CI on the
    /// aarch64 binary under qemu).
    #[command(hide = true)]
    SelfTest(selftest::Args),
}

/// Run the CLI with the process arguments; returns the exit code.
pub fn main() -> i32 {
    let cli = Cli::parse();
    // `status` reports the service's state in its exit code too, and `refine` and `localize`
    // the grade of what they served.
    let coded = match cli.command {
        Command::Status(t) => tech::status(t),
        Command::Refine(a) => refine::run(a),
        Command::Localize(a) => localize::run(a),
        command => {
            return match run(Cli { command }) {
                Ok(()) => 0,
                Err(e) => report(&e),
            }
        }
    };
    match coded {
        Ok(code) => code,
        Err(e) => report(&e),
    }
}

/// Print `e` on stderr (one line per problem, each prefixed `infraloc: `); its exit code.
fn report(e: &Error) -> i32 {
    for l in e.lines() {
        eprintln!("infraloc: {l}");
    }
    e.exit_code()
}

/// Dispatch a parsed command.
pub(crate) fn run(cli: Cli) -> Result<(), Error> {
    match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Localize(a) => localize::run(a).map(|_| ()),
        Command::Simulate(a) => simulate::run(a),
        Command::Project(a) => project::run(a),
        Command::Georef(a) => georef::run(a),
        Command::Rectify(a) => rectify::run(a),
        Command::Refine(a) => refine::run(a).map(|_| ()),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Study(a) => study::run(a),
        Command::Plot(c) => plot::run(c),
        Command::Tile(c) => tile::run(c),
        Command::Gps(c) => gps::run(c),
        Command::Kitti(c) => kitti::run(c),
        Command::Validate(a) => validate::run(a),
        Command::Daemon(a) => tech::daemon(a),
        Command::Status(t) => tech::status(t).map(|_| ()),
        Command::Relocalize(a) => tech::relocalize(a),
        Command::Pose(t) => tech::pose(t),
        Command::ClearFrames(t) => tech::clear_frames(t),
        Command::Overlay(a) => tech::overlay(a),
        Command::Man(a) => man::run(a),
        Command::SelfTest(a) => selftest::run(a),
    }
}

/// Parse `A,B,C` into numbers, naming the flag on error.
pub(crate) fn parse_list<const N: usize>(flag: &'static str, s: &str) -> Result<[f64; N], Error> {
    let bad = || Error::arg_quoted(flag, s, format!("expected {N} comma-separated numbers"));
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    v.try_into().map_err(|_| bad())
}

/// Parse `W,H` (pixels, each 200..=8000 so that every chart fits its labels).
pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), Error> {
    let [w, h] = parse_list::<2>("--size", s)?;
    let ok = |v: f64| v.fract() == 0.0 && (200.0..=8000.0).contains(&v);
    if !(ok(w) && ok(h)) {
        return Err(Error::arg(
            "--size",
            s,
            "expected W,H in pixels, each 200..8000",
        ));
    }
    Ok((w as u32, h as u32))
}

/// Default config path of the installed service.
pub(crate) const DEFAULT_CONFIG: &str = "/etc/infraloc/infraloc.toml";

/// Say once, on stderr, what an input reader adjusted (a re-orthonormalised rotation,
/// [`crate::orthonormal`]): `infraloc: note: FILE: FIELD …`.
pub(crate) fn note(line: &str) {
    eprintln!("infraloc: note: {line}");
}
