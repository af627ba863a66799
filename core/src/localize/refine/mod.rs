//! Refinement (the seed's step 2): the global part, the nearest-pixel MI grid [`search`] over the
//! objective of `localize::mi`, the Nelder–Mead [`polish`] and the [`rounds`] that alternate
//! them; the smooth estimator's [`local`] stage, the one local stage and σ source (its
//! [`ascent`], the [`information`] covariance and the competing [`optima`]); the [`quality`]
//! gates, the reported [`uncertainty`], and the service's [`drift`] check.

pub mod ascent;
pub mod drift;
pub mod information;
pub mod local;
pub mod optima;
pub mod polish;
pub mod quality;
pub mod region;
pub mod rounds;
pub mod search;
pub mod uncertainty;
pub mod verdict;

pub use local::{refine, refine_smooth};
pub use rounds::*;
