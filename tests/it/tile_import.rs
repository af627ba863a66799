//! `infraloc tile import` end to end, through the real binary: from PNG + world files (GDAL reads
//! the same PNG + .pgw and must report the same corners as our imported tile) and from GeoTIFFs
//! written by GDAL. Plus the import's error paths, each naming the file and the problem.

use image::{GrayImage, RgbImage};
use infraloc::map::cache::{find_tile, load_tile};
use infraloc::map::Crs;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const CORNER_TOL_M: f64 = 1e-6;

fn infraloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(args)
        .output()
        .unwrap()
}

fn gdal_geotransform(path: &Path) -> Vec<f64> {
    let out = Command::new("gdalinfo")
        .arg("-json")
        .arg(path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    v["geoTransform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn gdal_translate(args: &[&str], src: &Path, dst: &Path) {
    let out = Command::new("gdal_translate")
        .arg("-q")
        .args(args)
        .arg(src)
        .arg(dst)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

struct Inputs {
    sat: PathBuf,
    refl: PathBuf,
    height_tif: PathBuf,
    cps: PathBuf,
}

/// PNGs with world files; the height is a plain f32 TIFF (no geotags) with a .tfw.
fn make_inputs(dir: &Path) -> Inputs {
    let sat = dir.join("sat.png");
    RgbImage::from_fn(40, 30, |x, y| image::Rgb([x as u8 * 6, y as u8 * 8, 77]))
        .save(&sat)
        .unwrap();
    // Satellite at 0.1 m, upper-left pixel centre (500 100.05, 4 400 199.95).
    std::fs::write(
        dir.join("sat.pgw"),
        "0.1\n0\n0\n-0.1\n500100.05\n4400199.95\n",
    )
    .unwrap();
    let refl = dir.join("refl.png");
    GrayImage::from_fn(20, 15, |x, y| image::Luma([(x * 10 + y) as u8]))
        .save(&refl)
        .unwrap();
    let world = "0.2\n0.0\n0.0\n-0.2\n500100.1\n4400199.9\n";
    std::fs::write(dir.join("refl.pgw"), world).unwrap();
    let height_tif = dir.join("height.tif");
    {
        let f = std::fs::File::create(&height_tif).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(f).unwrap();
        let data: Vec<f32> = (0..300).map(|i| 100.0 + i as f32 * 0.25).collect();
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(20, 15, &data)
            .unwrap();
    }
    std::fs::write(dir.join("height.tfw"), world).unwrap();
    let cps = dir.join("cps.csv");
    std::fs::write(
        &cps,
        "id,x,y,z\nA,500101.0,4400198.0,101.5\nB,500102.5,4400197.25,101.0\n",
    )
    .unwrap();
    Inputs {
        sat,
        refl,
        height_tif,
        cps,
    }
}

#[test]
fn import_png_with_world_files_matches_gdal() {
    let dir = tempfile::tempdir().unwrap();
    let i = make_inputs(dir.path());
    let cache = dir.path().join("cache");
    let out = infraloc(&[
        "tile",
        "import",
        "--out",
        cache.to_str().unwrap(),
        "--id",
        "site-1",
        "--crs",
        "EPSG:32617",
        "--satellite",
        i.sat.to_str().unwrap(),
        "--reflectivity",
        i.refl.to_str().unwrap(),
        "--height",
        i.height_tif.to_str().unwrap(),
        "--height-world",
        dir.path().join("height.tfw").to_str().unwrap(),
        "--control-points",
        i.cps.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let td = cache.join("site-1");
    let t = load_tile(&td).unwrap();
    let sat = t.satellite.as_ref().unwrap();
    assert_eq!(sat.grid.crs, Crs::Epsg(32617));
    // GDAL reading the source PNG + world file and GDAL reading our tile agree on the corners.
    for (src, layer) in [(&i.sat, "satellite.tif"), (&i.refl, "reflectivity.tif")] {
        let a = gdal_geotransform(src);
        let b = gdal_geotransform(&td.join(layer));
        for k in 0..6 {
            assert!(
                (a[k] - b[k]).abs() <= CORNER_TOL_M,
                "{layer}: {a:?} vs {b:?}"
            );
        }
    }
    assert_eq!(
        (t.reflectivity.grid.x0, t.reflectivity.grid.y0),
        (500_100.0, 4_400_200.0)
    );
    assert_eq!(t.height.data[299], 100.0 + 299.0 * 0.25);
    assert_eq!(t.reflectivity.data[21], 11); // (x=1, y=1)
    assert_eq!(sat.data[41], [6, 8, 77]);
    assert_eq!(t.control_points.len(), 2);
    // The manifest records where the data came from.
    let manifest = std::fs::read_to_string(td.join("tile.toml")).unwrap();
    assert!(
        manifest.contains("sat.png + world file ") && manifest.contains("sat.pgw"),
        "{manifest}"
    );
    // And the tile is found from a WGS84 position inside it.
    let (lat, lon) = infraloc::geo::map_to_wgs84(Crs::Epsg(32617), 500_102.0, 4_400_198.5).unwrap();
    assert_eq!(find_tile(&cache, lat, lon, 0.5).unwrap().id, "site-1");
}

#[test]
fn import_geotiffs_written_by_gdal() {
    let dir = tempfile::tempdir().unwrap();
    let i = make_inputs(dir.path());
    let sat = dir.path().join("sat_g.tif");
    let refl = dir.path().join("refl_g.tif");
    let height = dir.path().join("height_g.tif");
    gdal_translate(
        &["-a_srs", "EPSG:32617", "-co", "COMPRESS=LZW"],
        &i.sat,
        &sat,
    );
    gdal_translate(
        &["-a_srs", "EPSG:32617", "-a_nodata", "255"],
        &i.refl,
        &refl,
    );
    gdal_translate(
        &[
            "-a_srs",
            "EPSG:32617",
            "-ot",
            "Float32",
            "-a_nodata",
            "-9999",
        ],
        &i.refl,
        &height,
    );
    let cache = dir.path().join("cache");
    let args = |crs: &str, id: &str| -> Output {
        infraloc(&[
            "tile",
            "import",
            "--out",
            cache.to_str().unwrap(),
            "--id",
            id,
            "--crs",
            crs,
            "--satellite",
            sat.to_str().unwrap(),
            "--reflectivity",
            refl.to_str().unwrap(),
            "--height",
            height.to_str().unwrap(),
        ])
    };
    let out = args("EPSG:32617", "g");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let t = load_tile(&cache.join("g")).unwrap();
    let g = gdal_geotransform(&refl);
    assert!((t.reflectivity.grid.x0 - g[0]).abs() <= CORNER_TOL_M);
    assert!((t.reflectivity.grid.y0 - g[3]).abs() <= CORNER_TOL_M);
    assert_eq!(t.reflectivity.nodata, Some(255));
    assert_eq!(t.height.nodata, Some(-9999.0));
    assert_eq!(t.height.data[21], 11.0);

    // --crs must agree with the GeoTIFF's own EPSG code.
    let out = args("EPSG:32618", "bad");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("sat_g.tif")
            && err.contains("EPSG:32617")
            && err.contains("--crs is EPSG:32618"),
        "{err}"
    );
    assert!(!cache.join("bad").exists());
    // A CRS whose metres are not metres on the command line.
    let out = args("EPSG:3857", "bad");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("EPSG:3857 is Web Mercator"), "{err}");
}

#[test]
fn import_errors_name_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let i = make_inputs(dir.path());
    let cache = dir.path().join("cache");
    let run = |refl: &Path, height: &Path, height_world: Option<&Path>| -> String {
        let mut a: Vec<String> = [
            "tile",
            "import",
            "--out",
            cache.to_str().unwrap(),
            "--id",
            "x",
            "--crs",
            "EPSG:32617",
            "--satellite",
            i.sat.to_str().unwrap(),
            "--reflectivity",
            refl.to_str().unwrap(),
            "--height",
            height.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        if let Some(w) = height_world {
            a.extend(["--height-world".to_string(), w.display().to_string()]);
        }
        let refs: Vec<&str> = a.iter().map(String::as_str).collect();
        let out = infraloc(&refs);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).trim().to_string()
    };
    // No world file for the height TIFF (none given, none beside it).
    let alone = dir.path().join("alone.tif");
    std::fs::copy(&i.height_tif, &alone).unwrap();
    let e = run(&i.refl, &alone, None);
    assert!(
        e.contains("alone.tif") && e.contains("no georeference"),
        "{e}"
    );
    // Grids that disagree: height world file shifted by one pixel.
    let shifted = dir.path().join("shifted.tfw");
    std::fs::write(&shifted, "0.2\n0\n0\n-0.2\n500100.3\n4400199.9\n").unwrap();
    let e = run(&i.refl, &i.height_tif, Some(&shifted));
    assert!(
        e.contains("height.tif") && e.contains("differs from reflectivity grid"),
        "{e}"
    );
    // Rotated world file.
    let rotated = dir.path().join("rot.tfw");
    std::fs::write(&rotated, "0.2\n0.01\n0\n-0.2\n500100.1\n4400199.9\n").unwrap();
    let e = run(&i.refl, &i.height_tif, Some(&rotated));
    assert!(e.contains("rot.tfw") && e.contains("rotation terms"), "{e}");
    // A 16-bit PNG reflectivity.
    let p16 = dir.path().join("r16.png");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(20, 15, image::Luma([1000]))
        .save(&p16)
        .unwrap();
    std::fs::copy(dir.path().join("refl.pgw"), dir.path().join("r16.pgw")).unwrap();
    let e = run(&p16, &i.height_tif, Some(&dir.path().join("height.tfw")));
    assert!(
        e.contains("r16.png") && e.contains("unsupported pixel type"),
        "{e}"
    );
    assert!(!cache.join("x").exists());
}
