//! `infraloc kitti import`: a KITTI rig's calibration as infraloc inputs, in the three layouts
//! people hold KITTI in (docs/kitti.md):
//! - the **object benchmark**: `calib/NNNNNN.txt` (P0..P3, R0_rect, Tr_velo_to_cam) with the
//!   frame's image for the size;
//! - **KITTI raw**: a recording day's `calib_cam_to_cam.txt` + `calib_velo_to_cam.txt`, rectified
//!   cameras 00–03;
//! - **KITTI-360**: `calibration/` — the rectified perspective cameras 00 and 01, and the fisheyes
//!   02 and 03 in the MEI model (OpenCV omnidir), posed through `calib_cam_to_pose.txt`.
//!
//! The layout is detected from `--calib` (a file or a directory) or named with `--layout`; the
//! formulas are in [`crate::camera::kitti_rigs`]. The command writes
//! - the camera as OpenCV FileStorage YAML (docs/interfaces.md, "Camera intrinsics files"),
//! - the camera's pose with the **Velodyne frame as the map frame** (`"crs": "LOCAL"`: x forward,
//!   y left, z up, metres) as an `infraloc.pose.v1` JSON that `refine --init`, `plot mi-surface
//!   --pose` and `project --pose` read,
//! - optionally a start perturbed from it (`--perturb x=…,y=…,z=…,yaw=…`, the search's own move:
//!   centre shifted in the Velodyne frame, yaw about its up axis through the camera centre),
//! - for KITTI raw and KITTI-360, optionally a drive's frames as the pairs of one pooled `refine`
//!   (`--drive DIR`: a pairs file for `refine --pairs`, and the command line printed).
//!
//! Everything is read and checked before anything is written; a bad file is one line naming it.
//! So a LiDAR–camera rig's extrinsic can be checked (or re-estimated) with `refine`, and the
//! official calibration is the reference.

use crate::camera::import::is_kitti_calib;
use crate::camera::kitti_rigs::{self, FisheyeTangential, Kitti360Files, RigCamera, Source};
use crate::camera::{import::to_opencv_yaml, CameraModel};
use crate::error::{Error, Result};
use crate::map::Crs;
use crate::pose::CamFromMap;
use crate::posefile::{format_utc, PoseFile};
use std::path::{Path, PathBuf};

/// `kitti` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Camera YAML and Velodyne-frame pose JSON from a KITTI calibration (object benchmark,
    /// KITTI raw or KITTI-360), and optionally a drive's frames as pooled-refine pairs.
    Import(ImportArgs),
}

/// The three KITTI layouts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Layout {
    /// Object benchmark: `calib/NNNNNN.txt` with P0..P3, R0_rect, Tr_velo_to_cam.
    Object,
    /// KITTI raw: a day's `calib_cam_to_cam.txt` and `calib_velo_to_cam.txt`.
    Raw,
    /// KITTI-360: `calibration/` (perspective.txt, calib_cam_to_velo.txt,
    /// calib_cam_to_pose.txt, image_02.yaml, image_03.yaml).
    Kitti360,
}

impl Layout {
    fn name(self) -> &'static str {
        match self {
            Layout::Object => "object",
            Layout::Raw => "raw",
            Layout::Kitti360 => "kitti360",
        }
    }
}

