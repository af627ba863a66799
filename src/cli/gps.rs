//! `infraloc gps …` (placeholder: implemented by the node I/O work in progress).

use crate::error::{Error, Result};

/// GPS subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// NMEA log → one JSON line per fix.
    Decode,
}

/// Run a gps subcommand.
pub fn run(_c: Command) -> Result<()> {
    Err(Error::Invalid("gps decode: not built yet".into()))
}
