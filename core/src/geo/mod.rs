//! Geodesy: WGS84 ↔ projected map CRS. Pure computation, no I/O.
//!
//! The map frame of a tile is a projected CRS in metres named by its EPSG code: a WGS84 UTM zone
//! (EPSG 32601–32660 north, 32701–32760 south) or any other projected CRS whose definition
//! `proj4rs` can express (ETRS89 / UTM 258xx, Amersfoort / RD New 28992, RGF93 / Lambert-93 2154,
//! NAD83 State Planes in metres, …; the EPSG → PROJ.4 table is `proj4rs`'s `crs-definitions`).
//! The projection maths is `proj4rs` (a Rust port of PROJ.4; for UTM its extended transverse
//! Mercator, `etmerc`, which PROJ ≥ 6 also uses for `+proj=utm`). A datum other than WGS84 is
//! reached through the definition's `+towgs84` Helmert parameters, as PROJ does when it has no
//! grid for the datum. `tests/it/geo_reference.rs` checks UTM against pyproj on a global grid to
//! ≤ 1 mm, `tests/it/geo_national_grids.rs` the national grids over each one's area. Projection
//! objects are built once per CRS and cached, because parsing a proj string costs far more than
//! projecting a point.

mod crs;
pub mod error;
pub mod georef;
pub mod stated;

pub use crs::{Crs, SUPPORTED_CRS};
pub use error::GeoError;

use crate::error::{Error, Result};
use proj4rs::proj::Proj;
use proj4rs::transform::{transform, Transform, TransformClosure};
use std::collections::BTreeMap;
use std::sync::{Mutex, OnceLock};

/// Base of the EPSG codes of WGS84 / UTM north zones (zone N → 32600 + N).
pub(crate) const UTM_NORTH_BASE: u32 = 32600;
/// Base of the EPSG codes of WGS84 / UTM south zones (zone N → 32700 + N).
pub(crate) const UTM_SOUTH_BASE: u32 = 32700;
/// Number of UTM zones.
pub(crate) const UTM_ZONES: u32 = 60;
/// Width of a UTM zone, degrees of longitude.
const ZONE_WIDTH_DEG: f64 = 6.0;

/// UTM zone (1..=60) and hemisphere of a WGS84 UTM EPSG code; `None` for any other code.
pub(crate) fn utm_zone_of(epsg: u32) -> Option<(u32, Hemisphere)> {
    let zone_in = |base: u32| {
        epsg.checked_sub(base)
            .filter(|z| (1..=UTM_ZONES).contains(z))
    };
    if let Some(z) = zone_in(UTM_NORTH_BASE) {
        Some((z, Hemisphere::North))
    } else {
        zone_in(UTM_SOUTH_BASE).map(|z| (z, Hemisphere::South))
    }
}

/// UTM zone (1..=60) of a WGS84 UTM CRS; `None` for any other CRS.
pub fn utm_zone(crs: Crs) -> Option<u32> {
    match crs {
        Crs::Epsg(code) => utm_zone_of(code).map(|(z, _)| z),
        Crs::Local => None,
    }
}

/// Hemisphere of a UTM zone (south zones use a 10 000 km false northing).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hemisphere {
    /// EPSG 326zz.
    North,
    /// EPSG 327zz.
    South,
}

/// Check that `crs` is a CRS this crate can relate to WGS84: a projected CRS in metres with an
/// EPSG code (see the module docs).
pub fn check_crs(crs: Crs) -> Result<()> {
    projection(crs).map(|_| ())
}

/// The projection of a map CRS (cached).
fn projection(crs: Crs) -> Result<&'static Proj> {
    match crs {
        Crs::Epsg(code) => match utm_zone_of(code) {
            Some((zone, hemi)) => utm_proj(zone, hemi),
            None => epsg_proj(code),
        },
        Crs::Local => Err(GeoError::Local.into()),
    }
}

/// Projections of EPSG codes other than WGS84 UTM, built on first use. Each is leaked once, so a
/// process holds at most one per code it has seen (a handful: the tiles' CRSs).
static OTHER: Mutex<BTreeMap<u32, std::result::Result<&'static Proj, GeoError>>> =
    Mutex::new(BTreeMap::new());