/// Arguments of `kitti import`.
#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// The calibration: object benchmark `calib/NNNNNN.txt`; KITTI raw: the day's directory
    /// (or its calib_cam_to_cam.txt / calib_velo_to_cam.txt); KITTI-360: `calibration/`, the
    /// dataset's root, or a file in `calibration/`.
    #[arg(long)]
    pub calib: PathBuf,
    /// The layout, when it should not be detected from --calib.
    #[arg(long, value_enum)]
    pub layout: Option<Layout>,
    /// The camera: 0–3, written as P2, 2, 02 or image_02 (default: P2 for the object benchmark,
    /// 02 for KITTI raw, 00 for KITTI-360; KITTI-360's 02 and 03 are the MEI fisheyes).
    #[arg(long)]
    pub camera: Option<String>,
    /// The camera's image. Object benchmark: required (its calibration has no image size; only
    /// the size is read). KITTI raw and KITTI-360: optional, checked against the calibration's size.
    #[arg(long)]
    pub image: Option<PathBuf>,
    /// Write the camera here (OpenCV FileStorage YAML, docs/interfaces.md, "Camera intrinsics files").
    #[arg(long)]
    pub camera_out: PathBuf,
    /// Write the calibration's camera pose here (Velodyne frame as the map, crs LOCAL).
    #[arg(long)]
    pub pose_out: PathBuf,
    /// Offsets for a perturbed start: x=M,y=M,z=M,yaw=DEG[,pitch=DEG,roll=DEG] (missing = 0).
    #[arg(long, requires = "start_out")]
    pub perturb: Option<String>,
    /// Write the perturbed start here (with --perturb).
    #[arg(long, requires = "perturb")]
    pub start_out: Option<PathBuf>,
    /// KITTI-360 fisheyes: keep the tangential terms p1, p2 (OpenCV omnidir, the default) or drop
    /// them (KITTI-360's devkit projection, which applies k1, k2 only).
    #[arg(long, value_enum, default_value = "keep")]
    pub fisheye_tangential: Tangential,
    /// KITTI raw or KITTI-360: a drive's frames as the pairs of one pooled refine (the
    /// synchronised drive directory: image_0N/data[_rect|_rgb]/ or image_0N/, and
    /// velodyne_points/data/ or velodyne/; for KITTI-360's data_2d_raw/SEQ the scans of
    /// data_3d_raw/SEQ). Every frame with a scan is taken (see --frames, --every); each must have
    /// the camera's image.
    #[arg(long)]
    pub drive: Option<PathBuf>,
    /// With --drive: which frames, as frame numbers and inclusive ranges, e.g. 250,360,500-900.
    #[arg(long, requires = "drive")]
    pub frames: Option<String>,
    /// With --drive: keep every K-th of the selected frames (from the first).
    #[arg(long, requires = "drive", default_value_t = 1)]
    pub every: usize,
    /// With --drive: write the pairs file for `refine --pairs` here (IMAGE<TAB>POINTS lines,
    /// absolute paths); without it the printed command repeats --image/--points.
    #[arg(long, requires = "drive")]
    pub pairs_out: Option<PathBuf>,
}

/// `--fisheye-tangential`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Tangential {
    /// Keep p1, p2 (OpenCV omnidir; docs/contracts.md §2).
    Keep,
    /// Drop p1, p2 (KITTI-360's devkit `cam2image`).
    Drop,
}

/// Run a `kitti` subcommand.
pub(super) fn run(c: Command) -> Result<()> {
    match c {
        Command::Import(a) => import(a),
    }
}

/// Parse `x=…,y=…,z=…,yaw=…[,pitch=…,roll=…]` into the search's offsets (m, m, m, °, °, °).
pub(crate) fn parse_perturbation(s: &str) -> Result<[f64; 6]> {
    const KEYS: [&str; 6] = ["x", "y", "z", "yaw", "pitch", "roll"];
    let bad = |m: String| Error::arg_quoted("--perturb", s, m);
    let mut o = [0.0; 6];
    let mut seen = [false; 6];
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (k, v) = part
            .split_once('=')
            .ok_or_else(|| bad(format!("{part:?} is not KEY=VALUE")))?;
        let i = KEYS
            .iter()
            .position(|n| *n == k.trim())
            .ok_or_else(|| bad(format!("unknown axis {k:?} (x, y, z, yaw, pitch, roll)")))?;
        if seen[i] {
            return Err(bad(format!("{k} given twice")));
        }
        seen[i] = true;
        o[i] = v
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| bad(format!("{k}: {v:?} is not a finite number")))?;
    }
    Ok(o)
}

