//! Refinement (the seed's step 2): the MI grid [`search`] over the objective of
//! `localize::mi`, the local 6-DoF [`polish`], the [`quality`] gate, the [`uncertainty`] of the
//! answer, the [`rounds`] that alternate search and polish, the smooth estimator's [`local`]
//! stage (its [`ascent`] and the [`information`] covariance), and the service's [`drift`] check.

pub mod ascent;
pub mod drift;
pub mod information;
pub mod local;
pub mod optima;
pub mod polish;
pub mod quality;
pub mod rounds;
pub mod search;
pub mod uncertainty;

pub use rounds::*;
