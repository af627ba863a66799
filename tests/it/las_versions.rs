//! LAS as each version is written, by another writer: `tests/reference/las_matrix.py` has laspy
//! (+ lazrs) write the same 3000 points as LAS 1.0–1.4 × {GeoTIFF keys, WKT VLR, no CRS} × {LAS,
//! LAZ}, and once in every point format 0–10 (two of them with extra bytes). `tile build` must
//! read every file, count all its points, and make the same rasters from each. Then headers that
//! contradict their file's size: one line naming the file and the field, nothing written.
//!
//! Needs python3 with laspy[lazrs] and numpy, and gdal-bin for the orthophoto (`.ci/setup`).

use super::tile_build::assert_refused;
use crate::common::{infraloc, s};
use infraloc::map::cache::load_tile;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The patch the script writes, EPSG:25832.
const BOX: &str = "691000,5335000,691020,5335020";
/// Points in every file.
const POINTS: usize = 3000;

/// The matrix's files and manifest, written once per test binary.
fn matrix() -> &'static (PathBuf, Vec<Value>) {
    static M: OnceLock<(PathBuf, Vec<Value>)> = OnceLock::new();
    M.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("las-matrix");
        let _ = std::fs::remove_dir_all(&dir);
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/reference/las_matrix.py");
        let out = Command::new("python3")
            .arg(script)
            .arg(&dir)
            .output()
            .expect("python3 with laspy[lazrs] and numpy is needed: see .ci/setup");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let rows: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
        // A uniform orthophoto over the patch: the satellite layer is not what is tested here,
        // and formats 0, 1, 4, 6, 9 carry no colour.
        let ortho = dir.join("ortho.tif");
        let o = Command::new("gdal_create")
            .args([
                "-of", "GTiff", "-outsize", "40", "40", "-bands", "3", "-ot", "Byte",
            ])
            .args(["-burn", "128", "-a_srs", "EPSG:25832", "-a_ullr"])
            .args(["690990", "5335030", "691030", "5334990", s(&ortho)])
            .output()
            .expect("gdal_create (gdal-bin) must be installed: see .ci/setup");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (dir, rows)
    })
}

fn build(out: &Path, id: &str, file: &Path, extra: &[&str]) -> std::process::Output {
    let ortho = matrix().0.join("ortho.tif");
    let mut args = vec!["tile", "build", "--out", s(out), "--id", id, "--bbox", BOX];
    args.extend_from_slice(&["--orthophoto", s(&ortho)]);
    args.extend_from_slice(extra);
    args.push(s(file));
    infraloc(&args)
}

#[test]
fn every_version_format_and_crs_record_reads_to_the_same_rasters() {
    let (dir, rows) = matrix();
    assert_eq!(
        rows.len(),
        30 + 13,
        "the matrix and the 11 formats (2 with extra bytes)"
    );
    let tmp = tempfile::tempdir().unwrap();
    let mut first = None;
    for (i, r) in rows.iter().enumerate() {
        let name = r["file"].as_str().unwrap();
        let crs: &[&str] = if r["crs"] == "none" {
            &["--crs", "EPSG:25832"]
        } else {
            &[]
        };
        let id = format!("t{i}");
        let o = build(tmp.path(), &id, &dir.join(name), crs);
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let tile = load_tile(&tmp.path().join(&id)).unwrap();
        let toml = std::fs::read_to_string(tmp.path().join(&id).join("tile.toml")).unwrap();
        assert!(
            toml.contains(&format!("of {POINTS} points")),
            "{name}: not every point decoded: {toml}"
        );
        let cells = tile.reflectivity.data.iter().filter(|&&v| v > 0).count();
        let layers = (
            tile.reflectivity.data,
            tile.height
                .data
                .iter()
                .map(|h| h.to_bits())
                .collect::<Vec<_>>(),
        );
        match &first {
            None => {
                assert!(
                    cells > 1500,
                    "{name}: only {cells} cells with ground (of 2100 ground points)"
                );
                first = Some((name, layers));
            }
            Some((f, l)) => assert!(*l == layers, "{name}: rasters differ from {f}'s"),
        }
    }
}

/// Little-endian u32 at `at`.
fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

#[test]
fn headers_that_contradict_the_file_size_are_refused_naming_the_field() {
    let (dir, _) = matrix();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cache");
    let las12 = std::fs::read(dir.join("v1.2_pf3_geotiff.las")).unwrap();
    let las14 = std::fs::read(dir.join("v1.4_pf6_wkt.laz")).unwrap();
    let case = |name: &str, bytes: &[u8], field: &str| {
        let p = tmp.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let o = build(&out, "t", &p, &[]);
        assert_refused(&o, &out, name, field);
    };
    // A header cut short (a copy that stopped early).
    case("cut.las", &las12[..150], "header: truncated");
    // A VLR table that runs past the end of the file: more VLRs than there are.
    let mut b = las12.clone();
    put_u32(&mut b, 100, 40_000);
    let offset = u32::from_le_bytes(b[96..100].try_into().unwrap()) as usize;
    case("vlrs.las", &b[..offset], "number of VLRs 40000");
    // An EVLR count with no EVLRs: LAS 1.4 says two, starting at the end of the file.
    let mut b = las14.clone();
    let end = b.len() as u64;
    b[235..243].copy_from_slice(&end.to_le_bytes());
    put_u32(&mut b, 243, 2);
    case("evlrs.laz", &b, "number of EVLRs 2");
    // Point records past the end of the file.
    case(
        "points.las",
        &las12[..las12.len() - 10],
        "number of point records 3000",
    );
}
