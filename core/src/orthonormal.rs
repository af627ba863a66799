//! Rotations read from files: pose files (`rotation_cam_from_map`) and calibration files (KITTI's
//! `R_rect_00`, `Tr_velo_to_cam`, KITTI-360's `calib_cam_to_velo.txt`, …) print their matrices
//! with a few decimals, so what they hold is a rotation only to that precision. KITTI-360's
//! official `R_rect_00` (six decimals) is 1.7e-6 from orthonormal.
//!
//! One rule for all of them, measured as the Frobenius norm `|RᵀR − I|` (with `det R > 0`):
//! - up to [`SILENT_TOL`] (1e-6): a rotation to printed precision or f64 round-off; projected onto
//!   the nearest rotation without a word;
//! - up to [`ACCEPT_TOL`] (1e-4): accepted and projected onto the nearest rotation (the
//!   orthogonal polar factor, by SVD), and the reader says so once ([`ReadRotation::note`]);
//! - beyond, or `det R ≤ 0`: not a rotation (a transposed, mistyped or scaled matrix): a one-line
//!   error naming the file and field.

use nalgebra::{Matrix3, Rotation3};
use std::path::Path;

/// At or below this `|RᵀR − I|` a matrix is a rotation to its printed precision: projected
/// silently.
pub const SILENT_TOL: f64 = 1e-6;
/// Largest `|RᵀR − I|` accepted (and projected onto the nearest rotation, with a note).
pub const ACCEPT_TOL: f64 = 1e-4;

/// A matrix read from a file, as a rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadRotation {
    /// The nearest rotation (the matrix itself, bit for bit, when it is orthonormal to 1e-12).
    pub rotation: Rotation3<f64>,
    /// `|RᵀR − I|` of the matrix as read (Frobenius norm).
    pub deviation: f64,
}

impl ReadRotation {
    /// Whether the reader should say that it re-orthonormalised the matrix (the deviation is
    /// above [`SILENT_TOL`]).
    pub fn reorthonormalised(&self) -> bool {
        self.deviation > SILENT_TOL
    }

    /// The one line that says so (`FILE: FIELD re-orthonormalised …`), or `None` for a matrix
    /// that is a rotation to printed precision.
    pub fn note(&self, file: &Path, field: &str) -> Option<String> {
        self.reorthonormalised().then(|| {
            format!(
                "{}: {field} re-orthonormalised (|RᵀR−I| = {:.2e} ≤ {ACCEPT_TOL:.0e}: projected onto the nearest rotation)",
                file.display(),
                self.deviation
            )
        })
    }
}

/// `|RᵀR − I|` (Frobenius) of `m`.
pub fn deviation(m: &Matrix3<f64>) -> f64 {
    (m.transpose() * m - Matrix3::identity()).norm()
}

/// A matrix read from a file that is not a rotation under the rule of this module. Renders as
/// `[FIELD: ]not a rotation (|RᵀR−I| = …, det = …; accepted up to 1e-4 with det > 0)`: the
/// caller prefixes the file (and the field, when [`NotARotation::field`] is `None`).
#[derive(Debug, Clone, PartialEq)]
pub struct NotARotation {
    /// The field the matrix was read from, when the reader named it.
    pub field: Option<String>,
    /// `|RᵀR − I|` of the matrix (Frobenius norm).
    pub deviation: f64,
    /// Its determinant.
    pub det: f64,
}

impl std::fmt::Display for NotARotation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(field) = &self.field {
            write!(f, "{field}: ")?;
        }
        let (dev, det) = (self.deviation, self.det);
        write!(
            f,
            "not a rotation (|RᵀR−I| = {dev:.2e}, det = {det:.4}; accepted up to {ACCEPT_TOL:.0e} with det > 0)"
        )
    }
}

impl std::error::Error for NotARotation {}

/// `m` as a rotation under the rule of this module. The error names no field: the caller
/// prefixes the file and field.
pub fn rotation_from_file(m: &Matrix3<f64>) -> Result<ReadRotation, NotARotation> {
    let dev = deviation(m);
    let det = m.determinant();
    if !(dev <= ACCEPT_TOL && det > 0.0) {
        return Err(NotARotation {
            field: None,
            deviation: dev,
            det,
        });
    }
    Ok(ReadRotation {
        rotation: nearest_rotation(m),
        deviation: dev,
    })
}

