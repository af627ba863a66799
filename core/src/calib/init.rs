//! Initial intrinsics and view poses, after Mei & Rives (ICRA 2007): ξ = 1 and no distortion, so
//! that a pixel lifts to a ray in closed form; the generalised focal γ from the board's straight
//! lines; then each view's pose from the homography between the board plane and the lifted rays.
//!
//! The line estimate alone fails on lines through the image centre and on short lines, so it is one
//! candidate among a logarithmic scan of γ; the candidate whose homography poses reproject best
//! (median view RMS) wins. That is what makes the start robust on strongly distorted lenses too.

use super::model::LensModel;
use crate::camera::CameraModel;
use nalgebra::{DMatrix, Matrix3, Point2, Rotation3, SymmetricEigen, Vector3};

/// A view's pose: board point `X` → camera point `R·X + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Pose {
    pub r: Rotation3<f64>,
    pub t: Vector3<f64>,
}

impl Pose {
    /// The board point in the camera frame.
    pub(crate) fn apply(&self, x: &[f64; 3]) -> Vector3<f64> {
        self.r * Vector3::new(x[0], x[1], x[2]) + self.t
    }
}

/// A planar board's own 2-D frame: `q = B·(X − o)` has q.z = 0 for every board point. The first
/// axis follows the first two points, so a grid listed row by row keeps its rows and columns
/// aligned with the frame's axes.
#[derive(Debug, Clone)]
pub(crate) struct Plane {
    b: Matrix3<f64>,
    o: Vector3<f64>,
    /// Board points in plane coordinates.
    pub q: Vec<[f64; 2]>,
}

/// Relative out-of-plane spread above which object points count as not planar.
const PLANARITY_TOL: f64 = 1e-6;

impl Plane {
    /// The frame of a planar point set; `Err` names why there is none.
    pub(super) fn fit(obj: &[[f64; 3]]) -> Result<Plane, super::error::PlaneError> {
        let n = obj.len() as f64;
        let pts: Vec<Vector3<f64>> = obj.iter().map(|p| Vector3::new(p[0], p[1], p[2])).collect();
        let o = pts.iter().sum::<Vector3<f64>>() / n;
        let mut cov = Matrix3::zeros();
        for p in &pts {
            let d = p - o;
            cov += d * d.transpose();
        }
        let eig = SymmetricEigen::new(cov);
        let mut idx = [0usize, 1, 2];
        idx.sort_by(|a, b| eig.eigenvalues[*a].total_cmp(&eig.eigenvalues[*b]));
        let (lmin, lmax) = (eig.eigenvalues[idx[0]], eig.eigenvalues[idx[2]]);
        if !(lmax > 0.0) || eig.eigenvalues[idx[1]] < 1e-12 * lmax {
            return Err(super::error::PlaneError::Collinear);
        }
        if lmin.max(0.0).sqrt() > PLANARITY_TOL * lmax.sqrt() {
            return Err(super::error::PlaneError::NotPlanar);
        }
        let normal: Vector3<f64> = eig.eigenvectors.column(idx[0]).into();
        // First axis: from the first point to the next distinct one, projected into the plane.
        let first = pts
            .iter()
            .map(|p| p - pts[0])
            .map(|d| d - normal * normal.dot(&d))
            .find(|d| d.norm() > 1e-9 * lmax.sqrt())
            .unwrap_or_else(|| eig.eigenvectors.column(idx[2]).into());
        let e1 = first.normalize();
        let e3 = normal;
        let e2 = e3.cross(&e1);
        let b = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]);
        let q = pts
            .iter()
            .map(|p| {
                let v = b * (p - o);
                [v.x, v.y]
            })
            .collect();
        Ok(Plane { b, o, q })
    }

    /// The board's normal in board coordinates.
    pub(crate) fn normal(&self) -> Vector3<f64> {
        self.b.row(2).transpose()
    }

    /// The board pose from a pose of the plane frame (camera point = `rp·q + tp`).
    fn board_pose(&self, rp: Rotation3<f64>, tp: Vector3<f64>) -> Pose {
        let r = Rotation3::from_matrix_unchecked(rp.matrix() * self.b);
        Pose {
            r,
            t: tp - r * self.o,
        }
    }

    /// Straight lines of the grid: points sharing one plane coordinate, 4 or more to a line.
    pub(super) fn lines(&self) -> Vec<Vec<usize>> {
        let mut out = Vec::new();
        let extent = self
            .q
            .iter()
            .map(|q| q[0].abs().max(q[1].abs()))
            .fold(0.0, f64::max);
        let tol = 1e-6 * extent.max(1e-12);
        for axis in 0..2 {
            let mut order: Vec<usize> = (0..self.q.len()).collect();
            order.sort_by(|a, b| self.q[*a][axis].total_cmp(&self.q[*b][axis]));
            let mut group: Vec<usize> = Vec::new();
            for i in order {
                if let Some(&last) = group.last() {
                    if (self.q[i][axis] - self.q[last][axis]).abs() > tol {
                        if group.len() >= 4 {
                            out.push(std::mem::take(&mut group));
                        }
                        group.clear();
                    }
                }
                group.push(i);
            }
            if group.len() >= 4 {
                out.push(group);
            }
        }
        out
    }
}

