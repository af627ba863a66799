//! The layout of a LAS/LAZ file as its version defines it: the header (through the `las` crate's
//! version-aware raw reader), the VLR table and, from LAS 1.4 on, the EVLR table, each checked
//! against the file's size before anything is allocated or read from it.
//!
//! LAS 1.0–1.2 headers are 227 bytes, 1.3 adds the waveform offset (235), 1.4 the EVLR fields and
//! the 64-bit point counts (375). Fields a version does not define are not read: the bytes after a
//! 1.0–1.3 header belong to its VLRs. A header that contradicts the file's size is refused with the
//! field it names, so that a cut or corrupt file fails in one line instead of somewhere inside a
//! reader (or, for a length read from the file, in an allocation of that length).

use std::io::{Read, Seek, SeekFrom};

/// Bytes of a VLR header: reserved, user id, record id, record length, description.
const VLR_HEADER: u64 = 54;
/// Bytes of an EVLR header (its record length is 64-bit).
const EVLR_HEADER: u64 = 60;
/// Largest CRS record kept (a WKT is a few kilobytes; a longer one is not a CRS).
const MAX_CRS_RECORD: u64 = 1 << 20;
/// User id of the CRS records.
const LASF_PROJECTION: &str = "LASF_Projection";
/// Record id of the OGC WKT CRS record.
pub const WKT_RECORD: u16 = 2112;
/// Offset of "number of EVLRs" in a LAS 1.4 header (after "start of first EVLR", u64 at 235).
const NUMBER_OF_EVLRS_AT: usize = 243;

/// A CRS record (LASF_Projection) of the VLR or EVLR table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CrsRecord {
    /// Record id: 34735–34737 GeoTIFF keys, 2112 WKT.
    pub record_id: u16,
    /// Whether it came from the EVLR table.
    pub extended: bool,
    /// The record's bytes.
    pub data: Vec<u8>,
}

/// What a LAS/LAZ file's header and record tables say, each checked against the file's size.
#[derive(Debug, Clone, PartialEq)]
pub struct LasLayout {
    /// Version (major, minor).
    pub version: (u8, u8),
    /// Point format 0–10 (without LAZ's compression bits).
    pub point_format: u8,
    /// Whether the points are LAZ-compressed.
    pub compressed: bool,
    /// Global encoding; its WKT bit (4) is defined from LAS 1.4 on only.
    pub global_encoding: u16,
    /// Number of point records (LAS 1.4: the 64-bit field when the legacy one is 0).
    pub points: u64,
    /// Header bounds `[xmin, ymin, zmin, xmax, ymax, zmax]`, as the header states them.
    pub bounds: [f64; 6],
    /// VLRs in the table.
    pub vlrs: u32,
    /// EVLRs in the table (LAS 1.4; 0 before).
    pub evlrs: u32,
    /// The CRS records of both tables, in file order.
    pub crs_records: Vec<CrsRecord>,
}

impl LasLayout {
    /// Whether the header's global encoding says the CRS is a WKT (LAS 1.4's bit 4; earlier
    /// versions do not define it).
    pub fn wkt_bit(&self) -> bool {
        self.version >= (1, 4) && self.global_encoding & 0x10 != 0
    }
}

/// Header size of a LAS version (1.0–1.2: 227, 1.3: 235, 1.4: 375).
fn version_header_size(minor: u8) -> u64 {
    match minor {
        0..=2 => 227,
        3 => 235,
        _ => 375,
    }
}

fn read_at<R: Read + Seek>(r: &mut R, at: u64, buf: &mut [u8]) -> std::io::Result<()> {
    r.seek(SeekFrom::Start(at))?;
    r.read_exact(buf)
}

