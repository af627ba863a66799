//! Why a CRS or a position is refused. Each variant renders as the one line a user reads, naming
//! the CRS or the position at fault.

use super::crs::{Crs, SUPPORTED_CRS};

/// A geodesy error: a CRS this crate cannot relate to WGS84, a projection that failed, or a
/// position out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeoError {
    /// `LOCAL` was asked for a WGS84 relation.
    #[error("CRS LOCAL has no relation to WGS84 ({})", SUPPORTED_CRS)]
    Local,
    /// An EPSG code with no definition.
    #[error("unknown EPSG:{code} ({})", SUPPORTED_CRS)]
    UnknownEpsg {
        /// The code.
        code: u32,
    },
    /// A projection method whose port is not checked against PROJ.
    #[error(
        "EPSG:{code} uses the {method} projection, which infraloc does not reproduce to 1 mm of PROJ ({})",
        SUPPORTED_CRS
    )]
    UnverifiedMethod {
        /// The code.
        code: u32,
        /// The PROJ.4 method (`+proj=`).
        method: String,
    },
    /// A datum whose shift to WGS84 the definition does not carry.
    #[error(
        "EPSG:{code} is on a datum ({datum}) whose shift to WGS84 infraloc does not have: positions would be off by up to hundreds of metres ({})",
        SUPPORTED_CRS
    )]
    UnshiftedDatum {
        /// The code.
        code: u32,
        /// The datum or ellipsoid named by the definition.
        datum: String,
    },
    /// A definition `proj4rs` cannot parse.
    #[error(
        "EPSG:{code}: its definition is not expressible in proj4rs ({reason}); {}",
        SUPPORTED_CRS
    )]
    NotExpressible {
        /// The code.
        code: u32,
        /// `proj4rs`'s words.
        reason: String,
    },
    /// Web Mercator, whose metres are not metres.
    #[error(
        "EPSG:{code} is Web Mercator, whose \"metres\" are true metres only at the equator; {}",
        SUPPORTED_CRS
    )]
    WebMercator {
        /// The code.
        code: u32,
    },
    /// A geographic CRS (degrees).
    #[error(
        "EPSG:{code} is a geographic CRS (degrees); a tile needs a projected CRS in metres ({})",
        SUPPORTED_CRS
    )]
    Geographic {
        /// The code.
        code: u32,
    },
    /// A geocentric CRS.
    #[error(
        "EPSG:{code} is a geocentric CRS; a tile needs a projected CRS in metres ({})",
        SUPPORTED_CRS
    )]
    Geocentric {
        /// The code.
        code: u32,
    },
    /// A projected CRS in units other than metres.
    #[error(
        "EPSG:{code} is in {units} ({to_meter} m); a tile needs a projected CRS in metres, e.g. the metre variant of the same zone"
    )]
    NotMetres {
        /// The code.
        code: u32,
        /// The unit's name.
        units: String,
        /// Metres per unit.
        to_meter: f64,
    },
    /// A projection of this crate's own (WGS84, a UTM zone) could not be built.
    #[error("{name} projection: {reason}")]
    Projection {
        /// Which (`WGS84`, `UTM zone 17`, `UTM zone 56 +south`).
        name: String,
        /// `proj4rs`'s words.
        reason: String,
    },
    /// A WGS84 position outside the globe.
    #[error(
        "WGS84 position lat={lat}, lon={lon}: latitude must be in [-90, 90], longitude finite"
    )]
    LatLon {
        /// Latitude, degrees.
        lat: f64,
        /// Longitude, degrees.
        lon: f64,
    },
    /// Map coordinates that are not finite.
    #[error("{crs} position x={x}, y={y}: coordinates must be finite")]
    NonFinite {
        /// Their CRS.
        crs: Crs,
        /// Easting.
        x: f64,
        /// Northing.
        y: f64,
    },
    /// A transformation failed (`what`: from → to).
    #[error("{what}: {reason}")]
    Transform {
        /// The position and the CRSs, e.g. `WGS84 lat=…, lon=… → EPSG:32617`.
        what: String,
        /// `proj4rs`'s words.
        reason: String,
    },
    /// A transformation gave a non-finite result.
    #[error("{what}: no finite result")]
    NoFiniteResult {
        /// The position and the CRSs, as in [`GeoError::Transform`].
        what: String,
    },
    /// CRS text that is neither `EPSG:<code>` nor `LOCAL`.
    #[error("CRS {text:?}: expected EPSG:<code> or LOCAL")]
    CrsSyntax {
        /// The text as given.
        text: String,
    },
    /// `EPSG:` followed by something other than a number.
    #[error("CRS {text:?}: EPSG code is not a number")]
    CrsCode {
        /// The text as given.
        text: String,
    },
}
