//! `infraloc simulate` (placeholder: implemented by the foundation work in progress).

use crate::error::{Error, Result};

/// Arguments of `simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `simulate`.
pub fn run(_a: Args) -> Result<()> {
    Err(Error::Invalid("simulate: not built yet".into()))
}