fn pose_json(pose: &CamFromMap, cam_json: serde_json::Value, stage: serde_json::Value) -> String {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let mut pf = PoseFile::new(pose, Crs::Local, "", format_utc(now, None));
    pf.intrinsics = cam_json;
    pf.stages = vec![stage];
    pf.to_json()
}

/// Read a calibration file whole (a missing one is an error naming it).
fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

/// The camera index 0–3 of `--camera` (`P2`, `2`, `02`, `image_02`, `cam2`).
fn camera_index(s: &str) -> Result<u8> {
    let t = s.trim();
    let lower = t.to_ascii_lowercase();
    let digits = ["image_", "cam", "p"]
        .iter()
        .find_map(|p| lower.strip_prefix(p))
        .unwrap_or(&lower);
    digits
        .parse::<u8>()
        .ok()
        .filter(|n| *n <= 3)
        .ok_or_else(|| {
            Error::arg_quoted(
                "--camera",
                s,
                "expected a camera 0–3 (P2, 2, 02 or image_02)",
            )
        })
}

/// The calibration's layout and the directory (raw, KITTI-360) or file (object) it is in.
fn detect(calib: &Path, named: Option<Layout>) -> Result<(Layout, PathBuf)> {
    const RAW: [&str; 2] = ["calib_cam_to_cam.txt", "calib_velo_to_cam.txt"];
    const K360: [&str; 3] = [
        "perspective.txt",
        "calib_cam_to_velo.txt",
        "calib_cam_to_pose.txt",
    ];
    let has = |d: &Path, names: &[&str]| names.iter().any(|n| d.join(n).is_file());
    let meta = std::fs::metadata(calib).map_err(|e| Error::io(calib, e))?;
    if meta.is_dir() {
        let nested = calib.join("calibration");
        let found = if has(calib, &RAW) {
            Some((Layout::Raw, calib.to_path_buf()))
        } else if has(calib, &K360) {
            Some((Layout::Kitti360, calib.to_path_buf()))
        } else if has(&nested, &K360) {
            Some((Layout::Kitti360, nested))
        } else {
            None
        };
        return match (found, named) {
            (Some((l, d)), None) => Ok((l, d)),
            (Some((l, d)), Some(n)) if l == n => Ok((l, d)),
            (_, Some(Layout::Object)) => Err(Error::input(
                calib,
                "is a directory: the object benchmark's --calib is a calib/NNNNNN.txt file",
            )),
            (_, Some(n)) => Err(Error::input(
                calib,
                format!(
                    "no {} calibration here (expected {})",
                    n.name(),
                    if n == Layout::Raw {
                        RAW.join(" and ")
                    } else {
                        K360.join(", ")
                    }
                ),
            )),
            (None, None) => Err(Error::input(
                calib,
                format!(
                    "cannot tell the KITTI layout: no {} (raw) nor {} (KITTI-360, here or in calibration/); name it with --layout",
                    RAW.join(" / "),
                    K360.join(" / ")
                ),
            )),
        };
    }
    let dir = calib
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let name = calib.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let by_name = if RAW.contains(&name) {
        Some(Layout::Raw)
    } else if K360.contains(&name) || (name.starts_with("image_0") && name.ends_with(".yaml")) {
        Some(Layout::Kitti360)
    } else {
        None
    };
    match (by_name.or(named), named) {
        (Some(l), Some(n)) if l != n => Err(Error::input(
            calib,
            format!("is a {} calibration file, not {}", l.name(), n.name()),
        )),
        (Some(Layout::Object), _) => Ok((Layout::Object, calib.to_path_buf())),
        (Some(l), _) => Ok((l, dir)),
        (None, _) => {
            if is_kitti_calib(&read(calib)?) {
                Ok((Layout::Object, calib.to_path_buf()))
            } else {
                Err(Error::input(
                    calib,
                    "not a KITTI calibration: expected an object-benchmark calib/NNNNNN.txt (P0..P3, R0_rect, Tr_velo_to_cam), a KITTI raw or a KITTI-360 calibration directory",
                ))
            }
        }
    }
}

