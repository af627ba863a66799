//! WGS84 ↔ UTM against pyproj (PROJ 9): `tests/data/geo/utm_pyproj.csv`, made by
//! `tests/reference/make_geo_refs.py` — every zone of both hemispheres, latitudes −80..84, the
//! central meridian, zone edges (±3°), points 4.5–9° into the neighbour zones and the equator
//! projected into north and south zones. Forward and inverse must agree to 1 mm.

use infraloc::geo::{map_to_wgs84, wgs84_to_map};
use infraloc::map::Crs;

/// Agreement required with pyproj, metres.
const TOL_M: f64 = 1e-3;
/// Metres per degree of latitude (mean), to express angular inverse errors as ground distance.
const M_PER_DEG: f64 = 111_320.0;

struct Row {
    epsg: u32,
    lat: f64,
    lon: f64,
    x: f64,
    y: f64,
}

fn rows() -> Vec<Row> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/geo/utm_pyproj.csv");
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Row {
                epsg: f[0].parse().unwrap(),
                lat: f[1].parse().unwrap(),
                lon: f[2].parse().unwrap(),
                x: f[3].parse().unwrap(),
                y: f[4].parse().unwrap(),
            }
        })
        .collect()
}

#[test]
fn forward_and_inverse_match_pyproj_to_1mm() {
    let rows = rows();
    assert!(
        rows.len() > 20_000,
        "reference grid too small: {}",
        rows.len()
    );
    let (mut max_fwd, mut max_inv) = (0.0f64, 0.0f64);
    let mut worst = String::new();
    for r in &rows {
        let crs = Crs::Epsg(r.epsg);
        let (x, y) = wgs84_to_map(crs, r.lat, r.lon).unwrap();
        let fwd = (x - r.x).hypot(y - r.y);
        if fwd > max_fwd {
            max_fwd = fwd;
            worst = format!("forward EPSG:{} lat={} lon={}", r.epsg, r.lat, r.lon);
        }
        let (lat, lon) = map_to_wgs84(crs, r.x, r.y).unwrap();
        let mut dlon = lon - r.lon;
        dlon -= 360.0 * (dlon / 360.0).round();
        let inv = M_PER_DEG * (lat - r.lat).hypot(dlon * r.lat.to_radians().cos());
        if inv > max_inv {
            max_inv = inv;
            worst = format!("inverse EPSG:{} lat={} lon={}", r.epsg, r.lat, r.lon);
        }
    }
    eprintln!(
        "{} points: max forward error {max_fwd:.3e} m, max inverse error {max_inv:.3e} m (last worst: {worst})",
        rows.len()
    );
    assert!(
        max_fwd <= TOL_M,
        "forward {max_fwd} m > {TOL_M} m ({worst})"
    );
    assert!(
        max_inv <= TOL_M,
        "inverse {max_inv} m > {TOL_M} m ({worst})"
    );
}
