//! Localization: initialization (matching + PnP) and refinement (mutual information), in three
//! rooms over one [`frame`]:
//! - [`mi`]: the MI engine both steps share — the estimator, the projection and histogram
//!   [`mi::kernel`], the LiDAR [`mi::points`], the search space ([`mi::space`]) and the objective
//!   that scores a pose ([`mi::objective`]);
//! - [`init`]: the seed's step 1 from a GPS prior (satellite sweep, patch matching, PnP,
//!   hypotheses judged by the LiDAR MI); it never imports [`refine`];
//! - [`refine`]: the seed's step 2 (grid search, polish, quality gate, uncertainty, the rounds).
//!
//! [`pnp`] (P3P on bearings + RANSAC + LM) serves both; [`pipeline`] runs prior → init → refine →
//! gate. Design and measurements: `docs/refine.md`.

pub mod error;
pub mod frame;
pub mod init;
pub mod mi;
pub mod pipeline;
pub mod pnp;
pub(crate) mod poly;
pub mod refine;
pub mod synth;
