//! `infraloc validate [--config FILE] [--keys-only] [--running] [--json]`.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::preflight;
use serde_json::json;
use std::path::PathBuf;

/// Arguments of `validate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Configuration file.
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Check the keys only, not the files, devices and directories they name (for a config
    /// written on another machine than the node).
    #[arg(long, conflicts_with = "running")]
    pub keys_only: bool,
    /// Ask the running daemon to validate its own config file, as a reload (SIGHUP) would read it.
    #[arg(long)]
    pub running: bool,
    /// With --running: the control socket (default: `[daemon] socket` of --config).
    #[arg(long, requires = "running")]
    pub socket: Option<PathBuf>,
    /// Print JSON (`{"ok": …, "warnings": […]}`, with `"problems"` when not ok) instead of
    /// "config OK".
    #[arg(long)]
    pub json: bool,
}

/// Load, validate and check a config; warnings go to stderr, success prints "config OK".
/// Problems: every one, one line each naming its key, exit 78.
pub(super) fn run(a: Args) -> Result<()> {
    if a.running {
        return super::tech::validate_running(a.socket.as_deref(), &a.config, a.json);
    }
    let result = if a.keys_only {
        Config::load(&a.config).map(|c| {
            let w = c.check();
            (c, w)
        })
    } else {
        preflight::load_for_service(&a.config)
    };
    let warnings = match result {
        Ok((_, w)) => w,
        Err(e) => {
            if a.json {
                let problems = match &e {
                    Error::ConfigList { problems, .. } => problems.clone(),
                    Error::Config { msg, .. } => vec![msg.clone()],
                    e => vec![e.to_string()],
                };
                println!(
                    "{}",
                    json!({"ok": false, "config": a.config, "problems": problems})
                );
            }
            return Err(e);
        }
    };
    if a.json {
        println!(
            "{}",
            json!({"ok": true, "config": a.config, "warnings": warnings})
        );
        return Ok(());
    }
    for w in warnings {
        eprintln!("warning: {}: {w}", a.config.display());
    }
    println!("config OK");
    Ok(())
}
