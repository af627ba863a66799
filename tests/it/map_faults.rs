//! Map faults are named as map faults (issue 19, deliverable 4), through `infraloc localize` on a
//! simulated scene: a tile whose height layer is all NaN fails in the `tile` stage naming the
//! layer (not as a PnP failure that points at the lens); a corrupt tile elsewhere in the cache is
//! skipped and reported while the covering tile localizes; a manifest in the wrong UTM zone is a
//! CRS mismatch, not "nearest tile 496 km away". No failed run touches the pose file. `refine
//! --tiles` and `plot mi-surface --tiles` look tiles up as `localize` does: a covering tile whose
//! layer is corrupt is passed over for the next one.

use crate::common;

use infraloc::map::cache::{load_tile, write_tile};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");

fn scene() -> &'static Path {
    static SCENE: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &SCENE
        .get_or_init(|| {
            let d = tempfile::tempdir().unwrap();
            let dir = d.path().join("scene");
            common::simulate(BIN, &dir, &["--seed", "3", "--preset", "small"]);
            (d, dir)
        })
        .1
}

fn tile_dir() -> PathBuf {
    let tiles = scene().join("tiles");
    let e = std::fs::read_dir(&tiles).unwrap().next().unwrap().unwrap();
    e.path()
}

/// `localize` with `tiles` as the cache, writing over a pose file that holds `OLD`.
fn localize(w: &Path, tiles: &Path) -> (Output, String) {
    let pose = w.join("pose.json");
    std::fs::write(&pose, "OLD").unwrap();
    let out = Command::new(BIN)
        .args(["localize", "--config"])
        .arg(scene().join("infraloc.toml"))
        .arg("--tiles")
        .arg(tiles)
        .arg("--out")
        .arg(&pose)
        .arg("--report")
        .arg(w.join("report.json"))
        .output()
        .unwrap();
    let after = std::fs::read_to_string(&pose).unwrap();
    (out, after)
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn an_all_nan_height_layer_fails_in_the_tile_stage_naming_the_layer() {
    let w = tempfile::tempdir().unwrap();
    let mut t = load_tile(&tile_dir()).unwrap();
    t.height.data.iter_mut().for_each(|h| *h = f32::NAN);
    let cache = w.path().join("tiles");
    write_tile(&cache, &t).unwrap();
    let (out, pose) = localize(w.path(), &cache);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.starts_with("infraloc: tile: ") && err.contains("height.tif: height layer"),
        "{err}"
    );
    assert!(err.contains("valid data in only 0.0 %"), "{err}");
    assert_eq!(pose, "OLD", "a failed run changed the pose file");
}

#[test]
fn a_corrupt_tile_elsewhere_is_skipped_and_reported() {
    let w = tempfile::tempdir().unwrap();
    let cache = w.path().join("tiles");
    common::copy_tree(&tile_dir(), &cache.join(tile_dir().file_name().unwrap()));
    // A second tile directory with a truncated manifest, sorted before the good one.
    std::fs::create_dir_all(cache.join("aaa-broken")).unwrap();
    std::fs::write(
        cache.join("aaa-broken/tile.toml"),
        "format = \"infraloc.tile.v1\"\nid = ",
    )
    .unwrap();
    let (out, pose) = localize(w.path(), &cache);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(pose.contains("\"camera_center\""), "{pose}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(w.path().join("report.json")).unwrap())
            .unwrap();
    let skipped = report["skipped_tiles"].as_array().expect("skipped_tiles");
    assert_eq!(skipped.len(), 1, "{report}");
    assert!(
        skipped[0]["reason"]
            .as_str()
            .unwrap()
            .contains("aaa-broken/tile.toml"),
        "{report}"
    );
}

#[test]
fn a_manifest_in_the_wrong_utm_zone_is_a_crs_mismatch() {
    let w = tempfile::tempdir().unwrap();
    let cache = w.path().join("tiles");
    let dst = cache.join(tile_dir().file_name().unwrap());
    common::copy_tree(&tile_dir(), &dst);
    let m = std::fs::read_to_string(dst.join("tile.toml")).unwrap();
    let crs = m
        .lines()
        .find(|l| l.starts_with("crs = "))
        .unwrap()
        .to_string();
    let code: u32 = crs
        .trim_start_matches("crs = \"EPSG:")
        .trim_end_matches('"')
        .parse()
        .unwrap();
    let wrong = format!("crs = \"EPSG:{}\"", code + 1);
    std::fs::write(dst.join("tile.toml"), m.replace(&crs, &wrong)).unwrap();
    let (out, pose) = localize(w.path(), &cache);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.starts_with("infraloc: tile: "), "{err}");
    assert!(
        err.contains("CRS mismatch")
            && err.contains(&format!("says EPSG:{}", code + 1))
            && err.contains(&format!("EPSG:{code}, the prior's UTM zone")),
        "{err}"
    );
    assert!(!err.contains("km away") && !err.contains("m away"), "{err}");
    assert_eq!(pose, "OLD");
}