/// The camera of `--calib` in its layout, and the files it was read from.
fn load_rig(a: &ImportArgs, layout: Layout, at: &Path, n: u8) -> Result<(RigCamera, Vec<PathBuf>)> {
    match layout {
        Layout::Object => {
            let image = a.image.as_ref().ok_or_else(|| {
                Error::Usage(
                    "--image: the object benchmark's calibration has no image size; give the frame's image"
                        .into(),
                )
            })?;
            let text = read(at)?;
            let (w, h) = image_size(image)?;
            let rig = kitti_rigs::object(
                Source {
                    path: at,
                    text: &text,
                },
                n,
                w,
                h,
            )?;
            Ok((rig, vec![at.to_path_buf()]))
        }
        Layout::Raw => {
            let (cc, vc) = (
                at.join("calib_cam_to_cam.txt"),
                at.join("calib_velo_to_cam.txt"),
            );
            let (tc, tv) = (read(&cc)?, read(&vc)?);
            let rig = kitti_rigs::raw(
                Source {
                    path: &cc,
                    text: &tc,
                },
                Source {
                    path: &vc,
                    text: &tv,
                },
                n,
            )?;
            Ok((rig, vec![cc, vc]))
        }
        Layout::Kitti360 => {
            let cv = at.join("calib_cam_to_velo.txt");
            let cp = at.join("calib_cam_to_pose.txt");
            let pp = at.join("perspective.txt");
            let fy = at.join(format!("image_0{n}.yaml"));
            let tcv = read(&cv)?;
            let tcp = (n != 0).then(|| read(&cp)).transpose()?;
            let tpp = (n <= 1).then(|| read(&pp)).transpose()?;
            let tfy = (n >= 2).then(|| read(&fy)).transpose()?;
            let mut used = vec![cv.clone()];
            for (p, t) in [(&cp, &tcp), (&pp, &tpp), (&fy, &tfy)] {
                if t.is_some() {
                    used.push(p.clone());
                }
            }
            fn src<'a>(path: &'a Path, text: &'a Option<String>) -> Option<Source<'a>> {
                text.as_deref().map(|text| Source { path, text })
            }
            let files = Kitti360Files {
                cam_to_velo: Source {
                    path: &cv,
                    text: &tcv,
                },
                cam_to_pose: src(&cp, &tcp),
                perspective: src(&pp, &tpp),
                fisheye: src(&fy, &tfy),
            };
            let tangential = match a.fisheye_tangential {
                Tangential::Keep => FisheyeTangential::Keep,
                Tangential::Drop => FisheyeTangential::Drop,
            };
            let rig = kitti_rigs::kitti360(files, n, tangential)?;
            Ok((rig, used))
        }
    }
}

fn image_size(image: &Path) -> Result<(u32, u32)> {
    image::image_dimensions(image)
        .map_err(|e| Error::input(image, format!("cannot read image size: {e}")))
}

/// A drive's frames: (frame name, image, scan), in frame order.
type Frames = Vec<(String, PathBuf, PathBuf)>;

/// The first of `dir`'s `candidates` that is a directory.
fn first_dir(dir: &Path, candidates: &[PathBuf], what: &str) -> Result<PathBuf> {
    candidates
        .iter()
        .find(|c| c.is_dir())
        .cloned()
        .ok_or_else(|| {
            let list: Vec<String> = candidates
                .iter()
                .map(|c| c.strip_prefix(dir).unwrap_or(c).display().to_string())
                .collect();
            Error::input(
                dir,
                format!("no {what} directory (looked for {})", list.join(", ")),
            )
        })
}

/// Parse `--frames` (`250,360,500-900`) into inclusive ranges.
fn frame_ranges(spec: &str) -> Result<Vec<(u64, u64)>> {
    let bad = |m: String| Error::arg_quoted("--frames", spec, m);
    let mut out = Vec::new();
    for item in spec.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let num = |t: &str| {
            t.trim()
                .parse::<u64>()
                .map_err(|_| bad(format!("{t:?} is not a frame number")))
        };
        let (a, b) = match item.split_once('-') {
            Some((a, b)) => (num(a)?, num(b)?),
            None => (num(item)?, num(item)?),
        };
        if a > b {
            return Err(bad(format!("{item:?} runs backwards")));
        }
        out.push((a, b));
    }
    if out.is_empty() {
        return Err(bad("no frame named".into()));
    }
    Ok(out)
}

