//! MI refinement (seed §"Refinement of camera localization using Maximization of Mutual
//! Information"): from an initial pose, maximise the mutual information between LiDAR ground
//! reflectivity and the fisheye grayscale at the points' projections over Θ = [x, y, z, ψ].
//!
//! Layout: [`points`] (the point type and its f32 hot-loop form), [`mi`] (the pure estimator),
//! [`kernel`] (project + sample + joint histogram, the hot loop), [`search`] (exhaustive and tiled
//! coarse-to-fine grid search), [`quality`] (peak statistics and the gate). [`points_io`] is the I/O
//! shell that reads CSV / PCD / LAS point files. Design and measurements: `docs/refine.md`.

pub mod kernel;
pub mod mi;
pub mod points;
pub mod points_io;
pub mod quality;
pub mod refine;
pub mod search;
pub mod synth;
