//! Point-file readers (I/O shell): CSV, PCD and LAS → [`GroundPoint`]s in the file's frame.
//!
//! - **CSV**: header required, naming at least `x`, `y`, `z`, `reflectivity` (or `intensity`; any
//!   order, extra columns ignored); reflectivity 0–255 (rounded to the nearest integer), or 0–1
//!   when every value of the file lies in [0, 1] and some are fractional (e.g. KITTI's
//!   normalised reflectance), scaled ×255.
//! - **PCD** (`.pcd`), `DATA ascii` or `DATA binary` (not `binary_compressed`): fields `x y z` and
//!   `intensity` or `reflectivity` (SIZE/TYPE/COUNT honoured, other fields skipped).
//! - **LAS** 1.0–1.4 (`.las`), point formats 0–10 (X, Y, Z and intensity have the same offsets in
//!   all of them); coordinates = integer · scale + offset; LAZ (compressed) is rejected.
//! - **Velodyne `.bin`** (KITTI's raw sweeps): records of four float32 little-endian values x, y, z,
//!   reflectance, no header; the file's length must be a multiple of 16 bytes. Reflectance is
//!   scaled as the PCD/LAS floats below (KITTI's 0–1 → ×255, as CSV values in [0, 1]).
//!
//! Intensity scaling to 0–255 (PCD, LAS and `.bin`; CSV only the [0, 1] case), from the file's own
//! range so that one file is scaled uniformly:
//! - integers: taken as they are if the largest ≤ 255; otherwise divided by the smallest full-scale
//!   2^b − 1 (b = 12 or 16 in practice) that holds the largest value, times 255 — so a 16-bit LAS
//!   intensity (the spec's normalisation) maps 65535 → 255 and a 12-bit sensor 4095 → 255;
//! - floats: ×255 if all lie in [0, 1], as they are if in [0, 255], else × 255 / max.
//!
//! MI only uses the *order* statistics of reflectivity through its (equalised) bins, so the exact
//! scale matters little; what matters is that it is monotonic and the same for every point.
//!
//! Non-finite coordinates are rejected (one-line error naming the file and point).
//!
//! The LAS reader is ours rather than the `las` crate's: it reads the same coordinates,
//! rejects unusable scale factors, and says what a truncated file is missing
//! (docs/architecture.md, "Kept crates and own code", has the comparison).

use crate::error::{Error, Result};
use crate::localize::mi::points::{validate, GroundPoint};
use std::path::Path;

/// Read a point file, format by extension (`.csv`, `.pcd`, `.las`, `.bin`; `.txt` as CSV).
pub fn read_points(path: &Path) -> Result<Vec<GroundPoint>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let pts = match ext.as_str() {
        "csv" | "txt" => parse_csv(&bytes).map_err(|m| Error::input(path, m))?,
        "pcd" => parse_pcd(&bytes).map_err(|m| Error::input(path, m))?,
        "las" => parse_las(&bytes).map_err(|m| Error::input(path, m))?,
        "bin" => parse_velodyne_bin(&bytes).map_err(|m| Error::input(path, m))?,
        "laz" => return Err(Error::input(
            path,
            "LAZ (compressed LAS) is not supported; decompress with `laszip` or `pdal translate`",
        )),
        _ => {
            return Err(Error::input(
                path,
                "unknown point file type (expected .csv, .pcd, .las or a Velodyne .bin)",
            ))
        }
    };
    validate(&pts, &path.display().to_string())?;
    Ok(pts)
}

