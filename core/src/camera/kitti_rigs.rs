//! The three KITTI calibration layouts as a camera and that camera's pose in the Velodyne frame
//! (`infraloc kitti import`, docs/kitti.md). Pure: file texts in, camera and pose out;
//! every failure an [`Error::Input`] naming the file and the key.
//!
//! - **Object benchmark** (`calib/NNNNNN.txt`): `Pi · [R0_rect · (R·X + T); 1]` with
//!   `[R | T] = Tr_velo_to_cam` ([`KittiCalib`]).
//! - **KITTI raw** (`calib_cam_to_cam.txt` + `calib_velo_to_cam.txt` of a recording day): the same
//!   formula with `R_rect_00`, `P_rect_0N` and the `R:`/`T:` of `calib_velo_to_cam.txt` (the raw
//!   devkit's `P_rect_0N · R_rect_00 · [R | T] · X`, for every camera N); the image size is
//!   `S_rect_0N`.
//! - **KITTI-360** (`calibration/`): `calib_cam_to_velo.txt` is camera 00 (unrectified) → Velodyne,
//!   `calib_cam_to_pose.txt` each camera → the vehicle frame, so camera N → Velodyne is
//!   `T_cam00→velo · T_cam00→pose⁻¹ · T_camN→pose`. The perspective cameras 00 and 01 are
//!   rectified by `R_rect_0N` and projected by the left 3×3 of `P_rect_0N` (`perspective.txt`;
//!   size `S_rect_0N`), as KITTI-360's devkit does (it leaves `P_rect_01`'s baseline column out
//!   and takes camera 01's own `calib_cam_to_pose.txt` entry). The fisheyes 02 and 03 are the MEI
//!   model of `image_0N.yaml`: OpenCV omnidir with fx, fy = gamma1, gamma2 and cx, cy = u0, v0.
//!   KITTI-360's devkit projects them without the tangential p1, p2 (its `cam2image`); the camera
//!   file keeps them, as OpenCV omnidir and the calibration's MEI model apply them (docs/contracts.md
//!   §2), unless the caller drops them ([`FisheyeTangential::Drop`]).
//!
//! Every rotation read goes through [`crate::orthonormal`]: up to 1e-4 from orthonormal it is
//! projected onto the nearest rotation (and the result's `notes` say so, naming the file and
//! field); beyond, it is an error naming them.

use super::import::{parse_camera, parse_kitti_calib, KittiCalib};
use super::{Camera, CameraError};
use crate::error::{Error, Result};
use crate::orthonormal::rotation_rows;
use nalgebra::{Matrix3, Rotation3, Vector3};
use std::path::Path;

/// A calibration file: its path (for messages) and its text.
#[derive(Debug, Clone, Copy)]
pub struct Source<'a> {
    /// Where it was read from.
    pub path: &'a Path,
    /// What it holds.
    pub text: &'a str,
}

/// A camera of a KITTI rig and its pose in the Velodyne frame.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    /// The camera model (a pinhole as Mei with ξ = 0, or a KITTI-360 fisheye's MEI).
    pub camera: Camera,
    /// Velodyne → camera rotation: `X_cam = rotation · X_velo + translation`.
    pub rotation: Rotation3<f64>,
    /// Velodyne → camera translation, metres.
    pub translation: Vector3<f64>,
    /// One line per rotation that was re-orthonormalised (`FILE: FIELD re-orthonormalised …`).
    pub notes: Vec<String>,
}

/// What to do with a KITTI-360 fisheye's tangential terms p1, p2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FisheyeTangential {
    /// Keep them: OpenCV omnidir's projection with the calibration's p1, p2 (the default).
    #[default]
    Keep,
    /// Set them to 0: KITTI-360's devkit projection (`cam2image` applies k1, k2 only).
    Drop,
}

/// A rigid transform `x ↦ r·x + t`.
#[derive(Debug, Clone, Copy)]
struct Rigid {
    r: Rotation3<f64>,
    t: Vector3<f64>,
}

impl Rigid {
    fn inverse(&self) -> Rigid {
        let r = self.r.inverse();
        Rigid {
            r,
            t: -(r * self.t),
        }
    }

    /// `self ∘ other`: first `other`, then `self`.
    fn after(&self, other: &Rigid) -> Rigid {
        Rigid {
            r: self.r * other.r,
            t: self.r * other.t + self.t,
        }
    }
}

