//! The coordinate reference system of map data, as files name it.

use serde::{Deserialize, Serialize};

/// The "supported" part of every unknown-CRS message, so all callers say the same thing.
pub const SUPPORTED_CRS: &str =
    "supported: WGS84 UTM 326xx/327xx; projected EPSG CRSs in metres in transverse Mercator or \
     Lambert conformal conic on ETRS89, NAD83 or another GRS80 datum (e.g. ETRS89 UTM 258xx, \
     Lambert-93 2154, NAD83 State Planes); RD New 28992; CH1903+ / LV95 2056; CH1903 / LV03 21781";

/// A coordinate reference system of map data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Crs {
    /// An EPSG code (e.g. 32617 = WGS84 / UTM 17N).
    Epsg(u32),
    /// A local metric right-handed frame with z up; no WGS84 lookups.
    Local,
}

impl std::fmt::Display for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Crs::Epsg(c) => write!(f, "EPSG:{c}"),
            Crs::Local => write!(f, "LOCAL"),
        }
    }
}
