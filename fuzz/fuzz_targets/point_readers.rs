//! Arbitrary bytes as a LiDAR point file, through each reader (CSV, PCD, LAS, Velodyne `.bin`):
//! no panic, and every point a reader accepts has finite coordinates (each reader promises to
//! reject non-finite ones with an error naming the point). The same bytes as the header, VLR and
//! EVLR tables of a LAS 1.0–1.4 file (`map::las_header`, what `tile build` checks before the `las`
//! crate reads anything) and their CRS records as a WKT (`geo::stated`): no panic, no allocation
//! beyond the file, and an accepted layout within the file's bytes and its version's fields.
#![no_main]

use infraloc::geo::stated::wkt_in_metres;
use infraloc::map::las_header::{read_layout, WKT_RECORD};
use infraloc::points_io::{parse_csv, parse_las, parse_pcd, parse_velodyne_bin};
use libfuzzer_sys::fuzz_target;
use std::io::Cursor;

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
    if let Ok(layout) = read_layout(&mut Cursor::new(data), data.len() as u64) {
        assert!(layout.version.0 == 1 && layout.version.1 <= 4, "{:?}", layout.version);
        assert!(layout.version.1 == 4 || layout.evlrs == 0, "EVLRs before LAS 1.4");
        assert!(layout.point_format <= 10);
        let records: usize = layout.crs_records.iter().map(|r| r.data.len()).sum();
        assert!(records <= data.len(), "CRS records longer than the file");
        for r in layout.crs_records.iter().filter(|r| r.record_id == WKT_RECORD) {
            let _ = wkt_in_metres(&String::from_utf8_lossy(&r.data));
        }
    }
    // WKT text straight from the bytes, as a CRS record would hold it.
    let _ = wkt_in_metres(&String::from_utf8_lossy(data));
});
