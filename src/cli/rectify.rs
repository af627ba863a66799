//! `infraloc rectify` (placeholder: implemented by the foundation work in progress).

use crate::error::{Error, Result};

/// Arguments of `rectify`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `rectify`.
pub fn run(_a: Args) -> Result<()> {
    Err(Error::Invalid("rectify: not built yet".into()))
}
