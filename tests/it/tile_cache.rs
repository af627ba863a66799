//! Tile cache robustness: every bad input gives an `Error::Input` whose one line names the file
//! and the problem — never a panic. Plus `find_tile` selection and atomic replacement.

use infraloc::geo::{map_to_wgs84, wgs84_to_map};
use infraloc::map::cache::{find_tile, load_tile, read_manifest, write_tile};
use infraloc::map::{geotiff, Crs, GeoGrid, Raster, Tile};
use std::path::Path;

fn tile(id: &str, crs: Crs, x0: f64, y0: f64, n: usize) -> Tile {
    let grid = GeoGrid {
        crs,
        x0,
        y0,
        res: 0.5,
        width: n,
        height: n,
    };
    Tile {
        id: id.into(),
        satellite: Some(Raster::filled(
            GeoGrid {
                res: 0.25,
                width: 2 * n,
                height: 2 * n,
                ..grid
            },
            [9, 8, 7],
            None,
        )),
        reflectivity: Raster {
            grid,
            data: (0..grid.len()).map(|i| (i % 200) as u8 + 1).collect(),
            nodata: Some(0),
        },
        height: Raster::filled(grid, 12.5f32, None),
        control_points: vec![],
    }
}

fn err_of<T: std::fmt::Debug>(r: infraloc::Result<T>) -> String {
    let e = r.unwrap_err();
    let s = e.to_string();
    assert!(!s.contains('\n'), "multi-line error: {s}");
    s
}

fn written(dir: &Path) -> std::path::PathBuf {
    write_tile(
        dir,
        &tile("t1", Crs::Epsg(32617), 500_000.0, 4_400_000.0, 32),
    )
    .unwrap();
    dir.join("t1")
}

#[test]
fn truncated_or_corrupt_tiff_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let td = written(dir.path());
    let full = std::fs::read(td.join("height.tif")).unwrap();
    let p = dir.path().join("cut.tif");
    // Every truncation length in steps, and a few corrupted bytes: Err (or, for corruption that
    // happens to hit pixel data, Ok) — never a panic.
    for len in (0..full.len()).step_by(37).chain([full.len() - 1]) {
        std::fs::write(&p, &full[..len]).unwrap();
        let e = err_of(geotiff::read_f32(&p));
        assert!(e.starts_with(&format!("{}: ", p.display())), "{e}");
    }
    for pos in (0..full.len().min(600)).step_by(3) {
        let mut bad = full.clone();
        bad[pos] ^= 0xA5;
        std::fs::write(&p, &bad).unwrap();
        if let Err(e) = geotiff::read_f32(&p) {
            assert!(e.to_string().contains("cut.tif"), "{e}");
        }
    }
    // A truncated layer inside a tile: load_tile names that layer.
    std::fs::write(td.join("reflectivity.tif"), &full[..full.len() / 2]).unwrap();
    let e = err_of(load_tile(&td));
    assert!(
        e.contains("reflectivity.tif") && e.contains("truncated or corrupt"),
        "{e}"
    );
}

#[test]
fn wrong_sample_type_and_missing_georeference() {
    let dir = tempfile::tempdir().unwrap();
    let td = written(dir.path());
    // height.tif where a u8 is expected.
    std::fs::copy(td.join("height.tif"), td.join("reflectivity.tif")).unwrap();
    let e = err_of(load_tile(&td));
    assert!(
        e.contains("reflectivity.tif: sample type is f32, expected u8 gray"),
        "{e}"
    );
    // A plain TIFF without geotags.
    let p = dir.path().join("plain.tif");
    let f = std::fs::File::create(&p).unwrap();
    tiff::encoder::TiffEncoder::new(f)
        .unwrap()
        .write_image::<tiff::encoder::colortype::Gray8>(4, 4, &[0u8; 16])
        .unwrap();
    let e = err_of(geotiff::read_gray8(&p));
    assert!(e.contains("plain.tif: no georeference"), "{e}");
    // 16-bit gray is not a supported sample type.
    let p = dir.path().join("u16.tif");
    let f = std::fs::File::create(&p).unwrap();
    tiff::encoder::TiffEncoder::new(f)
        .unwrap()
        .write_image::<tiff::encoder::colortype::Gray16>(4, 4, &[0u16; 16])
        .unwrap();
    let e = err_of(geotiff::read_image(&p));
    assert!(e.contains("u16.tif: unsupported sample type"), "{e}");
}

/// Write a u8 GeoTIFF georeferenced by ModelTransformation (and arbitrary GeoKeys).
fn write_with_transformation(p: &Path, m: [f64; 16], keys: &[u16]) {
    use tiff::encoder::{colortype::Gray8, TiffEncoder};
    use tiff::tags::Tag;
    let f = std::fs::File::create(p).unwrap();
    let mut enc = TiffEncoder::new(f).unwrap();
    let mut img = enc.new_image::<Gray8>(3, 2).unwrap();
    img.encoder()
        .write_tag(Tag::ModelTransformationTag, &m[..])
        .unwrap();
    img.encoder()
        .write_tag(Tag::GeoKeyDirectoryTag, keys)
        .unwrap();
    img.write_data(&[1, 2, 3, 4, 5, 6]).unwrap();
}

