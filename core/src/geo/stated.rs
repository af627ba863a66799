//! A CRS as a survey file states it, made into a tile's CRS: a projected CRS in metres named by
//! an EPSG code, and the exact conversion of the file's coordinates into it.
//!
//! - **Feet.** A CRS in US survey feet or international feet (the State Planes; or a metre EPSG
//!   code whose coordinates a GeoTIFF ProjLinearUnits key says are feet) becomes the EPSG CRS with
//!   the same projection, the same datum and metre units (NAD83 / California zone 5 (ftUS), 2229 →
//!   NAD83 / California zone 5, 26945). Both are one projection, so the conversion is exact and
//!   linear: `x_m = x · unit − x₀ + x₀'`, x₀ and x₀' the false eastings in metres of the two
//!   definitions (they may differ by the rounding of the feet value, 0.1 mm for 2229).
//! - **A WKT without an EPSG code** (ESRI writers) is read from its parameters, as GDAL identifies
//!   one: projection method and parameters, ellipsoid and datum name, linear unit. The EPSG CRS in
//!   metres with the same projection and datum is the tile's.
//!
//! The datum of each EPSG CRS comes from the EPSG table's WKT, reduced at build time (`build.rs`)
//! to a datum name per code: the PROJ.4 strings give NAD83(HARN), NAD83(2011) and ETRS89 all as
//! `+ellps=GRS80`, and a tile labelled with another realization than its survey's would be wrong by
//! up to a metre.

use super::{utm_zone_of, Crs, GeoError};

include!(concat!(env!("OUT_DIR"), "/epsg_datums.rs"));

/// International foot, metres.
pub const FOOT: f64 = 0.3048;
/// US survey foot, metres.
pub const US_SURVEY_FOOT: f64 = 1200.0 / 3937.0;
/// Angles equal to this many degrees are the same parameter (the EPSG table rounds to 1e-13).
const ANGLE_TOL_DEG: f64 = 1e-8;
/// False eastings and northings this close are the same (feet definitions round to 0.1 mm).
const OFFSET_TOL_M: f64 = 1e-3;
/// WKT nesting accepted (real CRSs nest 5 deep).
const MAX_DEPTH: usize = 32;

/// How a file's coordinates become a tile's: the tile's CRS and `tile = file · scale + shift`.
#[derive(Debug, Clone, PartialEq)]
pub struct Metric {
    /// The tile's CRS: projected, metres, an EPSG code.
    pub crs: Crs,
    /// The file's horizontal unit: its name and metres per unit.
    pub unit: (String, f64),
    /// Added to x · unit, metres (the difference of the false eastings).
    pub dx: f64,
    /// Added to y · unit, metres.
    pub dy: f64,
    /// The vertical unit the CRS states (a compound WKT's vertical part), if it states one.
    pub vertical: Option<(String, f64)>,
}

impl Metric {
    /// The identity: the file is in the tile's CRS already.
    pub fn identity(crs: Crs) -> Self {
        Metric {
            crs,
            unit: ("metre".into(), 1.0),
            dx: 0.0,
            dy: 0.0,
            vertical: None,
        }
    }

    /// Whether coordinates pass unchanged.
    pub fn is_identity(&self) -> bool {
        self.unit.1 == 1.0 && self.dx == 0.0 && self.dy == 0.0
    }
}

/// Why a stated CRS makes no tile CRS.
#[derive(Debug, Clone, PartialEq)]
pub enum StatedError {
    /// A geocentric CRS (EPSG:4978, a WKT GEOCCS); its name.
    Geocentric(String),
    /// A geographic CRS (latitude, longitude); its name.
    Geographic(String),
    /// Anything else, in words.
    Other(String),
}

impl std::fmt::Display for StatedError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StatedError::Geocentric(n) => write!(f, "{n} is a geocentric CRS"),
            StatedError::Geographic(n) => {
                write!(f, "{n} is a geographic CRS (latitude, longitude)")
            }
            StatedError::Other(m) => f.write_str(m),
        }
    }
}

/// Name and metres per unit of a linear unit EPSG code (GeoTIFF ProjLinearUnits, VerticalUnits).
pub fn linear_unit(code: u16) -> Option<(&'static str, f64)> {
    match code {
        9001 => Some(("metre", 1.0)),
        9002 => Some(("foot", FOOT)),
        9003 => Some(("US survey foot", US_SURVEY_FOOT)),
        _ => None,
    }
}

