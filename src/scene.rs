//! A simulated scene directory read back into memory (truth.json, camera.yaml, frames/, tiles/;
//! docs/interfaces.md, "Scene directory"), for the commands that study a scene (`study`, `plot mi-surface`). The
//! directory is written by `infraloc simulate`.

use crate::camera::load_camera;
use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::map::cache::load_covering;
use crate::map::{Crs, Tile};
use crate::pose::CamFromMap;
use image::GrayImage;
use std::path::{Path, PathBuf};

/// A scene directory read into memory.
#[derive(Debug, Clone)]
pub(crate) struct SceneFiles {
    /// Intrinsics given to the localizer (camera.yaml).
    pub camera: Camera,
    /// Temporal median of frames/*.png (what the pipeline refines on).
    pub gray: GrayImage,
    /// The tile covering the true camera position.
    pub tile: Tile,
    /// True pose (truth.json).
    pub truth: CamFromMap,
    /// Control points of truth.json: map point and true pixel.
    pub control: Vec<([f64; 3], [f64; 2])>,
}

/// An error naming `frames` unless the image is the camera's (`yaml`) size.
fn same_size(gray: &GrayImage, camera: &Camera, frames: &Path, yaml: &str) -> Result<()> {
    if (gray.width(), gray.height()) == (camera.width(), camera.height()) {
        return Ok(());
    }
    Err(Error::input(
        frames,
        format!(
            "frames are {}×{} but {yaml} is {}×{}",
            gray.width(),
            gray.height(),
            camera.width(),
            camera.height()
        ),
    ))
}

/// Read a scene directory; each missing or bad part is a one-line error naming it.
pub(crate) fn load_scene(dir: &Path) -> Result<SceneFiles> {
    if !dir.is_dir() {
        return Err(Error::input(dir, "scene directory not found"));
    }
    let tp = dir.join("truth.json");
    let truth = crate::eval::truth::read_truth(&tp)?;
    let control = truth
        .control_points
        .iter()
        .map(|c| (c.map, c.pixel))
        .collect();
    let crs = match truth.crs {
        Some(c @ Crs::Epsg(_)) => c,
        _ => return Err(Error::input(&tp, "\"crs\" must be an EPSG code")),
    };
    let camera = load_camera(&dir.join("camera.yaml"))?;
    let fdir = dir.join("frames");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&fdir)
        .map_err(|e| Error::io(&fdir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::input(&fdir, "no PNG frames"));
    }
    let frames = files
        .iter()
        .map(|p| crate::capture::load_gray(p))
        .collect::<Result<Vec<_>>>()?;
    let gray =
        crate::capture::temporal_median(&frames).map_err(|e| Error::input(&fdir, e.to_string()))?;
    same_size(&gray, &camera, &fdir, "camera.yaml")?;
    let c = truth.pose.center();
    let (lat, lon) = crate::geo::map_to_wgs84(crs, c.x, c.y)?;
    let radius_m = crate::localize::pipeline::Params::default().mi_radius_m;
    let (tile, _) = load_covering(&dir.join("tiles"), lat, lon, 0.0, radius_m)?;
    Ok(SceneFiles {
        camera,
        gray,
        tile,
        truth: truth.pose,
        control,
    })
}

/// The gantry preset's perspective camera and first LiDAR sweep (`simulate --preset gantry`:
/// perspective/camera.yaml, perspective/frames/000.png, perspective/truth_lidar.json and
/// lidar/000.pcd): one image and the sweep taken with it, as a real gantry gives them.
#[derive(Debug, Clone)]
pub(crate) struct PerspectiveFiles {
    /// Intrinsics (perspective/camera.yaml).
    pub camera: Camera,
    /// The first frame.
    pub gray: GrayImage,
    /// The first sweep, in the LiDAR frame.
    pub points: Vec<crate::map::GroundPoint>,
    /// True pose of the camera in the LiDAR frame (perspective/truth_lidar.json).
    pub truth: CamFromMap,
}

/// Read a gantry scene's perspective camera and sweep; each missing or bad part is a one-line
/// error naming it (a scene of another preset has no perspective/ directory).
pub(crate) fn load_perspective(dir: &Path) -> Result<PerspectiveFiles> {
    let pdir = dir.join("perspective");
    if !pdir.is_dir() {
        return Err(Error::input(
            &pdir,
            "not found: only `simulate --preset gantry` writes a perspective camera",
        ));
    }
    let camera = load_camera(&pdir.join("camera.yaml"))?;
    let fp = pdir.join("frames").join("000.png");
    let gray = crate::capture::load_gray(&fp)?;
    same_size(&gray, &camera, &fp, "perspective/camera.yaml")?;
    let points = crate::points_io::read_points(&dir.join("lidar").join("000.pcd"))?;
    let truth = crate::posefile::read_pose(&pdir.join("truth_lidar.json"))?.pose;
    Ok(PerspectiveFiles {
        camera,
        gray,
        points,
        truth,
    })
}

/// The captures of a day (`simulate --times K`): the temporal median of each time's burst, in
/// time order, as truth.json's `acquisition.times` lists them. A scene of one capture has none:
/// the error names the directory and the flag that makes them.
pub(crate) fn load_times(dir: &Path, camera: &Camera) -> Result<Vec<GrayImage>> {
    let tp = dir.join("truth.json");
    let text = std::fs::read_to_string(&tp).map_err(|e| Error::io(&tp, e))?;
    let doc: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::input(&tp, e.to_string()))?;
    let medians: Vec<&str> = doc["acquisition"]["times"]
        .as_array()
        .map(|ts| ts.iter().filter_map(|t| t["median"].as_str()).collect())
        .unwrap_or_default();
    if medians.is_empty() {
        return Err(Error::input(
            &tp,
            "no acquisition.times: a scene of one capture (simulate it with --times K)",
        ));
    }
    medians
        .iter()
        .map(|m| {
            let p = dir.join(m);
            let g = crate::capture::load_gray(&p)?;
            same_size(&g, camera, &p, "camera.yaml")?;
            Ok(g)
        })
        .collect()
}

/// The gantry's captures of a day (`simulate --preset gantry --times K`): each time's first
/// perspective frame and the sweep taken with it, from perspective/pairs_times.tsv.
pub(crate) fn load_perspective_times(
    dir: &Path,
    camera: &Camera,
) -> Result<Vec<(GrayImage, Vec<crate::map::GroundPoint>)>> {
    let pairs = dir.join("perspective").join("pairs_times.tsv");
    if !pairs.is_file() {
        return Err(Error::input(
            &pairs,
            "not found: a gantry scene of one capture (simulate it with --times K)",
        ));
    }
    crate::cli::pairs::read(&pairs)?
        .iter()
        .map(|(image, points)| {
            let g = crate::capture::load_gray(image)?;
            same_size(&g, camera, image, "perspective/camera.yaml")?;
            Ok((g, crate::points_io::read_points(points)?))
        })
        .collect()
}
