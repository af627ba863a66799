//! `infraloc tile …` (placeholder: implemented by the foundation work in progress).

use crate::error::{Error, Result};

/// Tile subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Build a tile from GeoTIFFs or images + world files.
    Import,
}

/// Run a tile subcommand.
pub fn run(_c: Command) -> Result<()> {
    Err(Error::Invalid("tile import: not built yet".into()))
}