/// Mei & Rives' generalised focal from one board line seen through a ξ = 1 camera centred at `c`:
/// a pixel lifts to the ray (u′, v′, γ/2 − ρ²/(2γ)) with (u′, v′) = pixel − c, ρ² = u′² + v′², and
/// the rays of a line lie in a plane through the centre, normal n. So
/// [u′, v′, ½, −ρ²/2]·(n1, n2, n3·γ, n3/γ) = 0 for every point; the null vector gives γ² = c3/c4.
pub(crate) fn gamma_from_line(
    image: &[[f64; 2]],
    line: &[usize],
    c: [f64; 2],
    scale: f64,
) -> Option<f64> {
    let mut a = DMatrix::<f64>::zeros(line.len(), 4);
    for (row, &i) in line.iter().enumerate() {
        let (u, v) = ((image[i][0] - c[0]) / scale, (image[i][1] - c[1]) / scale);
        a[(row, 0)] = u;
        a[(row, 1)] = v;
        a[(row, 2)] = 0.5;
        a[(row, 3)] = -0.5 * (u * u + v * v);
    }
    let eig = SymmetricEigen::new(a.transpose() * &a);
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))?;
    let n = eig.eigenvectors.column(imin);
    // A line through the centre (n3 ≈ 0) says nothing about γ.
    let (c3, c4) = (n[2], n[3]);
    if c4.abs() < 1e-9 || c3 / c4 <= 0.0 {
        return None;
    }
    let g = scale * (c3 / c4).sqrt();
    g.is_finite().then_some(g)
}