/// Parse CSV text with an `x,y,z,reflectivity` header.
pub fn parse_csv(bytes: &[u8]) -> std::result::Result<Vec<GroundPoint>, String> {
    let text = std::str::from_utf8(bytes).map_err(|_| "not UTF-8 text".to_string())?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or("empty file")?;
    let cols: Vec<String> = header
        .split(',')
        .map(|c| c.trim().trim_matches('"').to_ascii_lowercase())
        .collect();
    let find = |name: &str| {
        cols.iter().position(|c| c == name).ok_or_else(|| {
            format!(
                "header {header:?} has no column {name:?} (need x,y,z,reflectivity or intensity)"
            )
        })
    };
    let ir = find("reflectivity").or_else(|e| find("intensity").map_err(|_| e))?;
    let (ix, iy, iz) = (find("x")?, find("y")?, find("z")?);
    let mut out = Vec::new();
    let mut raw = Vec::new();
    for (ln, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let get = |i: usize, name: &str| -> std::result::Result<f64, String> {
            f.get(i)
                .ok_or_else(|| format!("line {}: missing {name}", ln + 1))?
                .parse::<f64>()
                .map_err(|_| format!("line {}: {name} is not a number", ln + 1))
        };
        let r = get(ir, "reflectivity")?;
        if !(0.0..=255.0).contains(&r) {
            return Err(format!("line {}: reflectivity {r} outside 0–255", ln + 1));
        }
        let p = GroundPoint {
            x: get(ix, "x")?,
            y: get(iy, "y")?,
            z: get(iz, "z")?,
            reflectivity: 0,
        };
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return Err(format!("line {}: non-finite coordinate", ln + 1));
        }
        out.push(p);
        raw.push(r);
    }
    // 0–255 as given; a file whose every value lies in [0, 1], some of them fractional, is
    // normalised reflectance (×255): read as given it would round to two bins and leave MI
    // nothing to measure. (A file of 0s and 1s only stays as given.)
    let normalised = raw.iter().all(|r| *r <= 1.0) && raw.iter().any(|r| r.fract() != 0.0);
    for (p, r) in out.iter_mut().zip(&raw) {
        p.reflectivity = if normalised { r * 255.0 } else { *r }.round() as u8;
    }
    Ok(out)
}

/// Bytes of one Velodyne `.bin` record: x, y, z, reflectance as float32.
const VELODYNE_RECORD: usize = 16;

/// Parse a Velodyne `.bin` sweep (KITTI's `velodyne/NNNNNN.bin`): float32 LE x, y, z, reflectance.
pub fn parse_velodyne_bin(bytes: &[u8]) -> std::result::Result<Vec<GroundPoint>, String> {
    if bytes.len() % VELODYNE_RECORD != 0 {
        return Err(format!(
            "{} bytes is not a whole number of Velodyne records (x, y, z, reflectance as float32: \
             {VELODYNE_RECORD} bytes each)",
            bytes.len()
        ));
    }
    let n = bytes.len() / VELODYNE_RECORD;
    let mut xyz = Vec::with_capacity(n);
    let mut refl = Vec::with_capacity(n);
    for (k, r) in bytes.chunks_exact(VELODYNE_RECORD).enumerate() {
        let f = |i: usize| f32::from_le_bytes([r[4 * i], r[4 * i + 1], r[4 * i + 2], r[4 * i + 3]]);
        let v = f(3);
        if !v.is_finite() || v < 0.0 {
            return Err(format!(
                "point {k}: reflectance {v} is negative or non-finite"
            ));
        }
        xyz.push([f(0) as f64, f(1) as f64, f(2) as f64]);
        refl.push(v as f64);
    }
    finish(xyz, scale_intensity(RawIntensity::Float(refl))?)
}

/// Raw intensity values before scaling.
enum RawIntensity {
    Int(Vec<u64>),
    Float(Vec<f64>),
}

/// Scale intensities to 0–255 (see the module docs).
fn scale_intensity(raw: RawIntensity) -> std::result::Result<Vec<u8>, String> {
    match raw {
        RawIntensity::Int(v) => {
            let max = v.iter().copied().max().unwrap_or(0);
            if max <= 255 {
                return Ok(v.into_iter().map(|x| x as u8).collect());
            }
            let bits = 64 - max.leading_zeros();
            let full = ((1u128 << bits) - 1) as f64;
            Ok(v.into_iter()
                .map(|x| (x as f64 * 255.0 / full).round().min(255.0) as u8)
                .collect())
        }
        RawIntensity::Float(v) => {
            if v.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err("intensity: negative or non-finite value".into());
            }
            let max = v.iter().copied().fold(0.0, f64::max);
            let k = if max <= 1.0 {
                255.0
            } else if max <= 255.0 {
                1.0
            } else {
                255.0 / max
            };
            Ok(v.into_iter()
                .map(|x| (x * k).round().min(255.0) as u8)
                .collect())
        }
    }
}

/// One PCD field.
#[derive(Debug, Clone)]
struct PcdField {
    name: String,
    size: usize,
    kind: u8,
    count: usize,
    offset: usize,
}