/// Read and check the layout of a LAS/LAZ file of `len` bytes. The error names the field.
pub fn read_layout<R: Read + Seek>(r: &mut R, len: u64) -> Result<LasLayout, String> {
    let io = |what: &str, e: std::io::Error| format!("{what}: {e}");
    let mut sig = [0u8; 4];
    if len < 4 {
        return Err(format!(
            "header: the file has {len} bytes, not even a LAS signature"
        ));
    }
    read_at(r, 0, &mut sig).map_err(|e| io("signature", e))?;
    if &sig != b"LASF" {
        return Err(format!(
            "signature {sig:?}: not \"LASF\", so not a LAS/LAZ file"
        ));
    }
    if len < 227 {
        return Err(format!(
            "header: truncated, the file has {len} bytes and the smallest LAS header (1.0–1.2) 227"
        ));
    }
    let mut ver = [0u8; 2];
    read_at(r, 24, &mut ver).map_err(|e| io("version", e))?;
    let (major, minor) = (ver[0], ver[1]);
    if major != 1 || minor > 4 {
        return Err(format!("version {major}.{minor}: LAS 1.0 to 1.4 are read"));
    }
    let want = version_header_size(minor);
    if len < want {
        return Err(format!(
            "header: truncated, the file has {len} bytes and a LAS 1.{minor} header {want}"
        ));
    }
    r.seek(SeekFrom::Start(0)).map_err(|e| io("header", e))?;
    let h = las::raw::Header::read_from(&mut *r).map_err(|e| format!("header: {e}"))?;
    let header_size = u64::from(h.header_size);
    if header_size < want {
        return Err(format!(
            "header size {header_size}: a LAS 1.{minor} header has {want} bytes"
        ));
    }
    if header_size > len {
        return Err(format!(
            "header size {header_size}: past the end of the file ({len} bytes)"
        ));
    }
    let offset = u64::from(h.offset_to_point_data);
    if offset < header_size || offset > len {
        return Err(format!(
            "offset to point data {offset}: outside the file after its {header_size}-byte header \
             ({len} bytes)"
        ));
    }
    let compressed = h.point_data_record_format & 0xc0 != 0;
    let point_format = h.point_data_record_format & 0x3f;
    if point_format > 10 {
        return Err(format!(
            "point data format {point_format}: LAS defines 0 to 10"
        ));
    }
    let legacy = u64::from(h.number_of_point_records);
    let points = match h.large_file {
        Some(lf) if legacy == 0 => lf.number_of_point_records,
        _ => legacy,
    };
    let mut crs_records = Vec::new();
    // The VLR table lies between the header and the point data.
    let n_vlrs = h.number_of_variable_length_records;
    read_vlrs(r, (header_size, offset, len), n_vlrs, &mut crs_records)?;
    let record_len = u64::from(h.point_data_record_length);
    let points_end = if compressed {
        None
    } else {
        let end = points
            .checked_mul(record_len)
            .and_then(|b| b.checked_add(offset))
            .filter(|&e| e <= len);
        Some(end.ok_or_else(|| {
            format!(
                "number of point records {points}: {points} records of {record_len} bytes from \
                 byte {offset} run past the end of the file ({len} bytes)"
            )
        })?)
    };
    let mut n_evlrs = 0;
    if minor >= 4 {
        let mut raw = [0u8; 4];
        read_at(r, NUMBER_OF_EVLRS_AT as u64, &mut raw).map_err(|e| io("number of EVLRs", e))?;
        n_evlrs = u32::from_le_bytes(raw);
        let start = h.evlr.map_or(0, |e| e.start_of_first_evlr);
        if n_evlrs > 0 {
            if start == 0 {
                return Err(format!(
                    "number of EVLRs {n_evlrs}: the start of the first EVLR is 0"
                ));
            }
            let floor = points_end.unwrap_or(offset);
            if start < floor {
                return Err(format!(
                    "start of first EVLR {start}: inside the point data (which ends at byte {floor})"
                ));
            }
            read_evlrs(r, start, n_evlrs, len, &mut crs_records)?;
        }
    }
    Ok(LasLayout {
        version: (major, minor),
        point_format,
        compressed,
        global_encoding: h.global_encoding,
        points,
        bounds: [h.min_x, h.min_y, h.min_z, h.max_x, h.max_y, h.max_z],
        vlrs: n_vlrs,
        evlrs: n_evlrs,
        crs_records,
    })
}

