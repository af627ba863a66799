//! Point-cloud inputs of `infraloc tile build` (I/O shell): LAS 1.2–1.4 and LAZ through the `las`
//! crate (LAZ decompressed by `laz`, the maintained Rust LASzip), COPC read node by node (only the
//! octree nodes that meet the box are decompressed), and PCD files or Autoware split PCD maps (a
//! directory with `pointcloud_map_metadata.yaml`; only the grid files that meet the box are read).
//!
//! Points are handed to the caller one chunk at a time, so memory does not grow with the input;
//! the caller keeps what falls in its box. Noise classes (LAS 7 low noise, 18 high noise) are
//! dropped on read.

use super::las_header::LasLayout;
use super::Crs;
use crate::error::{Error, Result};
use crate::geo::stated::{self, Metric, StatedError};
use std::path::{Path, PathBuf};

/// Points decompressed per chunk of a LAS/LAZ file.
const CHUNK_POINTS: u64 = 1 << 16;
/// LAS classification: ground.
pub(crate) const CLASS_GROUND: u8 = 2;
/// LAS classifications dropped on read: low noise (7), high noise (18).
const CLASS_NOISE: [u8; 2] = [7, 18];
/// Name of an Autoware split map's metadata file.
pub(crate) const AUTOWARE_METADATA: &str = "pointcloud_map_metadata.yaml";

/// One point of an input cloud, in the file's CRS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CloudPoint {
    /// Easting, northing, height.
    pub xyz: [f64; 3],
    /// Raw intensity (LAS: 16-bit field; PCD: already 0–255).
    pub intensity: u16,
    /// LAS classification (0 for PCD).
    pub class: u8,
    /// LAS RGB (16-bit fields), if the point format has them.
    pub rgb: Option<[u16; 3]>,
}

/// The box to read, map CRS: `[xmin, ymin, xmax, ymax]`.
pub(crate) type Box2 = [f64; 4];

fn in_box(b: &Box2, x: f64, y: f64) -> bool {
    x >= b[0] && x < b[2] && y >= b[1] && y < b[3]
}

fn boxes_meet(a: &Box2, b: &Box2) -> bool {
    a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]
}

/// What an input is, from its header.
#[derive(Debug, Clone)]
pub(crate) enum Kind {
    /// LAS or LAZ read front to back.
    Las,
    /// COPC: LAZ with an octree hierarchy.
    Copc,
    /// The PCD files to read (one, or the grid files of a split map that meet the box).
    Pcd(Vec<PathBuf>),
}

/// How a cloud's coordinates become the tile's: `x · xy + dx`, `y · xy + dy`, `z · z` (feet to
/// metres, and the false-origin shift between a feet CRS and its metre twin; `geo::stated`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ToTile {
    /// Metres per horizontal unit of the file.
    pub xy: f64,
    /// Added to x, metres.
    pub dx: f64,
    /// Added to y, metres.
    pub dy: f64,
    /// Metres per vertical unit of the file.
    pub z: f64,
}

impl ToTile {
    /// Coordinates that pass unchanged.
    pub(crate) const IDENTITY: ToTile = ToTile {
        xy: 1.0,
        dx: 0.0,
        dy: 0.0,
        z: 1.0,
    };

    /// A file point in the tile's CRS.
    pub(crate) fn apply(&self, [x, y, z]: [f64; 3]) -> [f64; 3] {
        if *self == Self::IDENTITY {
            return [x, y, z];
        }
        [x * self.xy + self.dx, y * self.xy + self.dy, z * self.z]
    }
}

/// An opened input: its kind and the CRS its header declares.
#[derive(Debug, Clone)]
pub(crate) struct Cloud {
    /// The file or directory.
    pub path: PathBuf,
    /// How it is read.
    pub kind: Kind,
    /// The tile CRS of the file's GeoTIFF keys or WKT; `None` if it has none (PCD never has one)
    /// or states one that makes no tile CRS (`refusal`).
    pub crs: Option<Crs>,
    /// From the file's coordinates to `crs`'s.
    pub to_tile: ToTile,
    /// The CRS as the file states it, for messages (`GeoTIFF keys EPSG:2229`, `WKT PROJCS[…]`).
    pub stated: Option<String>,
    /// Why the stated CRS makes no tile CRS: refused unless `--override-crs` replaces it.
    pub refusal: Option<String>,
    /// Header bounds `[xmin, ymin, zmin, xmax, ymax, zmax]` in the file's units (LAS only).
    pub header_bounds: Option<[f64; 6]>,
}