/// Definitions checked against pyproj (`tests/it/geo_national_grids.rs`) that the EPSG table
/// cannot give as PROJ uses them: the table carries no `+towgs84`, so a datum other than WGS84's
/// would be taken for WGS84 itself (CH1903+ came out 189 m off). Each carries PROJ's default
/// WGS84 operation (rotations in the position-vector convention of `+towgs84`): RD New
/// "Amersfoort to WGS 84 (4)", CH1903+ / LV95 "CH1903+ to WGS 84 (1)", CH1903 / LV03 "CH1903 to
/// WGS 84 (2)" (the same shift: the two frames differ by LV95's local distortions, ≤ 1.6 m, which
/// PROJ's default operation ignores as well).
const DEFINITION_OVERRIDES: [(u32, &str); 3] = [
    (
        28992,
        "+proj=sterea +lat_0=52.15616055555555 +lon_0=5.38763888888889 +k=0.9999079 +x_0=155000 \
         +y_0=463000 +ellps=bessel +towgs84=565.4171,50.3319,465.5524,-0.398957388243134,\
         0.343987817378283,-1.87740163998045,4.0725 +units=m +no_defs",
    ),
    (
        2056,
        "+proj=somerc +lat_0=46.9524055555556 +lon_0=7.43958333333333 +k_0=1 +x_0=2600000 \
         +y_0=1200000 +ellps=bessel +towgs84=674.374,15.056,405.346,0,0,0,0 +units=m +no_defs",
    ),
    (
        21781,
        "+proj=somerc +lat_0=46.9524055555556 +lon_0=7.43958333333333 +k_0=1 +x_0=600000 \
         +y_0=200000 +ellps=bessel +towgs84=674.374,15.056,405.346,0,0,0,0 +units=m +no_defs",
    ),
];

/// Projection methods of the EPSG table whose `proj4rs` port agrees with PROJ to 1 mm over the
/// areas of use checked (`tests/it/geo_national_grids.rs`): transverse Mercator (`utm`, and
/// `tmerc`, which `proj4rs` runs as PROJ does, with the extended algorithm `etmerc`) and Lambert
/// conformal conic. Any other method is refused rather than trusted unchecked: e.g. `laea` (3035
/// came out 1.5 mm off at the edges of its area), `krovak`, `omerc`, `stere`.
const VERIFIED_METHODS: [&str; 4] = ["utm", "tmerc", "etmerc", "lcc"];

/// Ellipsoids and datums taken as WGS84 with no shift, as PROJ's default operations take ETRS89,
/// NAD83 and RGF93 (their frames differ from WGS84's by about a metre, far inside the GPS prior).
const WGS84_ELLIPSOIDS: [&str; 2] = ["GRS80", "WGS84"];
const WGS84_DATUMS: [&str; 2] = ["WGS84", "NAD83"];

/// `Ok` when the EPSG table's definition `def` of `code` uses a verified projection method on a
/// datum taken as WGS84; else the reason.
fn vet_definition(code: u32, def: &str) -> std::result::Result<(), GeoError> {
    let param = |key: &str| {
        def.split_whitespace().find_map(|t| {
            t.strip_prefix('+')
                .and_then(|t| t.strip_prefix(key))
                .and_then(|t| t.strip_prefix('='))
        })
    };
    let method = param("proj").unwrap_or("?");
    if !VERIFIED_METHODS.contains(&method) || def.split_whitespace().any(|t| t == "+approx") {
        return Err(GeoError::UnverifiedMethod {
            code,
            method: method.to_string(),
        });
    }
    let on_wgs84 = param("ellps").is_some_and(|e| WGS84_ELLIPSOIDS.contains(&e))
        || param("datum").is_some_and(|d| WGS84_DATUMS.contains(&d));
    if !on_wgs84 || param("towgs84").is_some() || param("nadgrids").is_some() {
        let datum = param("datum").or_else(|| param("ellps")).unwrap_or("?");
        return Err(GeoError::UnshiftedDatum {
            code,
            datum: datum.to_string(),
        });
    }
    Ok(())
}

/// Web Mercator codes: projected, nominally metres, but scaled by 1/cos(latitude).
const WEB_MERCATOR: [u32; 2] = [3857, 900_913];

fn epsg_proj(code: u32) -> Result<&'static Proj> {
    let mut cache = OTHER.lock().unwrap_or_else(|p| p.into_inner());
    cache
        .entry(code)
        .or_insert_with(|| build_epsg_proj(code).map(|p| &*Box::leak(Box::new(p))))
        .clone()
        .map_err(Error::from)
}