#[test]
fn model_transformation_north_up_only_and_crs_keys() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("mt.tif");
    let utm = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32717];
    #[rustfmt::skip]
    let north_up = [0.5, 0.0, 0.0, 300_000.0, 0.0, -0.5, 0.0, 7_000_000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    write_with_transformation(&p, north_up, &utm);
    let r = geotiff::read_gray8(&p).unwrap();
    assert_eq!(
        r.grid,
        GeoGrid {
            crs: Crs::Epsg(32717),
            x0: 300_000.0,
            y0: 7_000_000.0,
            res: 0.5,
            width: 3,
            height: 2
        }
    );
    let mut rotated = north_up;
    rotated[1] = 0.1;
    write_with_transformation(&p, rotated, &utm);
    let e = err_of(geotiff::read_gray8(&p));
    assert!(e.contains("mt.tif") && e.contains("north-up"), "{e}");
    // Geographic (EPSG:4326) and user-defined projected CRSs are refused by name.
    let geographic = [1, 1, 0, 2, 1024, 0, 1, 2, 2048, 0, 1, 4326];
    write_with_transformation(&p, north_up, &geographic);
    let e = err_of(geotiff::read_gray8(&p));
    assert!(
        e.contains("mt.tif") && e.contains("EPSG:4326") && e.contains("geographic CRS"),
        "{e}"
    );
    let user = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32767];
    write_with_transformation(&p, north_up, &user);
    let e = err_of(geotiff::read_gray8(&p));
    assert!(e.contains("mt.tif") && e.contains("user-defined"), "{e}");
    let merc = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 3857];
    write_with_transformation(&p, north_up, &merc);
    let e = err_of(geotiff::read_gray8(&p));
    assert!(e.contains("mt.tif: EPSG:3857 is Web Mercator"), "{e}");
}

#[test]
fn grids_that_disagree() {
    let dir = tempfile::tempdir().unwrap();
    let td = written(dir.path());
    // Replace height.tif with one shifted by a pixel: both the manifest check and the shared-grid
    // check name height.tif.
    let mut h = load_tile(&td).unwrap().height;
    h.grid.x0 += 0.5;
    geotiff::write_f32(&td.join("height.tif"), &h).unwrap();
    let e = err_of(load_tile(&td));
    assert!(
        e.contains("height.tif") && e.contains("differs from tile.toml"),
        "{e}"
    );
    // write_tile refuses a tile whose LiDAR grids differ.
    let mut t = tile("t2", Crs::Epsg(32617), 0.0, 0.0, 8);
    t.height.grid.width = 9;
    t.height.data.resize(72, 0.0);
    let e = err_of(write_tile(dir.path(), &t));
    assert!(
        e.contains("t2") && e.contains("reflectivity grid") && e.contains("differ"),
        "{e}"
    );
    assert!(!dir.path().join("t2").exists());
}

#[test]
fn missing_layer_manifest_and_bad_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let td = written(dir.path());
    std::fs::remove_file(td.join("satellite.tif")).unwrap();
    let e = err_of(load_tile(&td));
    assert!(e.contains("satellite.tif: missing layer satellite"), "{e}");

    let td = written(dir.path());
    let m = std::fs::read_to_string(td.join("tile.toml")).unwrap();
    std::fs::write(
        td.join("tile.toml"),
        m.replace("crs = \"EPSG:32617\"", "crs = \"EPSG:3857\""),
    )
    .unwrap();
    let e = err_of(load_tile(&td));
    assert!(
        e.contains("tile.toml: crs: EPSG:3857 is Web Mercator"),
        "{e}"
    );

    std::fs::write(td.join("tile.toml"), format!("{m}\nbogus-key = 1\n")).unwrap();
    let e = err_of(load_tile(&td));
    assert!(
        e.contains("tile.toml: line ") && e.contains("bogus-key"),
        "{e}"
    );

    std::fs::remove_file(td.join("tile.toml")).unwrap();
    let e = err_of(load_tile(&td));
    assert!(e.contains("tile.toml: missing tile manifest"), "{e}");
    let e = err_of(find_tile(dir.path(), 39.7, -81.0, 0.0));
    assert!(e.contains("tile.toml: missing tile manifest"), "{e}");
}

