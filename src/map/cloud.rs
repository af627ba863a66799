//! Point-cloud inputs of `infraloc tile build` (I/O shell): LAS 1.2–1.4 and LAZ through the `las`
//! crate (LAZ decompressed by `laz`, the maintained Rust LASzip), COPC read node by node (only the
//! octree nodes that meet the box are decompressed), and PCD files or Autoware split PCD maps (a
//! directory with `pointcloud_map_metadata.yaml`; only the grid files that meet the box are read).
//!
//! Points are handed to the caller one chunk at a time, so memory does not grow with the input;
//! the caller keeps what falls in its box. Noise classes (LAS 7 low noise, 18 high noise) are
//! dropped on read.

use super::Crs;
use crate::error::{Error, Result};
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

/// An opened input: its kind and the CRS its header declares.
#[derive(Debug, Clone)]
pub(crate) struct Cloud {
    /// The file or directory.
    pub path: PathBuf,
    /// How it is read.
    pub kind: Kind,
    /// CRS from the file's GeoTIFF keys or WKT; `None` if it has none (PCD never has one).
    pub crs: Option<Crs>,
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
    if path.is_dir() {
        let files = autoware_files(path, bx)?;
        return Ok(Cloud {
            path: path.to_path_buf(),
            kind: Kind::Pcd(files),
            crs: None,
        });
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "pcd" => Ok(Cloud {
            path: path.to_path_buf(),
            kind: Kind::Pcd(vec![path.to_path_buf()]),
            crs: None,
        }),
        "las" | "laz" => {
            let reader = las::Reader::from_path(path).map_err(las_err(path))?;
            let header = reader.header();
            let kind = if header.copc_info_vlr().is_some() {
                Kind::Copc
            } else {
                Kind::Las
            };
            Ok(Cloud {
                path: path.to_path_buf(),
                kind,
                crs: match las_crs(header, path)? {
                    Some(c) => Some(c),
                    None => evlr_wkt_crs(path)?,
                },
            })
        }
        _ => Err(Error::input(
            path,
            "unknown point cloud type (expected .las, .laz, .copc.laz, .pcd or an Autoware map directory)",
        )),
    }
}

/// The CRS a LAS header declares: GeoTIFF keys (ProjectedCSTypeGeoKey) or an OGC WKT VLR.
fn las_crs(header: &las::Header, path: &Path) -> Result<Option<Crs>> {
    if let Some(wkt) = header.get_wkt_crs_bytes() {
        let text = String::from_utf8_lossy(wkt);
        return wkt_epsg(text.trim_end_matches('\0'))
            .map(|c| Some(Crs::Epsg(c)))
            .map_err(|m| Error::input(path, format!("WKT CRS VLR: {m}")));
    }
    let keys = header
        .get_geotiff_crs()
        .map_err(|e| Error::input(path, format!("GeoTIFF CRS VLR: {e}")))?;
    let Some(keys) = keys else { return Ok(None) };
    match (
        keys.get_projected_crs_geo_key_value(),
        keys.get_geodetic_crs_geo_key_value(),
    ) {
        (Some(code), _) if code != USER_DEFINED => Ok(Some(Crs::Epsg(u32::from(code)))),
        (Some(_), _) => Err(Error::input(
            path,
            "GeoTIFF CRS VLR: user-defined projected CRS (no EPSG code); give the tile's --crs \
             after reprojecting, or write the file with an EPSG code",
        )),
        (None, Some(code)) => Ok(Some(Crs::Epsg(u32::from(code)))),
        (None, None) => Ok(None),
    }
}

/// LAS 1.4 header: start of the first EVLR (u64) and the number of EVLRs (u32).
const START_OF_FIRST_EVLR: u64 = 235;
/// Bytes of an EVLR header: reserved, user id, record id, length after header, description.
const EVLR_HEADER: usize = 60;

/// The WKT CRS of an EVLR past the first (the `las` crate reads only the first EVLR; COPC files
/// keep their hierarchy there and their CRS in a later one).
fn evlr_wkt_crs(path: &Path) -> Result<Option<Crs>> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut head = [0u8; 12];
    let io = |e: std::io::Error| Error::input(path, format!("EVLRs: {e}"));
    f.seek(SeekFrom::Start(START_OF_FIRST_EVLR)).map_err(io)?;
    if f.read_exact(&mut head).is_err() {
        return Ok(None);
    }
    let mut at = u64::from_le_bytes(head[..8].try_into().unwrap_or_default());
    let count = u32::from_le_bytes(head[8..].try_into().unwrap_or_default());
    for _ in 0..count.min(1024) {
        let mut h = [0u8; EVLR_HEADER];
        f.seek(SeekFrom::Start(at)).map_err(io)?;
        f.read_exact(&mut h).map_err(io)?;
        let user = String::from_utf8_lossy(&h[2..18]);
        let record = u16::from_le_bytes([h[18], h[19]]);
        let len = u64::from_le_bytes(h[20..28].try_into().unwrap_or_default());
        if user
            .trim_end_matches('\0')
            .eq_ignore_ascii_case("LASF_Projection")
            && record == 2112
        {
            let mut wkt = Vec::new();
            (&mut f)
                .take(len.min(1 << 20))
                .read_to_end(&mut wkt)
                .map_err(io)?;
            let text = String::from_utf8_lossy(&wkt);
            return wkt_epsg(text.trim_end_matches('\0'))
                .map(|c| Some(Crs::Epsg(c)))
                .map_err(|m| Error::input(path, format!("WKT CRS EVLR: {m}")));
        }
        at = at.saturating_add(EVLR_HEADER as u64).saturating_add(len);
    }
    Ok(None)
}