/// A `KEY: values` calibration file (KITTI raw's and KITTI-360's text files). Values are parsed
/// when a key is asked for, so keys with text values (`calib_time`) are no error.
struct KeyFile<'a> {
    path: &'a Path,
    entries: Vec<(&'a str, &'a str)>,
    notes: Vec<String>,
}

impl<'a> KeyFile<'a> {
    fn parse(src: Source<'a>) -> Result<Self> {
        let mut entries = Vec::new();
        for (i, line) in src.text.lines().enumerate() {
            let line = line.trim_start_matches('\u{feff}').trim();
            if line.is_empty() {
                continue;
            }
            let Some((k, v)) = line.split_once(':') else {
                return Err(Error::input(
                    src.path,
                    format!("line {}: expected KEY: values", i + 1),
                ));
            };
            let k = k.trim();
            if entries.iter().any(|(e, _)| *e == k) {
                return Err(Error::input(src.path, format!("{k}: given twice")));
            }
            entries.push((k, v));
        }
        Ok(KeyFile {
            path: src.path,
            entries,
            notes: Vec::new(),
        })
    }

    fn err(&self, msg: impl Into<String>) -> Error {
        Error::input(self.path, msg)
    }

    fn keys(&self) -> String {
        self.entries
            .iter()
            .map(|(k, _)| *k)
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Exactly `N` finite numbers under `key`.
    fn numbers<const N: usize>(&self, key: &str) -> Result<[f64; N]> {
        let (_, v) = self
            .entries
            .iter()
            .find(|(k, _)| *k == key)
            .ok_or_else(|| self.err(format!("missing key {key} (has {})", self.keys())))?;
        numbers::<N>(v, key, self.path)
    }

    /// A row-major 3×3 rotation under `key`, through [`crate::orthonormal`].
    fn rotation(&mut self, key: &str) -> Result<Rotation3<f64>> {
        let m = self.numbers::<9>(key)?;
        self.checked_rotation(&m, key)
    }

    fn checked_rotation(&mut self, m: &[f64; 9], field: &str) -> Result<Rotation3<f64>> {
        let r = rotation_rows(m, field).map_err(|e| self.err(e.to_string()))?;
        self.notes.extend(r.note(self.path, field));
        Ok(r.rotation)
    }

    /// A 3×4 row-major `[R | t]` under `key`.
    fn rigid(&mut self, key: &str) -> Result<Rigid> {
        let m = self.numbers::<12>(key)?;
        rigid_of(&m, key, self)
    }

    /// An image size `W H` (written as reals, e.g. `1.242000e+03 3.750000e+02`).
    fn size(&self, key: &str) -> Result<(u32, u32)> {
        let [w, h] = self.numbers::<2>(key)?;
        let ok = |v: f64| v.fract() == 0.0 && (1.0..=100_000.0).contains(&v);
        if !(ok(w) && ok(h)) {
            return Err(self.err(format!("{key}: {w} × {h} is not an image size in pixels")));
        }
        Ok((w as u32, h as u32))
    }
}

/// `[R | t]` of a row-major 3×4, its rotation checked as `field`.
fn rigid_of(m: &[f64; 12], field: &str, file: &mut KeyFile) -> Result<Rigid> {
    let rows = [m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]];
    let r = file.checked_rotation(&rows, &format!("{field} (rotation)"))?;
    Ok(Rigid {
        r,
        t: Vector3::new(m[3], m[7], m[11]),
    })
}

/// Exactly `N` finite numbers in `text`, named `key` in errors.
fn numbers<const N: usize>(text: &str, key: &str, path: &Path) -> Result<[f64; N]> {
    let v = text
        .split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| Error::input(path, format!("{key}: {t:?} is not a finite number")))
        })
        .collect::<Result<Vec<f64>>>()?;
    let n = v.len();
    v.try_into()
        .map_err(|_| Error::input(path, format!("{key}: expected {N} numbers, found {n}")))
}