#[test]
fn find_tile_picks_the_covering_tile_or_names_the_nearest() {
    let dir = tempfile::tempdir().unwrap();
    let crs = Crs::Epsg(32633);
    // Two 16 m tiles (32 px at 0.5 m), 100 m apart, plus one in the southern hemisphere.
    write_tile(dir.path(), &tile("a", crs, 400_000.0, 5_000_000.0, 32)).unwrap();
    write_tile(dir.path(), &tile("b", crs, 400_100.0, 5_000_000.0, 32)).unwrap();
    write_tile(
        dir.path(),
        &tile("s", Crs::Epsg(32733), 400_000.0, 5_000_000.0, 32),
    )
    .unwrap();
    std::fs::create_dir(dir.path().join(".tmp-crashed-1")).unwrap(); // ignored
    let wgs = |x: f64, y: f64| map_to_wgs84(crs, x, y).unwrap();

    let (lat, lon) = wgs(400_108.0, 4_999_992.0);
    let r = find_tile(dir.path(), lat, lon, 5.0).unwrap();
    assert_eq!(r.id, "b");
    assert!((r.position.0 - 400_108.0).abs() < 1e-6 && (r.position.1 - 4_999_992.0).abs() < 1e-6);
    assert_eq!(r.extent, (400_100.0, 4_999_984.0, 400_116.0, 5_000_000.0));

    // Inside "a" but within 5 m of its edge: margin not met, the error says how deep it is.
    let (lat, lon) = wgs(400_002.0, 4_999_992.0);
    let e = err_of(find_tile(dir.path(), lat, lon, 5.0));
    assert!(
        e.contains("nearest tile \"a\"") && e.contains("only 2.0 m inside"),
        "{e}"
    );
    // Between the tiles: 34 m east of "a", 50 m west of "b".
    let (lat, lon) = wgs(400_050.0, 4_999_990.0);
    let e = err_of(find_tile(dir.path(), lat, lon, 1.0));
    assert!(
        e.starts_with(&format!("tile: {}: no tile covers", dir.path().display())),
        "{e}"
    );
    assert!(e.contains("nearest tile \"a\" is 34.0 m away"), "{e}");
    // Far away: the nearest is "b" (east of "a"), distance in metres of the tile's CRS to its
    // south-east corner.
    let (x, y) = wgs84_to_map(crs, 45.0, 15.5).unwrap();
    let e = err_of(find_tile(dir.path(), 45.0, 15.5, 1.0));
    assert!(
        x > 400_116.0 && y < 4_999_984.0,
        "15.5E 45N is south-east of tile b"
    );
    let want = ((x - 400_116.0).powi(2) + (y - 4_999_984.0).powi(2)).sqrt();
    assert!(
        e.contains(&format!("nearest tile \"b\" is {want:.1} m away")),
        "{e} (want {want:.1})"
    );
    // The other side of the world: no meaningless transverse-Mercator distance, but the
    // great-circle one, to the nearer tile "b". pyproj.Geod(ellps="WGS84").inv from b's centre
    // (45.146336°N, 13.729342°E) to 45°N 100°E: 6 438 647.3 m; the sphere is within 0.5 %.
    let e = err_of(find_tile(dir.path(), 45.0, 100.0, 1.0));
    let metres: f64 = e
        .split("nearest tile \"b\" is ")
        .nth(1)
        .and_then(|r| r.split(" m away").next())
        .unwrap_or_else(|| panic!("{e}"))
        .parse()
        .unwrap();
    assert!((metres / 6_438_647.3 - 1.0).abs() < 5e-3, "{e}");
    // An empty cache says so.
    let empty = tempfile::tempdir().unwrap();
    let e = err_of(find_tile(empty.path(), 45.0, 15.5, 1.0));
    let want = format!("tile: {}: no tiles in the cache", empty.path().display());
    assert!(e.starts_with(&want), "{e}");
    // So does a cache directory that is not there, naming the stage like the others.
    let gone = empty.path().join("gone");
    let e = err_of(find_tile(&gone, 45.0, 15.5, 1.0));
    assert!(e.starts_with(&format!("tile: {}: ", gone.display())), "{e}");
}

#[test]
fn rewrite_replaces_atomically_and_manifest_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = tile("r", Crs::Epsg(32610), 550_000.0, 4_100_000.0, 16);
    write_tile(dir.path(), &t).unwrap();
    let m1 = read_manifest(&dir.path().join("r")).unwrap();
    let text1 = std::fs::read_to_string(dir.path().join("r/tile.toml")).unwrap();
    write_tile(dir.path(), &t).unwrap();
    let text2 = std::fs::read_to_string(dir.path().join("r/tile.toml")).unwrap();
    assert_eq!(text1, text2);
    t.reflectivity.data[0] = 77;
    write_tile(dir.path(), &t).unwrap();
    assert_eq!(
        load_tile(&dir.path().join("r")).unwrap().reflectivity.data[0],
        77
    );
    assert_eq!(m1.layers.reflectivity.nodata, Some(0.0));
    assert!(m1.layers.height.nodata.unwrap().is_nan());
    // Only the tile remains: no temporaries.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(names, ["r"]);
}