/// The projection of EPSG `code`, refused unless it is projected, in metres, and either one of
/// [`DEFINITION_OVERRIDES`] or in a verified method on a datum taken as WGS84 ([`vet_definition`]).
fn build_epsg_proj(code: u32) -> std::result::Result<Proj, GeoError> {
    let unknown = || GeoError::UnknownEpsg { code };
    let short = u16::try_from(code).map_err(|_| unknown())?;
    let overridden = DEFINITION_OVERRIDES.iter().find(|(c, _)| *c == code);
    let def = match overridden {
        Some((_, def)) => def,
        None => crs_definitions::from_code(short).ok_or_else(unknown)?.proj4,
    };
    let p = Proj::from_proj_string(def).map_err(|e| {
        // A method proj4rs lacks (Krovak, oblique Mercator, …) is one we have not verified either.
        match overridden.map_or_else(|| vet_definition(code, def), |_| Ok(())) {
            Err(why) => why,
            Ok(()) => GeoError::NotExpressible {
                code,
                reason: e.to_string(),
            },
        }
    })?;
    if WEB_MERCATOR.contains(&code) {
        return Err(GeoError::WebMercator { code });
    }
    if p.is_latlong() {
        return Err(GeoError::Geographic { code });
    }
    if p.is_geocent() {
        return Err(GeoError::Geocentric { code });
    }
    // Raster resolutions, search radii and pose errors are all metres.
    if p.to_meter() != 1.0 {
        return Err(GeoError::NotMetres {
            code,
            units: p.units().to_string(),
            to_meter: p.to_meter(),
        });
    }
    if overridden.is_none() {
        vet_definition(code, def)?;
    }
    Ok(p)
}

/// Standard UTM zone number (1..=60) of a WGS84 position, including the Norway (32V) and Svalbard
/// (31X–37X) exceptions of the UTM definition. Longitude is wrapped to [−180, 180).
pub(crate) fn utm_zone_for(lat: f64, lon: f64) -> u32 {
    let lon = (lon + 180.0).rem_euclid(360.0) - 180.0;
    let mut zone = (((lon + 180.0) / ZONE_WIDTH_DEG).floor() as u32 + 1).clamp(1, UTM_ZONES);
    // Norway: band V (56°..64°N) zone 32 is widened west to 3°E.
    if (56.0..64.0).contains(&lat) && (3.0..12.0).contains(&lon) {
        zone = 32;
    }
    // Svalbard: band X (72°..84°N) has only the odd zones 31, 33, 35, 37 between 0° and 42°E.
    if (72.0..=84.0).contains(&lat) {
        zone = match lon {
            l if (0.0..9.0).contains(&l) => 31,
            l if (9.0..21.0).contains(&l) => 33,
            l if (21.0..33.0).contains(&l) => 35,
            l if (33.0..42.0).contains(&l) => 37,
            _ => zone,
        };
    }
    zone
}

/// EPSG code of the WGS84 UTM zone of a position: 326zz north of the equator (latitude ≥ 0),
/// 327zz south of it.
pub fn utm_epsg_for(lat: f64, lon: f64) -> u32 {
    let base = if lat >= 0.0 {
        UTM_NORTH_BASE
    } else {
        UTM_SOUTH_BASE
    };
    base + utm_zone_for(lat, lon)
}

/// Longitude of the central meridian of UTM zone `zone` (1..=60), degrees.
pub fn central_meridian(zone: u32) -> f64 {
    -183.0 + ZONE_WIDTH_DEG * f64::from(zone)
}

/// Mean Earth radius (IUGG), metres.
const MEAN_EARTH_RADIUS_M: f64 = 6_371_008.8;

/// Great-circle distance between two WGS84 positions on the mean sphere, metres (haversine;
/// within 0.5 % of the ellipsoidal distance). For coarse "how far away" messages only.
pub fn great_circle_m(lat1: f64, lon1: f64, lat2: f64, lon2: f64) -> f64 {
    let (p1, p2) = (lat1.to_radians(), lat2.to_radians());
    let dp = p2 - p1;
    let dl = (lon2 - lon1).to_radians();
    let h = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * MEAN_EARTH_RADIUS_M * h.sqrt().min(1.0).asin()
}

/// One point handed to `proj4rs::transform` (it wants a type implementing its `Transform`).
struct Pt(f64, f64);

impl Transform for Pt {
    fn transform_coordinates<F: TransformClosure>(
        &mut self,
        f: &mut F,
    ) -> proj4rs::errors::Result<()> {
        let (x, y, _) = f(self.0, self.1, 0.0)?;
        self.0 = x;
        self.1 = y;
        Ok(())
    }
}

/// Number of cached projections: 60 north + 60 south zones.
const N_CACHED: usize = 2 * UTM_ZONES as usize;