/// `refine --tiles` and `plot mi-surface --tiles` on `tiles` about the scene's true pose, with a
/// small search box: (refine's output, its report without timings, plot's output, the plot).
fn refine_and_plot(w: &Path, tiles: &Path) -> (Output, serde_json::Value, Output, Vec<u8>) {
    let s = scene();
    let common = |cmd: &mut Command| {
        cmd.arg("--camera")
            .arg(s.join("camera.yaml"))
            .arg("--image")
            .arg(s.join("frames/000.png"))
            .arg("--tiles")
            .arg(tiles)
            .args(["--search", "x=0.1:0.05,y=0.1:0.05,z=0.1:0.05,yaw=0.5:0.25"]);
    };
    let mut refine = Command::new(BIN);
    refine
        .args(["refine", "--grid-only", "--init"])
        .arg(s.join("truth.json"));
    common(&mut refine);
    let refined = refine
        .arg("--report")
        .arg(w.join("report.json"))
        .output()
        .unwrap();
    let mut report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(w.join("report.json")).unwrap_or_default())
            .unwrap_or_default();
    strip_timings(&mut report);
    let mut plot = Command::new(BIN);
    plot.args(["plot", "mi-surface", "--pose"])
        .arg(s.join("truth.json"));
    common(&mut plot);
    let plotted = plot
        .args(["--size", "400,200", "--out"])
        .arg(w.join("surface.png"))
        .output()
        .unwrap();
    let png = std::fs::read(w.join("surface.png")).unwrap_or_default();
    (refined, report, plotted, png)
}

/// Remove the keys that hold timings (they differ run to run).
fn strip_timings(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| !(k.contains("seconds") || k.ends_with("_s") || k == "elapsed"));
            m.values_mut().for_each(strip_timings);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(strip_timings),
        _ => {}
    }
}

#[test]
fn refine_and_plot_pass_over_a_corrupt_covering_tile_as_localize_does() {
    let w = tempfile::tempdir().unwrap();
    let good = w.path().join("good");
    let name = tile_dir().file_name().unwrap().to_owned();
    common::copy_tree(&tile_dir(), &good.join(&name));
    // The same tile again under an id sorted first (same extent, so it is the first choice),
    // its height layer cut short.
    let both = w.path().join("both");
    common::copy_tree(&tile_dir(), &both.join(&name));
    let broken = both.join("aaa-broken");
    common::copy_tree(&tile_dir(), &broken);
    let m = std::fs::read_to_string(broken.join("tile.toml")).unwrap();
    let id = format!("id = \"{}\"", name.to_string_lossy());
    assert!(m.contains(&id), "{m}");
    std::fs::write(
        broken.join("tile.toml"),
        m.replace(&id, "id = \"aaa-broken\""),
    )
    .unwrap();
    let height = std::fs::read(broken.join("height.tif")).unwrap();
    std::fs::write(broken.join("height.tif"), &height[..height.len() / 2]).unwrap();

    let (wg, wb) = (w.path().join("run-good"), w.path().join("run-both"));
    std::fs::create_dir_all(&wg).unwrap();
    std::fs::create_dir_all(&wb).unwrap();
    let (refined, report, plotted, png) = refine_and_plot(&wg, &good);
    assert!(!report.is_null(), "{}", text(&refined.stderr));
    assert!(plotted.status.success(), "{}", text(&plotted.stderr));
    let (refined_b, report_b, plotted_b, png_b) = refine_and_plot(&wb, &both);
    // The corrupt tile changes nothing: same exit, same report, same plot.
    assert_eq!(
        refined_b.status.code(),
        refined.status.code(),
        "{}",
        text(&refined_b.stderr)
    );
    assert_eq!(report_b, report);
    assert!(plotted_b.status.success(), "{}", text(&plotted_b.stderr));
    assert!(
        png_b == png,
        "the plot differs with the corrupt tile in the cache"
    );
}
