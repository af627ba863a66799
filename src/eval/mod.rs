//! Evaluation against the simulator's ground truth: the `truth.json` reader ([`truth`]), the
//! scoring of poses against it ([`truth_eval`]: errors, the oracle, ground error by distance band)
//! and the seed's robustness study ([`study`]). Nothing of the node's job depends on it.

pub(crate) mod study;
pub mod truth;
pub mod truth_eval;
