//! The integration tests, one binary: each file in `tests/` used to be a binary of its own that
//! linked the whole crate, so the suite's build was mostly linking. One module per subject, the
//! shared helpers in `common` (its scenes are simulated once per run, whichever modules ask).
//!
//! Two tiers (docs/architecture.md "Tests"): the fast tier runs by default; the slow tier (5 MP scenes, the real
//! KITTI data, long soaks) is `#[ignore = "slow tier: …"]`, and CI runs both (`bash .ci/test`, or
//! `--include-ignored`). `bash .ci/test --fast` runs the fast tier alone.
//!
//! Every test shares this process: none may change the environment, the current directory, the
//! umask or signal dispositions (the services under test are child processes), and a test that
//! spawns this binary as its own child names the child test by its module path.

mod common;

mod aravis_fake;
mod calibrate_cli;
mod calibrate_sim;
mod camera_reference;
mod config_cli;
mod control_socket;
mod daemon_e2e;
mod demo_cli;
mod gantry_sim;
mod gdal_reads_tiles;
mod geo_national_grids;
mod geo_reference;
mod georef_cli;
mod georef_service;
mod gnss_gpsd;
mod gnss_prior;
mod gnss_robust;
mod gnss_serial;
mod initializer_served;
mod kitti_layouts;
mod las_versions;
mod layering;
mod localize_failures;
mod low_pole;
mod man_pages;
mod map_faults;
mod matcher;
mod metrics;
mod packaging;
mod polish_synthetic;
mod quality_gate;
mod real_kitti;
mod rectify_reference;
mod refine_cli;
mod refine_forward;
mod refine_pooled;
mod refine_synthetic;
mod runner_up;
mod simulate_cli;
mod simulate_times;
mod small_faults;
mod study_cli;
mod survey_corpus;
mod systemd_units;
mod tile_build;
mod tile_cache;
mod tile_import;
mod tile_scans;
mod validate_cli;
