//! `tile build` on other writers' survey files (`../shared/data/survey`, its README describes
//! each): every file builds over its own extent, with `--crs` only where it carries none, or is
//! refused in one line naming the file and a real cause, with nothing written. The tiles that
//! build are compared with `tests/reference/survey_reference.py` (laspy + pyproj + numpy):
//! every point read, the extent where pyproj puts the points (to 1 mm), reflectivity equal and
//! heights to f32 rounding in every cell, and GDAL reads each tile in the expected EPSG CRS in
//! metres. The feet files (two State Planes in US survey feet, a statewide Lambert in
//! international feet, a metre code with a feet unit key) must come out in the metre CRS of the
//! same projection and datum.
//!
//! Files without RGB get a uniform orthophoto (gdal_create) so that their LiDAR layers are
//! tested whether or not a LiDAR-only tile is possible.
//!
//! Needs the survey directory, python3 with laspy[lazrs], pyproj and numpy, and gdal-bin.

use super::tile_build::assert_refused;
use crate::common::{infraloc, s, shared_data};
use infraloc::map::cache::load_tile;
use infraloc::map::Crs;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;

/// US survey foot, metres.
const FT_US: f64 = 1200.0 / 3937.0;
/// International foot, metres.
const FT: f64 = 0.3048;

/// A corpus file that must build.
struct Builds {
    file: &'static str,
    /// `--crs` for a file without one.
    crs: Option<&'static str>,
    /// The CRS of its coordinates as pyproj takes it.
    src: &'static str,
    /// The tile's EPSG code.
    tile: u32,
    /// Metres per vertical unit.
    z: f64,
    /// `--res` and `--ground-cell`: coarser for the kilometre-wide files.
    res: f64,
    /// Whether its points carry RGB.
    rgb: bool,
    /// What stderr must also say (a note, a warning).
    says: &'static str,
}

const BUILDS: [Builds; 9] = [
    // LAS 1.0, point format 0, TerraScan: EPSG:32128 (metres) with a US-feet unit key.
    Builds {
        file: "test.laz",
        crs: None,
        src: "EPSG:2271",
        tile: 32128,
        z: FT_US,
        res: 0.1,
        rgb: false,
        says: "US survey foot",
    },
    // LAS 1.0, point format 1, no CRS record, no ground class (the filter).
    Builds {
        file: "TO_core_last_zoom.laz",
        crs: Some("EPSG:26917"),
        src: "EPSG:26917",
        tile: 26917,
        z: 1.0,
        res: 0.1,
        rgb: false,
        says: "",
    },
    // LAS 1.1, lasclip, Latin-1 bytes in its GeoAsciiParams.
    Builds {
        file: "32-1-472-150-76.laz",
        crs: None,
        src: "EPSG:25832",
        tile: 25832,
        z: 1.0,
        res: 0.1,
        rgb: false,
        says: "",
    },
    // LAS 1.2, lassort, no CRS record: Swiss LV03; a header whose minimum z is 41 m too high.
    Builds {
        file: "zurich.laz",
        crs: Some("EPSG:21781"),
        src: "EPSG:21781",
        tile: 21781,
        z: 1.0,
        res: 0.1,
        rgb: false,
        says: "",
    },
    // LAS 1.2, point format 2, 1.4 km long.
    Builds {
        file: "point-color.las",
        crs: None,
        src: "EPSG:26910",
        tile: 26910,
        z: 1.0,
        res: 1.0,
        rgb: true,
        says: "",
    },
    // LAS 1.2, State Plane California 5 in US survey feet, heights in feet, no ground class.
    Builds {
        file: "certainty3d-color-utm-feet-navd88.las",
        crs: None,
        src: "EPSG:2229",
        tile: 26945,
        z: FT_US,
        res: 1.0,
        rgb: true,
        says: "EPSG:26945",
    },
    // LAS 1.4, GeoTIFF keys (NAD83 / Nebraska, feet) and an ESRI WKT (NAD83(2011), feet) disagree.
    Builds {
        file: "file_with_both_wkt_and_geotiff_vlrs.las",
        crs: None,
        src: "EPSG:6880",
        tile: 6516,
        z: FT_US,
        res: 0.1,
        rgb: false,
        says: "disagree",
    },
    // LAS 1.4, point format 7, ESRI-style WKT without an EPSG code, international feet.
    Builds {
        file: "autzen_trim_7.las",
        crs: None,
        src: "EPSG:2994",
        tile: 2993,
        z: FT,
        res: 0.1,
        rgb: true,
        says: "EPSG:2993",
    },
    // LAS 1.4, point format 8, LAZ, two extra-bytes VLRs.
    Builds {
        file: "las_with_several_extra_byte_bloc.laz",
        crs: None,
        src: "EPSG:2154",
        tile: 2154,
        z: 1.0,
        res: 0.5,
        rgb: true,
        says: "",
    },
];

