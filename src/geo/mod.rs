//! Geodesy: WGS84 ↔ projected map CRS (UTM). Pure computation, no I/O.