fn pcd_value(b: &[u8], kind: u8, size: usize) -> std::result::Result<f64, String> {
    // A record slice shorter than the field (a malformed header) is an error, never an index
    // past the end.
    let b = b
        .get(..size)
        .ok_or_else(|| format!("PCD record too short for a {size}-byte field"))?;
    let v = match (kind, size) {
        (b'F', 4) => f32::from_le_bytes(b[..4].try_into().unwrap_or_default()) as f64,
        (b'F', 8) => f64::from_le_bytes(b[..8].try_into().unwrap_or_default()),
        (b'U', 1) => b[0] as f64,
        (b'U', 2) => u16::from_le_bytes([b[0], b[1]]) as f64,
        (b'U', 4) => u32::from_le_bytes(b[..4].try_into().unwrap_or_default()) as f64,
        (b'I', 1) => b[0] as i8 as f64,
        (b'I', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
        (b'I', 4) => i32::from_le_bytes(b[..4].try_into().unwrap_or_default()) as f64,
        _ => return Err(format!("unsupported PCD TYPE {} SIZE {size}", kind as char)),
    };
    Ok(v)
}

/// A PCD file's header: its fields laid out in a record, the points it declares, the data's
/// encoding and where the data starts.
struct PcdHeader {
    fields: Vec<PcdField>,
    /// Bytes of one binary record.
    record: usize,
    /// The POINTS line's count.
    npoints: usize,
    /// The DATA line's encoding, lower case.
    data: String,
    /// Byte offset of the data after the header.
    data_start: usize,
}

/// Read a PCD header up to and including its DATA line; each field gets its SIZE, TYPE, COUNT
/// and offset in a binary record.
fn parse_pcd_header(bytes: &[u8]) -> std::result::Result<PcdHeader, String> {
    let mut pos = 0;
    let mut fields: Vec<PcdField> = Vec::new();
    let (mut sizes, mut types, mut counts) = (Vec::new(), Vec::new(), Vec::new());
    let mut npoints: Option<usize> = None;
    let mut data: Option<String> = None;
    while pos < bytes.len() {
        let end = bytes[pos..]
            .iter()
            .position(|&c| c == b'\n')
            .map(|e| pos + e + 1)
            .unwrap_or(bytes.len());
        let line = std::str::from_utf8(&bytes[pos..end])
            .map_err(|_| "PCD header is not text".to_string())?
            .trim();
        pos = end;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut it = line.split_whitespace();
        let key = it.next().unwrap_or("").to_ascii_uppercase();
        let rest: Vec<&str> = it.collect();
        match key.as_str() {
            "FIELDS" => {
                fields = rest
                    .iter()
                    .map(|n| PcdField {
                        name: n.to_ascii_lowercase(),
                        size: 4,
                        kind: b'F',
                        count: 1,
                        offset: 0,
                    })
                    .collect()
            }
            "SIZE" => {
                sizes = rest
                    .iter()
                    .map(|s| s.parse::<usize>().unwrap_or(0))
                    .collect()
            }
            "TYPE" => {
                types = rest
                    .iter()
                    .map(|s| s.as_bytes().first().copied().unwrap_or(0))
                    .collect()
            }
            "COUNT" => {
                counts = rest
                    .iter()
                    .map(|s| s.parse::<usize>().unwrap_or(0))
                    .collect()
            }
            "POINTS" => {
                npoints = Some(
                    rest.first()
                        .and_then(|s| s.parse().ok())
                        .ok_or("POINTS is not a number")?,
                )
            }
            "DATA" => {
                data = Some(rest.first().unwrap_or(&"").to_ascii_lowercase());
                break;
            }
            _ => {}
        }
    }
    let data = data.ok_or("no DATA line in the PCD header")?;
    let n = npoints.ok_or("no POINTS line in the PCD header")?;
    if fields.is_empty() {
        return Err("no FIELDS line in the PCD header".into());
    }
    let mut off: usize = 0;
    for (i, f) in fields.iter_mut().enumerate() {
        f.size = *sizes.get(i).unwrap_or(&4);
        f.kind = *types.get(i).unwrap_or(&b'F');
        f.count = *counts.get(i).unwrap_or(&1);
        if !matches!(f.size, 1 | 2 | 4 | 8) || f.count == 0 {
            return Err(format!(
                "PCD field {}: SIZE {} COUNT {} (SIZE 1, 2, 4 or 8 and COUNT ≥ 1 expected)",
                f.name, f.size, f.count
            ));
        }
        f.offset = off;
        off = f
            .size
            .checked_mul(f.count)
            .and_then(|b| off.checked_add(b))
            .ok_or_else(|| format!("PCD field {}: COUNT {} too large", f.name, f.count))?;
    }
    Ok(PcdHeader {
        fields,
        record: off,
        npoints: n,
        data,
        data_start: pos,
    })
}

/// Parse a PCD file (ascii or binary).
pub fn parse_pcd(bytes: &[u8]) -> std::result::Result<Vec<GroundPoint>, String> {
    let PcdHeader {
        fields,
        record,
        npoints: n,
        data,
        data_start: pos,
    } = parse_pcd_header(bytes)?;
    let find = |n: &str| fields.iter().position(|f| f.name == n);
    let (ix, iy, iz) = (
        find("x").ok_or("PCD has no field x")?,
        find("y").ok_or("PCD has no field y")?,
        find("z").ok_or("PCD has no field z")?,
    );
    let ii = find("intensity")
        .or_else(|| find("reflectivity"))
        .ok_or("PCD has no field intensity or reflectivity")?;
    let int_kind = fields[ii].kind;
    // POINTS is only a claim until the data is read: no allocation beyond what the file can hold.
    let mut xyz = Vec::with_capacity(n.min(bytes.len() - pos));
    let (mut ri, mut rf) = (Vec::new(), Vec::new());
    match data.as_str() {
        "ascii" => {
            let text = std::str::from_utf8(&bytes[pos..]).map_err(|_| "PCD data is not text")?;
            // Column of each field's first element.
            let mut col = Vec::new();
            let mut c = 0;
            for f in &fields {
                col.push(c);
                c += f.count;
            }
            for (k, line) in text.lines().filter(|l| !l.trim().is_empty()).take(n).enumerate() {
                let v: Vec<&str> = line.split_whitespace().collect();
                let get = |i: usize| -> std::result::Result<f64, String> {
                    v.get(col[i])
                        .and_then(|s| s.parse::<f64>().ok())
                        .ok_or_else(|| format!("PCD point {k}: field {} unreadable", fields[i].name))
                };
                xyz.push([get(ix)?, get(iy)?, get(iz)?]);
                let val = get(ii)?;
                if int_kind == b'F' {
                    rf.push(val);
                } else {
                    ri.push(val.max(0.0) as u64);
                }
            }
        }
        "binary" => {
            let body = &bytes[pos..];
            let need = n.checked_mul(record);
            if need.is_none_or(|need| body.len() < need) {
                return Err(format!(
                    "PCD binary data holds {} bytes, {n} points of {record} bytes need more",
                    body.len(),
                ));
            }
            for k in 0..n {
                let r = &body[k * record..(k + 1) * record];
                let get = |i: usize| pcd_value(&r[fields[i].offset..], fields[i].kind, fields[i].size);
                xyz.push([get(ix)?, get(iy)?, get(iz)?]);
                let val = get(ii)?;
                if int_kind == b'F' {
                    rf.push(val);
                } else {
                    ri.push(val.max(0.0) as u64);
                }
            }
        }
        other => {
            return Err(format!(
                "PCD DATA {other} is not supported (ascii or binary; convert binary_compressed with pcl_convert_pcd_ascii_binary)"
            ))
        }
    }
    if xyz.len() != n {
        return Err(format!("PCD declares {n} points, found {}", xyz.len()));
    }
    let refl = scale_intensity(if int_kind == b'F' {
        RawIntensity::Float(rf)
    } else {
        RawIntensity::Int(ri)
    })?;
    finish(xyz, refl)
}

fn finish(xyz: Vec<[f64; 3]>, refl: Vec<u8>) -> std::result::Result<Vec<GroundPoint>, String> {
    xyz.into_iter()
        .zip(refl)
        .enumerate()
        .map(|(k, (p, r))| {
            if p.iter().all(|v| v.is_finite()) {
                Ok(GroundPoint {
                    x: p[0],
                    y: p[1],
                    z: p[2],
                    reflectivity: r,
                })
            } else {
                Err(format!(
                    "point {k}: non-finite coordinate ({}, {}, {})",
                    p[0], p[1], p[2]
                ))
            }
        })
        .collect()
}

fn le_u16(b: &[u8], o: usize) -> std::result::Result<u16, String> {
    b.get(o..o + 2)
        .map(|s| u16::from_le_bytes([s[0], s[1]]))
        .ok_or_else(|| format!("LAS header truncated at byte {o}"))
}
fn le_u32(b: &[u8], o: usize) -> std::result::Result<u32, String> {
    b.get(o..o + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or_else(|| format!("LAS header truncated at byte {o}"))
}
fn le_f64(b: &[u8], o: usize) -> std::result::Result<f64, String> {
    b.get(o..o + 8)
        .and_then(|s| s.try_into().ok())
        .map(f64::from_le_bytes)
        .ok_or_else(|| format!("LAS header truncated at byte {o}"))
}

/// LAS public-header offsets (ASPRS LAS 1.2–1.4 specification, table "Public Header Block").
mod las {
    pub(crate) const VERSION_MAJOR: usize = 24;
    pub(crate) const VERSION_MINOR: usize = 25;
    pub(crate) const OFFSET_TO_POINTS: usize = 96;
    pub(crate) const POINT_FORMAT: usize = 104;
    pub(crate) const RECORD_LENGTH: usize = 105;
    pub(crate) const LEGACY_COUNT: usize = 107;
    pub(crate) const SCALE: usize = 131;
    pub(crate) const OFFSET: usize = 155;
    /// LAS 1.4 64-bit point count.
    pub(crate) const COUNT_64: usize = 247;
    /// Bytes of X, Y, Z (i32 each) + intensity (u16), common to formats 0–10.
    pub(crate) const MIN_RECORD: usize = 14;
}

/// Parse a LAS file.
pub fn parse_las(b: &[u8]) -> std::result::Result<Vec<GroundPoint>, String> {
    if b.get(0..4) != Some(b"LASF") {
        return Err("not a LAS file (no LASF signature)".into());
    }
    let (maj, min) = (b.get(las::VERSION_MAJOR), b.get(las::VERSION_MINOR));
    let (maj, min) = (
        *maj.ok_or("LAS header truncated")?,
        *min.ok_or("LAS header truncated")?,
    );
    if maj != 1 || min > 4 {
        return Err(format!("LAS version {maj}.{min} not supported (1.0–1.4)"));
    }
    let start = le_u32(b, las::OFFSET_TO_POINTS)? as usize;
    let fmt_byte = *b.get(las::POINT_FORMAT).ok_or("LAS header truncated")?;
    if fmt_byte & 0x80 != 0 || fmt_byte & 0x40 != 0 {
        return Err("compressed (LAZ) point data is not supported".into());
    }
    let fmt = fmt_byte & 0x3f;
    if fmt > 10 {
        return Err(format!("LAS point data format {fmt} not supported (0–10)"));
    }
    let rec = le_u16(b, las::RECORD_LENGTH)? as usize;
    if rec < las::MIN_RECORD {
        return Err(format!(
            "LAS point record length {rec} < {}",
            las::MIN_RECORD
        ));
    }
    let mut n = le_u32(b, las::LEGACY_COUNT)? as u64;
    if n == 0 && min >= 4 {
        n = b
            .get(las::COUNT_64..las::COUNT_64 + 8)
            .and_then(|s| s.try_into().ok())
            .map(u64::from_le_bytes)
            .ok_or("LAS 1.4 header truncated")?;
    }
    let n = n as usize;
    let s = [
        le_f64(b, las::SCALE)?,
        le_f64(b, las::SCALE + 8)?,
        le_f64(b, las::SCALE + 16)?,
    ];
    let o = [
        le_f64(b, las::OFFSET)?,
        le_f64(b, las::OFFSET + 8)?,
        le_f64(b, las::OFFSET + 16)?,
    ];
    if s.iter().any(|v| !(v.is_finite() && *v != 0.0)) {
        return Err(format!("LAS scale factors {s:?} unusable"));
    }
    let need = n.checked_mul(rec).and_then(|d| d.checked_add(start));
    if need.is_none_or(|need| b.len() < need) {
        return Err(format!(
            "LAS file has {} bytes, its {n} points of {rec} bytes from offset {start} need {}",
            b.len(),
            need.map_or("more than can be addressed".to_string(), |k| k.to_string())
        ));
    }
    let mut xyz = Vec::with_capacity(n);
    let mut inten = Vec::with_capacity(n);
    for k in 0..n {
        let r = &b[start + k * rec..start + (k + 1) * rec];
        let i = |o: usize| i32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]) as f64;
        xyz.push([i(0) * s[0] + o[0], i(4) * s[1] + o[1], i(8) * s[2] + o[2]]);
        inten.push(u16::from_le_bytes([r[12], r[13]]) as u64);
    }
    finish(xyz, scale_intensity(RawIntensity::Int(inten))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Inputs the `point_readers` fuzz target found (docs/fuzzing.md): each is an error, not a
    /// panic.
    #[test]
    fn fuzz_found_inputs_are_errors() {
        // COUNT of a field unreadable (taken as 0): the binary reader indexed an empty slice.
        let mut pcd =
            b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 2\nTYPE F F F U\n\
            COUNT 1 1 1 I1W\nDTH 2\nHEIGHT \0\x001NT 1 1 1 1\nW\nPOINTS 2\nDATA binary\n"
                .to_vec();
        pcd.extend_from_slice(&[0, 0, 0x80, 0x3f, 0, 0, 0, 0x40, 0, 0, 0x40, 0x40, 0x2c, 1]);
        pcd.extend_from_slice(&[
            0, 0, 0x80, 0x40, 0, 0, 0xa0, 0x40, 1, 0, 0xc0, 0x40, 0xff, 0xf,
        ]);
        assert!(parse_pcd(&pcd).unwrap_err().contains("COUNT"));
        // Sizes and counts whose product overflows, and a POINTS count no file can hold.
        let huge = format!(
            "FIELDS x y z intensity\nSIZE 8 4 4 4\nCOUNT {} 1 1 1\nPOINTS 1\nDATA binary\n",
            usize::MAX / 2
        );
        assert!(parse_pcd(huge.as_bytes())
            .unwrap_err()
            .contains("too large"));
        let many = format!(
            "FIELDS x y z intensity\nPOINTS {}\nDATA binary\n0123456789abcdef",
            usize::MAX / 3
        );
        assert!(parse_pcd(many.as_bytes())
            .unwrap_err()
            .contains("need more"));
        let many_ascii = format!(
            "FIELDS x y z intensity\nPOINTS {}\nDATA ascii\n1 2 3 4\n",
            usize::MAX
        );
        assert!(parse_pcd(many_ascii.as_bytes())
            .unwrap_err()
            .contains("declares"));
        // LAS: a 1.4 64-bit point count whose records overflow the address space.
        let mut las = las_bytes(0, &[4]);
        las[25] = 4;
        las[107..111].copy_from_slice(&0u32.to_le_bytes());
        las.resize(255, 0);
        las[247..255].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(parse_las(&las)
            .unwrap_err()
            .contains("need more than can be addressed"));
    }

    #[test]
    fn csv_any_column_order_and_errors() {
        let t = b"reflectivity,z,x,y,extra\n12,1.5,500000.25,4000000.5,q\n255,1.0,1,2,\n";
        let p = parse_csv(t).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].x, 500000.25);
        assert_eq!(p[0].y, 4000000.5);
        assert_eq!(p[0].z, 1.5);
        assert_eq!(p[0].reflectivity, 12);
        assert!(parse_csv(b"1,2,3,4\n").unwrap_err().contains("no column"));
        assert!(parse_csv(b"x,y,z,reflectivity\n1,2,3,300\n")
            .unwrap_err()
            .contains("outside"));
        assert!(parse_csv(b"x,y,z,reflectivity\n1,2,nan,3\n")
            .unwrap_err()
            .contains("non-finite"));
    }

    #[test]
    fn csv_normalised_reflectance_and_intensity_header() {
        // KITTI-style reflectance in [0, 1] under an `intensity` header: scaled to 0–255, order
        // kept (read as given it would round to 0 and 1).
        let p =
            parse_csv(b"x,y,z,intensity\n0,0,0,0.0\n1,0,0,0.25\n2,0,0,0.5\n3,0,0,1.0\n").unwrap();
        let r: Vec<u8> = p.iter().map(|p| p.reflectivity).collect();
        assert_eq!(r, vec![0, 64, 128, 255]);
        // One value above 1: the file is 0–255, taken as given; so is a file of 0s and 1s.
        let p = parse_csv(b"x,y,z,reflectivity\n0,0,0,0.4\n1,0,0,2\n").unwrap();
        assert_eq!((p[0].reflectivity, p[1].reflectivity), (0, 2));
        let p = parse_csv(b"x,y,z,reflectivity\n0,0,0,0\n1,0,0,1\n").unwrap();
        assert_eq!((p[0].reflectivity, p[1].reflectivity), (0, 1));
    }

    /// A LAS 1.2 file written field by field from the ASPRS table (independent of the reader's
    /// constants).
    fn las_bytes(format: u8, intensities: &[u16]) -> Vec<u8> {
        let rec: u16 = match format {
            0 => 20,
            1 => 28,
            2 => 26,
            _ => 34,
        };
        let mut h = vec![0u8; 227];
        h[0..4].copy_from_slice(b"LASF");
        h[24] = 1;
        h[25] = 2;
        h[94..96].copy_from_slice(&227u16.to_le_bytes());
        h[96..100].copy_from_slice(&227u32.to_le_bytes());
        h[104] = format;
        h[105..107].copy_from_slice(&rec.to_le_bytes());
        h[107..111].copy_from_slice(&(intensities.len() as u32).to_le_bytes());
        for (k, v) in [0.001f64, 0.001, 0.01].iter().enumerate() {
            h[131 + 8 * k..139 + 8 * k].copy_from_slice(&v.to_le_bytes());
        }
        for (k, v) in [500000.0f64, 4000000.0, 100.0].iter().enumerate() {
            h[155 + 8 * k..163 + 8 * k].copy_from_slice(&v.to_le_bytes());
        }
        for (k, &it) in intensities.iter().enumerate() {
            let mut r = vec![0u8; rec as usize];
            r[0..4].copy_from_slice(&(1234 + k as i32).to_le_bytes());
            r[4..8].copy_from_slice(&(-5678i32).to_le_bytes());
            r[8..12].copy_from_slice(&250i32.to_le_bytes());
            r[12..14].copy_from_slice(&it.to_le_bytes());
            h.extend_from_slice(&r);
        }
        h
    }

    #[test]
    fn las_formats_scale_offset_and_intensity() {
        for fmt in 0..=3u8 {
            let p = parse_las(&las_bytes(fmt, &[0, 65535, 32768])).unwrap();
            assert_eq!(p.len(), 3);
            assert!((p[1].x - 500001.235).abs() < 1e-9, "{}", p[1].x);
            assert!((p[0].y - 3999994.322).abs() < 1e-9);
            assert!((p[0].z - 102.5).abs() < 1e-9);
            // 16-bit full scale → 255; 32768 → 127.5 → 128.
            assert_eq!(
                p.iter().map(|q| q.reflectivity).collect::<Vec<_>>(),
                vec![0, 255, 128]
            );
        }
        // 8-bit intensities are kept; 12-bit ones scale by 255/4095.
        let p = parse_las(&las_bytes(1, &[0, 200, 255])).unwrap();
        assert_eq!(p[1].reflectivity, 200);
        let p = parse_las(&las_bytes(1, &[4095, 2048])).unwrap();
        assert_eq!((p[0].reflectivity, p[1].reflectivity), (255, 128));
        let mut laz = las_bytes(1, &[1]);
        laz[104] |= 0x80;
        assert!(parse_las(&laz).unwrap_err().contains("LAZ"));
        let short = las_bytes(1, &[1, 2, 3]);
        assert!(parse_las(&short[..short.len() - 5])
            .unwrap_err()
            .contains("need"));
    }

    /// Velodyne records written value by value (independent of the reader's constants).
    fn velodyne_bytes(points: &[[f32; 4]]) -> Vec<u8> {
        points
            .iter()
            .flat_map(|p| p.iter().flat_map(|v| v.to_le_bytes()))
            .collect()
    }

    #[test]
    fn velodyne_bin_records_and_reflectance_scaling() {
        let b = velodyne_bytes(&[
            [12.5, -3.25, -1.75, 0.0],
            [5.0, 0.5, -1.5, 0.5],
            [-20.0, 7.0, 0.25, 1.0],
        ]);
        let p = parse_velodyne_bin(&b).unwrap();
        assert_eq!(p.len(), 3);
        assert_eq!((p[0].x, p[0].y, p[0].z), (12.5, -3.25, -1.75));
        assert_eq!((p[2].x, p[2].y, p[2].z), (-20.0, 7.0, 0.25));
        // KITTI reflectance 0–1 scaled ×255 as CSV values in [0, 1]: 0.5 → 127.5 → 128.
        let r: Vec<u8> = p.iter().map(|q| q.reflectivity).collect();
        assert_eq!(r, vec![0, 128, 255]);
        // The CSV reader scales the same values the same way.
        let csv = parse_csv(b"x,y,z,intensity\n0,0,0,0.0\n0,0,0,0.5\n0,0,0,1.0\n").unwrap();
        assert_eq!(csv.iter().map(|q| q.reflectivity).collect::<Vec<_>>(), r);
        // A torn file: one-line error naming the byte count.
        let e = parse_velodyne_bin(&b[..b.len() - 3]).unwrap_err();
        assert!(e.contains("45 bytes") && e.contains("16 bytes"), "{e}");
        assert!(!e.contains('\n'));
        // Non-finite coordinates and reflectance are refused, naming the point.
        let e = parse_velodyne_bin(&velodyne_bytes(&[
            [1.0, 2.0, 3.0, 0.1],
            [f32::NAN, 0.0, 0.0, 0.2],
        ]))
        .unwrap_err();
        assert!(e.starts_with("point 1: non-finite"), "{e}");
        let e = parse_velodyne_bin(&velodyne_bytes(&[[1.0, 2.0, 3.0, f32::INFINITY]])).unwrap_err();
        assert!(e.starts_with("point 0: reflectance"), "{e}");
    }

    #[test]
    fn velodyne_bin_through_read_points_names_the_file() {
        let dir = std::env::temp_dir().join(format!("infraloc-velo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("000042.bin");
        std::fs::write(
            &good,
            velodyne_bytes(&[[1.0, 2.0, 3.0, 0.25], [4.0, 5.0, 6.0, 0.75]]),
        )
        .unwrap();
        let p = read_points(&good).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!((p[1].x, p[1].reflectivity), (4.0, 191));
        let torn = dir.join("torn.BIN");
        std::fs::write(&torn, [0u8; 17]).unwrap();
        let e = read_points(&torn).unwrap_err().to_string();
        assert!(
            e.starts_with(&torn.display().to_string()) && e.contains("17 bytes"),
            "{e}"
        );
        let empty = dir.join("empty.bin");
        std::fs::write(&empty, []).unwrap();
        let e = read_points(&empty).unwrap_err().to_string();
        assert!(
            e.contains("empty.bin") && e.contains("no ground points"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn pcd_ascii_and_binary() {
        let a = b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n1.5 2.5 -0.5 0.25\n3 4 5 1.0\n";
        let p = parse_pcd(a).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!((p[0].x, p[0].y, p[0].z), (1.5, 2.5, -0.5));
        // Floats in [0, 1] scale by 255.
        assert_eq!((p[0].reflectivity, p[1].reflectivity), (64, 255));

        let mut b = b"VERSION 0.7\nFIELDS x y z rgb reflectivity\nSIZE 8 8 8 4 1\nTYPE F F F U U\nCOUNT 1 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n".to_vec();
        for (x, r) in [(10.0f64, 7u8), (-3.25, 200)] {
            b.extend_from_slice(&x.to_le_bytes());
            b.extend_from_slice(&(x * 2.0).to_le_bytes());
            b.extend_from_slice(&1.0f64.to_le_bytes());
            b.extend_from_slice(&0xffffffffu32.to_le_bytes());
            b.push(r);
        }
        let p = parse_pcd(&b).unwrap();
        assert_eq!((p[1].x, p[1].y, p[1].reflectivity), (-3.25, -6.5, 200));
        assert!(parse_pcd(&b[..b.len() - 1]).unwrap_err().contains("need"));
        let nan = b"FIELDS x y z intensity\nPOINTS 1\nDATA ascii\nnan 1 2 3\n";
        assert!(parse_pcd(nan).unwrap_err().contains("non-finite"));
        let cmp = b"FIELDS x y z intensity\nPOINTS 1\nDATA binary_compressed\n";
        assert!(parse_pcd(cmp).unwrap_err().contains("not supported"));
    }
}