/// The rectified pinhole of projection `key` (`P_rect_0N`), `width`×`height`, as KITTI's object
/// code builds it (Mei with ξ = 0, K's skew kept), and `K⁻¹ · P[:, 3]` (the camera's offset from
/// the reference camera in its rectified frame).
fn pinhole(file: &KeyFile, key: &str, size: (u32, u32)) -> Result<(Camera, Vector3<f64>)> {
    let p = file.numbers::<12>(key)?;
    let calib = KittiCalib {
        projections: vec![(key.to_string(), p)],
        r0_rect: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        tr_velo_to_cam: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
    };
    let cam = calib
        .camera(key, size.0, size.1)
        .map_err(|m| file.err(m.to_string()))?;
    let (_, b) = calib
        .cam_from_velo(key)
        .map_err(|m| file.err(m.to_string()))?;
    Ok((cam, Vector3::from(b)))
}

/// Camera `n` (0–3) of a KITTI object-benchmark frame, `width`×`height` (from its image). The
/// projection is `Pn`; `R0_rect` and `Tr_velo_to_cam`'s rotation are checked and orthonormalised
/// before they are composed.
pub fn object(calib: Source, n: u8, width: u32, height: u32) -> Result<RigCamera> {
    let mut c = parse_kitti_calib(calib.text, calib.path)?;
    let mut file = KeyFile {
        path: calib.path,
        entries: Vec::new(),
        notes: Vec::new(),
    };
    let r0 = file.checked_rotation(&c.r0_rect, "R0_rect")?;
    let tr = rigid_of(&c.tr_velo_to_cam, "Tr_velo_to_cam", &mut file)?;
    c.r0_rect = row_major(&r0);
    let rt = row_major(&tr.r);
    c.tr_velo_to_cam = [
        rt[0], rt[1], rt[2], tr.t.x, rt[3], rt[4], rt[5], tr.t.y, rt[6], rt[7], rt[8], tr.t.z,
    ];
    let name = format!("P{n}");
    let camera = c
        .camera(&name, width, height)
        .map_err(|m| Error::input(calib.path, m.to_string()))?;
    let (r, t) = c
        .cam_from_velo(&name)
        .map_err(|m| Error::input(calib.path, m.to_string()))?;
    Ok(RigCamera {
        camera,
        rotation: Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&r.concat())),
        translation: Vector3::from(t),
        notes: file.notes,
    })
}

/// Camera `n` (0–3) of a KITTI raw recording day: `calib_cam_to_cam.txt` (`R_rect_00`,
/// `P_rect_0N`, `S_rect_0N`) and `calib_velo_to_cam.txt` (`R`, `T`). Velodyne → rectified camera
/// N: `R = R_rect_00 · R_velo`, `t = R_rect_00 · T + K⁻¹ · P_rect_0N[:, 3]`.
pub fn raw(cam_to_cam: Source, velo_to_cam: Source, n: u8) -> Result<RigCamera> {
    let mut cc = KeyFile::parse(cam_to_cam)?;
    let mut vc = KeyFile::parse(velo_to_cam)?;
    let size = cc.size(&format!("S_rect_0{n}"))?;
    let (camera, b) = pinhole(&cc, &format!("P_rect_0{n}"), size)?;
    let r_rect = cc.rotation("R_rect_00")?;
    let r = vc.rotation("R")?;
    let t = Vector3::from(vc.numbers::<3>("T")?);
    let mut notes = cc.notes;
    notes.append(&mut vc.notes);
    Ok(RigCamera {
        camera,
        rotation: r_rect * r,
        translation: r_rect * t + b,
        notes,
    })
}

/// The files of KITTI-360's `calibration/` a camera needs.
#[derive(Debug, Clone, Copy)]
pub struct Kitti360Files<'a> {
    /// `calib_cam_to_velo.txt`: camera 00 → Velodyne, 12 numbers (3×4, row-major).
    pub cam_to_velo: Source<'a>,
    /// `calib_cam_to_pose.txt`: `image_0N:` camera N → vehicle, 3×4 each (cameras 01–03).
    pub cam_to_pose: Option<Source<'a>>,
    /// `perspective.txt`: `R_rect_0N`, `P_rect_0N`, `S_rect_0N` (cameras 00, 01).
    pub perspective: Option<Source<'a>>,
    /// `image_0N.yaml`: the fisheye's MEI intrinsics (cameras 02, 03).
    pub fisheye: Option<Source<'a>>,
}