/// A projection in PROJ.4 terms, lengths in metres, angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Params {
    /// `tmerc` (UTM included) or `lcc`; anything else is `other`.
    method: &'static str,
    lat_0: f64,
    lon_0: f64,
    /// Standard parallels (LCC; 0 for TM).
    lat_1: f64,
    lat_2: f64,
    k: f64,
    x_0: f64,
    y_0: f64,
    /// Ellipsoid semi-major axis and inverse flattening, if known.
    ellps: Option<(f64, f64)>,
    /// Metres per unit of the coordinates.
    unit: f64,
}

impl Params {
    /// Same projection on the same ellipsoid (false origin within [`OFFSET_TOL_M`]; units aside).
    /// A conic's two standard parallels are one cone in either order.
    fn same_projection(&self, o: &Params) -> bool {
        let ang = |a: f64, b: f64| (a - b).abs() <= ANGLE_TOL_DEG;
        let sorted = |p: &Params| (p.lat_1.max(p.lat_2), p.lat_1.min(p.lat_2));
        let ((a1, a2), (b1, b2)) = (sorted(self), sorted(o));
        let ellps = match (self.ellps, o.ellps) {
            (Some((a1, f1)), Some((a2, f2))) => (a1 - a2).abs() < 1e-3 && (f1 - f2).abs() < 1e-6,
            _ => true,
        };
        self.method == o.method
            && self.method != "other"
            && ang(self.lat_0, o.lat_0)
            && ang(self.lon_0, o.lon_0)
            && ang(a1, b1)
            && ang(a2, b2)
            && (self.k - o.k).abs() <= 1e-10
            && (self.x_0 - o.x_0).abs() <= OFFSET_TOL_M
            && (self.y_0 - o.y_0).abs() <= OFFSET_TOL_M
            && ellps
    }
}

/// Semi-major axis and inverse flattening of a PROJ ellipsoid or datum name.
fn ellipsoid(name: &str) -> Option<(f64, f64)> {
    match name {
        "GRS80" | "NAD83" => Some((6_378_137.0, 298.257_222_101)),
        "WGS84" => Some((6_378_137.0, 298.257_223_563)),
        "bessel" => Some((6_377_397.155, 299.152_812_8)),
        "intl" => Some((6_378_388.0, 297.0)),
        "airy" => Some((6_377_563.396, 299.324_964_6)),
        "krass" => Some((6_378_245.0, 298.3)),
        _ => None,
    }
}

/// The parameters of a PROJ.4 definition.
fn parse_proj4(def: &str) -> Params {
    let get = |key: &str| {
        def.split_whitespace().find_map(|t| {
            t.strip_prefix('+')
                .and_then(|t| t.strip_prefix(key))
                .and_then(|t| t.strip_prefix('='))
        })
    };
    let num = |key: &str| get(key).and_then(|v| v.parse::<f64>().ok());
    let unit = match (get("units"), num("to_meter")) {
        (_, Some(f)) => f,
        (Some("ft"), _) => FOOT,
        (Some("us-ft"), _) => US_SURVEY_FOOT,
        (Some("m") | None, _) => 1.0,
        (Some(_), _) => f64::NAN,
    };
    let ellps = match (num("a"), num("rf"), num("b")) {
        (Some(a), Some(rf), _) => Some((a, rf)),
        (Some(a), None, Some(b)) => Some((a, a / (a - b))),
        _ => get("ellps").or_else(|| get("datum")).and_then(ellipsoid),
    };
    let mut p = Params {
        method: "other",
        lat_0: num("lat_0").unwrap_or(0.0),
        lon_0: num("lon_0").unwrap_or(0.0),
        lat_1: 0.0,
        lat_2: 0.0,
        k: num("k").or_else(|| num("k_0")).unwrap_or(1.0),
        x_0: num("x_0").unwrap_or(0.0),
        y_0: num("y_0").unwrap_or(0.0),
        ellps,
        unit,
    };
    match get("proj") {
        Some("tmerc" | "etmerc") => p.method = "tmerc",
        Some("utm") => {
            let zone = num("zone").unwrap_or(0.0);
            p = Params {
                method: "tmerc",
                lat_0: 0.0,
                lon_0: zone * 6.0 - 183.0,
                k: 0.9996,
                x_0: 500_000.0,
                y_0: if get("south").is_some() || def.contains("+south") {
                    10_000_000.0
                } else {
                    0.0
                },
                ..p
            };
        }
        Some("lcc") => {
            p.method = "lcc";
            p.lat_1 = num("lat_1").unwrap_or(p.lat_0);
            p.lat_2 = num("lat_2").unwrap_or(p.lat_1);
        }
        _ => {}
    }
    p
}

