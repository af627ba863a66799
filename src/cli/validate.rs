//! `infraloc validate [--config FILE] [--running] [--json]`.

use crate::config::Config;
use crate::error::Result;
use serde_json::json;
use std::path::PathBuf;

/// Arguments of `validate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Configuration file.
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Ask the running daemon to validate its own config file, as a reload (SIGHUP) would read it.
    #[arg(long)]
    pub running: bool,
    /// With --running: the control socket (default: `[daemon] socket` of --config).
    #[arg(long, requires = "running")]
    pub socket: Option<PathBuf>,
    /// Print JSON (`{"ok": …, "warnings": […]}`) instead of "config OK".
    #[arg(long)]
    pub json: bool,
}

/// Load, validate and check a config; warnings go to stderr, success prints "config OK".
pub fn run(a: Args) -> Result<()> {
    if a.running {
        return super::tech::validate_running(a.socket.as_deref(), &a.config, a.json);
    }
    let cfg = Config::load(&a.config)?;
    cfg.validate(&a.config)?;
    let warnings = cfg.check();
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