/// A corpus file refused for its CRS: extra arguments, and what the one line must say.
const REFUSED: [(&str, &[&str], &str); 3] = [
    // A local frame (negative coordinates, typed as they are): no CRS to give.
    (
        "vegetation_1_3.las",
        &["--bbox", "-98452,-55976,-98447,-55969"],
        "has no CRS",
    ),
    // A geocentric label on UTM coordinates.
    ("lone-star.copc.laz", &[], "the label is wrong"),
    // A SLAM map in a local frame.
    ("map.pcd", &[], "has no CRS"),
];

fn survey(file: &str) -> PathBuf {
    let p = shared_data("survey").join(file);
    assert!(
        p.is_file(),
        "{} missing: set INFRALOC_SHARED_DATA",
        p.display()
    );
    p
}

fn build(out: &Path, file: &Path, args: &[&str]) -> std::process::Output {
    let mut a = vec!["tile", "build", "--out", s(out), "--id", "t"];
    a.extend_from_slice(args);
    a.push(s(file));
    infraloc(&a)
}

/// The code of GDAL's CRS (the last `ID["EPSG",N]` of its WKT2) and its linear unit's name.
fn gdal_crs(tif: &Path) -> (u32, String) {
    let o = Command::new("gdalinfo")
        .args(["-json", s(tif)])
        .output()
        .expect("gdalinfo (gdal-bin) must be installed: see .ci/setup");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let info: Value = serde_json::from_slice(&o.stdout).unwrap();
    let wkt = info["coordinateSystem"]["wkt"]
        .as_str()
        .unwrap()
        .to_string();
    let i = wkt.rfind("ID[\"EPSG\",").unwrap();
    let code = wkt[i + 10..i + 10 + wkt[i + 10..].find(']').unwrap()]
        .parse()
        .unwrap();
    let j = wkt.rfind("LENGTHUNIT[\"").unwrap();
    let unit = wkt[j + 12..j + 12 + wkt[j + 12..].find('"').unwrap()].to_string();
    (code, unit)
}