fn las_err(path: &Path) -> impl Fn(las::Error) -> Error + '_ {
    move |e| {
        let m = e.to_string();
        // A LAZ file's chunk table sits at its end: a cut file fails while being opened.
        if m.contains("failed to fill whole buffer") {
            Error::input(
                path,
                format!("truncated: the file ends before the data its header announces ({m})"),
            )
        } else {
            Error::input(path, format!("not a readable LAS/LAZ file: {m}"))
        }
    }
}

/// Open an input and read its header (not its points). `bx` selects an Autoware map's files.
pub(crate) fn open(path: &Path, bx: &Box2) -> Result<Cloud> {
    let bare = |kind| Cloud {
        path: path.to_path_buf(),
        kind,
        crs: None,
        to_tile: ToTile::IDENTITY,
        stated: None,
        refusal: None,
        header_bounds: None,
    };
    if path.is_dir() {
        return Ok(bare(Kind::Pcd(autoware_files(path, bx)?)));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "pcd" => Ok(bare(Kind::Pcd(vec![path.to_path_buf()]))),
        "las" | "laz" => {
            // The layout first: the las crate would read whatever lengths the header states.
            let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
            let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
            let mut buf = std::io::BufReader::new(&mut f);
            let layout =
                super::las_header::read_layout(&mut buf, len).map_err(|m| Error::input(path, m))?;
            let reader = las::Reader::from_path(path).map_err(las_err(path))?;
            let header = reader.header();
            let kind = if header.copc_info_vlr().is_some() {
                Kind::Copc
            } else {
                Kind::Las
            };
            let mut cloud = bare(kind);
            cloud.header_bounds = Some(layout.bounds);
            let stated = las_crs(&layout, header, path)?;
            for n in &stated.notes {
                warn(path, n);
            }
            cloud.stated = stated.label;
            match stated.metric {
                Some(Ok(m)) => {
                    let z = stated.vertical.unwrap_or(m.unit.1);
                    cloud.to_tile = ToTile {
                        xy: m.unit.1,
                        dx: m.dx,
                        dy: m.dy,
                        z,
                    };
                    cloud.crs = Some(m.crs);
                    if cloud.to_tile != ToTile::IDENTITY {
                        crate::cli::note(&format!(
                            "{}: {} is in {}: the tile is in {}, x and y × {} {:+.4} m, {:+.4} m, \
                             heights × {z}",
                            path.display(),
                            cloud.stated.as_deref().unwrap_or("its CRS"),
                            m.unit.0,
                            m.crs,
                            m.unit.1,
                            m.dx,
                            m.dy
                        ));
                    }
                }
                Some(Err(e)) => cloud.refusal = Some(refusal(&e, &layout.bounds)),
                None => {}
            }
            Ok(cloud)
        }
        _ => Err(Error::input(
            path,
            "unknown point cloud type (expected .las, .laz, .copc.laz, .pcd or an Autoware split map directory)",
        )),
    }
}

/// One warning line on stderr about an input.
fn warn(path: &Path, msg: &str) {
    eprintln!("infraloc: warning: {}: {msg}", path.display());
}

/// Mean Earth radius ± the highest and lowest ground, metres: where geocentric points lie.
const EARTH_SURFACE_M: std::ops::RangeInclusive<f64> = 6_300_000.0..=6_400_000.0;

/// The refusal of a stated CRS, saying whether the points contradict it (then the label, not
/// the points, is what is wrong, and `--override-crs` is the way out).
fn refusal(e: &StatedError, b: &[f64; 6]) -> String {
    let c = [
        (b[0] + b[3]) / 2.0,
        (b[1] + b[4]) / 2.0,
        (b[2] + b[5]) / 2.0,
    ];
    match e {
        StatedError::Geocentric(_) => {
            let r = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
            if EARTH_SURFACE_M.contains(&r) {
                format!("{e}; reproject the points to a projected CRS in metres first")
            } else {
                format!(
                    "{e}, but its points are {:.0} km from the Earth's centre, not on its surface: \
                     the label is wrong; give the right CRS with --crs EPSG:N --override-crs",
                    r / 1000.0
                )
            }
        }
        StatedError::Geographic(_) => {
            if c[0].abs() <= 360.0 && c[1].abs() <= 90.0 {
                format!("{e}; reproject the points to a projected CRS in metres first")
            } else {
                format!(
                    "{e}, but its points (x {:.0}, y {:.0}) are no longitude and latitude: the \
                     label is wrong; give the right CRS with --crs EPSG:N --override-crs",
                    c[0], c[1]
                )
            }
        }
        StatedError::Other(m) => m.clone(),
    }
}

