//! Localization: initialization (matching + PnP) and refinement (mutual information).

pub mod pnp;
pub mod poly;
