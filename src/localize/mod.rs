//! Localization: initialization (matching + PnP) and refinement (mutual information).
//!
//! MI refinement (seed §"Refinement of camera localization using Maximization of Mutual
//! Information"): from an initial pose, maximise the mutual information between LiDAR ground
//! reflectivity and the fisheye grayscale at the points' projections over Θ = [x, y, z, ψ].
//! [`points`] (the point type and its f32 hot-loop form), [`mi`] (the pure estimator), [`kernel`]
//! (project + sample + joint histogram, the hot loop), [`search`] (exhaustive and tiled
//! coarse-to-fine grid search), [`polish`] (a local 6-DoF Nelder–Mead after it), [`quality`] (peak statistics and the gate), [`refine`] (one call).
//! Initialization: [`coarse`] (the dense orientation [`sweep`] over yaw × height × translation)
//! then [`init`] (patch matching + `pnp`, hypotheses judged by [`verify`]); [`ground`] holds the
//! ground and image geometry they share. [`matcher`] is the seam where another matcher (a learned
//! one, or correspondences from a file) replaces the built-in satellite matching. [`points_io`] is the I/O shell that reads CSV / PCD / LAS point files. Design and measurements:
//! `docs/refine.md`.

pub mod coarse;
pub mod frame;
pub mod gradient;
pub mod ground;
pub mod init;
pub mod kernel;
pub mod matcher;
pub mod mi;
pub mod pipeline;
pub(crate) mod pnp;
pub mod points;
pub mod points_io;
pub mod polish;
pub(crate) mod poly;
pub mod quality;
pub mod refine;
pub mod search;
pub mod smooth;
pub(crate) mod study;
pub mod sweep;
pub mod synth;
pub mod truth_eval;
pub mod uncertainty;
pub mod verify;