/// Clouds whose stated CRS made no tile CRS are refused; with `override_crs` every stated CRS is
/// replaced by `--crs` instead, one warning per cloud.
pub(crate) fn settle_crs(
    clouds: &mut [Cloud],
    override_crs: bool,
    flag: Option<Crs>,
) -> Result<()> {
    if override_crs {
        let Some(crs) = flag else {
            return Err(Error::Usage(
                "--override-crs replaces the clouds' CRS with --crs: give --crs EPSG:N".into(),
            ));
        };
        for c in clouds.iter_mut() {
            if let Some(s) = c.stated.take() {
                warn(
                    &c.path,
                    &format!("its CRS ({s}) is replaced by --crs {crs} (--override-crs)"),
                );
            }
            c.crs = None;
            c.refusal = None;
            c.to_tile = ToTile::IDENTITY;
        }
        return Ok(());
    }
    match clouds.iter().find_map(|c| Some((c, c.refusal.as_ref()?))) {
        Some((c, why)) => Err(Error::input(&c.path, format!("CRS: {why}"))),
        None => Ok(()),
    }
}

/// What a LAS header states about its CRS.
struct Stated {
    /// The tile CRS it makes, or why it makes none; `None` if it states none.
    metric: Option<std::result::Result<Metric, StatedError>>,
    /// How the file states it.
    label: Option<String>,
    /// Metres per vertical unit, if the file states the vertical unit.
    vertical: Option<f64>,
    /// Warnings (GeoTIFF keys and WKT that disagree).
    notes: Vec<String>,
}

/// The CRS a LAS header declares: GeoTIFF keys (ProjectedCSTypeGeoKey, with ProjLinearUnits and
/// VerticalUnits) and an OGC WKT (E)VLR. When both are there and disagree, LAS 1.4's rule decides:
/// the WKT for point formats 6–10 or when the global encoding's WKT bit is set, else the keys.
fn las_crs(layout: &LasLayout, header: &las::Header, path: &Path) -> Result<Stated> {
    let wkt = layout
        .crs_records
        .iter()
        .find(|r| r.record_id == super::las_header::WKT_RECORD)
        .map(|r| {
            String::from_utf8_lossy(&r.data)
                .trim_end_matches(['\0', ' ', '\n'])
                .to_string()
        })
        .filter(|t| !t.is_empty());
    let keys = header
        .get_geotiff_crs()
        .map_err(|e| Error::input(path, format!("GeoTIFF CRS VLR: {e}")))?;
    let key = |id: u16| {
        keys.as_ref()?
            .entries
            .iter()
            .find_map(|k| match (k.id == id, &k.data) {
                (true, las::crs::GeoTiffData::U16(v)) => Some(*v),
                _ => None,
            })
    };
    let unit_key =
        |id: u16, what: &str| -> std::result::Result<Option<(&'static str, f64)>, StatedError> {
            match key(id) {
                None => Ok(None),
                Some(c) => stated::linear_unit(c).map(Some).ok_or_else(|| {
                    StatedError::Other(format!("GeoTIFF {what} {c}: not metres or feet"))
                }),
            }
        };
    let from_keys = match (key(3072), key(2048)) {
        (Some(USER_DEFINED), _) => Some((
            "GeoTIFF keys: a user-defined projected CRS".to_string(),
            Err(StatedError::Other(
                "GeoTIFF CRS VLR: user-defined projected CRS (no EPSG code); give --crs EPSG:N \
                 --override-crs, or write the file with an EPSG code"
                    .into(),
            )),
        )),
        (Some(code), _) => {
            let unit = unit_key(3076, "ProjLinearUnits");
            let label = match unit {
                Ok(Some((n, _))) => format!("GeoTIFF keys EPSG:{code} with ProjLinearUnits {n}"),
                _ => format!("GeoTIFF keys EPSG:{code}"),
            };
            Some((
                label,
                unit.and_then(|u| stated::epsg_in_metres(u32::from(code), u)),
            ))
        }
        (None, Some(code)) => Some((
            format!("GeoTIFF keys EPSG:{code}"),
            Err(StatedError::Geographic(format!("EPSG:{code}"))),
        )),
        (None, None) => None,
    };
    let from_wkt = wkt.map(|w| {
        let name = w.split('"').nth(1).unwrap_or("").to_string();
        (format!("WKT \"{name}\""), stated::wkt_in_metres(&w))
    });
    let wkt_rules = layout.wkt_bit() || layout.point_format >= 6;
    let mut notes = Vec::new();
    let (first, second) = if wkt_rules {
        (from_wkt, from_keys)
    } else {
        (from_keys, from_wkt)
    };
    let chosen = match (first, second) {
        (Some((l1, Ok(m1))), Some((l2, Ok(m2)))) => {
            if m1.crs != m2.crs || m1.unit.1 != m2.unit.1 {
                notes.push(format!(
                    "{l1} (tile {}, {}) and {l2} (tile {}, {}) disagree; {} decides (LAS 1.4: \
                     the WKT for point formats 6–10 or with the WKT bit, else the keys)",
                    m1.crs, m1.unit.0, m2.crs, m2.unit.0, l1
                ));
            }
            Some((l1, Ok(m1)))
        }
        (Some((l1, Err(e1))), Some((l2, Ok(m2)))) => {
            notes.push(format!("{l1}: {e1}; taking {l2} instead"));
            Some((l2, Ok(m2)))
        }
        (Some(c), _) | (None, Some(c)) => Some(c),
        (None, None) => None,
    };
    let vertical = match chosen.as_ref().map(|(_, m)| m) {
        Some(Ok(Metric {
            vertical: Some((_, f)),
            ..
        })) => Some(*f),
        _ => unit_key(4099, "VerticalUnits")
            .ok()
            .flatten()
            .map(|(_, f)| f),
    };
    let (label, metric) = match chosen {
        Some((l, m)) => (Some(l), Some(m)),
        None => (None, None),
    };
    Ok(Stated {
        metric,
        label,
        vertical,
        notes,
    })
}