/// A grey GeoTIFF in EPSG `epsg` with 2 m pixels covering `b` and 1 m beyond it.
fn uniform_orthophoto(path: &Path, epsg: u32, b: [f64; 4]) {
    let (x0, y1) = (b[0].floor() - 1.0, b[3].ceil() + 1.0);
    let (w, h) = (
        ((b[2] + 1.0 - x0) / 2.0).ceil(),
        ((y1 - b[1] + 1.0) / 2.0).ceil(),
    );
    let o = Command::new("gdal_create")
        .args(["-of", "GTiff", "-outsize", &w.to_string(), &h.to_string()])
        .args(["-bands", "3", "-ot", "Byte", "-burn", "128"])
        .args(["-a_srs", &format!("EPSG:{epsg}"), "-a_ullr"])
        .args([x0, y1, x0 + 2.0 * w, y1 - 2.0 * h].map(|v| v.to_string()))
        .arg(path)
        .output()
        .expect("gdal_create (gdal-bin) must be installed: see .ci/setup");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn survey_files_build_or_are_refused_in_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let jobs: Vec<Value> = BUILDS
        .iter()
        .map(|b| {
            json!({"name": b.file, "file": survey(b.file), "src": b.src,
                   "tile": format!("EPSG:{}", b.tile), "z": b.z, "res": b.res,
                   "cell": b.res.max(0.5)})
        })
        .collect();
    let jobs_file = tmp.path().join("jobs.json");
    std::fs::write(&jobs_file, serde_json::to_vec(&jobs).unwrap()).unwrap();
    let refs = tmp.path().join("refs");
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/reference/survey_reference.py"
    );
    let o = Command::new("python3")
        .args([script, s(&jobs_file), s(&refs)])
        .output()
        .expect("python3 with laspy[lazrs], pyproj and numpy is needed: see .ci/setup");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    for b in &BUILDS {
        let meta: Value =
            serde_json::from_slice(&std::fs::read(refs.join(format!("{}.json", b.file))).unwrap())
                .unwrap();
        let out = tmp.path().join(b.file);
        let res = b.res.to_string();
        let cell = b.res.max(0.5).to_string();
        let mut args = vec!["--res", res.as_str(), "--ground-cell", cell.as_str()];
        if let Some(c) = b.crs {
            args.extend_from_slice(&["--crs", c]);
        }
        let ortho = tmp.path().join(format!("{}.tif", b.file));
        if !b.rgb {
            // A uniform orthophoto over the reference's extent.
            let e: Vec<f64> = meta["extent"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            uniform_orthophoto(&ortho, b.tile, [e[0], e[1], e[2], e[3]]);
            args.extend_from_slice(&["--orthophoto", s(&ortho)]);
        }
        let o = build(&out, &survey(b.file), &args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{}: {err}", b.file);
        assert!(
            err.contains(b.says),
            "{}: stderr does not say {:?}: {err}",
            b.file,
            b.says
        );
        let dir = out.join("t");
        let tile = load_tile(&dir).unwrap();
        let g = tile.reflectivity.grid;
        assert_eq!(g.crs, Crs::Epsg(b.tile), "{}", b.file);
        // Every point decoded, as laspy counts them.
        let toml = std::fs::read_to_string(dir.join("tile.toml")).unwrap();
        let n = meta["points"].as_u64().unwrap();
        assert!(
            toml.contains(&format!("of {n} points")),
            "{}: {toml}",
            b.file
        );
        // The extent where pyproj puts the points; a unit conversion is a scale and a shift.
        assert!(
            meta["affine_residual_m"].as_f64().unwrap() < 1e-6,
            "{}: {meta}",
            b.file
        );
        let want = |k: &str| meta[k].as_f64().unwrap();
        assert!(
            (g.x0 - want("x0")).abs() < 1e-3 && (g.y0 - want("y0")).abs() < 1e-3,
            "{}: {g:?} {meta}",
            b.file
        );
        assert_eq!(
            (g.width as u64, g.height as u64),
            (
                meta["width"].as_u64().unwrap(),
                meta["height"].as_u64().unwrap()
            ),
            "{}",
            b.file
        );
        // Rasters cell for cell.
        let refl = std::fs::read(refs.join(format!("{}.u8", b.file))).unwrap();
        let hgt: Vec<f32> = std::fs::read(refs.join(format!("{}.f32", b.file)))
            .unwrap()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let cells = meta["cells"].as_u64().unwrap() as usize;
        assert!(
            cells >= 200,
            "{}: the reference has {cells} ground cells",
            b.file
        );
        let refl_diff = refl
            .iter()
            .zip(&tile.reflectivity.data)
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(
            refl_diff, 0,
            "{}: {refl_diff} of {cells} reflectivity cells differ",
            b.file
        );
        for (i, (r, t)) in hgt.iter().zip(&tile.height.data).enumerate() {
            assert!(
                (r.is_nan() && t.is_nan()) || (r - t).abs() <= f32::EPSILON * r.abs(),
                "{}: height cell {i}: reference {r}, tile {t}",
                b.file
            );
        }
        // GDAL: the tile's CRS, in metres.
        for layer in ["reflectivity.tif", "height.tif"] {
            assert_eq!(
                gdal_crs(&dir.join(layer)),
                (b.tile, "metre".to_string()),
                "{} {layer}",
                b.file
            );
        }
    }

    for (file, args, why) in REFUSED {
        let out = tmp.path().join("refused");
        let o = build(&out, &survey(file), args);
        assert_refused(&o, &out, file, why);
    }
    // The mislabelled file builds when told its CRS, with a warning naming the label it replaced.
    let out = tmp.path().join("lone-star");
    let ortho = tmp.path().join("lone-star.tif");
    uniform_orthophoto(&ortho, 32612, [515368.0, 4918340.0, 515402.0, 4918382.0]);
    let o = build(
        &out,
        &survey("lone-star.copc.laz"),
        &[
            "--crs",
            "EPSG:32612",
            "--override-crs",
            "--orthophoto",
            s(&ortho),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() && err.contains("is replaced by --crs EPSG:32612"),
        "{err}"
    );
}