/// The PROJ.4 definition of an EPSG code (the overrides of `geo` first).
fn definition(code: u32) -> Option<&'static str> {
    if let Some((_, d)) = super::DEFINITION_OVERRIDES.iter().find(|(c, _)| *c == code) {
        return Some(d);
    }
    let short = u16::try_from(code).ok()?;
    crs_definitions::from_code(short).map(|d| d.proj4)
}

/// The datum name of a projected EPSG code, from the build-time table.
fn datum_of(code: u32) -> Option<&'static str> {
    let short = u16::try_from(code).ok()?;
    let i = PROJECTED.binary_search_by_key(&short, |r| r.0).ok()?;
    DATUM_NAMES.get(usize::from(PROJECTED[i].1)).copied()
}

/// A datum name reduced for comparison: ESRI's `D_` prefix, case, punctuation and the words
/// "datum" and "ensemble" dropped; ESRI's short names for the common datums spelt out.
fn datum_key(name: &str) -> String {
    let name = name.strip_prefix("D_").unwrap_or(name);
    let k: String = name
        .chars()
        .filter(char::is_ascii_alphanumeric)
        .collect::<String>()
        .to_ascii_uppercase()
        .replace("DATUM", "")
        .replace("ENSEMBLE", "");
    let alias = match k.as_str() {
        "NORTHAMERICAN1983HARN" | "NAD1983HARN" | "NAD83HARN" => {
            "NAD83HIGHACCURACYREFERENCENETWORK"
        }
        "NAD19832011" | "NAD832011" => "NAD83NATIONALSPATIALREFERENCESYSTEM2011",
        "NORTHAMERICAN1983CSRS" | "NAD83CSRS" => "NAD83CANADIANSPATIALREFERENCESYSTEM",
        "NAD1983" | "NAD83" => "NORTHAMERICAN1983",
        "WGS1984" | "WGS84" => "WORLDGEODETICSYSTEM1984",
        "ETRS1989" | "ETRS89" => "EUROPEANTERRESTRIALREFERENCESYSTEM1989",
        _ => "",
    };
    if alias.is_empty() {
        k
    } else {
        alias.to_string()
    }
}

/// The metre EPSG CRS with the same projection as `src` on the datum `datum`: `prefer` if it is
/// one, else the lowest such code. EPSG codes named in feet are skipped even where the table's
/// definition says metres (deprecated entries such as 26822).
fn metre_twin(src: &Params, datum: &str, prefer: Option<u32>) -> Option<u32> {
    let key = datum_key(datum);
    let fits = |code: u32| {
        definition(code).is_some_and(|d| {
            let p = parse_proj4(d);
            p.unit == 1.0 && p.same_projection(src)
        })
    };
    if let Some(c) = prefer.filter(|&c| fits(c)) {
        return Some(c);
    }
    PROJECTED
        .iter()
        .filter(|(_, d, feet)| !feet && datum_key(DATUM_NAMES[usize::from(*d)]) == key)
        .map(|(c, _, _)| u32::from(*c))
        .find(|&c| fits(c))
}