/// The frames of `drive` for camera `n`: every scan (or those `--frames` names, every
/// `--every`-th), each with its image, which must exist and be the camera's size, and a scan
/// that is whole 16-byte points.
fn drive_frames(a: &ImportArgs, drive: &Path, n: u8, size: (u32, u32)) -> Result<Frames> {
    let cam = drive.join(format!("image_0{n}"));
    let images = first_dir(
        drive,
        &[
            cam.join("data_rect"),
            cam.join("data_rgb"),
            cam.join("data"),
            cam.clone(),
        ],
        &format!("camera 0{n} image"),
    )?;
    let mut scan_dirs = vec![drive.join("velodyne_points/data"), drive.join("velodyne")];
    // KITTI-360 keeps a sequence's images under data_2d_raw/SEQ and its scans under data_3d_raw/SEQ.
    if let (Some(parent), Some(seq)) = (drive.parent(), drive.file_name()) {
        if parent.file_name().and_then(|n| n.to_str()) == Some("data_2d_raw") {
            if let Some(root) = parent.parent() {
                scan_dirs.push(
                    root.join("data_3d_raw")
                        .join(seq)
                        .join("velodyne_points/data"),
                );
            }
        }
    }
    let scans = first_dir(drive, &scan_dirs, "Velodyne scan")?;
    let mut all: Vec<(u64, String)> = Vec::new();
    for e in std::fs::read_dir(&scans).map_err(|e| Error::io(&scans, e))? {
        let e = e.map_err(|e| Error::io(&scans, e))?;
        let p = e.path();
        if p.extension().and_then(|x| x.to_str()) != Some("bin") {
            continue;
        }
        if let Some(stem) = p.file_stem().and_then(|s| s.to_str()) {
            if let Ok(k) = stem.parse::<u64>() {
                all.push((k, stem.to_string()));
            }
        }
    }
    all.sort();
    if all.is_empty() {
        return Err(Error::input(
            &scans,
            "no Velodyne scan (NNNNNNNNNN.bin) here",
        ));
    }
    let width = all[0].1.len();
    let chosen: Vec<String> = match &a.frames {
        None => all.iter().map(|(_, s)| s.clone()).collect(),
        Some(spec) => {
            let mut out = Vec::new();
            for (lo, hi) in frame_ranges(spec)? {
                let inside: Vec<&String> = all
                    .iter()
                    .filter(|(k, _)| (lo..=hi).contains(k))
                    .map(|(_, s)| s)
                    .collect();
                if inside.is_empty() {
                    let want = scans.join(format!("{lo:0width$}.bin"));
                    return Err(if lo == hi {
                        Error::input(&want, "no such scan (named by --frames)")
                    } else {
                        Error::input(
                            &scans,
                            format!("no scan of frames {lo}–{hi} here (--frames)"),
                        )
                    });
                }
                out.extend(inside.into_iter().cloned());
            }
            out.sort_by_key(|s| s.parse::<u64>().unwrap_or(0));
            out.dedup();
            out
        }
    };
    if a.every == 0 {
        return Err(Error::arg("--every", 0, "must be at least 1"));
    }
    let mut frames = Vec::new();
    for stem in chosen.into_iter().step_by(a.every) {
        let image = images.join(format!("{stem}.png"));
        let scan = scans.join(format!("{stem}.bin"));
        if !image.is_file() {
            return Err(Error::input(
                &image,
                format!("no image for frame {stem} (its scan is {})", scan.display()),
            ));
        }
        let got = image_size(&image)?;
        if got != size {
            return Err(Error::input(
                &image,
                format!(
                    "image is {}×{} but camera 0{n} is {}×{}",
                    got.0, got.1, size.0, size.1
                ),
            ));
        }
        let len = std::fs::metadata(&scan)
            .map_err(|e| Error::io(&scan, e))?
            .len();
        if len == 0 || len % 16 != 0 {
            return Err(Error::input(
                &scan,
                format!(
                    "{len} bytes is not a whole number of points (16 bytes each: x, y, z, reflectance as float32)"
                ),
            ));
        }
        frames.push((stem, image, scan));
    }
    Ok(frames)
}

