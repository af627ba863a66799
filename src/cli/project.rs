//! `infraloc project` (placeholder: implemented by the foundation work in progress).

use crate::error::{Error, Result};

/// Arguments of `project`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `project`.
pub fn run(_a: Args) -> Result<()> {
    Err(Error::Invalid("project: not built yet".into()))
}
