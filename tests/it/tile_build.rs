//! `infraloc tile build` end to end, through the real binary, on point clouds written by other
//! projects' writers (laspy + lazrs: LAZ; copclib: COPC; a PCD written to the PCL spec, whole and
//! as an Autoware split map) by `tests/reference/cloud_reference.py`, against that script's numpy
//! rasters: per 0.1 m cell the median of the ground points' normalised intensity and height, from
//! LAS class 2 (LAZ, COPC) or the lowest-surface filter (PCD). GDAL must read the tile in the
//! clouds' CRS. Then the bad inputs, each one line naming the file, nothing written.
//!
//! Needs python3 with laspy[lazrs], copclib, pyproj and numpy, and gdal-bin (`.ci/setup`).

use crate::common::{infraloc, s};
use infraloc::map::cache::load_tile;
use infraloc::map::{Crs, Tile};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The tile box of the reference script, EPSG:25832.
const BOX: &str = "691015,5335015,691045,5335045";

/// The reference clouds and rasters, made once per test binary.
fn refs() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        // Under cargo's per-target scratch space, not /tmp: a static is never dropped, so a
        // temporary directory would outlive every run. Each run starts it afresh.
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("tile-build-refs");
        let _ = std::fs::remove_dir_all(&dir);
        let script = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/reference/cloud_reference.py"
        );
        let out = Command::new("python3")
            .arg(script)
            .arg(&dir)
            .output()
            .expect("python3 with laspy[lazrs], copclib, pyproj, numpy is needed: see .ci/setup");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir
    })
}

struct Reference {
    refl: Vec<u8>,
    height: Vec<f32>,
    meta: Value,
}

fn reference(name: &str) -> Reference {
    let d = refs();
    let refl = std::fs::read(d.join(format!("{name}.u8"))).unwrap();
    let height = std::fs::read(d.join(format!("{name}.f32")))
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let meta =
        serde_json::from_slice(&std::fs::read(d.join(format!("{name}.json"))).unwrap()).unwrap();
    Reference { refl, height, meta }
}

fn build(out: &Path, id: &str, extra: &[&str]) -> Output {
    build_in(out, id, BOX, extra)
}

fn build_in(out: &Path, id: &str, bbox: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "tile",
        "build",
        "--out",
        out.to_str().unwrap(),
        "--id",
        id,
        "--bbox",
        bbox,
    ];

    args.extend_from_slice(extra);
    infraloc(&args)
}