/// `p` quoted for a POSIX shell when it needs it.
fn shell_word(p: &Path) -> String {
    let s = p.display().to_string();
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "_./:=,+-@%".contains(c))
    {
        s
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

fn import(a: ImportArgs) -> Result<()> {
    // Everything is parsed and checked before anything is written.
    let perturb = a.perturb.as_deref().map(parse_perturbation).transpose()?;
    let (layout, at) = detect(&a.calib, a.layout)?;
    let n = match (&a.camera, layout) {
        (Some(c), _) => camera_index(c)?,
        (None, Layout::Kitti360) => 0,
        (None, _) => 2,
    };
    let camera_name = match layout {
        Layout::Object => format!("P{n}"),
        _ => format!("0{n}"),
    };
    let (rig, sources) = load_rig(&a, layout, &at, n)?;
    let cam = rig.camera;
    let size = (cam.width(), cam.height());
    if let (Some(image), false) = (&a.image, layout == Layout::Object) {
        let got = image_size(image)?;
        if got != size {
            return Err(Error::input(
                image,
                format!(
                    "image is {}×{} but camera {camera_name} of the calibration is {}×{}",
                    got.0, got.1, size.0, size.1
                ),
            ));
        }
    }
    let frames = match &a.drive {
        None => None,
        Some(_) if layout == Layout::Object => {
            return Err(Error::Usage(
                "--drive: the object benchmark's frames each have their own calibration; pool the frames of one KITTI raw or KITTI-360 drive".into(),
            ))
        }
        Some(d) => {
            let d = std::fs::canonicalize(d).map_err(|e| Error::io(d, e))?;
            Some(drive_frames(&a, &d, n, size)?)
        }
    };
    let m = rig.rotation.matrix();
    let rows = [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]);
    let pose = CamFromMap::from_rows(rows, rig.translation.into());
    let cam_json = serde_json::to_value(&cam).unwrap_or_default();
    let source = |p: &Path| p.display().to_string();
    let stage = serde_json::json!({
        "name": "kitti-calibration",
        "layout": layout.name(),
        "calib": sources.iter().map(|p| source(p)).collect::<Vec<_>>(),
        "camera": camera_name,
        "map_frame": "velodyne",
        "reorthonormalised": rig.notes,
    });
    for line in &rig.notes {
        super::note(line);
    }
    crate::persist::write_atomic(&a.camera_out, to_opencv_yaml(&cam).as_bytes())?;
    crate::persist::write_atomic(
        &a.pose_out,
        pose_json(&pose, cam_json.clone(), stage.clone()).as_bytes(),
    )?;
    let c = pose.center();
    let (yaw, pitch, roll) = pose.yaw_pitch_roll();
    let model = match &cam {
        crate::camera::Camera::Mei(m) if m.xi != 0.0 => {
            format!("MEI ξ = {:.4}, f = {:.3} px", m.xi, m.fx)
        }
        crate::camera::Camera::Mei(m) => format!("f = {:.3} px", m.fx),
        crate::camera::Camera::Equidistant(e) => format!("equidistant, f = {:.3} px", e.fx),
    };
    println!(
        "kitti: {} camera {camera_name} {}×{}, {model}; camera centre ({:+.4}, {:+.4}, {:+.4}) m in \
         the Velodyne frame, yaw {:.3}°, pitch {:.3}°, roll {:.3}°; wrote {} and {}",
        layout.name(),
        size.0,
        size.1,
        c.x,
        c.y,
        c.z,
        yaw.to_degrees(),
        pitch.to_degrees(),
        roll.to_degrees(),
        a.camera_out.display(),
        a.pose_out.display()
    );
    if let (Some(o), Some(path)) = (perturb, &a.start_out) {
        let start = crate::localize::mi::space::pose_at(&pose, &o);
        let mut stage = stage;
        stage["perturbation"] = serde_json::json!({
            "x_m": o[0], "y_m": o[1], "z_m": o[2], "yaw_deg": o[3], "pitch_deg": o[4], "roll_deg": o[5],
        });
        crate::persist::write_atomic(path, pose_json(&start, cam_json, stage).as_bytes())?;
        println!(
            "kitti: start perturbed by ({:+.3}, {:+.3}, {:+.3}) m, yaw {:+.3}°, pitch {:+.3}°, roll \
             {:+.3}°: wrote {}",
            o[0],
            o[1],
            o[2],
            o[3],
            o[4],
            o[5],
            path.display()
        );
    }
    if let Some(frames) = frames {
        let pairs: Vec<(PathBuf, PathBuf)> = frames
            .iter()
            .map(|(_, i, s)| (i.clone(), s.clone()))
            .collect();
        let init = a.start_out.as_ref().unwrap_or(&a.pose_out);
        let mut cmd = format!(
            "infraloc refine --camera {} --init {}",
            shell_word(&a.camera_out),
            shell_word(init)
        );
        if let Some(path) = &a.pairs_out {
            crate::persist::write_atomic(path, super::pairs::format(&pairs).as_bytes())?;
            cmd.push_str(&format!(" --pairs {}", shell_word(path)));
        } else {
            for (i, s) in &pairs {
                cmd.push_str(&format!(
                    " --image {} --points {}",
                    shell_word(i),
                    shell_word(s)
                ));
            }
        }
        let (first, last) = (&frames[0].0, &frames[frames.len() - 1].0);
        println!(
            "kitti: {} frames ({first}–{last}) pooled in one refine{}:",
            frames.len(),
            a.pairs_out
                .as_ref()
                .map(|p| format!(", pairs written to {}", p.display()))
                .unwrap_or_default()
        );
        println!("{cmd}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_names_and_frame_lists() {
        for (name, n) in [
            ("P2", 2),
            ("2", 2),
            ("02", 2),
            ("image_03", 3),
            ("cam0", 0),
            ("p1", 1),
        ] {
            assert_eq!(camera_index(name).unwrap(), n, "{name}");
        }
        for bad in ["P4", "image_", "left", "-1"] {
            let e = camera_index(bad).unwrap_err().to_string();
            assert!(e.starts_with("--camera") && e.contains("0–3"), "{e}");
        }
        assert_eq!(
            frame_ranges("250, 360,500-900").unwrap(),
            [(250, 250), (360, 360), (500, 900)]
        );
        for (bad, what) in [
            ("9-3", "runs backwards"),
            ("x", "not a frame number"),
            (",", "no frame"),
        ] {
            let e = frame_ranges(bad).unwrap_err().to_string();
            assert!(e.starts_with("--frames") && e.contains(what), "{e}");
        }
        assert_eq!(shell_word(Path::new("/a/b_c-1.png")), "/a/b_c-1.png");
        assert_eq!(shell_word(Path::new("/a b/it's")), "'/a b/it'\\''s'");
    }

    #[test]
    fn perturbation_spec() {
        assert_eq!(
            parse_perturbation("x=0.1, yaw=-1.5,z=0.02").unwrap(),
            [0.1, 0.0, 0.02, -1.5, 0.0, 0.0]
        );
        assert_eq!(parse_perturbation("").unwrap(), [0.0; 6]);
        for (bad, what) in [
            ("x=1,x=2", "given twice"),
            ("q=1", "unknown axis"),
            ("x=nan", "not a finite number"),
            ("x", "not KEY=VALUE"),
        ] {
            let e = parse_perturbation(bad).unwrap_err().to_string();
            assert!(e.starts_with("--perturb") && e.contains(what), "{e}");
        }
    }
}