/// Like [`rotation_from_file`] for a row-major 3×3, with the error naming `field`.
pub fn rotation_rows(rows: &[f64; 9], field: &str) -> Result<ReadRotation, NotARotation> {
    rotation_from_file(&Matrix3::from_row_slice(rows)).map_err(|e| NotARotation {
        field: Some(field.to_string()),
        ..e
    })
}

/// The rotation nearest to `m` in the Frobenius norm (the orthogonal factor of its polar
/// decomposition, `U · diag(1, 1, det(U Vᵀ)) · Vᵀ` from `m = U Σ Vᵀ`). A matrix already orthonormal
/// to 1e-12 is returned bit for bit (UTM-sized translations turn a 1e-12 rotation change into
/// micrometres of centre shift).
pub fn nearest_rotation(m: &Matrix3<f64>) -> Rotation3<f64> {
    if deviation(m) < 1e-12 {
        return Rotation3::from_matrix_unchecked(*m);
    }
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        // nalgebra computes both factors when asked; keep a rotation all the same.
        return Rotation3::from_matrix_eps(m, 1e-15, 0, Rotation3::identity());
    };
    let s = (u * vt).determinant().signum();
    let d = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, s));
    Rotation3::from_matrix_unchecked(u * d * vt)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// KITTI-360's official `R_rect_00` as `calibration/perspective.txt` prints it.
    const KITTI360_R_RECT_00: [f64; 9] = [
        0.999974, -0.007141, -0.000089, 0.007141, 0.999969, -0.003247, 0.000112, 0.003247, 0.999995,
    ];

    #[test]
    fn six_decimal_rotation_is_accepted_with_a_note_and_projected() {
        let r = rotation_rows(&KITTI360_R_RECT_00, "R_rect_00").unwrap();
        assert!((1.6e-6..1.8e-6).contains(&r.deviation), "{}", r.deviation);
        let note = r.note(Path::new("perspective.txt"), "R_rect_00").unwrap();
        assert!(
            note.starts_with("perspective.txt: R_rect_00 re-orthonormalised (|RᵀR−I| = 1.")
                && !note.contains('\n'),
            "{note}"
        );
        let q = r.rotation.matrix();
        assert!(deviation(q) < 1e-14);
        // The nearest rotation moves no entry by more than the printed precision.
        let m = Matrix3::from_row_slice(&KITTI360_R_RECT_00);
        assert!((q - m).amax() < 1e-6, "{}", (q - m).amax());
        // It is nearer than any other: a small extra turn only moves it further away.
        let turn = Rotation3::from_euler_angles(1e-4, -2e-4, 3e-4);
        assert!((q - m).norm() < ((r.rotation * turn).matrix() - m).norm());
    }

    #[test]
    fn beyond_1e_4_or_a_reflection_is_refused() {
        let mut off = KITTI360_R_RECT_00;
        off[0] += 1e-3;
        let e = rotation_rows(&off, "R_rect_00").unwrap_err().to_string();
        assert!(
            e.starts_with("R_rect_00: not a rotation (|RᵀR−I| = 2.0") && !e.contains('\n'),
            "{e}"
        );
        let flip = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0];
        assert!(rotation_rows(&flip, "R")
            .unwrap_err()
            .to_string()
            .contains("det = -1"));
    }

    #[test]
    fn an_exact_rotation_is_kept_bit_for_bit_and_silent() {
        let r = Rotation3::from_euler_angles(0.3, -0.2, 1.1);
        let got = rotation_from_file(r.matrix()).unwrap();
        assert_eq!(got.rotation, r);
        assert_eq!(got.note(Path::new("p.json"), "rotation_cam_from_map"), None);
        // Seven printed digits (KITTI's object benchmark): projected, but silently.
        let m = r.matrix().map(|v| (v * 1e7).round() / 1e7);
        let got = rotation_from_file(&m).unwrap();
        assert!(got.deviation < SILENT_TOL && !got.reorthonormalised());
        assert!(deviation(got.rotation.matrix()) < 1e-14);
    }
}
