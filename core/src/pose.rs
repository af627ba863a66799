//! Rigid transforms typed by the frames they connect, so that `world→camera` is a type.
//!
//! Conventions (docs/interfaces.md, "Frames and conventions"): map frame W = projected CRS (x east, y north, z up); camera frame C =
//! OpenCV optical (x right, y down, z forward). A [`CamFromMap`] maps `X_c = R·X_w + t`.
//!
//! Yaw/pitch/roll are defined relative to a *nadir* camera whose image x axis points east and whose
//! image "up" (−y) points north: `R_map_from_cam = Rz(yaw)·Ry(pitch)·Rx(roll)·N`, `N = diag(1,−1,−1)`.
//! So yaw is a rotation about the map's up axis, and yaw = pitch = roll = 0 is a north-up nadir view.

use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::marker::PhantomData;

/// Marker: the map frame W (tile CRS, metres; possibly origin-shifted, see [`crate::map`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Map;
/// Marker: the camera's OpenCV optical frame C.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cam;

/// A rigid transform taking coordinates in frame `From` to frame `To`: `x_to = R·x_from + t`.
#[derive(Debug)]
pub struct Isometry<To, From> {
    /// Rotation `R` (To ← From).
    pub rotation: Rotation3<f64>,
    /// Translation `t`, expressed in `To`.
    pub translation: Vector3<f64>,
    _frames: PhantomData<(To, From)>,
}

// Manual impls: derive would wrongly require the marker types to be Clone/PartialEq.
impl<To, From> Clone for Isometry<To, From> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<To, From> Copy for Isometry<To, From> {}
impl<To, From> PartialEq for Isometry<To, From> {
    fn eq(&self, o: &Self) -> bool {
        self.rotation == o.rotation && self.translation == o.translation
    }
}

/// World(map)→camera pose, the seed's `[ᶜR_W, ᶜt_W]`.
pub type CamFromMap = Isometry<Cam, Map>;
/// The fixed rotation from a north-up nadir camera's optical frame to the map frame.
pub(crate) fn nadir() -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0))
}

impl<To, From> Isometry<To, From> {
    /// Build from rotation and translation.
    pub(crate) fn new(rotation: Rotation3<f64>, translation: Vector3<f64>) -> Self {
        Isometry {
            rotation,
            translation,
            _frames: PhantomData,
        }
    }

    /// Map a point from `From` into `To`.
    #[inline]
    pub fn transform(&self, p: &Point3<f64>) -> Point3<f64> {
        self.rotation * p + self.translation
    }

    /// Rotate a direction (no translation).
    #[inline]
    pub fn rotate(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * v
    }

    /// The inverse transform (`From` ← `To`).
    pub fn inverse(&self) -> Isometry<From, To> {
        let r_inv = self.rotation.inverse();
        Isometry::new(r_inv, -(r_inv * self.translation))
    }

    #[cfg(test)]
    /// Compose: `self ∘ other` maps `Mid`-less chains, `To ← From ← Other`.
    pub(crate) fn compose<Other>(&self, other: &Isometry<From, Other>) -> Isometry<To, Other> {
        Isometry::new(
            self.rotation * other.rotation,
            self.rotation * other.translation + self.translation,
        )
    }
}

impl CamFromMap {
    /// Camera centre in the map frame, `c = −Rᵀ t`.
    pub fn center(&self) -> Point3<f64> {
        Point3::from(-(self.rotation.inverse() * self.translation))
    }

    /// Build from the camera centre (map frame) and `R_cam_from_map`.
    pub fn from_center(rotation: Rotation3<f64>, center: &Point3<f64>) -> Self {
        Self::new(rotation, -(rotation * center.coords))
    }

    /// Build from camera centre and yaw/pitch/roll in radians (see the module docs).
    pub fn from_center_ypr(center: &Point3<f64>, yaw: f64, pitch: f64, roll: f64) -> Self {
        let map_from_cam = Rotation3::from_euler_angles(roll, pitch, yaw) * nadir();
        Self::from_center(map_from_cam.inverse(), center)
    }

