//! Arbitrary text as a match file (`[init] matcher = "match-file"`): the parser never panics,
//! and a file it accepts has at least one row, every value finite.
#![no_main]

use infraloc::localize::init::matcher::MatchFile;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(m) = MatchFile::parse(text, Path::new("matches.csv")) {
        assert!(!m.rows().is_empty(), "accepted a file without rows");
        for r in m.rows() {
            let vals = [r.pixel.x, r.pixel.y, r.map_xy.0, r.map_xy.1, r.z.unwrap_or(0.0)];
            assert!(vals.iter().all(|v| v.is_finite()), "non-finite row accepted: {r:?}");
        }
    }
});
