//! Refinement (the seed's step 2): the MI grid [`search`] over the objective of
//! `localize::mi`, the local 6-DoF [`polish`], the [`quality`] gate, the [`uncertainty`] of the
//! answer, and the [`rounds`] that alternate search and polish, and the service's [`drift`] check.

pub mod drift;
pub mod gradient;
pub mod polish;
pub mod quality;
pub mod rounds;
pub mod search;
pub mod uncertainty;

pub use rounds::*;
