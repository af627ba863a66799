//! Extracts from the EPSG table's WKT what its PROJ.4 strings lose: each projected CRS's geodetic
//! datum (NAD83, NAD83(HARN) and NAD83(2011) all read `+ellps=GRS80` there) and whether its name
//! says feet. `geo::stated` needs both to find the metre CRS of a survey's CRS. The table is made
//! here, at build time, so that the binary carries a few tens of kilobytes instead of the
//! table's 9 MB of WKT.

use std::collections::BTreeMap;
use std::fmt::Write as _;

/// The datum (or datum ensemble) name of a WKT2 `PROJCRS`, and the CRS's own name.
fn names(wkt: &str) -> Option<(&str, &str)> {
    let quoted = |s: &'static str| -> Option<&str> {
        let i = wkt.find(s)? + s.len();
        let rest = &wkt[i..];
        Some(&rest[..rest.find('"')?])
    };
    let crs = quoted("PROJCRS[\"")?;
    let datum = quoted(",DATUM[\"").or_else(|| quoted(",ENSEMBLE[\""))?;
    Some((crs, datum))
}

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    let mut datums: BTreeMap<String, u16> = BTreeMap::new();
    let mut rows = String::new();
    for code in 0..=u16::MAX {
        let Some(def) = crs_definitions::from_code(code) else {
            continue;
        };
        let Some((name, datum)) = names(def.wkt) else {
            continue;
        };
        let next = datums.len() as u16;
        let id = *datums.entry(datum.to_string()).or_insert(next);
        let feet = name.contains("ft") || name.contains("feet") || name.contains("foot");
        let _ = writeln!(rows, "    ({code}, {id}, {feet}),");
    }
    let mut by_id: Vec<(&u16, &String)> = datums.iter().map(|(n, i)| (i, n)).collect();
    by_id.sort();
    let mut out = String::from(
        "/// Projected EPSG CRSs: (code, index into [`DATUM_NAMES`], whether the name says feet).\n\
         pub(super) static PROJECTED: &[(u16, u16, bool)] = &[\n",
    );
    out.push_str(&rows);
    out.push_str("];\n/// Datum (or datum ensemble) names of the EPSG table, as it spells them.\n");
    out.push_str("pub(super) static DATUM_NAMES: &[&str] = &[\n");
    for (_, n) in by_id {
        let _ = writeln!(out, "    {n:?},");
    }
    out.push_str("];\n");
    let dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    std::fs::write(format!("{dir}/epsg_datums.rs"), out).expect("write OUT_DIR/epsg_datums.rs");
}
