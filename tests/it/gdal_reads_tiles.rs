//! GDAL is the independent reference for our GeoTIFFs: write a tile, run `gdalinfo -json` on each
//! layer and check that GDAL sees the EPSG code, the corner coordinates (PixelIsArea), the size,
//! the band type and the nodata value we meant. Then the reverse: files that GDAL writes
//! (PixelIsPoint, LZW, gray satellite) must read back onto the grid GDAL reports.
//!
//! Needs `gdalinfo`/`gdal_translate` (gdal-bin, installed by `.ci/setup`).

use infraloc::map::cache::{load_tile, write_tile};
use infraloc::map::{geotiff, ControlPoint, Crs, GeoGrid, Raster, Tile};
use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// Corner agreement required, metres (checked on GDAL's full-precision geotransform).
const CORNER_TOL_M: f64 = 1e-6;
/// `gdalinfo` prints `cornerCoordinates` of projected rasters rounded to 3 decimals.
const PRINTED_CORNER_TOL_M: f64 = 0.5e-3 + 1e-9;

fn gdalinfo(path: &Path) -> Value {
    let out = Command::new("gdalinfo")
        .arg("-json")
        .arg(path)
        .output()
        .expect("gdalinfo (gdal-bin) must be installed: see .ci/setup");
    assert!(
        out.status.success(),
        "gdalinfo {}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The EPSG code GDAL resolved: the last `ID["EPSG",N]` of the WKT2 (the CRS's own id).
fn epsg_of(info: &Value) -> u32 {
    let wkt = info["coordinateSystem"]["wkt"].as_str().unwrap();
    let i = wkt.rfind("ID[\"EPSG\",").expect("no EPSG id in WKT");
    let rest = &wkt[i + 10..];
    rest[..rest.find(']').unwrap()].parse().unwrap()
}

fn corner(info: &Value, key: &str) -> (f64, f64) {
    let c = &info["cornerCoordinates"][key];
    (c[0].as_f64().unwrap(), c[1].as_f64().unwrap())
}

/// Upper-left and lower-right corners from GDAL's geotransform (full precision), checked against
/// the rounded `cornerCoordinates`; asserts the raster is north-up.
fn gdal_corners(info: &Value) -> ((f64, f64), (f64, f64)) {
    let gt: Vec<f64> = info["geoTransform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!((gt[2], gt[4]), (0.0, 0.0), "not north-up");
    let (w, h) = (
        info["size"][0].as_f64().unwrap(),
        info["size"][1].as_f64().unwrap(),
    );
    let ul = (gt[0], gt[3]);
    let lr = (gt[0] + w * gt[1], gt[3] + h * gt[5]);
    for (key, c) in [("upperLeft", ul), ("lowerRight", lr)] {
        let printed = corner(info, key);
        assert!((printed.0 - c.0).abs() <= PRINTED_CORNER_TOL_M);
        assert!((printed.1 - c.1).abs() <= PRINTED_CORNER_TOL_M);
    }
    (ul, lr)
}

fn check_layer(path: &Path, g: &GeoGrid, bands: usize, band_type: &str, nodata: Option<f64>) {
    let info = gdalinfo(path);
    let Crs::Epsg(code) = g.crs else { panic!() };
    assert_eq!(epsg_of(&info), code, "{}", path.display());
    assert_eq!(info["size"][0].as_u64().unwrap() as usize, g.width);
    assert_eq!(info["size"][1].as_u64().unwrap() as usize, g.height);
    let (xmin, ymin, xmax, ymax) = g.bounds();
    let (ul, lr) = gdal_corners(&info);
    for (got, want) in [(ul.0, xmin), (ul.1, ymax), (lr.0, xmax), (lr.1, ymin)] {
        assert!(
            (got - want).abs() <= CORNER_TOL_M,
            "{}: GDAL corner {got} vs ours {want}",
            path.display()
        );
    }
    assert_eq!(
        info["metadata"][""]["AREA_OR_POINT"].as_str(),
        Some("Area"),
        "{}",
        path.display()
    );
    let b = info["bands"].as_array().unwrap();
    assert_eq!(b.len(), bands, "{}", path.display());
    for band in b {
        assert_eq!(
            band["type"].as_str().unwrap(),
            band_type,
            "{}",
            path.display()
        );
        match nodata {
            None => assert!(band.get("noDataValue").is_none(), "{}", path.display()),
            Some(nd) => {
                // GDAL gives a JSON number, or a string for NaN.
                let v = &band["noDataValue"];
                let got = v
                    .as_f64()
                    .or_else(|| v.as_str().and_then(|s| s.parse().ok()))
                    .unwrap_or_else(|| panic!("{}: noDataValue {v}", path.display()));
                assert!(
                    got == nd || (got.is_nan() && nd.is_nan()),
                    "{}: GDAL nodata {got} vs ours {nd}",
                    path.display()
                );
            }
        }
    }
}

fn tile(id: &str, crs: Crs, x0: f64, y0: f64) -> Tile {
    let sat_grid = GeoGrid {
        crs,
        x0: x0 - 1.05,
        y0: y0 + 0.95,
        res: 0.1,
        width: 64,
        height: 48,
    };
    let grid = GeoGrid {
        crs,
        x0,
        y0,
        res: 0.2,
        width: 21,
        height: 17,
    };
    let sat = Raster {
        grid: sat_grid,
        data: (0..sat_grid.len())
            .map(|i| [(i % 251) as u8, (i / 7 % 256) as u8, 200])
            .collect(),
        nodata: None,
    };
    let mut refl = Raster {
        grid,
        data: (0..grid.len()).map(|i| 1 + (i % 254) as u8).collect(),
        nodata: Some(0),
    };
    refl.data[5] = 0;
    let mut height = Raster {
        grid,
        data: (0..grid.len()).map(|i| 150.0 + i as f32 * 0.01).collect(),
        nodata: None,
    };
    height.data[7] = f32::NAN;
    Tile {
        id: id.into(),
        satellite: Some(sat),
        reflectivity: refl,
        height,
        control_points: vec![ControlPoint {
            id: "cp1".into(),
            xyz: [x0 + 1.0, y0 - 1.0, 150.5],
        }],
    }
}

#[test]
fn gdal_places_every_layer_where_we_say() {
    let dir = tempfile::tempdir().unwrap();
    // Non-round origins in a north and a south zone.
    for (id, crs, x0, y0) in [
        (
            "north",
            Crs::Epsg(32617),
            500_123.456_789,
            4_400_987.654_321,
        ),
        ("south", Crs::Epsg(32756), 334_455.125, 6_250_111.875),
    ] {
        let t = tile(id, crs, x0, y0);
        write_tile(dir.path(), &t).unwrap();
        let td = dir.path().join(id);
        check_layer(
            &td.join("satellite.tif"),
            &t.satellite.as_ref().unwrap().grid,
            3,
            "Byte",
            None,
        );
        check_layer(
            &td.join("reflectivity.tif"),
            &t.reflectivity.grid,
            1,
            "Byte",
            Some(0.0),
        );
        check_layer(
            &td.join("height.tif"),
            &t.height.grid,
            1,
            "Float32",
            Some(f64::NAN),
        );
        // And our own reader agrees with what we wrote.
        let back = load_tile(&td).unwrap();
        assert_eq!(back.satellite, t.satellite);
        assert_eq!(back.reflectivity, t.reflectivity);
        assert_eq!(back.height.grid, t.height.grid);
        assert_eq!(back.control_points, t.control_points);
    }
}

fn gdal_translate(args: &[&str], src: &Path, dst: &Path) {
    let out = Command::new("gdal_translate")
        .args(["-q"])
        .args(args)
        .arg(src)
        .arg(dst)
        .output()
        .expect("gdal_translate (gdal-bin)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn we_read_gdal_written_files_onto_gdals_grid() {
    let dir = tempfile::tempdir().unwrap();
    let t = tile("t", Crs::Epsg(32633), 412_345.678, 5_123_456.789);
    write_tile(dir.path(), &t).unwrap();
    let td = dir.path().join("t");

    // PixelIsPoint + LZW, written by GDAL: the corner GDAL reports must be our x0, y0.
    let pt = dir.path().join("point.tif");
    gdal_translate(
        &["-co", "COMPRESS=LZW", "-mo", "AREA_OR_POINT=Point"],
        &td.join("reflectivity.tif"),
        &pt,
    );
    let info = gdalinfo(&pt);
    assert_eq!(
        info["metadata"][""]["AREA_OR_POINT"].as_str(),
        Some("Point")
    );
    let r = geotiff::read_gray8(&pt).unwrap();
    let (ul, _) = gdal_corners(&info);
    assert!(
        (r.grid.x0 - ul.0).abs() <= CORNER_TOL_M,
        "{} vs {}",
        r.grid.x0,
        ul.0
    );
    assert!(
        (r.grid.y0 - ul.1).abs() <= CORNER_TOL_M,
        "{} vs {}",
        r.grid.y0,
        ul.1
    );
    assert_eq!(r.data, t.reflectivity.data);
    assert_eq!(r.nodata, Some(0));

    // One band of the satellite, as GDAL writes a gray image: reads as RGB with equal bands.
    let gray = dir.path().join("gray.tif");
    gdal_translate(
        &["-b", "2", "-co", "COMPRESS=DEFLATE"],
        &td.join("satellite.tif"),
        &gray,
    );
    let s = geotiff::read_rgb8(&gray).unwrap();
    let sat = t.satellite.as_ref().unwrap();
    assert_eq!(s.grid, sat.grid);
    assert!(s.data.iter().zip(&sat.data).all(|(a, b)| a == &[b[1]; 3]));

    // A GDAL-written f32 with a numeric nodata.
    let f = dir.path().join("h.tif");
    gdal_translate(&["-a_nodata", "-9999"], &td.join("height.tif"), &f);
    let h = geotiff::read_f32(&f).unwrap();
    assert_eq!(h.grid, t.height.grid);
    assert_eq!(h.nodata, Some(-9999.0));

    // Layers in many chunks (decoded in parallel): 16-pixel tiles with partial ones at the right
    // and bottom edges, and short strips; with the predictors GDAL offers.
    let chunked = |name: &str, args: &[&str]| {
        let out = dir.path().join(name);
        gdal_translate(args, &td.join(name), &out);
        out
    };
    // Deflated in 16-pixel tiles with a predictor: 2 (horizontal) for bytes, 3 (floating point).
    let tiled = |name: &str, predictor: &str| {
        let p = format!("PREDICTOR={predictor}");
        let args = [
            "-co",
            "TILED=YES",
            "-co",
            "BLOCKXSIZE=16",
            "-co",
            "BLOCKYSIZE=16",
        ];
        chunked(
            name,
            &[&args[..], &["-co", "COMPRESS=DEFLATE", "-co", &p]].concat(),
        )
    };
    let s = geotiff::read_rgb8(&tiled("satellite.tif", "2")).unwrap();
    assert_eq!(&s, sat);
    let h = geotiff::read_f32(&tiled("height.tif", "3")).unwrap();
    assert_eq!(h.grid, t.height.grid);
    assert!(h
        .data
        .iter()
        .zip(&t.height.data)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    let r = geotiff::read_gray8(&chunked(
        "reflectivity.tif",
        &["-co", "BLOCKYSIZE=4", "-co", "COMPRESS=LZW"],
    ))
    .unwrap();
    assert_eq!(r, t.reflectivity);
    // GDAL wrote what was asked: tiles and strips of those sizes.
    let info = gdalinfo(&dir.path().join("height.tif"));
    assert_eq!(info["bands"][0]["block"], serde_json::json!([16, 16]));
    let info = gdalinfo(&dir.path().join("reflectivity.tif"));
    assert_eq!(info["bands"][0]["block"], serde_json::json!([21, 4]));
}