/// Pose of a plane from its points `q` (plane coordinates) and the rays they were seen along:
/// the DLT homography ray ∝ H·(q, 1), then H = λ[r1 r2 t]. Rays may point backwards (θ > 90°):
/// the sign of λ is chosen so that H·(q, 1) agrees with the rays, not so that z > 0.
pub(crate) fn plane_pose(
    q: &[[f64; 2]],
    rays: &[Vector3<f64>],
) -> Option<(Rotation3<f64>, Vector3<f64>)> {
    if q.len() < 4 {
        return None;
    }
    // Normalise the plane coordinates (Hartley) for conditioning.
    let n = q.len() as f64;
    let (mx, my) = (
        q.iter().map(|p| p[0]).sum::<f64>() / n,
        q.iter().map(|p| p[1]).sum::<f64>() / n,
    );
    let s = q.iter().map(|p| (p[0] - mx).hypot(p[1] - my)).sum::<f64>() / n;
    if !(s > 0.0) {
        return None;
    }
    let k = std::f64::consts::SQRT_2 / s;
    let mut ata = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    for (p, r) in q.iter().zip(rays) {
        let x = [(p[0] - mx) * k, (p[1] - my) * k, 1.0];
        // r × (H x) = 0: rows for the x and y components of the cross product.
        let mut r1 = [0.0; 9];
        let mut r2 = [0.0; 9];
        let mut r3 = [0.0; 9];
        for j in 0..3 {
            // (r × Hx)_0 = r1·(h3·x) − r2·(h2·x), etc., with h_i the rows of H.
            r1[3 + j] = -r.z * x[j];
            r1[6 + j] = r.y * x[j];
            r2[j] = r.z * x[j];
            r2[6 + j] = -r.x * x[j];
            r3[j] = -r.y * x[j];
            r3[3 + j] = r.x * x[j];
        }
        for row in [r1, r2, r3] {
            let v = nalgebra::SVector::<f64, 9>::from_row_slice(&row);
            ata += v * v.transpose();
        }
    }
    let eig = SymmetricEigen::new(ata);
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))?;
    let h = eig.eigenvectors.column(imin);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let t_norm = Matrix3::new(k, 0.0, -k * mx, 0.0, k, -k * my, 0.0, 0.0, 1.0);
    let hm = hn * t_norm;
    let agree: f64 = q
        .iter()
        .zip(rays)
        .map(|(p, r)| r.dot(&(hm * Vector3::new(p[0], p[1], 1.0))))
        .sum();
    let (c1, c2, c3) = (hm.column(0), hm.column(1), hm.column(2));
    let mut lambda = 2.0 / (c1.norm() + c2.norm());
    if agree < 0.0 {
        lambda = -lambda;
    }
    let (r1, r2) = (c1 * lambda, c2 * lambda);
    let m = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut rot = u * vt;
    if rot.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        rot = u2 * vt;
    }
    let t = c3 * lambda;
    (rot.iter().all(|v| v.is_finite()) && t.iter().all(|v| v.is_finite()))
        .then(|| (Rotation3::from_matrix_unchecked(rot), t))
}

/// One view's data as the initialisation sees it.
pub(crate) struct InitView<'a> {
    pub plane: &'a Plane,
    pub image: &'a [[f64; 2]],
}

/// Pose of one view under intrinsics `p`: lift the pixels, homography, decompose.
pub(crate) fn view_pose(
    model: LensModel,
    p: &[f64],
    size: (u32, u32),
    v: &InitView,
) -> Option<Pose> {
    let cam = model.camera(p, size.0, size.1);
    let (mut q, mut rays) = (Vec::new(), Vec::new());
    for (qi, px) in v.plane.q.iter().zip(v.image) {
        if let Ok(r) = cam.unproject(&Point2::new(px[0], px[1])) {
            q.push(*qi);
            rays.push(r.into_inner());
        }
    }
    let (rp, tp) = plane_pose(&q, &rays)?;
    Some(v.plane.board_pose(rp, tp))
}

/// RMS reprojection error (px) of one view under intrinsics `p` and `pose`, `None` if a point
/// does not project.
pub(crate) fn view_rms(
    model: LensModel,
    p: &[f64],
    pose: &Pose,
    obj: &[[f64; 3]],
    image: &[[f64; 2]],
) -> Option<f64> {
    let mut ss = 0.0;
    for (x, uv) in obj.iter().zip(image) {
        let c = pose.apply(x);
        let pr = model.project(p, [c.x, c.y, c.z])?;
        ss += (pr[0] - uv[0]).powi(2) + (pr[1] - uv[1]).powi(2);
    }
    Some((ss / obj.len() as f64).sqrt())
}

/// Number of γ values in the logarithmic scan.
const SCAN_STEPS: usize = 48;
/// Scan range of γ relative to the larger image side.
const SCAN_RANGE: (f64, f64) = (0.05, 2.5);