/// The tile CRS of EPSG `code` whose coordinates are in `unit` (a GeoTIFF ProjLinearUnits key
/// that overrides the definition's unit), or in the definition's own unit.
pub fn epsg_in_metres(code: u32, unit: Option<(&str, f64)>) -> Result<Metric, StatedError> {
    if utm_zone_of(code).is_some() {
        return match unit {
            None | Some((_, 1.0)) => Ok(Metric::identity(Crs::Epsg(code))),
            Some((n, _)) => Err(StatedError::Other(format!(
                "EPSG:{code} with its unit overridden to {n}: a UTM zone is in metres"
            ))),
        };
    }
    let def = definition(code)
        .ok_or_else(|| StatedError::Other(GeoError::UnknownEpsg { code }.to_string()))?;
    if def.contains("+proj=geocent") {
        return Err(StatedError::Geocentric(format!("EPSG:{code}")));
    }
    if def.contains("+proj=longlat") || def.contains("+proj=latlong") {
        return Err(StatedError::Geographic(format!("EPSG:{code}")));
    }
    let p = parse_proj4(def);
    let (uname, f) = match unit {
        Some((n, f)) => (n.to_string(), f),
        None => (unit_name(p.unit), p.unit),
    };
    if f == 1.0 && p.unit == 1.0 {
        return Ok(Metric::identity(Crs::Epsg(code)));
    }
    if !f.is_finite() {
        return Err(StatedError::Other(format!(
            "EPSG:{code}: its unit is not metres or feet"
        )));
    }
    let datum = datum_of(code).ok_or_else(|| {
        StatedError::Other(format!(
            "EPSG:{code} is not a projected CRS of the EPSG table"
        ))
    })?;
    let twin = metre_twin(&p, datum, Some(code)).ok_or_else(|| {
        StatedError::Other(format!(
            "EPSG:{code} is in {uname} and the EPSG table has no CRS in metres with its projection \
             on {datum}"
        ))
    })?;
    Ok(into_twin(&p, twin, (uname, f)))
}

/// The conversion of coordinates of projection `src` in `unit` into its metre twin `twin`: the
/// unit's scale and the difference of the false origins.
fn into_twin(src: &Params, twin: u32, unit: (String, f64)) -> Metric {
    let tp = parse_proj4(definition(twin).unwrap_or_default());
    Metric {
        crs: Crs::Epsg(twin),
        unit,
        dx: tp.x_0 - src.x_0,
        dy: tp.y_0 - src.y_0,
        vertical: None,
    }
}

fn unit_name(f: f64) -> String {
    if f == 1.0 {
        "metre".into()
    } else if f == FOOT {
        "foot".into()
    } else if f == US_SURVEY_FOOT {
        "US survey foot".into()
    } else {
        format!("units of {f} m")
    }
}

/// A WKT1 element: keyword and arguments.
#[derive(Debug, Clone, PartialEq)]
enum Arg {
    Text(String),
    Num(f64),
    Word(String),
    Node(Node),
}

#[derive(Debug, Clone, PartialEq)]
struct Node {
    key: String,
    args: Vec<Arg>,
}

impl Node {
    fn child<'a>(&'a self, key: &'a str) -> Option<&'a Node> {
        self.children(key).next()
    }
    fn children<'a>(&'a self, key: &'a str) -> impl Iterator<Item = &'a Node> + 'a {
        self.args.iter().filter_map(move |a| match a {
            Arg::Node(n) if n.key.eq_ignore_ascii_case(key) => Some(n),
            _ => None,
        })
    }
    fn name(&self) -> &str {
        match self.args.first() {
            Some(Arg::Text(t)) => t,
            _ => "",
        }
    }
    fn num(&self, i: usize) -> Option<f64> {
        match self.args.get(i) {
            Some(Arg::Num(v)) => Some(*v),
            _ => None,
        }
    }
    /// The EPSG code of its own AUTHORITY / ID child.
    fn epsg(&self) -> Option<u32> {
        self.args.iter().find_map(|a| match a {
            Arg::Node(n)
                if (n.key.eq_ignore_ascii_case("AUTHORITY")
                    || n.key.eq_ignore_ascii_case("ID"))
                    && n.name().eq_ignore_ascii_case("EPSG") =>
            {
                match n.args.get(1) {
                    Some(Arg::Text(t)) => t.trim().parse().ok(),
                    Some(Arg::Num(v)) if v.fract() == 0.0 && *v > 0.0 => Some(*v as u32),
                    _ => None,
                }
            }
            _ => None,
        })
    }
}

/// Parse a WKT (1 or 2) into its element tree.
fn parse_wkt(s: &str) -> Result<Node, String> {
    let b = s.trim().trim_end_matches('\0').as_bytes();
    let mut i = 0;
    let node = parse_node(b, &mut i, 0)?;
    Ok(node)
}

fn skip_ws(b: &[u8], i: &mut usize) {
    while *i < b.len() && b[*i].is_ascii_whitespace() {
        *i += 1;
    }
}