    /// Yaw, pitch, roll in radians (see the module docs).
    pub fn yaw_pitch_roll(&self) -> (f64, f64, f64) {
        let body = self.rotation.inverse() * nadir().inverse();
        let (roll, pitch, yaw) = body.euler_angles();
        (yaw, pitch, roll)
    }

    /// The same pose rotated by `dyaw` radians about the map's up axis through the camera centre,
    /// then with its centre moved by `dc` (map frame). This is the refinement's search move.
    pub fn perturbed(&self, dc: &Vector3<f64>, dyaw: f64) -> Self {
        let c = self.center() + dc;
        let map_from_cam =
            Rotation3::from_axis_angle(&Vector3::z_axis(), dyaw) * self.rotation.inverse();
        Self::from_center(map_from_cam.inverse(), &c)
    }

    /// OpenCV rotation vector (axis·angle) of `R_cam_from_map`.
    pub(crate) fn rvec(&self) -> Vector3<f64> {
        self.rotation.scaled_axis()
    }

    /// Quaternion of `R_map_from_cam`, in (x, y, z, w) order.
    pub(crate) fn quaternion_map_from_cam_xyzw(&self) -> [f64; 4] {
        let q = UnitQuaternion::from_rotation_matrix(&self.rotation.inverse());
        [q.i, q.j, q.k, q.w]
    }

    /// Row-major 3×3 rotation `R_cam_from_map`.
    pub(crate) fn rotation_rows(&self) -> [[f64; 3]; 3] {
        let m = self.rotation.matrix();
        [
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ]
    }

    /// Build from a row-major rotation (re-orthonormalised) and a translation.
    pub fn from_rows(rows: [[f64; 3]; 3], t: [f64; 3]) -> Self {
        let m = Matrix3::new(
            rows[0][0], rows[0][1], rows[0][2], rows[1][0], rows[1][1], rows[1][2], rows[2][0],
            rows[2][1], rows[2][2],
        );
        // Keep an already-orthonormal matrix bit-exact (UTM-sized translations turn a 1e-12
        // rotation change into micrometres of centre shift); project anything else onto SO(3).
        let r = if (m.transpose() * m - Matrix3::identity()).norm() < 1e-12 {
            Rotation3::from_matrix_unchecked(m)
        } else {
            Rotation3::from_matrix_eps(&m, 1e-15, 0, Rotation3::identity())
        };
        Self::new(r, Vector3::new(t[0], t[1], t[2]))
    }
}

