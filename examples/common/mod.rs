//! Helpers shared by the measuring examples (`drift_cost`, `scaling`; `benches/refine.rs` uses
//! the camera). Included with `#[path]`, so each user compiles only what it calls.
#![allow(dead_code, unreachable_pub)]

use infraloc::camera::{Camera, Mei};

/// Process CPU time (user + system, all threads), seconds.
pub fn cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant the kernel knows.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// The `5mp` preset's given intrinsics (scene seed 2), scaled to `width`×`height`: focal
/// lengths and the centre's column with the width, the centre's row with the height.
pub fn preset_camera(width: u32, height: u32) -> Camera {
    let s = width as f64 / 2448.0;
    Camera::Mei(Mei {
        width,
        height,
        fx: 1199.27 * s,
        fy: 1198.64 * s,
        cx: 1225.22 * s,
        cy: 1026.07 * height as f64 / 2048.0,
        skew: 0.0,
        xi: 1.2,
        k1: -0.2673,
        k2: 0.0929,
        p1: -1.7e-4,
        p2: -3.1e-5,
        fov_deg: Some(185.0),
    })
}