fn parse_node(b: &[u8], i: &mut usize, depth: usize) -> Result<Node, String> {
    if depth > MAX_DEPTH {
        return Err("WKT nested too deep".into());
    }
    skip_ws(b, i);
    let start = *i;
    while *i < b.len() && (b[*i].is_ascii_alphanumeric() || b[*i] == b'_') {
        *i += 1;
    }
    let key = String::from_utf8_lossy(&b[start..*i]).into_owned();
    skip_ws(b, i);
    if key.is_empty() || *i >= b.len() || !matches!(b[*i], b'[' | b'(') {
        return Err(format!("not a WKT element at byte {start}"));
    }
    *i += 1;
    let mut args = Vec::new();
    loop {
        skip_ws(b, i);
        let Some(&c) = b.get(*i) else {
            return Err(format!("WKT {key}: unclosed"));
        };
        match c {
            b']' | b')' => {
                *i += 1;
                return Ok(Node { key, args });
            }
            b',' => *i += 1,
            b'"' => {
                let mut t = Vec::new();
                *i += 1;
                loop {
                    match b.get(*i) {
                        None => return Err(format!("WKT {key}: unclosed quote")),
                        Some(b'"') if b.get(*i + 1) == Some(&b'"') => {
                            t.push(b'"');
                            *i += 2;
                        }
                        Some(b'"') => {
                            *i += 1;
                            break;
                        }
                        Some(&ch) => {
                            t.push(ch);
                            *i += 1;
                        }
                    }
                }
                args.push(Arg::Text(String::from_utf8_lossy(&t).into_owned()));
            }
            b'-' | b'+' | b'.' | b'0'..=b'9' => {
                let s0 = *i;
                while *i < b.len()
                    && matches!(b[*i], b'-' | b'+' | b'.' | b'e' | b'E' | b'0'..=b'9')
                {
                    *i += 1;
                }
                let t = String::from_utf8_lossy(&b[s0..*i]);
                let v = t
                    .parse::<f64>()
                    .map_err(|_| format!("WKT {key}: {t:?} is not a number"))?;
                args.push(Arg::Num(v));
            }
            _ => {
                let s0 = *i;
                let mut j = *i;
                while j < b.len() && (b[j].is_ascii_alphanumeric() || b[j] == b'_') {
                    j += 1;
                }
                let mut k = j;
                skip_ws(b, &mut k);
                if j > s0 && k < b.len() && matches!(b[k], b'[' | b'(') {
                    args.push(Arg::Node(parse_node(b, i, depth + 1)?));
                } else if j > s0 {
                    args.push(Arg::Word(String::from_utf8_lossy(&b[s0..j]).into_owned()));
                    *i = j;
                } else {
                    return Err(format!("WKT {key}: unexpected byte {c:#04x} at {s0}"));
                }
            }
        }
    }
}

/// The unit child of an element: its name and factor.
fn unit_of(n: &Node) -> Option<(String, f64)> {
    let u = n.child("UNIT").or_else(|| n.child("LENGTHUNIT"))?;
    Some((u.name().to_string(), u.num(1)?))
}

/// The tile CRS of a CRS stated as an OGC or ESRI WKT (1 or 2).
pub fn wkt_in_metres(wkt: &str) -> Result<Metric, StatedError> {
    let root = parse_wkt(wkt).map_err(StatedError::Other)?;
    let key = root.key.to_ascii_uppercase();
    let (horiz, vert) = match key.as_str() {
        "COMPD_CS" | "COMPOUNDCRS" => {
            let h = root
                .args
                .iter()
                .find_map(|a| match a {
                    Arg::Node(n)
                        if !n.key.eq_ignore_ascii_case("AUTHORITY")
                            && !n.key.eq_ignore_ascii_case("ID") =>
                    {
                        Some(n)
                    }
                    _ => None,
                })
                .ok_or_else(|| StatedError::Other("compound WKT without parts".into()))?;
            let v = root
                .children("VERT_CS")
                .chain(root.children("VERTCRS"))
                .next()
                .and_then(unit_of);
            (h, v)
        }
        _ => (&root, None),
    };
    let hk = horiz.key.to_ascii_uppercase();
    let name = format!("WKT {hk}[\"{}\"]", horiz.name());
    match hk.as_str() {
        "GEOCCS" => return Err(StatedError::Geocentric(name)),
        "GEOGCS" | "GEOGCRS" | "GEOGRAPHICCRS" => return Err(StatedError::Geographic(name)),
        "GEODCRS" | "GEODETICCRS" => {
            let cartesian = horiz
                .child("CS")
                .is_some_and(|c| matches!(c.args.first(), Some(Arg::Word(w)) if w.eq_ignore_ascii_case("Cartesian")));
            return Err(if cartesian {
                StatedError::Geocentric(name)
            } else {
                StatedError::Geographic(name)
            });
        }
        "PROJCS" | "PROJCRS" | "PROJECTEDCRS" => {}
        _ => return Err(StatedError::Other(format!("{name}: not a projected CRS"))),
    }
    let unit = unit_of(horiz).or_else(|| {
        // WKT2 states the unit on its axes or after CS.
        horiz.args.iter().find_map(|a| match a {
            Arg::Node(n) if n.key.eq_ignore_ascii_case("AXIS") => unit_of(n),
            _ => None,
        })
    });
    let mut metric = match horiz.epsg() {
        Some(code) => {
            let u = unit.as_ref().map(|(n, f)| (n.as_str(), *f));
            // The code's own unit unless the WKT says otherwise.
            let own = definition(code).map(|d| parse_proj4(d).unit);
            let over = u.filter(|(_, f)| own.is_none_or(|o| (o - f).abs() > 1e-12));
            epsg_in_metres(code, over)?
        }
        None => wkt1_in_metres(horiz, &name, unit)?,
    };
    metric.vertical = vert;
    Ok(metric)
}