/// Lazily built WGS84 geographic and UTM zone projections.
static LONGLAT: OnceLock<std::result::Result<Proj, GeoError>> = OnceLock::new();
static UTM: [OnceLock<std::result::Result<Proj, GeoError>>; N_CACHED] =
    [const { OnceLock::new() }; N_CACHED];

fn longlat() -> Result<&'static Proj> {
    LONGLAT
        .get_or_init(|| {
            Proj::from_proj_string("+proj=longlat +datum=WGS84 +no_defs").map_err(|e| {
                GeoError::Projection {
                    name: "WGS84".into(),
                    reason: e.to_string(),
                }
            })
        })
        .as_ref()
        .map_err(|e| e.clone().into())
}

fn utm_proj(zone: u32, hemi: Hemisphere) -> Result<&'static Proj> {
    let (slot, south) = match hemi {
        Hemisphere::North => (zone as usize - 1, ""),
        Hemisphere::South => (UTM_ZONES as usize + zone as usize - 1, " +south"),
    };
    UTM[slot]
        .get_or_init(|| {
            Proj::from_proj_string(&format!(
                "+proj=utm +zone={zone}{south} +datum=WGS84 +units=m +no_defs"
            ))
            .map_err(|e| GeoError::Projection {
                name: format!("UTM zone {zone}{south}"),
                reason: e.to_string(),
            })
        })
        .as_ref()
        .map_err(|e| e.clone().into())
}

/// WGS84 latitude/longitude (degrees) → map coordinates (easting, northing in metres) of `crs`.
pub fn wgs84_to_map(crs: Crs, lat: f64, lon: f64) -> Result<(f64, f64)> {
    let proj = projection(crs)?;
    if !(lat.abs() <= 90.0) || !lon.is_finite() {
        return Err(GeoError::LatLon { lat, lon }.into());
    }
    let mut p = Pt(lon.to_radians(), lat.to_radians());
    transform(longlat()?, proj, &mut p).map_err(|e| GeoError::Transform {
        what: format!("WGS84 lat={lat}, lon={lon} → {crs}"),
        reason: e.to_string(),
    })?;
    finite_or_err(p.0, p.1, || format!("WGS84 lat={lat}, lon={lon} → {crs}"))
}

/// Map coordinates of `crs` (easting, northing in metres) → WGS84 (latitude, longitude) degrees.
pub fn map_to_wgs84(crs: Crs, x: f64, y: f64) -> Result<(f64, f64)> {
    let proj = projection(crs)?;
    if !x.is_finite() || !y.is_finite() {
        return Err(GeoError::NonFinite { crs, x, y }.into());
    }
    let mut p = Pt(x, y);
    transform(proj, longlat()?, &mut p).map_err(|e| GeoError::Transform {
        what: format!("{crs} x={x}, y={y} → WGS84"),
        reason: e.to_string(),
    })?;
    let (lon, lat) = finite_or_err(p.0.to_degrees(), p.1.to_degrees(), || {
        format!("{crs} x={x}, y={y} → WGS84")
    })?;
    Ok((lat, lon))
}

/// Map coordinates of `from` → map coordinates of `to` (both projected, metres), through each
/// one's datum definition.
pub fn map_to_map(from: Crs, to: Crs, x: f64, y: f64) -> Result<(f64, f64)> {
    if from == to {
        return Ok((x, y));
    }
    let (pf, pt) = (projection(from)?, projection(to)?);
    if !x.is_finite() || !y.is_finite() {
        return Err(GeoError::NonFinite { crs: from, x, y }.into());
    }
    let mut p = Pt(x, y);
    transform(pf, pt, &mut p).map_err(|e| GeoError::Transform {
        what: format!("{from} x={x}, y={y} → {to}"),
        reason: e.to_string(),
    })?;
    finite_or_err(p.0, p.1, || format!("{from} x={x}, y={y} → {to}"))
}

fn finite_or_err(a: f64, b: f64, what: impl FnOnce() -> String) -> Result<(f64, f64)> {
    if a.is_finite() && b.is_finite() {
        Ok((a, b))
    } else {
        Err(GeoError::NoFiniteResult { what: what() }.into())
    }
}