/// GeoKey value meaning "user-defined".
const USER_DEFINED: u16 = 32767;

/// The PCD files of an Autoware split map that meet `bx` (all `.pcd` files of the directory, in
/// name order, when it has no metadata file).
fn autoware_files(dir: &Path, bx: &Box2) -> Result<Vec<PathBuf>> {
    let meta = dir.join(AUTOWARE_METADATA);
    if !meta.is_file() {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| Error::io(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("pcd")))
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(Error::input(
                dir,
                format!("directory holds no .pcd files and no {AUTOWARE_METADATA}"),
            ));
        }
        return Ok(files);
    }
    let text = std::fs::read_to_string(&meta).map_err(|e| Error::io(&meta, e))?;
    let docs = yaml_rust2::YamlLoader::load_from_str(&text)
        .map_err(|e| Error::input(&meta, format!("not YAML: {e}")))?;
    let doc = docs
        .first()
        .and_then(|d| d.as_hash())
        .ok_or_else(|| Error::input(&meta, "expected a mapping"))?;
    let num = |key: &str| -> Result<f64> {
        let v = &doc[&yaml_rust2::Yaml::String(key.into())];
        v.as_f64()
            .or_else(|| v.as_i64().map(|i| i as f64))
            .filter(|r| *r > 0.0)
            .ok_or_else(|| Error::input(&meta, format!("{key}: missing or not a positive number")))
    };
    let (rx, ry) = (num("x_resolution")?, num("y_resolution")?);
    let mut files = Vec::new();
    for (k, v) in doc {
        let Some(name) = k.as_str() else { continue };
        if name == "x_resolution" || name == "y_resolution" {
            continue;
        }
        let xy: Vec<f64> = v
            .as_vec()
            .map(|a| {
                a.iter()
                    .filter_map(|e| e.as_f64().or_else(|| e.as_i64().map(|i| i as f64)))
                    .collect()
            })
            .unwrap_or_default();
        let [x, y] = xy[..] else {
            return Err(Error::input(
                &meta,
                format!("{name}: expected [x, y] of the grid cell's lower-left corner"),
            ));
        };
        if boxes_meet(&[x, y, x + rx, y + ry], bx) {
            files.push(dir.join(name));
        }
    }
    files.sort();
    Ok(files)
}

