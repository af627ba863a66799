//! The names of a localization run's stages, one enum for every place that names them: the
//! progress callback, the service's status and progress messages, the pose file's and report's
//! `stages`, and the stage errors of the pipeline. Initialization is one stage, `pnp`, whichever
//! matcher feeds it (its sub-steps, the satellite sweep and the patch matching, say so in the
//! error text after the stage name).

use serde::{Deserialize, Serialize};

/// A stage of a localization run, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StageName {
    /// Accepted, not yet capturing.
    Starting,
    /// Taking frames.
    Capture,
    /// Acquiring the GPS prior.
    Prior,
    /// Finding and loading the map tile.
    Tile,
    /// Initialization: matching + PnP.
    Pnp,
    /// MI refinement.
    Mi,
    /// Comparing a new result with the served pose on the same frames.
    CrossCheck,
}

impl StageName {
    /// Name as printed and sent.
    pub fn name(self) -> &'static str {
        match self {
            StageName::Starting => "starting",
            StageName::Capture => "capture",
            StageName::Prior => "prior",
            StageName::Tile => "tile",
            StageName::Pnp => "pnp",
            StageName::Mi => "mi",
            StageName::CrossCheck => "cross-check",
        }
    }
}

impl std::fmt::Display for StageName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
