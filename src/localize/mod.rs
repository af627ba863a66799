//! Localization: initialization (matching + PnP) and refinement (mutual information).

pub mod init;
pub mod matching;
pub mod pnp;
pub mod poly;
