//! `infraloc daemon` and the technician commands that talk to it over the control socket:
//! `status`, `relocalize [--wait]`, `pose`, `overlay`, and `validate --running`.

use crate::config::{Config, DEFAULT_SOCKET};
use crate::control::{Client, Request};
use crate::error::{Error, Result};
use serde_json::Value;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Exit code of `status` when the service is degraded (serving an older pose).
pub const EXIT_DEGRADED: i32 = 3;
/// Exit code of `status` when no pose is served and the last attempt failed.
pub const EXIT_FAILED: i32 = 4;
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
            Some(n) => Error::Invalid(format!("{e} ({n})")),
            None => e,
        })
    }

    /// One request; a `busy` answer (every slot taken, the request not run) is retried for up to
    /// [`BUSY_RETRY`], then shown as the server's reason.
    fn call(&self, req: Request) -> Result<(Value, Option<Vec<u8>>)> {
        let start = std::time::Instant::now();
        loop {
            let (v, payload) = self.connect()?.call(&req, ANSWER_TIMEOUT, |_| {})?;
            let busy = v["error"].as_str().is_some_and(|e| e.starts_with("busy"));
            if !busy || start.elapsed() >= BUSY_RETRY {
                return Ok((v, payload));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }
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
pub fn daemon(a: DaemonArgs) -> Result<()> {
    crate::daemon::run(&a.config)
}

fn failed(v: &Value) -> Error {
    Error::Invalid(
        v["error"]
            .as_str()
            .unwrap_or("the daemon refused the request")
            .to_string(),
    )
}

/// `status`: returns the exit code (0 ok/starting, 3 degraded, 4 failed).
pub fn status(t: Target) -> Result<i32> {
    let (v, _) = t.call(Request::Status {})?;
    if v["ok"] != true {
        return Err(failed(&v));
    }
    if t.json {
        println!("{v}");
    } else {
        print!("{}", human_status(&v));
    }
    Ok(match v["state"].as_str() {
        Some("degraded") => EXIT_DEGRADED,
        Some("failed") => EXIT_FAILED,
        _ => 0,
    })
}

fn fmt_secs(v: &Value) -> String {
    v.as_f64()
        .map(|s| {
            if s >= 3600.0 {
                format!("{:.1} h", s / 3600.0)
            } else if s >= 60.0 {
                format!("{:.0} min", s / 60.0)
            } else {
                format!("{s:.0} s")
            }
        })
        .unwrap_or_else(|| "—".into())
}

/// The status as a technician reads it: the summary line first, then the details.
pub fn human_status(v: &Value) -> String {
    let mut o = String::new();
    let line = |o: &mut String, k: &str, val: String| o.push_str(&format!("  {k:<14} {val}\n"));
    o.push_str(&format!("{}\n", v["summary"].as_str().unwrap_or("?")));
    if let Some(p) = v["served"].as_object() {
        let c = &p["camera_center"];
        line(
            &mut o,
            "pose",
            format!(
                "{} ({}, tile {})",
                p["file"].as_str().unwrap_or("?"),
                p["crs"].as_str().unwrap_or("?"),
                p["tile_id"].as_str().unwrap_or("?")
            ),
        );
        line(
            &mut o,
            "centre",
            format!(
                "{:.3} {:.3} {:.3} m",
                c[0].as_f64().unwrap_or(f64::NAN),
                c[1].as_f64().unwrap_or(f64::NAN),
                c[2].as_f64().unwrap_or(f64::NAN)
            ),
        );
        line(
            &mut o,
            "yaw",
            format!(
                "{:.3}°",
                p["yaw_pitch_roll_deg"][0].as_f64().unwrap_or(f64::NAN)
            ),
        );
        line(
            &mut o,
            "computed",
            p["timestamp_utc"].as_str().unwrap_or("?").to_string(),
        );
    } else {
        line(&mut o, "pose", "none served".into());
    }
    if let Some(r) = v["running"].as_object() {
        line(
            &mut o,
            "running",
            format!(
                "{} ({}), {}",
                r["job"].as_str().unwrap_or("?"),
                r["stage"].as_str().unwrap_or("?"),
                fmt_secs(&r["seconds"])
            ),
        );
    }
    if let Some(r) = v["last_result"].as_object() {
        let what = if r["ok"] == true {
            format!(
                "ok in {}, {}",
                fmt_secs(&r["seconds"]),
                if r["served"] == true {
                    "served".to_string()
                } else {
                    format!("not served: {}", r["decision"].as_str().unwrap_or("?"))
                }
            )
        } else {
            format!("FAILED: {}", r["error"].as_str().unwrap_or("?"))
        };
        line(
            &mut o,
            "last run",
            format!("{} {what}", r["finished_utc"].as_str().unwrap_or("?")),
        );
        // A damaged tile elsewhere in the cache does not stop the node, but must be seen.
        for t in r["skipped_tiles"].as_array().into_iter().flatten() {
            line(
                &mut o,
                "tile skipped",
                t.as_str().unwrap_or("?").to_string(),
            );
        }
    }
    if let Some(d) = v["last_drift_check"].as_object() {
        let what = match d["moved"].as_bool() {
            Some(true) => format!(
                "MOVED: {}{}",
                d["reason"].as_str().unwrap_or("?"),
                d["resolved"]
                    .as_str()
                    .map(|r| format!(" ({r})"))
                    .unwrap_or_default()
            ),
            Some(false) => format!(
                "steady (shift {:.3} m, yaw {:.3}°)",
                d["shift_m"].as_f64().unwrap_or(f64::NAN),
                d["yaw_deg"].as_f64().unwrap_or(f64::NAN)
            ),
            None => format!("not run: {}", d["error"].as_str().unwrap_or("?")),
        };
        line(
            &mut o,
            "drift check",
            format!("{} {what}", d["checked_utc"].as_str().unwrap_or("?")),
        );
    }
    if v["failures_in_a_row"].as_u64().unwrap_or(0) > 0 {
        line(
            &mut o,
            "failures",
            format!("{} in a row", v["failures_in_a_row"]),
        );
    }
    if !v["next_localize_in_s"].is_null() {
        line(
            &mut o,
            "next run",
            format!("in {}", fmt_secs(&v["next_localize_in_s"])),
        );
    }
    if !v["next_drift_check_in_s"].is_null() {
        line(
            &mut o,
            "next check",
            format!("in {}", fmt_secs(&v["next_drift_check_in_s"])),
        );
    }
    line(
        &mut o,
        "daemon",
        format!(
            "pid {}, up {}, v{}, {}",
            v["pid"],
            fmt_secs(&v["uptime_s"]),
            v["version"].as_str().unwrap_or("?"),
            v["config"].as_str().unwrap_or("?")
        ),
    );
    o
}

/// `relocalize [--wait] [--force]`.
pub fn relocalize(a: RelocalizeArgs) -> Result<()> {
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
    let (v, _) = a.target.connect()?.call(&req, timeout, |p| {
        if !a.target.json {
            let stage = p["progress"].as_str().unwrap_or("?");
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
        println!("{v}");
    }
    if v["ok"] != true {
        return Err(Error::stage(
            "relocalize",
            v["error"].as_str().unwrap_or("failed").to_string(),
        ));
    }
    if !a.target.json {
        if a.wait {
            let c = &v["camera_center"];
            println!(
                "localized in {:.1} s: centre ({:.3}, {:.3}, {:.3}), yaw {:.3}°, score {:.4}; {}",
                v["seconds"].as_f64().unwrap_or(f64::NAN),
                c[0].as_f64().unwrap_or(f64::NAN),
                c[1].as_f64().unwrap_or(f64::NAN),
                c[2].as_f64().unwrap_or(f64::NAN),
                v["yaw_pitch_roll_deg"][0].as_f64().unwrap_or(f64::NAN),
                v["score"].as_f64().unwrap_or(f64::NAN),
                if v["served"] == true {
                    format!("served ({})", v["decision"].as_str().unwrap_or(""))
                } else {
                    format!(
                        "NOT served: {} (use --force to serve it)",
                        v["decision"].as_str().unwrap_or("")
                    )
                }
            );
        } else {
            println!("relocalization queued; `infraloc status` shows its progress");
        }
    }
    Ok(())
}

/// `pose`: the served pose document.
pub fn pose(t: Target) -> Result<()> {
    let (v, _) = t.call(Request::GetPose {})?;
    if v["ok"] != true {
        return Err(failed(&v));
    }
    println!(
        "{}",
        serde_json::to_string_pretty(&v["pose"]).unwrap_or_default()
    );
    Ok(())
}

/// `overlay --out PNG`.
pub fn overlay(a: OverlayArgs) -> Result<()> {
    let (v, png) = a.target.call(Request::DumpOverlay {})?;
    if v["ok"] != true {
        return Err(failed(&v));
    }
    let png = png.ok_or_else(|| Error::input(a.target.socket(), "answer without the PNG"))?;
    crate::persist::write_atomic(&a.out, &png)?;
    if !a.target.json {
        println!(
            "{}: overlay of the run at {} ({} bytes)",
            a.out.display(),
            v["timestamp_utc"].as_str().unwrap_or("?"),
            png.len()
        );
    }
    Ok(())
}

/// `validate --running`: ask the daemon to validate its config file as a reload would.
pub fn validate_running(socket: Option<&Path>, config: &Path, json: bool) -> Result<()> {
    let t = Target {
        socket: socket.map(Path::to_path_buf),
        config: config.to_path_buf(),
        json,
    };
    let (v, _) = t.call(Request::Validate {})?;
    if json {
        println!("{v}");
    }
    if v["ok"] != true {
        // The daemon's answer is the config error itself: same exit code as a local validate.
        let path = v["config"].as_str().unwrap_or("?");
        let msg = v["error"].as_str().unwrap_or("invalid");
        let prefix = format!("config {path}: ");
        return Err(Error::config(
            path,
            msg.strip_prefix(&prefix).unwrap_or(msg).to_string(),
        ));
    }
    if !json {
        if let Some(ws) = v["warnings"].as_array() {
            for w in ws {
                eprintln!("warning: {}", w.as_str().unwrap_or("?"));
            }
        }
        println!("config OK");
    }
    Ok(())
}