impl std::str::FromStr for Crs {
    type Err = GeoError;
    fn from_str(s: &str) -> Result<Self, GeoError> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("LOCAL") {
            return Ok(Crs::Local);
        }
        let code = t
            .strip_prefix("EPSG:")
            .or_else(|| t.strip_prefix("epsg:"))
            .ok_or_else(|| GeoError::CrsSyntax {
                text: s.to_string(),
            })?;
        code.parse::<u32>()
            .map(Crs::Epsg)
            .map_err(|_| GeoError::CrsCode {
                text: s.to_string(),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zone_selection() {
        assert_eq!(utm_epsg_for(40.0, -81.0), 32617);
        assert_eq!(utm_epsg_for(-33.9, 151.2), 32756);
        assert_eq!(utm_epsg_for(0.0, 0.0), 32631);
        assert_eq!(utm_epsg_for(-0.0001, -180.0), 32701);
        assert_eq!(utm_epsg_for(10.0, 180.0), 32601); // wraps
        assert_eq!(utm_epsg_for(10.0, 179.999), 32660);
        assert_eq!(utm_epsg_for(60.0, 5.0), 32632); // Norway
        assert_eq!(utm_epsg_for(78.0, 15.0), 32633); // Svalbard
    }

    #[test]
    fn unknown_epsg_is_rejected() {
        for code in [32600, 32700, 1, 99_999, 70_000] {
            let e = wgs84_to_map(Crs::Epsg(code), 10.0, 10.0)
                .unwrap_err()
                .to_string();
            assert_eq!(e, format!("unknown EPSG:{code} ({SUPPORTED_CRS})"));
        }
        // Geographic (WGS84, ETRS89), feet (NAD83 / New York Long Island ftUS), Web Mercator.
        for (code, why) in [
            (4326, "is a geographic CRS"),
            (4258, "is a geographic CRS"),
            (
                2263,
                "needs a projected CRS in metres, e.g. the metre variant",
            ),
            (3857, "Web Mercator"),
        ] {
            let e = check_crs(Crs::Epsg(code)).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("EPSG:{code} ")) && e.contains(why),
                "{e}"
            );
        }
        // Methods not verified against PROJ to 1 mm: LAEA Europe, Krovak, Polar stereographic.
        for (code, method) in [(3035, "laea"), (5514, "krovak"), (3413, "stere")] {
            let e = check_crs(Crs::Epsg(code)).unwrap_err().to_string();
            let want = format!("EPSG:{code} uses the {method} projection, which infraloc does not");
            assert!(e.starts_with(&want) && !e.contains('\n'), "{e}");
        }
        // Datums the EPSG table gives no WGS84 shift for: DHDN (Bessel), OSGB36 (Airy), NAD27.
        for (code, datum) in [(31467, "bessel"), (27700, "airy"), (26711, "NAD27")] {
            let e = check_crs(Crs::Epsg(code)).unwrap_err().to_string();
            let want = format!("EPSG:{code} is on a datum ({datum}) whose shift to WGS84");
            assert!(e.starts_with(&want), "{e}");
        }
        // National grids are accepted (tests/it/geo_national_grids.rs checks them against pyproj).
        for code in [28992, 2056, 21781, 25832, 2154, 2180, 32118, 26943, 32139] {
            check_crs(Crs::Epsg(code)).unwrap();
        }
        assert!(map_to_wgs84(Crs::Local, 0.0, 0.0).is_err());
        assert!(wgs84_to_map(Crs::Epsg(32617), f64::NAN, 0.0).is_err());
        assert!(wgs84_to_map(Crs::Epsg(32617), 91.0, 0.0).is_err());
    }

    #[test]
    fn great_circle_against_pyproj_geod() {
        // pyproj.Geod(ellps="WGS84").inv: 6 438 731.6 m and 14 102 659.7 m; the sphere is within
        // 0.5 % of the ellipsoid.
        let d = great_circle_m(45.146322013640194, 13.728070378524817, 45.0, 100.0);
        assert!((d / 6_438_731.6 - 1.0).abs() < 5e-3, "{d}");
        let d = great_circle_m(45.146322013640194, 13.728070378524817, -30.0, -100.0);
        assert!((d / 14_102_659.7 - 1.0).abs() < 5e-3, "{d}");
        assert_eq!(central_meridian(31), 3.0);
        assert_eq!(central_meridian(1), -177.0);
    }

    #[test]
    fn central_meridian_on_equator_is_false_easting() {
        // Definition of UTM: the central meridian maps to E = 500 000 m, the equator to N = 0
        // (north) or 10 000 000 m (south).
        let (x, y) = wgs84_to_map(Crs::Epsg(32631), 0.0, 3.0).unwrap();
        assert!((x - 500_000.0).abs() < 1e-6 && y.abs() < 1e-6, "{x} {y}");
        let (x, y) = wgs84_to_map(Crs::Epsg(32731), 0.0, 3.0).unwrap();
        assert!((x - 500_000.0).abs() < 1e-6 && (y - 10_000_000.0).abs() < 1e-6);
    }
}