/// Camera `n` (0–3) of KITTI-360 (see the module documentation for the chain).
pub fn kitti360(f: Kitti360Files, n: u8, tangential: FisheyeTangential) -> Result<RigCamera> {
    let missing = |what: &str| {
        Error::from(CameraError::Kitti360Missing {
            camera: n,
            what: what.to_string(),
        })
    };
    let (velo_from_cam0, mut notes) = velo_from_cam0(f.cam_to_velo)?;
    let velo_from_cam = if n == 0 {
        velo_from_cam0
    } else {
        let src = f
            .cam_to_pose
            .ok_or_else(|| missing("calib_cam_to_pose.txt"))?;
        let mut cp = KeyFile::parse(src)?;
        let pose_from_cam0 = cp.rigid("image_00")?;
        let pose_from_cam = cp.rigid(&format!("image_0{n}"))?;
        notes.append(&mut cp.notes);
        velo_from_cam0
            .after(&pose_from_cam0.inverse())
            .after(&pose_from_cam)
    };
    let cam_from_velo = velo_from_cam.inverse();
    match n {
        0 | 1 => {
            let src = f.perspective.ok_or_else(|| missing("perspective.txt"))?;
            let mut p = KeyFile::parse(src)?;
            let size = p.size(&format!("S_rect_0{n}"))?;
            let (camera, _) = pinhole(&p, &format!("P_rect_0{n}"), size)?;
            let r_rect = p.rotation(&format!("R_rect_0{n}"))?;
            notes.append(&mut p.notes);
            Ok(RigCamera {
                camera,
                rotation: r_rect * cam_from_velo.r,
                translation: r_rect * cam_from_velo.t,
                notes,
            })
        }
        2 | 3 => {
            let src = f
                .fisheye
                .ok_or_else(|| missing(&format!("image_0{n}.yaml")))?;
            let mut camera = parse_camera(src.text, src.path)?;
            match &mut camera {
                Camera::Mei(m) => {
                    if tangential == FisheyeTangential::Drop {
                        m.p1 = 0.0;
                        m.p2 = 0.0;
                    }
                }
                Camera::Equidistant(_) => {
                    return Err(Error::input(
                        src.path,
                        "not a MEI camera (KITTI-360's fisheyes are model_type: MEI)",
                    ))
                }
            }
            Ok(RigCamera {
                camera,
                rotation: cam_from_velo.r,
                translation: cam_from_velo.t,
                notes,
            })
        }
        _ => Err(CameraError::Kitti360Camera { camera: n }.into()),
    }
}

/// KITTI-360's Velodyne → vehicle ("pose") transform, `T_cam00→pose · T_cam00→velo⁻¹`, from
/// `calib_cam_to_velo.txt` and the `image_00` row of `calib_cam_to_pose.txt`: a scan point `X` is
/// in the world frame at `pose · (R·X + t)`, `pose` a row of `poses/poses.txt`. Returns `(R, t)`
/// and the notes of any rotation re-orthonormalised.
pub fn kitti360_velo_to_pose(
    cam_to_velo: Source,
    cam_to_pose: Source,
) -> Result<(Rotation3<f64>, Vector3<f64>, Vec<String>)> {
    let (velo_from_cam0, mut notes) = velo_from_cam0(cam_to_velo)?;
    let mut cp = KeyFile::parse(cam_to_pose)?;
    let pose_from_cam0 = cp.rigid("image_00")?;
    let pose_from_velo = pose_from_cam0.after(&velo_from_cam0.inverse());
    notes.append(&mut cp.notes);
    Ok((pose_from_velo.r, pose_from_velo.t, notes))
}

/// Camera 00 → Velodyne from `calib_cam_to_velo.txt`, and its notes.
fn velo_from_cam0(cam_to_velo: Source) -> Result<(Rigid, Vec<String>)> {
    // calib_cam_to_velo.txt has no key: its twelve numbers are the file.
    let mut cv = KeyFile {
        path: cam_to_velo.path,
        entries: vec![("T_cam00_to_velo", cam_to_velo.text)],
        notes: Vec::new(),
    };
    let r = cv.rigid("T_cam00_to_velo")?;
    Ok((r, cv.notes))
}

