//! `infraloc validate --config FILE`.

use crate::config::Config;
use crate::error::Result;
use std::path::PathBuf;

/// Arguments of `validate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Configuration file.
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
}

/// Load, validate and check a config; warnings go to stderr, success prints "config OK".
pub fn run(a: Args) -> Result<()> {
    let cfg = Config::load(&a.config)?;
    cfg.validate(&a.config)?;
    for w in cfg.check() {
        eprintln!("warning: {}: {w}", a.config.display());
    }
    println!("config OK");
    Ok(())
}
