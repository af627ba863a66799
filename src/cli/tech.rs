//! `infraloc daemon` and the technician commands that talk to it over the control socket:
//! `status`, `relocalize [--wait]`, `pose`, `overlay`, and `validate --running`.

use crate::config::{Config, DEFAULT_SOCKET};
use crate::control::{Answer, Client, Request};
use crate::daemon::status::{
    ConfigRefusal, DriftOutcome, OverlayAnswer, PoseAnswer, Queued, RunOutcome, RunResult, State,
    Status, Validated,
};
use crate::error::{Error, Result};
use crate::localize::refine::quality::Sigma;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Exit code of `status` when the service is degraded (serving an older pose).
pub(crate) const EXIT_DEGRADED: i32 = 3;
/// Exit code of `status` when no pose is served and the last attempt failed.
pub(crate) const EXIT_FAILED: i32 = 4;
/// How long a technician command keeps retrying a `busy` answer.
const BUSY_RETRY: Duration = Duration::from_secs(3);
/// How long a non-waiting request may take.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(10);

/// Arguments of `daemon`.
#[derive(Debug, clap::Args)]
pub struct DaemonArgs {
    /// Configuration file.
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
}

/// Where to find the daemon.
#[derive(Debug, Clone, clap::Args)]
pub struct Target {
    /// Control socket (default: `[daemon] socket` of --config, else /run/infraloc/control.sock).
    #[arg(long)]
    pub socket: Option<PathBuf>,
    /// Config file whose `[daemon] socket` to use.
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Print the daemon's JSON answer instead of the human summary.
    #[arg(long)]
    pub json: bool,
}

impl Target {
    /// The socket to use, and a note when the config could not say (its socket then is the
    /// default, and a failure to connect should mention why).
    fn socket_and_note(&self) -> (PathBuf, Option<String>) {
        if let Some(s) = &self.socket {
            return (s.clone(), None);
        }
        match Config::load(&self.config) {
            Ok(c) => (c.daemon.socket, None),
            Err(e) => (
                PathBuf::from(DEFAULT_SOCKET),
                Some(format!("{e}; tried the default socket")),
            ),
        }
    }

    fn socket(&self) -> PathBuf {
        self.socket_and_note().0
    }

    /// Connect, naming the config problem if the socket came from the default because of it.
    fn connect(&self) -> Result<Client> {
        let (path, note) = self.socket_and_note();
        Client::connect(&path).map_err(|e| match note {
            Some(note) => Error::Connect {
                source: Box::new(e),
                note,
            },
            None => e,
        })
    }