fn row_major(r: &Rotation3<f64>) -> [f64; 9] {
    let m = r.matrix();
    [
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;

    const CAM_TO_CAM: &str = "calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_00: 1.392000e+03 5.120000e+02
R_rect_00: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 4.351614e-03 9.999631e-01
P_rect_00: 7.215377e+02 0.000000e+00 6.095593e+02 0.000000e+00 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_rect_02: 1.242000e+03 3.750000e+02
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
";
    const VELO_TO_CAM: &str = "calib_time: 15-Mar-2012 11:37:16
R: 7.533745e-03 -9.999714e-01 -6.166020e-04 1.480249e-02 7.280733e-04 -9.998902e-01 9.998621e-01 7.523790e-03 1.480755e-02
T: -4.069766e-03 -7.631618e-02 -2.717806e-01
delta_f: 0.000000e+00 0.000000e+00
";

    fn src<'a>(name: &'a str, text: &'a str) -> Source<'a> {
        Source {
            path: Path::new(name),
            text,
        }
    }

    #[test]
    fn raw_camera_02_is_p_rect_r_rect_velo_element_by_element() {
        let r = raw(
            src("calib_cam_to_cam.txt", CAM_TO_CAM),
            src("calib_velo_to_cam.txt", VELO_TO_CAM),
            2,
        )
        .unwrap();
        assert_eq!((r.camera.width(), r.camera.height()), (1242, 375));
        assert!(r.notes.is_empty(), "{:?}", r.notes);
        let num = |t: &str, k: &str| -> Vec<f64> {
            t.lines()
                .find_map(|l| l.strip_prefix(&format!("{k}:")))
                .unwrap()
                .split_whitespace()
                .map(|v| v.parse().unwrap())
                .collect()
        };
        let (p, r0, rv, tv) = (
            num(CAM_TO_CAM, "P_rect_02"),
            num(CAM_TO_CAM, "R_rect_00"),
            num(VELO_TO_CAM, "R"),
            num(VELO_TO_CAM, "T"),
        );
        for x in [[10.0, 1.0, -1.5], [30.0, -8.0, 0.4], [6.0, 2.5, -1.7]] {
            let v: Vec<f64> = (0..3)
                .map(|i| (0..3).map(|j| rv[3 * i + j] * x[j]).sum::<f64>() + tv[i])
                .collect();
            let w: Vec<f64> = (0..3)
                .map(|i| (0..3).map(|j| r0[3 * i + j] * v[j]).sum())
                .collect();
            let h: Vec<f64> = (0..3)
                .map(|i| (0..3).map(|j| p[4 * i + j] * w[j]).sum::<f64>() + p[4 * i + 3])
                .collect();
            let xc = r.rotation * Vector3::from(x) + r.translation;
            let px = r.camera.project(&xc).unwrap();
            // KITTI's matrices are rotations to their 7 printed digits: ~1e-3 px at most.
            assert!(
                (px.x - h[0] / h[2]).abs() < 5e-3 && (px.y - h[1] / h[2]).abs() < 5e-3,
                "{px:?} vs {:?}",
                (h[0] / h[2], h[1] / h[2])
            );
        }
    }

    #[test]
    fn raw_errors_name_the_file_and_key() {
        let go = |cc: &str, vc: &str, n| {
            raw(
                src("calib_cam_to_cam.txt", cc),
                src("calib_velo_to_cam.txt", vc),
                n,
            )
            .unwrap_err()
            .to_string()
        };
        let e = go(CAM_TO_CAM, VELO_TO_CAM, 1);
        assert!(
            e.starts_with("calib_cam_to_cam.txt: missing key S_rect_01 (has calib_time"),
            "{e}"
        );
        let e = go(
            CAM_TO_CAM,
            &VELO_TO_CAM.replace("T: -4.069766e-03 ", "T: "),
            2,
        );
        assert_eq!(e, "calib_velo_to_cam.txt: T: expected 3 numbers, found 2");
        let e = go(
            &CAM_TO_CAM.replace("R_rect_00: 9.999239e-01", "R_rect_00: 9.989239e-01"),
            VELO_TO_CAM,
            2,
        );
        assert!(
            e.starts_with("calib_cam_to_cam.txt: R_rect_00: not a rotation"),
            "{e}"
        );
        let e = go(CAM_TO_CAM, "R 1 0 0\n", 2);
        assert_eq!(e, "calib_velo_to_cam.txt: line 1: expected KEY: values");
        let e = go(&CAM_TO_CAM.replace("1.242000e+03", "nan"), VELO_TO_CAM, 2);
        assert!(
            e.contains("S_rect_02: \"nan\" is not a finite number"),
            "{e}"
        );
    }
}
