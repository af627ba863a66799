//! Arbitrary bytes as a LiDAR point file, through each reader (CSV, PCD, LAS, Velodyne `.bin`):
//! no panic, and every point a reader accepts has finite coordinates (each reader promises to
//! reject non-finite ones with an error naming the point).
#![no_main]

use infraloc::points_io::{parse_csv, parse_las, parse_pcd, parse_velodyne_bin};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    for (name, parsed) in [
        ("csv", parse_csv(data)),
        ("pcd", parse_pcd(data)),
        ("las", parse_las(data)),
        ("bin", parse_velodyne_bin(data)),
    ] {
        if let Ok(points) = parsed {
            for p in &points {
                assert!(
                    p.x.is_finite() && p.y.is_finite() && p.z.is_finite(),
                    "{name}: non-finite point accepted: {p:?}"
                );
            }
        }
    }
});
