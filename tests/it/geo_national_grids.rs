//! WGS84 ↔ national grids against pyproj (PROJ 9): `tests/data/geo/national_pyproj.csv`, made by
//! `tests/reference/make_national_grid_refs.py` — a 9 × 9 grid over the EPSG area of use of each of
//! RD New (28992), CH1903+ / LV95 (2056), CH1903 / LV03 (21781), ETRS89 / UTM 28N–38N (25828–25838), Lambert-93 (2154),
//! Poland CS92 (2180, transverse Mercator), three NAD83 State Planes in metres (32118, 26943, 32139).
//! Forward (against pyproj's x, y) and inverse (against pyproj's inverse of them) must agree to
//! 1 mm, as the UTM zones do (tests/it/geo_reference.rs).

use infraloc::geo::{map_to_wgs84, wgs84_to_map};
use infraloc::map::Crs;
use std::collections::BTreeMap;

/// Agreement required with pyproj, metres.
const TOL_M: f64 = 1e-3;
/// Metres per degree of latitude (mean), to express angular inverse errors as ground distance.
const M_PER_DEG: f64 = 111_320.0;

#[test]
fn national_grids_match_pyproj_to_1mm() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/geo/national_pyproj.csv"
    );
    let text = std::fs::read_to_string(path).unwrap();
    let mut per_crs: BTreeMap<u32, (usize, f64, f64)> = BTreeMap::new();
    for l in text.lines().skip(1) {
        let f: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
        let (epsg, lat, lon, x, y) = (f[0] as u32, f[1], f[2], f[3], f[4]);
        // pyproj's inverse of (x, y): not (lat, lon) again where a 3-D Helmert meets 2-D points.
        let (plat, plon) = (f[5], f[6]);
        let crs = Crs::Epsg(epsg);
        let (gx, gy) = wgs84_to_map(crs, lat, lon).unwrap();
        let fwd = (gx - x).hypot(gy - y);
        let (ilat, ilon) = map_to_wgs84(crs, x, y).unwrap();
        let inv = M_PER_DEG * (ilat - plat).hypot((ilon - plon) * lat.to_radians().cos());
        let e = per_crs.entry(epsg).or_default();
        e.0 += 1;
        e.1 = e.1.max(fwd);
        e.2 = e.2.max(inv);
    }
    assert_eq!(
        per_crs.len(),
        19,
        "CRSs in the reference: {:?}",
        per_crs.keys()
    );
    let bad: Vec<String> = per_crs
        .iter()
        .filter(|(_, (n, fwd, inv))| *n < 70 || *fwd > TOL_M || *inv > TOL_M)
        .map(|(epsg, (n, fwd, inv))| {
            format!("EPSG:{epsg}: forward {fwd} m, inverse {inv} m over {n} points")
        })
        .collect();
    assert!(bad.is_empty(), "{}", bad.join("; "));
}
