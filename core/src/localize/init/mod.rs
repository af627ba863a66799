//! Initialization from a GPS prior alone (the seed's step 1): the [`coarse`] satellite sweep over
//! yaw × height × translation (on [`sweep`]'s orientation fields), then per hypothesis the [`fine`]
//! stage (ground patches matched against the satellite, PnP + RANSAC on their bearings), each
//! hypothesis judged by [`verify`] (the LiDAR MI); [`ground`] holds the ground and image geometry
//! they share, and [`matcher`] is the seam where another matcher replaces the built-in one.
//! Nothing here imports the refinement (`localize::refine`).

pub mod coarse;
pub mod fine;
pub mod ground;
pub mod matcher;
pub mod sweep;
pub mod verify;

pub use fine::*;
