//! TEMPORARY: UTM → WGS84 inverse (Krüger series to n³, ~0.1 mm), used only until
//! `crate::geo::map_to_wgs84` lands on main from the map work; then this file is deleted.

use crate::error::{Error, Result};
use crate::map::Crs;

/// WGS84 semi-major axis.
const A: f64 = 6_378_137.0;
/// WGS84 flattening.
const F: f64 = 1.0 / 298.257_223_563;
/// UTM scale factor.
const K0: f64 = 0.9996;

/// Map (UTM easting, northing) → (lat, lon) degrees.
pub fn map_to_wgs84(crs: Crs, x: f64, y: f64) -> Result<(f64, f64)> {
    let (zone, south) = match crs {
        Crs::Epsg(c) if (32601..=32660).contains(&c) => (c - 32600, false),
        Crs::Epsg(c) if (32701..=32760).contains(&c) => (c - 32700, true),
        _ => return Err(Error::Invalid(format!("{crs}: not a WGS84 UTM zone"))),
    };
    let n = F / (2.0 - F);
    let (n2, n3) = (n * n, n * n * n);
    let a_rect = A / (1.0 + n) * (1.0 + n2 / 4.0 + n2 * n2 / 64.0);
    let beta = [n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0, n2 / 48.0 + n3 / 15.0, 17.0 * n3 / 480.0];
    let delta = [2.0 * n - 2.0 * n2 / 3.0 - 2.0 * n3, 7.0 * n2 / 3.0 - 8.0 * n3 / 5.0, 56.0 * n3 / 15.0];
    let northing = if south { y - 10_000_000.0 } else { y };
    let xi = northing / (K0 * a_rect);
    let eta = (x - 500_000.0) / (K0 * a_rect);
    let (mut xp, mut ep) = (xi, eta);
    for (j, b) in beta.iter().enumerate() {
        let k = 2.0 * (j + 1) as f64;
        xp -= b * (k * xi).sin() * (k * eta).cosh();
        ep -= b * (k * xi).cos() * (k * eta).sinh();
    }
    let chi = (xp.sin() / ep.cosh()).asin();
    let mut phi = chi;
    for (j, d) in delta.iter().enumerate() {
        phi += d * (2.0 * (j + 1) as f64 * chi).sin();
    }
    let lon0 = (zone as f64 * 6.0 - 183.0).to_radians();
    let lam = lon0 + ep.sinh().atan2(xp.cos());
    Ok((phi.to_degrees(), lam.to_degrees()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn matches_pyproj() {
        // pyproj: Transformer.from_crs(4326, 32617, always_xy=True).transform(-83.74, 42.28)
        let (lat, lon) = super::map_to_wgs84(crate::map::Crs::Epsg(32617), 274068.9206748119, 4684500.906994122).unwrap();
        assert!((lat - 42.28).abs() < 2e-9 && (lon + 83.74).abs() < 2e-9, "{lat} {lon}");
    }
}