fn built(out: &Path, id: &str, extra: &[&str]) -> Tile {
    let o = build(out, id, extra);
    assert!(
        o.status.success(),
        "tile build {extra:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    load_tile(&out.join(id)).unwrap()
}

/// The tile equals the numpy reference: same grid, reflectivity exactly, height to f32 rounding.
fn assert_matches(tile: &Tile, r: &Reference, what: &str) {
    let g = tile.reflectivity.grid;
    assert_eq!(g.crs, Crs::Epsg(25832), "{what}");
    assert_eq!(
        (g.width, g.height),
        (
            r.meta["width"].as_u64().unwrap() as usize,
            r.meta["height"].as_u64().unwrap() as usize
        ),
        "{what}"
    );
    assert!(
        (g.x0 - r.meta["x0"].as_f64().unwrap()).abs() < 1e-9,
        "{what}"
    );
    assert!(
        (g.y0 - r.meta["y0"].as_f64().unwrap()).abs() < 1e-9,
        "{what}"
    );
    let cells = r.meta["cells"].as_u64().unwrap() as usize;
    assert!(
        cells > g.len() / 2,
        "{what}: the reference has ground ({cells})"
    );
    let mut refl_diff = 0;
    for (i, (a, b)) in tile.reflectivity.data.iter().zip(&r.refl).enumerate() {
        if a != b {
            refl_diff += 1;
            assert!(
                refl_diff < 5,
                "{what}: reflectivity cell {i}: {a} vs numpy {b}"
            );
        }
    }
    assert_eq!(refl_diff, 0, "{what}: reflectivity cells differ");
    for (i, (a, b)) in tile.height.data.iter().zip(&r.height).enumerate() {
        assert!(
            a.is_nan() == b.is_nan() && (a.is_nan() || a == b),
            "{what}: height cell {i}: {a} vs numpy {b}"
        );
    }
}

#[test]
fn laz_copc_and_pcd_match_numpy() {
    let d = refs();
    let out = tempfile::tempdir().unwrap();
    let class = reference("ref_class");
    let laz = built(out.path(), "laz", &[d.join("street.laz").to_str().unwrap()]);
    assert_matches(&laz, &class, "LAZ");
    // The satellite layer from the points' RGB: the highest point's colour per cell.
    let rgb = std::fs::read(d.join("ref_rgb.u8")).unwrap();
    let got: Vec<u8> = laz.satellite.data.iter().flatten().copied().collect();
    assert_eq!(laz.satellite.grid, laz.reflectivity.grid);
    assert!(got == rgb, "satellite RGB differs from numpy");
    let copc = built(
        out.path(),
        "copc",
        &[d.join("street.copc.laz").to_str().unwrap()],
    );
    assert_matches(&copc, &class, "COPC");

    let filt = reference("ref_filter");
    // PCD has no CRS and no RGB: --crs and an orthophoto (the LAZ tile's own satellite layer).
    let ortho = out.path().join("laz/satellite.tif");
    let pcd = built(
        out.path(),
        "pcd",
        &[
            d.join("street.pcd").to_str().unwrap(),
            "--crs",
            "EPSG:25832",
            "--orthophoto",
            ortho.to_str().unwrap(),
        ],
    );
    assert_matches(&pcd, &filt, "PCD");
    // An orthophoto on the tile's own grid is copied unchanged by the bilinear warp.
    assert_eq!(pcd.satellite, laz.satellite);
    let split = built(
        out.path(),
        "split",
        &[
            d.join("split").to_str().unwrap(),
            "--crs",
            "EPSG:25832",
            "--orthophoto",
            ortho.to_str().unwrap(),
        ],
    );
    assert_matches(&split, &filt, "Autoware split map");

    // The filter kept cars, people and the tree out: the height is the road's everywhere.
    let g = pcd.height.grid;
    let mut worst = 0.0f64;
    for row in 0..g.height {
        for col in 0..g.width {
            let z = pcd.height.data[row * g.width + col];
            if z.is_nan() {
                continue;
            }
            let (x, y) = g.pixel_center(col, row);
            let road = 520.0 + 0.02 * (x - 691_000.0) + 0.01 * (y - 5_335_000.0);
            worst = worst.max((f64::from(z) - road).abs());
        }
    }
    // Within the ground tolerance (0.2 m): beside a removed car on the 2 % slope the opened
    // surface is raised by up to the slope times the car's length (docs/map.md).
    assert!(worst < 0.2, "filtered height leaves the road by {worst} m");
}

#[test]
fn gdal_reads_the_built_tile_in_its_crs() {
    let d = refs();
    let out = tempfile::tempdir().unwrap();
    built(out.path(), "g", &[d.join("street.laz").to_str().unwrap()]);
    for layer in ["satellite.tif", "reflectivity.tif", "height.tif"] {
        let o = Command::new("gdalsrsinfo")
            .args(["-o", "epsg"])
            .arg(out.path().join("g").join(layer))
            .output()
            .expect("gdal-bin is needed: see .ci/setup");
        let s = String::from_utf8_lossy(&o.stdout);
        assert!(s.contains("EPSG:25832"), "{layer}: GDAL says {s}");
        let o = Command::new("gdalinfo")
            .arg("-json")
            .arg(out.path().join("g").join(layer))
            .output()
            .unwrap();
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        let gt: Vec<f64> = v["geoTransform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert!(
            (gt[0] - 691_015.0).abs() < 1e-6 && (gt[3] - 5_335_045.0).abs() < 1e-6,
            "{layer}: {gt:?}"
        );
        assert!(
            (gt[1] - 0.1).abs() < 1e-12 && (gt[5] + 0.1).abs() < 1e-12,
            "{layer}: {gt:?}"
        );
    }
}

/// One line on stderr naming `file` and containing `what`, non-zero exit, nothing written.
pub(crate) fn assert_refused(o: &Output, out: &Path, file: &str, what: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "accepted; stderr {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(err.contains(file) && err.contains(what), "{err}");
    assert!(
        !out.exists() || std::fs::read_dir(out).unwrap().next().is_none(),
        "something was written for {file}"
    );
}

#[test]
fn bad_inputs_are_refused_with_one_line() {
    let d = refs();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cache");
    let laz = std::fs::read(d.join("street.laz")).unwrap();

    let truncated = tmp.path().join("truncated.laz");
    std::fs::write(&truncated, &laz[..laz.len() / 2]).unwrap();
    let o = build(&out, "t", &[truncated.to_str().unwrap()]);
    assert_refused(&o, &out, "truncated.laz", "truncated");

    // No intensity: laspy writes the cloud again with intensity 0 everywhere.
    let dark = tmp.path().join("dark.laz");
    laspy_rewrite(
        &d.join("street.laz"),
        &dark,
        "import laspy",
        "l.intensity[:] = 0",
    );
    let o = build(&out, "t", &[dark.to_str().unwrap()]);
    assert_refused(&o, &out, "dark.laz", "no intensity");

    // Geographic CRS (WGS84) in the file, an unknown --crs for a PCD.
    let geo = tmp.path().join("geographic.laz");
    laspy_rewrite(
        &d.join("street.laz"),
        &geo,
        "import laspy, pyproj",
        "l.header.vlrs.clear(); l.header.add_crs(pyproj.CRS.from_epsg(4326))",
    );
    let o = build(&out, "t", &[geo.to_str().unwrap()]);
    assert_refused(&o, &out, "geographic.laz", "geographic CRS");
    let pcd = d.join("street.pcd");
    let o = build(&out, "t", &[pcd.to_str().unwrap(), "--crs", "EPSG:99999"]);
    assert_refused(&o, &out, "--crs", "unknown EPSG:99999");
    // CRSs whose projection (LAEA Europe) or datum (DHDN: the EPSG table has no shift to WGS84)
    // infraloc cannot reproduce to 1 mm of PROJ.
    let o = build(&out, "t", &[pcd.to_str().unwrap(), "--crs", "EPSG:3035"]);
    assert_refused(&o, &out, "--crs", "EPSG:3035 uses the laea projection");
    let o = build(&out, "t", &[pcd.to_str().unwrap(), "--crs", "EPSG:31467"]);
    assert_refused(&o, &out, "--crs", "EPSG:31467 is on a datum (bessel)");
    let o = build(&out, "t", &[pcd.to_str().unwrap()]);
    assert_refused(&o, &out, "street.pcd", "give --crs");

    // A box beside the survey holds no ground.
    let o = infraloc(&[
        "tile",
        "build",
        "--out",
        out.to_str().unwrap(),
        "--id",
        "t",
        "--bbox",
        "691200,5335200,691230,5335230",
        d.join("street.laz").to_str().unwrap(),
    ]);
    assert_refused(&o, &out, "street.laz", "no ground points in the box");

    // An orthophoto that covers only part of the box (the tile's satellite layer, cropped).
    let ok = tmp.path().join("ok");
    built(&ok, "laz", &[d.join("street.laz").to_str().unwrap()]);
    let part = tmp.path().join("part.tif");
    let g = Command::new("gdal_translate")
        .args(["-q", "-srcwin", "0", "0", "150", "300"])
        .arg(ok.join("laz/satellite.tif"))
        .arg(&part)
        .status()
        .unwrap();
    assert!(g.success());
    let o = build(
        &out,
        "t",
        &[
            d.join("street.laz").to_str().unwrap(),
            "--orthophoto",
            part.to_str().unwrap(),
        ],
    );
    assert_refused(&o, &out, "part.tif", "does not cover the box");
}

#[test]
fn orthophoto_in_another_crs_is_warped_as_gdalwarp_does() {
    let d = refs();
    let tmp = tempfile::tempdir().unwrap();
    let laz = d.join("street.laz");
    built(tmp.path(), "laz", &[laz.to_str().unwrap()]);
    // A 0.3 m orthophoto in ETRS89 / UTM 33N (its grid turned 2.5° against the 32N grid), by GDAL.
    let ortho = tmp.path().join("ortho25833.tif");
    let gdalwarp = |args: &[&str], src: &Path, dst: &Path| {
        let st = Command::new("gdalwarp")
            .arg("-q")
            .args(args)
            .arg(src)
            .arg(dst)
            .status()
            .expect("gdal-bin is needed: see .ci/setup");
        assert!(st.success());
    };
    let sat = tmp.path().join("laz/satellite.tif");
    gdalwarp(
        &[
            "-t_srs",
            "EPSG:25833",
            "-tr",
            "0.3",
            "0.3",
            "-r",
            "average",
            "-et",
            "0",
        ],
        &sat,
        &ortho,
    );
    let bbox = "691020,5335020,691040,5335040";
    let out = tmp.path().join("w");
    let o = build_in(
        &out,
        "w",
        bbox,
        &[
            laz.to_str().unwrap(),
            "--orthophoto",
            ortho.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ours = infraloc::map::geotiff::read_rgb8(&out.join("w/satellite.tif")).unwrap();
    // GDAL's bilinear warp of the same orthophoto onto the tile's grid, exact transforms.
    let theirs_path = tmp.path().join("gdal.tif");
    gdalwarp(
        &[
            "-t_srs",
            "EPSG:25832",
            "-te",
            "691020",
            "5335020",
            "691040",
            "5335040",
            "-tr",
            "0.1",
            "0.1",
            "-r",
            "bilinear",
            "-et",
            "0",
        ],
        &ortho,
        &theirs_path,
    );
    let theirs = infraloc::map::geotiff::read_rgb8(&theirs_path).unwrap();
    assert_eq!(ours.grid, theirs.grid);
    let mut worst = 0;
    for (a, b) in ours.data.iter().zip(&theirs.data) {
        for k in 0..3 {
            worst = worst.max((i32::from(a[k]) - i32::from(b[k])).abs());
        }
    }
    assert!(worst <= 1, "warp differs from gdalwarp by up to {worst}");
}

/// The simulator's round trip (docs/map.md, "From the simulator"): `tile build` on the scene's
/// `simulate --lidar-laz` cloud, with the scene's own satellite layer as the orthophoto, gives back
/// the simulator's LiDAR layers: the same grid, reflectivity cell for cell, height within the
/// LAZ's 1 mm coordinate step; the satellite layer is the scene's, resampled onto the tile's grid.
/// Refinement (`study`, the node's local stage) reads only the LiDAR layers, so a built tile
/// refines as the simulator's own does.
#[test]
fn simulated_lidar_round_trips_through_tile_build() {
    let tmp = tempfile::tempdir().unwrap();
    for seed in ["3", "11"] {
        let scene = tmp.path().join(format!("scene{seed}"));
        let laz = tmp.path().join(format!("lidar{seed}.laz"));
        let o = infraloc(&[
            "simulate",
            "--seed",
            seed,
            "--preset",
            "small",
            "--out",
            s(&scene),
            "--lidar-laz",
            s(&laz),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let tiles = scene.join("tiles");
        let id = std::fs::read_dir(&tiles)
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .file_name();
        let own = load_tile(&tiles.join(&id)).unwrap();
        let (x0, y0, x1, y1) = own.reflectivity.grid.bounds();
        let out = tmp.path().join(format!("built{seed}"));
        let o = build_in(
            &out,
            "t",
            &format!("{x0},{y0},{x1},{y1}"),
            &[
                s(&laz),
                "--res",
                &own.reflectivity.grid.res.to_string(),
                "--satellite-res",
                &own.satellite.grid.res.to_string(),
                "--orthophoto",
                s(&tiles.join(&id).join("satellite.tif")),
            ],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let got = load_tile(&out.join("t")).unwrap();
        assert_eq!(got.reflectivity.grid, own.reflectivity.grid, "seed {seed}");
        // The simulator's satellite grid is offset from its LiDAR grid by a fraction of a pixel, so
        // the built satellite layer is the bilinear resample of it onto the tile's grid.
        let (sg, og) = (got.satellite.grid, own.satellite.grid);
        assert_eq!((sg.x0, sg.y0, sg.res), (x0, y1, og.res), "seed {seed}");
        let mut sum = 0.0;
        for (i, px) in got.satellite.data.iter().enumerate() {
            let (x, y) = sg.pixel_center(i % sg.width, i / sg.width);
            let (c, r) = og.to_pixel(x, y);
            let near = own.satellite.data[r.round() as usize * og.width + c.round() as usize];
            sum += (0..3)
                .map(|k| f64::from(px[k].abs_diff(near[k])))
                .sum::<f64>();
        }
        let mean = sum / (3 * got.satellite.data.len()) as f64;
        assert!(
            mean < 3.0,
            "seed {seed}: satellite {mean} levels from the nearest pixel"
        );
        let cells = own.reflectivity.data.len();
        let (mut refl_diff, mut worst, mut invented) = (0, 0.0f32, 0);
        for i in 0..cells {
            let (r, z) = (own.reflectivity.data[i], own.height.data[i]);
            if Some(r) == own.reflectivity.nodata || !z.is_finite() {
                invented += usize::from(got.height.data[i].is_finite());
                continue;
            }
            refl_diff += usize::from(got.reflectivity.data[i] != r);
            worst = worst.max((got.height.data[i] - z).abs());
        }
        assert_eq!(refl_diff, 0, "seed {seed}: reflectivity cells differ");
        assert_eq!(
            invented, 0,
            "seed {seed}: data where the simulator has none"
        );
        assert!(worst <= 6e-4, "seed {seed}: height off by up to {worst} m");
    }
}

/// `src` read by laspy as `l` (after `imports`), changed by `edit`, written to `dst`.
fn laspy_rewrite(src: &Path, dst: &Path, imports: &str, edit: &str) {
    let py = format!("{imports}; l = laspy.read({src:?}); {edit}; l.write({dst:?})");
    assert!(
        Command::new("python3")
            .args(["-c", &py])
            .status()
            .unwrap()
            .success(),
        "{py}"
    );
}