/// Initial intrinsics: the best of the line-based γ (median over all lines) and a logarithmic scan,
/// judged by the median per-view RMS of the homography poses. Returns the intrinsics and the
/// candidate γ values' provenance for the report.
pub(crate) fn initial_intrinsics(
    model: LensModel,
    size: (u32, u32),
    views: &[InitView],
    objects: &[&[[f64; 3]]],
) -> Option<(Vec<f64>, InitInfo)> {
    let c = [(size.0 as f64 - 1.0) / 2.0, (size.1 as f64 - 1.0) / 2.0];
    let side = size.0.max(size.1) as f64;
    let mut line_gammas: Vec<f64> = views
        .iter()
        .flat_map(|v| {
            v.plane
                .lines()
                .into_iter()
                .filter_map(|l| gamma_from_line(v.image, &l, c, side / 2.0))
                .collect::<Vec<_>>()
        })
        .filter(|g| *g > SCAN_RANGE.0 * side && *g < SCAN_RANGE.1 * side)
        .collect();
    line_gammas.sort_by(f64::total_cmp);
    let line_gamma = (!line_gammas.is_empty()).then(|| line_gammas[line_gammas.len() / 2]);
    let mut candidates: Vec<f64> = (0..SCAN_STEPS)
        .map(|i| {
            let t = i as f64 / (SCAN_STEPS - 1) as f64;
            side * (SCAN_RANGE.0.ln() + t * (SCAN_RANGE.1 / SCAN_RANGE.0).ln()).exp()
        })
        .collect();
    candidates.extend(line_gamma);
    let score = |g: f64| -> f64 {
        let p = model.initial(g, c);
        let mut rms: Vec<f64> = views
            .iter()
            .zip(objects)
            .map(|(v, obj)| {
                view_pose(model, &p, size, v)
                    .and_then(|pose| view_rms(model, &p, &pose, obj, v.image))
                    .unwrap_or(f64::INFINITY)
            })
            .collect();
        rms.sort_by(f64::total_cmp);
        rms[rms.len() / 2]
    };
    let (best, best_score) = candidates
        .iter()
        .map(|g| (*g, score(*g)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    if !best_score.is_finite() {
        return None;
    }
    Some((
        model.initial(best, c),
        InitInfo {
            line_gamma,
            lines: line_gammas.len(),
            gamma: best,
            median_view_rms: best_score,
        },
    ))
}

/// How the start was found (for the report).
#[derive(Debug, Clone, serde::Serialize)]
pub struct InitInfo {
    /// Median generalised focal over the board lines (Mei & Rives), px.
    pub line_gamma: Option<f64>,
    /// Number of lines that gave a γ.
    pub lines: usize,
    /// The γ the optimisation started from, px.
    pub gamma: f64,
    /// Median per-view RMS of the start, px.
    pub median_view_rms: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_pose_recovers_a_pose_with_backward_rays() {
        // Board nearly in the x–z plane, straddling z = 0.
        let r = Rotation3::from_euler_angles(1.5, 0.1, 0.2);
        let t = Vector3::new(-0.25, 0.3, -0.2);
        let q: Vec<[f64; 2]> = (0..6)
            .flat_map(|i| (0..5).map(move |j| [i as f64 * 0.1, j as f64 * 0.1]))
            .collect();
        let rays: Vec<Vector3<f64>> = q
            .iter()
            .map(|p| (r * Vector3::new(p[0], p[1], 0.0) + t).normalize())
            .collect();
        assert!(rays.iter().any(|r| r.z < 0.0), "some rays beyond 90°");
        let (rr, tt) = plane_pose(&q, &rays).unwrap();
        let dr = (rr.matrix() - r.matrix()).norm();
        assert!(dr < 1e-9, "{dr}");
        assert!((tt - t).norm() < 1e-9);
    }

    #[test]
    fn line_gamma_is_exact_without_distortion() {
        // A ξ = 1 camera, γ = 500, looking at a line in 3-D that does not pass the centre.
        let (g, c) = (500.0, [640.0, 480.0]);
        let p = LensModel::Mei.initial(g, c);
        let image: Vec<[f64; 2]> = (0..8)
            .map(|i| {
                let x = [-0.8 + 0.25 * i as f64, 0.3, 0.5 + 0.05 * i as f64];
                LensModel::Mei.project(&p, x).unwrap()
            })
            .collect();
        let line: Vec<usize> = (0..8).collect();
        let got = gamma_from_line(&image, &line, c, 640.0).unwrap();
        assert!((got - g).abs() < 1e-6, "{got}");
    }
}