    /// One request; a `busy` answer (every slot taken, the request not run) is retried for up to
    /// [`BUSY_RETRY`], then shown as the server's reason.
    fn call(&self, req: Request) -> Result<Answer> {
        let start = std::time::Instant::now();
        loop {
            let a = self.connect()?.call(&req, ANSWER_TIMEOUT, |_| {})?;
            let busy = a.refusal().is_some_and(|e| e.starts_with("busy"));
            if !busy || start.elapsed() >= BUSY_RETRY {
                return Ok(a);
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

/// How `status` prints the service's status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum StatusFormat {
    /// The summary line, then the details (the default).
    Human,
    /// The daemon's JSON answer (as `--json`).
    Json,
    /// OpenMetrics text, the same the service writes into `[daemon] metrics-dir`.
    Openmetrics,
}

/// Arguments of `status`.
#[derive(Debug, clap::Args)]
pub struct StatusArgs {
    /// Output format (`--json` is short for `--format json`).
    #[arg(long, value_enum, default_value = "human")]
    pub format: StatusFormat,
    /// Where the daemon is.
    #[command(flatten)]
    pub target: Target,
}

/// Arguments of `relocalize`.
#[derive(Debug, clap::Args)]
pub struct RelocalizeArgs {
    /// Wait for the result, showing progress.
    #[arg(long)]
    pub wait: bool,
    /// Serve the result even if its quality is below the served pose's (it must still be ok).
    #[arg(long)]
    pub force: bool,
    /// Where the daemon is.
    #[command(flatten)]
    pub target: Target,
}

/// Arguments of `overlay`.
#[derive(Debug, clap::Args)]
pub struct OverlayArgs {
    /// PNG to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Where the daemon is.
    #[command(flatten)]
    pub target: Target,
}

/// Run the service.
pub(crate) fn daemon(a: DaemonArgs) -> Result<()> {
    crate::daemon::run(&a.config)
}

/// The daemon's answer when it served the request, else its reason as the error.
fn served(a: &Answer) -> Result<()> {
    match a.refusal() {
        None => Ok(()),
        Some(e) => Err(Error::Refused {
            reason: e.to_string(),
        }),
    }
}

/// `status`: returns the exit code (0 ok/starting, 3 degraded, 4 failed).
pub(crate) fn status(a: StatusArgs) -> Result<i32> {
    let t = a.target;
    let answer = t.call(Request::Status {})?;
    served(&answer)?;
    let s: Status = answer.parse("status")?;
    let format = if t.json { StatusFormat::Json } else { a.format };
    match format {
        StatusFormat::Json => println!("{}", answer.text()),
        StatusFormat::Human => print!("{}", human_status(&s)),
        StatusFormat::Openmetrics => print!(
            "{}",
            crate::daemon::metrics::render(&s, crate::daemon::metrics::now_unix())
        ),
    }
    let coarse = s.served.as_ref().is_some_and(|p| p.grade == "coarse");
    Ok(match s.state {
        State::Degraded => EXIT_DEGRADED,
        State::Failed => EXIT_FAILED,
        State::Ok if coarse => crate::error::EXIT_COARSE,
        State::Starting | State::Ok => 0,
    })
}

fn fmt_secs(s: f64) -> String {
    if s >= 3600.0 {
        format!("{:.1} h", s / 3600.0)
    } else if s >= 60.0 {
        format!("{:.0} min", s / 60.0)
    } else {
        format!("{s:.0} s")
    }
}

/// The status as a technician reads it: the summary line first, then the details.
pub(crate) fn human_status(v: &Status) -> String {
    let mut o = String::new();
    let line = |o: &mut String, k: &str, val: String| o.push_str(&format!("  {k:<14} {val}\n"));
    o.push_str(&format!("{}\n", v.summary));
    if let Some(p) = &v.served {
        let c = p.camera_center;
        line(
            &mut o,
            "pose",
            format!("{} ({}, tile {})", p.file.display(), p.crs, p.tile_id),
        );
        line(
            &mut o,
            "centre",
            format!("{:.3} {:.3} {:.3} m", c[0], c[1], c[2]),
        );
        line(&mut o, "yaw", format!("{:.3}°", p.yaw_pitch_roll_deg[0]));
        line(
            &mut o,
            "grade",
            match &p.grade_reason {
                Some(why) => format!("{} ({why})", p.grade),
                None => p.grade.clone(),
            },
        );
        line(&mut o, "uncertainty", sigma_line(p.sigma.as_ref()));
        line(&mut o, "computed", p.timestamp_utc.clone());
    } else {
        line(&mut o, "pose", "none served".into());
    }
    if let Some(r) = &v.running {
        line(
            &mut o,
            "running",
            format!(
                "{} ({}), {}",
                r.job.name(),
                r.stage.name(),
                fmt_secs(r.seconds)
            ),
        );
    }
    if let Some(r) = &v.last_result {
        let what = match &r.outcome {
            RunOutcome::Localized {
                served, decision, ..
            } => format!(
                "ok in {}, {}",
                fmt_secs(r.seconds),
                if *served {
                    "served".to_string()
                } else {
                    format!("not served: {decision}")
                }
            ),
            RunOutcome::Failed { error, .. } => format!("FAILED: {error}"),
        };
        line(&mut o, "last run", format!("{} {what}", r.finished_utc));
        if !r.pooled_frames.is_empty() {
            line(
                &mut o,
                "pooled",
                format!(
                    "{} earlier frame{} ({})",
                    r.pooled_frames.len(),
                    if r.pooled_frames.len() == 1 { "" } else { "s" },
                    r.pooled_frames.join(", ")
                ),
            );
        }
        if let RunOutcome::Localized { skipped_tiles, .. } = &r.outcome {
            for t in skipped_tiles {
                line(&mut o, "skipped tile", t.reason.clone());
            }
        }
    }
    if let Some(d) = &v.last_drift_check {
        let what = match &d.outcome {
            DriftOutcome::Ran(s) if s.verdict.moved => format!(
                "MOVED: {}{}",
                s.verdict.reason.as_deref().unwrap_or_default(),
                d.resolved
                    .as_deref()
                    .map(|r| format!(" ({r})"))
                    .unwrap_or_default()
            ),
            DriftOutcome::Ran(s) => format!(
                "steady (shift {:.3} m, yaw {:.3}°)",
                s.verdict.shift_m, s.verdict.yaw_deg
            ),
            DriftOutcome::NotRun { error, .. } => format!("not run: {error}"),
        };
        line(&mut o, "drift check", format!("{} {what}", d.checked_utc));
    }
    if !v.stored_frames.is_empty() {
        let mb = v.stored_frames.iter().map(|f| f.bytes).sum::<u64>() as f64 / 1e6;
        line(
            &mut o,
            "stored frames",
            format!(
                "{} ({:.1} MB): {}",
                v.stored_frames.len(),
                mb,
                v.stored_frames
                    .iter()
                    .map(|f| f.taken_utc.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        );
    }
    if v.failures_in_a_row > 0 {
        line(
            &mut o,
            "failures",
            format!("{} in a row", v.failures_in_a_row),
        );
    }
    if let Some(s) = v.next_localize_in_s {
        line(&mut o, "next run", format!("in {}", fmt_secs(s)));
    }
    if let Some(s) = v.next_drift_check_in_s {
        line(&mut o, "next check", format!("in {}", fmt_secs(s)));
    }
    line(
        &mut o,
        "daemon",
        format!(
            "pid {}, up {}, v{}, {}",
            v.pid,
            fmt_secs(v.uptime_s),
            v.version,
            v.config.display()
        ),
    );
    o
}

/// A pose's σ as a technician reads it (cm and degrees), or that the pose has none.
fn sigma_line(s: Option<&Sigma>) -> String {
    s.map_or_else(|| "σ unavailable".to_string(), Sigma::describe)
}

/// `relocalize [--wait] [--force]`.
pub(crate) fn relocalize(a: RelocalizeArgs) -> Result<()> {
    let req = Request::Relocalize {
        wait: a.wait,
        force: a.force,
    };
    let tty = std::io::stderr().is_terminal();
    let timeout = if a.wait {
        crate::daemon::WAIT_TIMEOUT
    } else {
        ANSWER_TIMEOUT
    };
    let start = std::time::Instant::now();
    let answer = a.target.connect()?.call(&req, timeout, |p| {
        if !a.target.json {
            // A newer daemon's stage is shown as it came.
            let stage = p.map_or_else(str::to_string, |s| s.name().to_string());
            if tty {
                eprint!(
                    "\r\x1b[K{:>5.1} s  {stage} …",
                    start.elapsed().as_secs_f64()
                );
            } else {
                eprintln!("{:.1} s: {stage}", start.elapsed().as_secs_f64());
            }
        }
    })?;
    if tty && a.wait && !a.target.json {
        eprint!("\r\x1b[K");
    }
    if a.target.json {
        println!("{}", answer.text());
    }
    if let Some(e) = answer.refusal() {
        return Err(Error::command("relocalize", e.to_string()));
    }
    if !a.target.json {
        if a.wait {
            let r: RunResult = answer.parse("result")?;
            let RunOutcome::Localized {
                served,
                decision,
                camera_center: c,
                yaw_pitch_roll_deg,
                score,
                sigma,
                ..
            } = &r.outcome
            else {
                // `ok: true` parses only as a localized result.
                return Err(Error::command(
                    "relocalize",
                    r.error().unwrap_or("failed").to_string(),
                ));
            };
            println!(
                "localized in {:.1} s: centre ({:.3}, {:.3}, {:.3}), yaw {:.3}°, score {:.4}, {}; {}",
                r.seconds,
                c[0],
                c[1],
                c[2],
                yaw_pitch_roll_deg[0],
                score.unwrap_or(f64::NAN),
                sigma_line(sigma.as_ref()),
                if *served {
                    format!("served ({decision})")
                } else {
                    format!("NOT served: {decision} (use --force to serve it)")
                }
            );
        } else {
            let Queued { queued: true } = answer.parse("answer")? else {
                return Err(Error::input(
                    a.target.socket(),
                    "the daemon's answer does not say the run is queued",
                ));
            };
            println!("relocalization queued; `infraloc status` shows its progress");
        }
    }
    Ok(())
}

/// `pose`: the served pose document.
pub(crate) fn pose(t: Target) -> Result<()> {
    let answer = t.call(Request::GetPose {})?;
    served(&answer)?;
    let p: PoseAnswer = answer.parse("pose")?;
    // Through a JSON value, so the keys are sorted as the daemon's answer has them.
    let pose = serde_json::to_value(&p.pose).unwrap_or_default();
    println!(
        "{}",
        serde_json::to_string_pretty(&pose).unwrap_or_default()
    );
    Ok(())
}

/// `clear-frames`: drop the service's stored frames of earlier runs.
pub(crate) fn clear_frames(t: Target) -> Result<()> {
    let answer = t.call(Request::ClearFrames {})?;
    served(&answer)?;
    let c: crate::daemon::status::Cleared = answer.parse("clear-frames answer")?;
    if t.json {
        println!("{}", answer.text());
    } else {
        println!(
            "{} stored frames dropped; the next runs pool only frames taken from now on",
            c.cleared
        );
    }
    Ok(())
}

/// `overlay --out PNG`.
pub(crate) fn overlay(a: OverlayArgs) -> Result<()> {
    let answer = a.target.call(Request::DumpOverlay {})?;
    served(&answer)?;
    let o: OverlayAnswer = answer.parse("overlay answer")?;
    let png = answer
        .payload()
        .ok_or_else(|| Error::input(a.target.socket(), "answer without the PNG"))?;
    crate::persist::write_atomic(&a.out, png)?;
    if !a.target.json {
        println!(
            "{}: overlay of the run at {} ({} bytes)",
            a.out.display(),
            o.timestamp_utc,
            png.len()
        );
    }
    Ok(())
}

/// `georef --running`: the daemon's georef answer (its refusal as the error).
pub(crate) fn georef_running(socket: Option<&Path>, config: &Path, req: Request) -> Result<Answer> {
    let t = Target {
        socket: socket.map(Path::to_path_buf),
        config: config.to_path_buf(),
        json: true,
    };
    let answer = t.call(req)?;
    served(&answer)?;
    Ok(answer)
}

/// `validate --running`: ask the daemon to validate its config file as a reload would.
pub(crate) fn validate_running(socket: Option<&Path>, config: &Path, json: bool) -> Result<()> {
    let t = Target {
        socket: socket.map(Path::to_path_buf),
        config: config.to_path_buf(),
        json,
    };
    let answer = t.call(Request::Validate {})?;
    if json {
        println!("{}", answer.text());
    }
    if let Some(e) = answer.refusal() {
        // A refusal naming the config file is the config error itself (same exit code as a
        // local validate); one that does not (busy) is the error as it came.
        let Ok(r) = answer.parse::<ConfigRefusal>("config error") else {
            return Err(Error::Refused {
                reason: e.to_string(),
            });
        };
        let prefix = format!("config {}: ", r.config.display());
        let msg = r.error.strip_prefix(&prefix).unwrap_or(&r.error);
        return Err(Error::config(&r.config, msg.to_string()));
    }
    let v: Validated = answer.parse("validation")?;
    if !json {
        for w in &v.warnings {
            eprintln!("warning: {w}");
        }
        println!("config OK");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::status::{Served, StageTime};
    use crate::map::cache::SkippedTile;

    fn status(sigma: Option<Sigma>) -> Status {
        Status {
            state: State::Ok,
            summary: "ok: serving pose".into(),
            pid: 7,
            version: "0.1.0".into(),
            config: "/etc/infraloc/infraloc.toml".into(),
            uptime_s: 90.0,
            served: Some(Served {
                file: "/var/lib/infraloc/pose.json".into(),
                timestamp_utc: "2026-01-02T03:04:05Z".into(),
                tile_id: "t1".into(),
                crs: "EPSG:32632".into(),
                camera_center: [1.0, 2.0, 3.0],
                yaw_pitch_roll_deg: [10.0, -80.0, 0.0],
                score: Some(0.1),
                sigma,
                grade: "precise".into(),
                grade_reason: None,
            }),
            running: None,
            last_result: Some(RunResult {
                finished_utc: "2026-01-02T03:04:05Z".into(),
                seconds: 20.0,
                outcome: RunOutcome::Localized {
                    served: true,
                    decision: "first pose".into(),
                    camera_center: [1.0, 2.0, 3.0],
                    yaw_pitch_roll_deg: [10.0, -80.0, 0.0],
                    score: Some(0.1),
                    sigma,
                    stages: vec![StageTime {
                        name: "mi".into(),
                        seconds: 4.0,
                    }],
                    skipped_tiles: vec![SkippedTile {
                        dir: "/c/aaa".into(),
                        reason: "tile: /c/aaa/tile.toml: truncated".into(),
                    }],
                },
                pooled_frames: Vec::new(),
            }),
            last_drift_check: None,
            failures_in_a_row: 0,
            next_localize_in_s: None,
            next_drift_check_in_s: None,
            reload_error: None,
            stored_frames: Vec::new(),
        }
    }

    #[test]
    fn human_status_shows_sigma_in_cm_and_degrees_and_the_skipped_tiles() {
        let s = human_status(&status(Some(Sigma {
            x: 0.012,
            y: 0.034,
            z: 0.005,
            yaw: 0.042,
            pitch: None,
            roll: None,
        })));
        assert!(
            s.contains("σ x 1.2 cm, y 3.4 cm, z 0.5 cm, yaw 0.042°"),
            "{s}"
        );
        assert!(
            s.contains("skipped tile   tile: /c/aaa/tile.toml: truncated"),
            "{s}"
        );
        let s = human_status(&status(None));
        assert!(s.contains("uncertainty    σ unavailable"), "{s}");
    }
}