/// Largest side of a tile taken from the clouds' own extent, metres: a node's tile covers the
/// camera's surroundings (a few hundred metres); a survey file is a tile of at most a few square
/// kilometres (1 km at 0.1 m is 10⁸ cells, about 3 GB while building, so a coarser `--res` for a
/// whole one). A larger survey is cut with `--bbox` or `--center`.
pub(crate) const MAX_EXTENT_SIDE_M: f64 = 2000.0;

/// Added to the extent's east and north edges, metres: a micrometre, below any LAS scale factor
/// and above the rounding of coordinates up to 10⁸ m.
const EXTENT_PAD_M: f64 = 1e-6;

/// The clouds' extent in the tile's CRS: of the points themselves (one more pass over each file),
/// because headers can be wrong; COPC's header bounds, which its writers compute from the points
/// to build the octree. Noise classes do not count. Refused above [`MAX_EXTENT_SIDE_M`] a side.
pub(crate) fn extent(clouds: &[Cloud]) -> Result<Box2> {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let mut grow = |x: f64, y: f64| {
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    };
    let everything = [f64::MIN, f64::MIN, f64::MAX, f64::MAX];
    for c in clouds {
        match (&c.kind, c.header_bounds) {
            (Kind::Copc, Some(h)) => {
                let lo = c.to_tile.apply([h[0], h[1], h[2]]);
                let hi = c.to_tile.apply([h[3], h[4], h[5]]);
                grow(lo[0], lo[1]);
                grow(hi[0], hi[1]);
            }
            _ => {
                read(c, &everything, |p| grow(p.xyz[0], p.xyz[1]))?;
            }
        }
    }
    let names = || {
        clouds
            .iter()
            .map(|c| c.path.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    if !(b[2] >= b[0] && b[3] >= b[1]) {
        return Err(Error::input(
            names(),
            "no points to take an extent from; give --bbox or --center",
        ));
    }
    let (w, h) = (b[2] - b[0], b[3] - b[1]);
    if w > MAX_EXTENT_SIDE_M || h > MAX_EXTENT_SIDE_M {
        return Err(Error::input(
            names(),
            format!(
                "the clouds' extent is {w:.0} m × {h:.0} m (x {}..{}, y {}..{}), more than \
                 {MAX_EXTENT_SIDE_M} m a side: cut the node's tile with --bbox or --center",
                b[0], b[2], b[1], b[3]
            ),
        ));
    }
    // The box is half-open: points on its east and north edges must fall inside it.
    Ok([b[0], b[1], b[2] + EXTENT_PAD_M, b[3] + EXTENT_PAD_M])
}

/// Per-input statistics gathered while reading, for the builder's normalisation and messages.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ReadStats {
    /// Points decoded (in or out of the box).
    pub decoded: u64,
    /// Points in the box handed on.
    pub kept: u64,
    /// Largest intensity of the decoded points.
    pub max_intensity: u16,
    /// Largest RGB component of the decoded points.
    pub max_rgb: u16,
    /// Whether the point format carries RGB.
    pub has_rgb: bool,
}

/// Read the points of `cloud` in `bx`, handing each to `sink`.
pub(crate) fn read(
    cloud: &Cloud,
    bx: &Box2,
    mut sink: impl FnMut(&CloudPoint),
) -> Result<ReadStats> {
    let mut stats = ReadStats::default();
    let mut take = |p: &CloudPoint, st: &mut ReadStats| {
        st.decoded += 1;
        st.max_intensity = st.max_intensity.max(p.intensity);
        if let Some(c) = p.rgb {
            st.max_rgb = st.max_rgb.max(c[0]).max(c[1]).max(c[2]);
        }
        let p = CloudPoint {
            xyz: cloud.to_tile.apply(p.xyz),
            ..*p
        };
        if in_box(bx, p.xyz[0], p.xyz[1]) && !CLASS_NOISE.contains(&p.class) {
            st.kept += 1;
            sink(&p);
        }
    };
    match &cloud.kind {
        Kind::Las => {
            let path = &cloud.path;
            let mut reader = las::Reader::from_path(path).map_err(las_err(path))?;
            let header = reader.header().clone();
            stats.has_rgb = header.point_format().has_color;
            let mut pd = las::PointDataBuilder::new().for_header(&header).build();
            let total = header.number_of_points();
            while stats.decoded < total {
                let n = reader
                    .fill_points(CHUNK_POINTS.min(total - stats.decoded), &mut pd)
                    .map_err(|e| {
                        Error::input(
                            path,
                            format!(
                                "truncated or corrupt point data after {} of {total} points: {e}",
                                stats.decoded
                            ),
                        )
                    })?;
                if n == 0 {
                    return Err(Error::input(
                        path,
                        format!(
                            "truncated: the header announces {total} points, the data ends after {}",
                            stats.decoded
                        ),
                    ));
                }
                each_point(&pd, |p| take(p, &mut stats));
            }
        }
        Kind::Copc => {
            let path = &cloud.path;
            let mut reader = las::CopcReader::from_path(path).map_err(las_err(path))?;
            let header = reader.header().clone();
            stats.has_rgb = header.point_format().has_color;
            let info = header
                .copc_info_vlr()
                .ok_or_else(|| Error::input(path, "COPC info VLR vanished"))?;
            // File order, so the reads move forward through the file.
            let mut entries: Vec<las::copc::Entry> = reader
                .hierarchy_entries()
                .filter(|e| e.point_count > 0)
                .filter(|e| {
                    let b = e.key.bounds(&info);
                    boxes_meet(&[b.min.x, b.min.y, b.max.x, b.max.y], bx)
                })
                .collect();
            entries.sort_by_key(|e| e.offset);
            for e in &entries {
                let pd = reader.read_entry(e).map_err(|err| {
                    Error::input(
                        path,
                        format!("COPC node {:?} at byte {}: {err}", e.key, e.offset),
                    )
                })?;
                each_point(&pd, |p| take(p, &mut stats));
            }
        }
        Kind::Pcd(files) => {
            for f in files {
                let bytes = std::fs::read(f).map_err(|e| Error::io(f, e))?;
                let pts = crate::points_io::parse_pcd(&bytes).map_err(|m| Error::input(f, m))?;
                for g in pts {
                    let p = CloudPoint {
                        xyz: [g.x, g.y, g.z],
                        intensity: u16::from(g.reflectivity),
                        class: 0,
                        rgb: None,
                    };
                    take(&p, &mut stats);
                }
            }
        }
    }
    Ok(stats)
}

/// Call `f` on each point of a decoded chunk.
fn each_point(pd: &las::PointData, mut f: impl FnMut(&CloudPoint)) {
    let mut rgb = pd.rgb();
    for ((((x, y), z), intensity), class) in pd
        .x()
        .zip(pd.y())
        .zip(pd.z())
        .zip(pd.intensity())
        .zip(pd.classification())
    {
        let rgb = rgb
            .as_mut()
            .and_then(|it| it.next())
            .map(|(r, g, b)| [r, g, b]);
        f(&CloudPoint {
            xyz: [x, y, z],
            intensity,
            class,
            rgb,
        });
    }
}

/// Sub-points per cell side written by [`write_lidar_laz`].
const LAZ_SUB: usize = 2;

/// Write a tile's LiDAR layers as a LAZ point cloud (LAS 1.2, point format 2, CRS as GeoTIFF
/// keys): per cell with data `LAZ_SUB`² ground points (class 2) spread over the cell, each with
/// the cell's height and reflectivity (× 257, the 16-bit intensity of LAS) and the colour of the
/// satellite pixel under it (× 257). `tile build` on the file gives back the tile's LiDAR layers.
pub(crate) fn write_lidar_laz(tile: &super::Tile, path: &Path) -> Result<()> {
    let g = tile.reflectivity.grid;
    let Crs::Epsg(code) = g.crs else {
        return Err(Error::input(path, "a LOCAL tile has no CRS to write"));
    };
    let code = u16::try_from(code)
        .map_err(|_| Error::input(path, format!("EPSG:{code} does not fit a GeoKey")))?;
    let lerr = |e: las::Error| Error::input(path, format!("LAZ write: {e}"));
    let mut b = las::Builder::from((1, 2));
    // Format 2: coordinates, intensity, class and RGB, no GPS time (the simulator has none).
    b.point_format = las::point::Format::new(2).map_err(lerr)?;
    let t = |offset: f64| las::Transform {
        scale: 0.001,
        offset,
    };
    b.transforms = las::Vector {
        x: t(g.x0.floor()),
        y: t(g.y0.floor()),
        z: t(0.0),
    };
    // GeoKeyDirectory: version 1.1.0, 3 keys: projected model, PixelIsArea, the EPSG code.
    let keys: [u16; 16] = [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, code];
    b.vlrs.push(las::Vlr {
        user_id: "LASF_Projection".into(),
        record_id: 34735,
        description: "GeoKeyDirectoryTag".into(),
        data: keys.iter().flat_map(|k| k.to_le_bytes()).collect(),
    });
    let header = b.into_header().map_err(lerr)?;
    let mut w = las::Writer::from_path(path, header).map_err(lerr)?;
    let sat = &tile.satellite;
    for row in 0..g.height {
        for col in 0..g.width {
            let i = row * g.width + col;
            let (r, z) = (tile.reflectivity.data[i], tile.height.data[i]);
            if Some(r) == tile.reflectivity.nodata || !z.is_finite() {
                continue;
            }
            let (cx, cy) = g.pixel_center(col, row);
            for k in 0..LAZ_SUB * LAZ_SUB {
                let off = |j: usize| ((j as f64 + 0.5) / LAZ_SUB as f64 - 0.5) * g.res;
                let (x, y) = (cx + off(k % LAZ_SUB), cy + off(k / LAZ_SUB));
                let (sc, sr) = sat.grid.to_pixel(x, y);
                let rgb = sat
                    .get(sc.round().max(0.0) as usize, sr.round().max(0.0) as usize)
                    .unwrap_or([0; 3]);
                let c = |v: u8| u16::from(v) * 257;
                w.write_point(las::Point {
                    x,
                    y,
                    z: f64::from(z),
                    intensity: u16::from(r) * 257,
                    classification: las::point::Classification::Ground,
                    color: Some(las::Color::new(c(rgb[0]), c(rgb[1]), c(rgb[2]))),
                    ..Default::default()
                })
                .map_err(lerr)?;
            }
        }
    }
    w.close().map_err(lerr)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wkt_crss() {
        let wkt1 = r#"PROJCS["Amersfoort / RD New",GEOGCS["Amersfoort",DATUM["Amersfoort",SPHEROID["Bessel 1841",6377397.155,299.1528128,AUTHORITY["EPSG","7004"]],AUTHORITY["EPSG","6289"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4289"]],PROJECTION["Oblique_Stereographic"],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","28992"]]"#;
        let crs = |w: &str| stated::wkt_in_metres(w).map(|m| m.crs);
        assert_eq!(crs(wkt1), Ok(Crs::Epsg(28992)));
        let compound = format!(
            r#"COMPD_CS["RD + NAP",{wkt1},VERT_CS["NAP height",VERT_DATUM["NAP",2005],UNIT["metre",1],AUTHORITY["EPSG","5709"]],AUTHORITY["EPSG","7415"]]"#
        );
        let m = stated::wkt_in_metres(&compound).unwrap();
        assert_eq!(
            (m.crs, m.vertical),
            (Crs::Epsg(28992), Some(("metre".into(), 1.0)))
        );
        let wkt2 = r#"PROJCRS["ETRS89 / UTM zone 32N",BASEGEOGCRS["ETRS89",ID["EPSG",4258]],CONVERSION["UTM zone 32N",ID["EPSG",16032]],CS[Cartesian,2],ID["EPSG",25832]]"#;
        assert_eq!(crs(wkt2), Ok(Crs::Epsg(25832)));
        let geographic = r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],AUTHORITY["EPSG","4326"]]"#;
        assert!(matches!(crs(geographic), Err(StatedError::Geographic(_))));
        // A projected CRS with neither an EPSG code nor parameters to identify it by.
        let anonymous = r#"PROJCS["custom",GEOGCS["x"],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert!(crs(anonymous).is_err());
        assert!(crs("LOCAL_CS[\"x\"]").is_err());
    }

    #[test]
    fn geocentric_labels_on_projected_points_are_called_wrong() {
        let e = StatedError::Geocentric("WKT GEOCCS[\"unnamed\"]".into());
        let lone_star = [515368.6, 4918340.4, 2322.9, 515401.0, 4918381.1, 2338.6];
        let m = refusal(&e, &lone_star);
        assert!(
            m.contains("4945 km from the Earth's centre") && m.contains("--override-crs"),
            "{m}"
        );
        let truly = [
            4_000_000.0,
            800_000.0,
            4_900_000.0,
            4_000_010.0,
            800_010.0,
            4_900_010.0,
        ];
        assert!(refusal(&e, &truly).contains("reproject"));
    }
}