/// A WKT1 PROJCS without an EPSG code, identified from its parameters.
fn wkt1_in_metres(
    p: &Node,
    name: &str,
    unit: Option<(String, f64)>,
) -> Result<Metric, StatedError> {
    let other = |m: String| StatedError::Other(format!("{name}: {m}"));
    let geog = p.child("GEOGCS").ok_or_else(|| {
        other("no GEOGCS (WKT2 without an EPSG id is not read); give --crs".into())
    })?;
    let datum = geog
        .child("DATUM")
        .ok_or_else(|| other("its GEOGCS has no DATUM".into()))?;
    let ellps = datum
        .child("SPHEROID")
        .and_then(|s| Some((s.num(1)?, s.num(2)?)));
    let deg = unit_of(geog).map_or(1.0, |(_, f)| f / 0.017_453_292_519_943_295);
    let (uname, uf) = unit.ok_or_else(|| other("no linear UNIT".into()))?;
    if !(uf > 0.0) {
        return Err(other(format!("UNIT {uname:?} {uf}")));
    }
    let method = p
        .child("PROJECTION")
        .map(|n| n.name().to_ascii_lowercase())
        .unwrap_or_default();
    let par = |names: &[&str]| {
        p.children("PARAMETER")
            .find(|n| names.iter().any(|k| n.name().eq_ignore_ascii_case(k)))
            .and_then(|n| n.num(1))
    };
    let lat_0 = par(&["latitude_of_origin", "latitude_of_center"]).unwrap_or(0.0) * deg;
    let lon_0 = par(&[
        "central_meridian",
        "longitude_of_origin",
        "longitude_of_center",
    ])
    .unwrap_or(0.0)
        * deg;
    let x0 = par(&["false_easting"]).unwrap_or(0.0) * uf;
    let y0 = par(&["false_northing"]).unwrap_or(0.0) * uf;
    let k = par(&["scale_factor"]).unwrap_or(1.0);
    let src = match method.as_str() {
        "transverse_mercator" => Params {
            method: "tmerc",
            lat_0,
            lon_0,
            lat_1: 0.0,
            lat_2: 0.0,
            k,
            x_0: x0,
            y_0: y0,
            ellps,
            unit: uf,
        },
        "lambert_conformal_conic"
        | "lambert_conformal_conic_2sp"
        | "lambert_conformal_conic_1sp" => {
            let lat_1 = par(&["standard_parallel_1"]).map_or(lat_0, |v| v * deg);
            let lat_2 = par(&["standard_parallel_2"]).map_or(lat_1, |v| v * deg);
            Params {
                method: "lcc",
                lat_0,
                lon_0,
                lat_1,
                lat_2,
                k,
                x_0: x0,
                y_0: y0,
                ellps,
                unit: uf,
            }
        }
        _ => {
            return Err(other(format!(
            "projection {:?} is not one infraloc relates to WGS84 (transverse Mercator, Lambert \
                 conformal conic)",
            p.child("PROJECTION").map_or("", |n| n.name())
        )))
        }
    };
    let twin = metre_twin(&src, datum.name(), None).ok_or_else(|| {
        other(format!(
            "no EPSG CRS in metres has its projection ({}) on its datum {:?}; give --crs EPSG:N \
             --override-crs",
            src.method,
            datum.name()
        ))
    })?;
    Ok(into_twin(&src, twin, (uname, uf)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feet_codes_have_metre_twins() {
        // NAD83 / California zone 5 (ftUS) → NAD83 / California zone 5.
        let m = epsg_in_metres(2229, None).unwrap();
        assert_eq!(m.crs, Crs::Epsg(26945));
        assert_eq!(m.unit.1, US_SURVEY_FOOT);
        assert!((m.dx + 0.000_101_6).abs() < 1e-9 && (m.dy + 0.000_101_6).abs() < 1e-9);
        // A metre code with a feet unit key: the same code, coordinates scaled.
        let m = epsg_in_metres(32128, Some(("US survey foot", US_SURVEY_FOOT))).unwrap();
        assert_eq!((m.crs, m.dx, m.dy), (Crs::Epsg(32128), 0.0, 0.0));
        // NAD83(2011) / Nebraska (ftUS) → NAD83(2011) / Nebraska, not NAD83 or NAD83(HARN).
        assert_eq!(epsg_in_metres(6880, None).unwrap().crs, Crs::Epsg(6516));
        // NAD83(HARN) / Oregon GIC Lambert (ft) → NAD83(HARN) / Oregon LCC (m).
        assert_eq!(epsg_in_metres(2994, None).unwrap().crs, Crs::Epsg(2993));
        assert_eq!(
            epsg_in_metres(25832, None).unwrap(),
            Metric::identity(Crs::Epsg(25832))
        );
        assert!(matches!(
            epsg_in_metres(4978, None),
            Err(StatedError::Geocentric(_))
        ));
        assert!(matches!(
            epsg_in_metres(4326, None),
            Err(StatedError::Geographic(_))
        ));
    }

    #[test]
    fn esri_wkts_are_identified() {
        let autzen = r#"PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic",GEOGCS["GCS_North_American_1983_HARN",DATUM["NAD83_High_Accuracy_Reference_Network",SPHEROID["GRS 1980",6378137,298.2572221010002,AUTHORITY["EPSG","7019"]],AUTHORITY["EPSG","6152"]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],PARAMETER["standard_parallel_1",43],PARAMETER["standard_parallel_2",45.5],PARAMETER["latitude_of_origin",41.75],PARAMETER["central_meridian",-120.5],PARAMETER["false_easting",1312335.958005249],PARAMETER["false_northing",0],UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]]"#;
        let m = wkt_in_metres(autzen).unwrap();
        assert_eq!((m.crs, m.unit.1), (Crs::Epsg(2993), FOOT));
        assert!(m.dx.abs() < 1e-6, "{}", m.dx);
        let nebraska = r#"PROJCS["NAD83_2011_Nebraska_ft",GEOGCS["GCS_NAD_1983_2011",DATUM["D_NAD83_NATIONAL_SPATIAL_REFERENCE_SYSTEM_2011",SPHEROID["GRS_1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["Degree",0.017453292519943295]],PROJECTION["Lambert_Conformal_Conic"],PARAMETER["scale_factor",1],PARAMETER["standard_parallel_1",40],PARAMETER["standard_parallel_2",43],PARAMETER["central_meridian",-100],PARAMETER["latitude_of_origin",39.83333333333334],PARAMETER["false_easting",1640416.666666667],PARAMETER["false_northing",0],UNIT["Foot_US",0.30480060960121924]]"#;
        let m = wkt_in_metres(nebraska).unwrap();
        assert_eq!(m.crs, Crs::Epsg(6516));
        let geocentric = r#"GEOCCS["unnamed",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["metre",1]]"#;
        assert!(matches!(
            wkt_in_metres(geocentric),
            Err(StatedError::Geocentric(_))
        ));
        // An unknown datum is refused by name.
        let odd = nebraska.replace("D_NAD83_NATIONAL_SPATIAL_REFERENCE_SYSTEM_2011", "D_Moon");
        let e = wkt_in_metres(&odd).unwrap_err().to_string();
        assert!(e.contains("D_Moon"), "{e}");
        assert!(parse_wkt("PROJCS[\"x\"").is_err());
        assert!(parse_wkt(&"A[".repeat(100)).is_err());
    }
}