/// Walk the VLR table of `n_vlrs` records from byte `header_size` (`(header_size, offset, len)`:
/// it must end by the point data's `offset` and the file's `len`), keeping its CRS records.
fn read_vlrs<R: Read + Seek>(
    r: &mut R,
    (header_size, offset, len): (u64, u64, u64),
    n_vlrs: u32,
    crs_records: &mut Vec<CrsRecord>,
) -> Result<(), String> {
    let io = |what: &str, e: std::io::Error| format!("{what}: {e}");
    let mut at = header_size;
    for i in 0..n_vlrs {
        let mut vh = [0u8; VLR_HEADER as usize];
        let end = at + VLR_HEADER;
        if end > len {
            return Err(format!(
                "number of VLRs {n_vlrs}: VLR {} of them at byte {at} runs past the end of the \
                 file ({len} bytes)",
                i + 1
            ));
        }
        read_at(r, at, &mut vh).map_err(|e| io("VLR table", e))?;
        let rec_len = u64::from(u16::from_le_bytes([vh[20], vh[21]]));
        let end = end + rec_len;
        if end > len {
            return Err(format!(
                "VLR {} of {n_vlrs} (at byte {at}, {rec_len} bytes of data): runs past the end of \
                 the file ({len} bytes)",
                i + 1
            ));
        }
        if end > offset {
            return Err(format!(
                "VLR {} of {n_vlrs} (at byte {at}, {rec_len} bytes of data): runs past the offset \
                 to point data {offset}",
                i + 1
            ));
        }
        keep_crs(
            r,
            &vh[2..18],
            u16::from_le_bytes([vh[18], vh[19]]),
            at + VLR_HEADER,
            rec_len,
            false,
            crs_records,
        )?;
        at = end;
    }
    Ok(())
}

/// Walk the EVLR table of `n_evlrs` records from byte `start` of a file of `len` bytes, keeping
/// its CRS records.
fn read_evlrs<R: Read + Seek>(
    r: &mut R,
    start: u64,
    n_evlrs: u32,
    len: u64,
    crs_records: &mut Vec<CrsRecord>,
) -> Result<(), String> {
    let io = |what: &str, e: std::io::Error| format!("{what}: {e}");
    let mut at = start;
    for i in 0..n_evlrs {
        let mut eh = [0u8; EVLR_HEADER as usize];
        if at + EVLR_HEADER > len {
            return Err(format!(
                "number of EVLRs {n_evlrs}: EVLR {} of them at byte {at} runs past the end \
                 of the file ({len} bytes)",
                i + 1
            ));
        }
        read_at(r, at, &mut eh).map_err(|e| io("EVLR table", e))?;
        let rec_len = u64::from_le_bytes(eh[20..28].try_into().unwrap_or([0xff; 8]));
        let end = (at + EVLR_HEADER)
            .checked_add(rec_len)
            .filter(|&e| e <= len)
            .ok_or_else(|| {
                format!(
                    "EVLR {} of {n_evlrs} (at byte {at}, {rec_len} bytes of data): runs past \
                     the end of the file ({len} bytes)",
                    i + 1
                )
            })?;
        keep_crs(
            r,
            &eh[2..18],
            u16::from_le_bytes([eh[18], eh[19]]),
            at + EVLR_HEADER,
            rec_len,
            true,
            crs_records,
        )?;
        at = end;
    }
    Ok(())
}