/// GeoKey value meaning "user-defined".
const USER_DEFINED: u16 = 32767;

/// The EPSG code of the horizontal CRS of an OGC WKT (WKT1 or WKT2): the last authority of its
/// projected CRS element, or of the whole text when it is not compound.
pub(crate) fn wkt_epsg(wkt: &str) -> std::result::Result<u32, String> {
    let upper = wkt.to_ascii_uppercase();
    // A compound CRS names its horizontal part first; its own code would be the compound's.
    let start = ["PROJCS[", "PROJCRS[", "PROJECTEDCRS["]
        .iter()
        .filter_map(|k| upper.find(k))
        .min();
    let part = match start {
        Some(s) => &wkt[s..s + element_len(&wkt[s..])],
        None => wkt,
    };
    // The CRS's own authority is a direct child of its element (depth 1); deeper ones name its
    // datum, units or base CRS.
    let up = part.to_ascii_uppercase();
    let mut depth = 0i32;
    let mut found = None;
    for (i, c) in up.char_indices() {
        match c {
            '[' | '(' => depth += 1,
            ']' | ')' => depth -= 1,
            _ if depth == 1 => {
                for k in ["AUTHORITY[\"EPSG\",", "ID[\"EPSG\","] {
                    if up[i..].starts_with(k) && (i == 0 || !up[..i].ends_with(char::is_alphabetic))
                    {
                        found = Some(i + k.len());
                    }
                }
            }
            _ => {}
        }
    }
    let pos = found
        .ok_or_else(|| "the WKT's CRS has no EPSG authority of its own; give --crs".to_string())?;
    let code: String = part[pos..]
        .trim_start_matches(['"', ' '])
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    code.parse::<u32>()
        .map_err(|_| "the WKT's EPSG authority is not a number; give --crs".to_string())
}

/// Length of the bracketed WKT element starting at `s` (up to its matching `]`).
fn element_len(s: &str) -> usize {
    let mut depth = 0i32;
    for (i, c) in s.char_indices() {
        match c {
            '[' | '(' => depth += 1,
            ']' | ')' => {
                depth -= 1;
                if depth == 0 {
                    return i + 1;
                }
            }
            _ => {}
        }
    }
    s.len()
}

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
        if in_box(bx, p.xyz[0], p.xyz[1]) && !CLASS_NOISE.contains(&p.class) {
            st.kept += 1;
            sink(p);
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
    let Some(sat) = &tile.satellite else {
        return Err(Error::input(
            path,
            "the tile has no satellite layer to colour the points",
        ));
    };
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
    fn wkt_codes() {
        let wkt1 = r#"PROJCS["Amersfoort / RD New",GEOGCS["Amersfoort",DATUM["Amersfoort",SPHEROID["Bessel 1841",6377397.155,299.1528128,AUTHORITY["EPSG","7004"]],AUTHORITY["EPSG","6289"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4289"]],PROJECTION["Oblique_Stereographic"],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","28992"]]"#;
        assert_eq!(wkt_epsg(wkt1), Ok(28992));
        let compound = format!(
            r#"COMPD_CS["RD + NAP",{wkt1},VERT_CS["NAP height",VERT_DATUM["NAP",2005],AUTHORITY["EPSG","5709"]],AUTHORITY["EPSG","7415"]]"#
        );
        assert_eq!(wkt_epsg(&compound), Ok(28992));
        let wkt2 = r#"PROJCRS["ETRS89 / UTM zone 32N",BASEGEOGCRS["ETRS89",ID["EPSG",4258]],CONVERSION["UTM zone 32N",ID["EPSG",16032]],CS[Cartesian,2],ID["EPSG",25832]]"#;
        assert_eq!(wkt_epsg(wkt2), Ok(25832));
        let geographic = r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],AUTHORITY["EPSG","4326"]]"#;
        assert_eq!(wkt_epsg(geographic), Ok(4326));
        // The last authority is the unit's: the CRS itself has none.
        let anonymous = r#"PROJCS["custom",GEOGCS["x"],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert!(wkt_epsg(anonymous).unwrap_err().contains("give --crs"));
        assert!(wkt_epsg("LOCAL_CS[\"x\"]")
            .unwrap_err()
            .contains("give --crs"));
    }
}