/// `a − b` wrapped to [−π, π): the signed difference of two yaw angles, radians.
pub fn angle_difference(a: f64, b: f64) -> f64 {
    (a - b + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// Offsets of `to` from `from`: camera-centre difference x, y, z (map frame, m), then the yaw,
/// pitch and roll differences (`to − from`, wrapped to [−180°, 180°), degrees).
pub fn offsets_between(from: &CamFromMap, to: &CamFromMap) -> [f64; 6] {
    let d = to.center() - from.center();
    let (ya, pa, ra) = from.yaw_pitch_roll();
    let (yb, pb, rb) = to.yaw_pitch_roll();
    let deg = |b: f64, a: f64| angle_difference(b, a).to_degrees();
    [d.x, d.y, d.z, deg(yb, ya), deg(pb, pa), deg(rb, ra)]
}

/// Angle in radians between two rotations. Goes through a quaternion because
/// `Rotation3::angle` takes `acos` of a trace that rounding can push past 3 (→ NaN).
pub fn rotation_angle_between(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    UnitQuaternion::from_rotation_matrix(&(a.inverse() * b)).angle()
}

/// Marginal σ per axis: metres for x, y, z; degrees for the angles (∞ where there is no peak).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sigma {
    /// Map x (m).
    pub x: f64,
    /// Map y (m).
    pub y: f64,
    /// Height (m).
    pub z: f64,
    /// Yaw (deg).
    pub yaw: f64,
    /// Pitch (deg), when estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pitch: Option<f64>,
    /// Roll (deg), when estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roll: Option<f64>,
}

impl Sigma {
    /// From a σ per axis name (x..yaw 0 where absent, the tilts absent).
    pub(crate) fn by_axis(g: impl Fn(&str) -> Option<f64>) -> Self {
        Sigma {
            x: g("x").unwrap_or(0.0),
            y: g("y").unwrap_or(0.0),
            z: g("z").unwrap_or(0.0),
            yaw: g("yaw").unwrap_or(0.0),
            pitch: g("pitch"),
            roll: g("roll"),
        }
    }

    /// One line for people: centimetres and degrees.
    pub fn describe(&self) -> String {
        let mut s = format!(
            "σ x {:.1} cm, y {:.1} cm, z {:.1} cm, yaw {:.3}°",
            100.0 * self.x,
            100.0 * self.y,
            100.0 * self.z,
            self.yaw
        );
        if let Some(p) = self.pitch {
            s += &format!(", pitch {p:.3}°");
        }
        if let Some(r) = self.roll {
            s += &format!(", roll {r:.3}°");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ypr_round_trip_and_center() {
        let c = Point3::new(10.0, -4.0, 8.0);
        let p = CamFromMap::from_center_ypr(&c, 0.7, 0.03, -0.02);
        let (y, pi, r) = p.yaw_pitch_roll();
        assert!((y - 0.7).abs() < 1e-12 && (pi - 0.03).abs() < 1e-12 && (r + 0.02).abs() < 1e-12);
        assert!((p.center() - c).norm() < 1e-12);
        // Nadir camera: the point straight below projects on the optical axis.
        let below = p.transform(&Point3::new(10.0, -4.0, 0.0));
        let nadir =
            CamFromMap::from_center_ypr(&c, 1.0, 0.0, 0.0).transform(&Point3::new(10.0, -4.0, 0.0));
        assert!(nadir.x.abs() < 1e-12 && nadir.y.abs() < 1e-12 && (nadir.z - 8.0).abs() < 1e-12);
        assert!(below.z > 7.9);
    }

    #[test]
    fn north_up_at_zero_yaw() {
        let p = CamFromMap::from_center_ypr(&Point3::new(0.0, 0.0, 10.0), 0.0, 0.0, 0.0);
        let east = p.transform(&Point3::new(1.0, 0.0, 0.0));
        let north = p.transform(&Point3::new(0.0, 1.0, 0.0));
        assert!(east.x > 0.0 && east.y.abs() < 1e-12);
        assert!(north.y < 0.0 && north.x.abs() < 1e-12);
    }

    #[test]
    fn perturbed_yaw_keeps_center_and_adds_yaw() {
        let c = Point3::new(1.0, 2.0, 6.0);
        let p = CamFromMap::from_center_ypr(&c, 0.2, 0.0, 0.0);
        let q = p.perturbed(&Vector3::new(0.5, 0.0, 0.0), 0.1);
        assert!((q.center() - Point3::new(1.5, 2.0, 6.0)).norm() < 1e-12);
        assert!((q.yaw_pitch_roll().0 - 0.3).abs() < 1e-12);
    }

    #[test]
    fn inverse_and_compose() {
        let p = CamFromMap::from_center_ypr(&Point3::new(3.0, 1.0, 5.0), 1.1, 0.05, 0.02);
        let id = p.compose(&p.inverse());
        assert!(id.translation.norm() < 1e-9);
        assert!(rotation_angle_between(&id.rotation, &Rotation3::identity()) < 1e-12);
        let rows = p.rotation_rows();
        let q = CamFromMap::from_rows(rows, p.translation.into());
        assert!(rotation_angle_between(&p.rotation, &q.rotation) < 1e-12);
    }
}