/// Keep the record at `data_at` if it is a CRS record (its length already checked).
fn keep_crs<R: Read + Seek>(
    r: &mut R,
    user: &[u8],
    record_id: u16,
    data_at: u64,
    rec_len: u64,
    extended: bool,
    out: &mut Vec<CrsRecord>,
) -> Result<(), String> {
    let user = String::from_utf8_lossy(user);
    let is_crs = user.trim_end_matches('\0') == LASF_PROJECTION
        && matches!(record_id, 34735..=34737 | WKT_RECORD);
    if !is_crs {
        return Ok(());
    }
    let table = if extended { "EVLR" } else { "VLR" };
    if rec_len > MAX_CRS_RECORD {
        return Err(format!(
            "{table} {LASF_PROJECTION} {record_id}: {rec_len} bytes, too long for a CRS record"
        ));
    }
    let mut data = vec![0u8; rec_len as usize];
    read_at(r, data_at, &mut data)
        .map_err(|e| format!("{table} {LASF_PROJECTION} {record_id}: {e}"))?;
    out.push(CrsRecord {
        record_id,
        extended,
        data,
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    /// A minimal uncompressed file: header of `minor`, one VLR, `n` points of format 0.
    fn file(minor: u8, n: u32) -> Vec<u8> {
        let hs = version_header_size(minor) as usize;
        let mut b = vec![0u8; hs];
        b[..4].copy_from_slice(b"LASF");
        b[24] = 1;
        b[25] = minor;
        b[94..96].copy_from_slice(&(hs as u16).to_le_bytes());
        let vlr_len = 54 + 8;
        b[96..100].copy_from_slice(&((hs + vlr_len) as u32).to_le_bytes());
        b[100..104].copy_from_slice(&1u32.to_le_bytes());
        b[104] = 0;
        b[105..107].copy_from_slice(&20u16.to_le_bytes());
        b[107..111].copy_from_slice(&n.to_le_bytes());
        for k in 0..3 {
            b[131 + 8 * k..139 + 8 * k].copy_from_slice(&0.01f64.to_le_bytes());
        }
        let mut vlr = vec![0u8; 54];
        vlr[2..8].copy_from_slice(b"custom");
        vlr[20..22].copy_from_slice(&8u16.to_le_bytes());
        b.extend_from_slice(&vlr);
        b.extend_from_slice(&[7u8; 8]);
        b.extend(std::iter::repeat_n(0u8, 20 * n as usize));
        b
    }

    fn layout(b: &[u8]) -> Result<LasLayout, String> {
        read_layout(&mut Cursor::new(b), b.len() as u64)
    }

    #[test]
    fn each_version_reads_only_its_own_fields() {
        for minor in 0..=4 {
            let mut b = file(minor, 3);
            if minor < 4 {
                // Bytes a 1.4 reader would take for the EVLR fields are the VLR's: huge here.
                let at = 235.min(b.len() - 12);
                b[at..at + 12].fill(0xff);
                b[version_header_size(minor) as usize + 20] = 8;
            }
            let l = layout(&b).unwrap_or_else(|e| panic!("1.{minor}: {e}"));
            assert_eq!(
                (l.version, l.points, l.vlrs, l.evlrs),
                ((1, minor), 3, 1, 0)
            );
        }
    }

    #[test]
    fn corrupt_tables_name_their_field() {
        let b = file(2, 3);
        let e = layout(&b[..100]).unwrap_err();
        assert!(e.starts_with("header: truncated"), "{e}");
        // A VLR table running past the end of the file.
        let mut v = b.clone();
        v[100..104].copy_from_slice(&5u32.to_le_bytes());
        let e = layout(&v[..300]).unwrap_err();
        assert!(e.starts_with("number of VLRs 5"), "{e}");
        let mut v = b.clone();
        v[227 + 20..227 + 22].copy_from_slice(&60000u16.to_le_bytes());
        let e = layout(&v).unwrap_err();
        assert!(e.starts_with("VLR 1 of 1"), "{e}");
        // Point records past the end.
        let e = layout(&b[..b.len() - 1]).unwrap_err();
        assert!(e.starts_with("number of point records 3"), "{e}");
        // An EVLR count with no EVLRs.
        let mut v = file(4, 3);
        let end = v.len() as u64;
        v[235..243].copy_from_slice(&end.to_le_bytes());
        v[243..247].copy_from_slice(&2u32.to_le_bytes());
        let e = layout(&v).unwrap_err();
        assert!(e.starts_with("number of EVLRs 2: EVLR 1"), "{e}");
        v[235..243].fill(0);
        let e = layout(&v).unwrap_err();
        assert!(e.starts_with("number of EVLRs 2: the start"), "{e}");
        // An EVLR whose length runs past the end, even by 2^63.
        let mut v = file(4, 3);
        let end = v.len() as u64;
        v[235..243].copy_from_slice(&end.to_le_bytes());
        v[243..247].copy_from_slice(&1u32.to_le_bytes());
        let mut e = vec![0u8; 60];
        e[20..28].copy_from_slice(&(1u64 << 63).to_le_bytes());
        v.extend_from_slice(&e);
        let err = layout(&v).unwrap_err();
        assert!(err.starts_with("EVLR 1 of 1"), "{err}");
    }
}
