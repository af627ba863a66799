//! Independent verification of initialization hypotheses by mutual information with the LiDAR map.
//!
//! The initializer's hypotheses come from satellite matching, and its own evidence (PnP inliers)
//! cannot tell a right pose from a self-consistent wrong one: road markings look alike after a
//! half turn, and the fine stage converges to agreeing local matches around whatever pose it starts
//! from (`lab/notebook.md`, "What fails, and why"). The LiDAR ground reflectivity is a second,
//! satellite-independent modality of the same ground, so the MI between it and the fisheye image
//! at a hypothesis is evidence the satellite matching cannot fake.
//!
//! The score is meant to *compare hypotheses of one frame*, so it is built to be comparable
//! across them: both variables are histogram-equalised per evaluation (the marginal entropies are
//! then ≈ log B whatever the exposure or reflectivity calibration, and MI measures only how well
//! one predicts the other), every evaluation uses the same number of points where it can, and the
//! first-order small-sample bias (B−1)²/2N is subtracted so a hypothesis that sees fewer points is
//! not favoured. A PnP pose is off by decimetres and a few tenths of a degree, where MI on a sharp
//! image already drops, so the image is sampled blurred (a mip level of about
//! [`VerifyParams::blur_m`] on the ground) and the score is the best over a small x/y/yaw grid
//! around the hypothesis.

use crate::camera::{Camera, CameraModel};
use crate::localize::init::ground::{focal_px, ground_disc, Mip};
use crate::localize::mi::kernel::{project_points, FastCamera, PoseF32};
use crate::localize::mi::{bin_lut, mutual_information, Binning, JointHist};
use crate::map::{GroundIndex, Tile};
use crate::pose::CamFromMap;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// Settings of [`MiVerifier`].
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyParams {
    /// Bins per variable (both equalised).
    pub bins: usize,
    /// Points per evaluation (a deterministic stride subsample of the visible ones).
    pub points: usize,
    /// Fewest visible points for a score at all.
    pub min_points: usize,
    /// Ground disc used: within this off-nadir angle of the camera, degrees …
    pub max_off_nadir_deg: f64,
    /// … and this radius, metres.
    pub max_radius_m: f64,
    /// Image blur on the ground at nadir, metres (chooses the mip level).
    pub blur_m: f64,
    /// Local grid around a PnP pose ([`MiVerifier::verify`]): x/y half range and step, metres …
    pub xy: (f64, f64),
    /// … yaw half range and step, degrees.
    pub yaw_deg: (f64, f64),
    /// Local grid around a sweep candidate ([`MiVerifier::screen`]): x/y half range and step, m …
    pub screen_xy: (f64, f64),
    /// … yaw half range and step, degrees …
    pub screen_yaw_deg: (f64, f64),
    /// … and points per evaluation (screening ranks dozens of candidates: it must be cheap).
    pub screen_points: usize,
}

impl Default for VerifyParams {
    fn default() -> Self {
        VerifyParams {
            bins: 16,
            points: 4000,
            min_points: 500,
            max_off_nadir_deg: 75.0,
            max_radius_m: 30.0,
            blur_m: 0.15,
            xy: (0.4, 0.2),
            yaw_deg: (2.0, 1.0),
            screen_xy: (0.2, 0.2),
            screen_yaw_deg: (1.5, 1.5),
            screen_points: 2000,
        }
    }
}

/// Step halvings of [`MiVerifier::climb`] (1 m → 0.125 m, 4° → 0.5°).
pub(crate) const CLIMB_HALVINGS: usize = 3;
/// Evaluation budget of one [`MiVerifier::climb`].
pub(crate) const CLIMB_MAX_EVALUATIONS: usize = 400;
/// [`MiVerifier::climb`] stays within this of its start in x and y, metres …
pub(crate) const CLIMB_MAX_XY_M: f64 = 4.0;
/// … and in yaw, degrees (and at least 1 m above the ground).
pub(crate) const CLIMB_MAX_YAW_DEG: f64 = 20.0;

/// A hypothesis' verification score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Verdict {
    /// Bias-corrected MI (nats) at the best pose of the local grid.
    pub mi: f64,
    /// That pose.
    pub pose: CamFromMap,
    /// Points that counted there.
    pub n: usize,
}

/// The LiDAR ground points of one disc, shifted to `origin` in f32 (as the MI kernel's projection
/// takes them: a few µm of rounding at 30 m, against the verifier's 15 cm blur).
#[derive(Debug, Clone, Default)]
struct DiscPoints {
    origin: [f64; 3],
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    refl: Vec<u8>,
}

/// Scores poses by MI between LiDAR reflectivity and the (blurred) image; built once per frame.
pub struct MiVerifier<'a> {
    cam: &'a dyn CameraModel,
    /// `cam` as the MI kernel's f32 projection, when it is the Mei model.
    fast: Option<FastCamera>,
    tile: &'a Tile,
    ground: GroundIndex<'a>,
    mip: Mip,
    focal: f64,
    p: VerifyParams,
}

impl<'a> MiVerifier<'a> {
    /// Prepare for one frame (`image` row-major at the camera's size, as [`crate::localize::init::initialize`]
    /// takes it).
    pub fn new(cam: &'a dyn CameraModel, image: &[u8], tile: &'a Tile, p: VerifyParams) -> Self {
        MiVerifier {
            cam,
            fast: cam
                .as_mei()
                .map(|m| FastCamera::new(&Camera::Mei(m.clone()), 0)),
            tile,
            // Nothing indexed until `for_search_area`: every disc is walked.
            ground: GroundIndex::new(tile, (0.0, 0.0), -1.0),
            mip: Mip::new(image, cam.width() as usize, cam.height() as usize),
            focal: focal_px(cam),
            p,
        }
    }

    /// Index the tile's ground cells that the hypotheses of a search within `radius_m` of
    /// `center` can see (their climbs' reach and the ground discs included): their discs' points
    /// are then counted and picked from per-row counts instead of walked, with the same result.
    /// Without it (or for a disc beyond it) every disc is walked.
    pub fn for_search_area(mut self, center: (f64, f64), radius_m: f64) -> Self {
        let reach = radius_m + CLIMB_MAX_XY_M + self.p.max_radius_m;
        self.ground = GroundIndex::new(self.tile, center, reach);
        self
    }

    /// The settings.
    pub(crate) fn params(&self) -> &VerifyParams {
        &self.p
    }

    /// (reflectivity, gray) of the points of `pts` that `cam` sees from `pose`, the gray sampled
    /// at mip level `level`, through the model's own f64 projection (cameras without a kernel
    /// projection).
    fn pairs<C: CameraModel + ?Sized>(
        &self,
        cam: &C,
        pose: &CamFromMap,
        pts: &DiscPoints,
        level: usize,
    ) -> Vec<(u8, u8)> {
        let mut pairs: Vec<(u8, u8)> = Vec::with_capacity(pts.refl.len());
        let cos_max_theta = cam.max_theta().cos();
        for (i, &r) in pts.refl.iter().enumerate() {
            let p = Point3::new(
                pts.origin[0] + pts.x[i] as f64,
                pts.origin[1] + pts.y[i] as f64,
                pts.origin[2] + pts.z[i] as f64,
            );
            let Ok(px) = cam.project_visible_cos(&pose.transform(&p).coords, cos_max_theta) else {
                continue;
            };
            if let Some(g) = self.mip.sample_level(level, px.x, px.y) {
                pairs.push((r, g.clamp(0.0, 255.0) as u8));
            }
        }
        pairs
    }

    /// [`Self::pairs`] through the MI kernel's f32 projection: all points projected at once
    /// (vectorised), then the seen ones sampled. The projection differs from the f64 model's by
    /// ~10⁻⁴ px, far below the mip level's blur; it was two thirds of a verification's cost.
    fn pairs_fast(
        &self,
        fast: &FastCamera,
        pose: &CamFromMap,
        pts: &DiscPoints,
        level: usize,
    ) -> Vec<(u8, u8)> {
        let n = pts.refl.len();
        let (mut us, mut vs, mut oks) = (vec![0f32; n], vec![0f32; n], vec![false; n]);
        let size = (self.cam.width() as usize, self.cam.height() as usize);
        project_points(
            (&pts.x, &pts.y, &pts.z),
            &PoseF32::new(pose, pts.origin),
            fast,
            size,
            (&mut us, &mut vs, &mut oks),
        );
        let mut pairs: Vec<(u8, u8)> = Vec::with_capacity(n);
        for i in 0..n {
            if !oks[i] {
                continue;
            }
            if let Some(g) = self.mip.sample_level(level, us[i] as f64, vs[i] as f64) {
                pairs.push((pts.refl[i], g.clamp(0.0, 255.0) as u8));
            }
        }
        pairs
    }

    /// Bias-corrected MI at exactly `pose` with the given points (`None` below `min_points`).
    fn mi_at(
        &self,
        pose: &CamFromMap,
        pts: &DiscPoints,
        footprint: f64,
        points: usize,
    ) -> Option<(f64, usize)> {
        let level = self.mip.level(footprint);
        let pairs = match &self.fast {
            Some(fast) => self.pairs_fast(fast, pose, pts, level),
            None => self.pairs(self.cam, pose, pts, level),
        };
        if pairs.len() < self.p.min_points {
            return None;
        }
        // Same count for every evaluation where possible: stride subsample, deterministic.
        let stride = (pairs.len() / points.max(1)).max(1);
        let pairs: Vec<(u8, u8)> = pairs.into_iter().step_by(stride).collect();
        let (mut cr, mut cg) = ([0u64; 256], [0u64; 256]);
        for &(r, g) in &pairs {
            cr[r as usize] += 1;
            cg[g as usize] += 1;
        }
        let b = self.p.bins;
        let (lr, lg) = (
            bin_lut(Binning::Equalized, b, &cr),
            bin_lut(Binning::Equalized, b, &cg),
        );
        let mut h = JointHist::new(b, b);
        let s = h.stride();
        for &(r, g) in &pairs {
            h.counts[lr[r as usize] as usize * s + lg[g as usize] as usize] += 1;
        }
        let n = pairs.len();
        let v = mutual_information(&h, false);
        let bias = ((b - 1) * (b - 1)) as f64 / (2.0 * n as f64);
        Some((v.mi - bias, n))
    }

    /// Verify a hypothesis: the best bias-corrected MI over the local grid around it. `None` when
    /// too few LiDAR points are seen (no evidence either way).
    pub fn verify(&self, pose: &CamFromMap) -> Option<Verdict> {
        self.best_near(pose, self.p.xy, self.p.yaw_deg, self.p.points)
    }

    /// Screen a sweep candidate: as [`Self::verify`] on the grid of
    /// [`VerifyParams::screen_xy`] / [`VerifyParams::screen_yaw_deg`] (a sweep candidate is off by
    /// up to half its sweep steps: 0.2 m, 1.5°, a few % of height) with
    /// [`VerifyParams::screen_points`] points.
    pub fn screen(&self, pose: &CamFromMap) -> Option<Verdict> {
        self.best_near(
            pose,
            self.p.screen_xy,
            self.p.screen_yaw_deg,
            self.p.screen_points,
        )
    }

    /// The camera's height above ground at `c` and the LiDAR ground points of the disc it sees,
    /// thinned by a stride to about `keep` (the projections are the cost, and a few × the
    /// evaluation's point count suffice).
    fn disc_points(&self, c: &Point3<f64>, keep: usize) -> (f64, DiscPoints) {
        let (cam_h, radius) = ground_disc(
            &self.tile.height,
            c,
            self.p.max_off_nadir_deg,
            self.p.max_radius_m,
        );
        // The disc holds ~10⁵ cells and a few thousand are kept: counted and picked from the
        // tile's row counts, not walked.
        let ground = self
            .ground
            .disc_strided((c.x, c.y), radius, |n| (n / keep.max(1)).max(1));
        let mut pts = DiscPoints {
            origin: [c.x, c.y, c.z],
            ..DiscPoints::default()
        };
        for g in ground {
            pts.x.push((g.x - c.x) as f32);
            pts.y.push((g.y - c.y) as f32);
            pts.z.push((g.z - c.z) as f32);
            pts.refl.push(g.reflectivity);
        }
        (cam_h, pts)
    }

    /// Climb the MI from `pose` over x, y, yaw and height: coordinate ascent with steps
    /// (1 m, 4°, 8 % of the height above ground) halved `CLIMB_HALVINGS` times, within
    /// `CLIMB_MAX_XY_M` / `CLIMB_MAX_YAW_DEG` of the start and 1 m above ground, on one fixed
    /// point set (the ground disc seen from `pose`, thinned to 3 × [`VerifyParams::points`]), at most
    /// `CLIMB_MAX_EVALUATIONS` evaluations. For a sweep candidate whose satellite match was too
    /// coarse for the fine stage (1–3 m, 5–15°, a height step off): the LiDAR map pulls it to where
    /// the fine stage can match. `None` when the start sees too few points. Deterministic.
    pub fn climb(&self, pose: &CamFromMap) -> Option<Verdict> {
        let c = pose.center();
        let points = self.p.points;
        let (cam_h, pts) = self.disc_points(&c, 3 * points);
        // One blur for every step: a blur schedule (half the x/y step) climbed fewer simulator
        // candidates into the refinement basin.
        let footprint = self.p.blur_m / cam_h * self.focal;
        let (yaw0, pitch, roll) = pose.yaw_pitch_roll();
        let at = |o: &[f64; 4]| {
            CamFromMap::from_center_ypr(
                &Point3::new(c.x + o[0], c.y + o[1], c.z + o[3]),
                yaw0 + o[2].to_radians(),
                pitch,
                roll,
            )
        };
        let score = |o: &[f64; 4]| self.mi_at(&at(o), &pts, footprint, points);
        let mut best = [0.0; 4];
        let (mut best_mi, mut best_n) = score(&best)?;
        let mut evals = 1;
        let mut step = [1.0, 1.0, 4.0, 0.08 * cam_h];
        for _ in 0..=CLIMB_HALVINGS {
            let mut improved = true;
            while improved && evals < CLIMB_MAX_EVALUATIONS {
                improved = false;
                for axis in 0..4 {
                    for sign in [1.0, -1.0] {
                        let mut o = best;
                        o[axis] += sign * step[axis];
                        // Stay near the start (the sweep's error is a few metres and degrees)
                        // and above the ground.
                        if o[0].abs() > CLIMB_MAX_XY_M
                            || o[1].abs() > CLIMB_MAX_XY_M
                            || o[2].abs() > CLIMB_MAX_YAW_DEG
                            || cam_h + o[3] < 1.0
                            || evals >= CLIMB_MAX_EVALUATIONS
                        {
                            continue;
                        }
                        evals += 1;
                        if let Some((v, n)) = score(&o) {
                            if v > best_mi {
                                (best, best_mi, best_n, improved) = (o, v, n, true);
                            }
                        }
                    }
                }
            }
            for s in &mut step {
                *s /= 2.0;
            }
        }
        Some(Verdict {
            mi: best_mi,
            pose: at(&best),
            n: best_n,
        })
    }

    /// Best bias-corrected MI over the x/y/yaw grid around `pose`.
    fn best_near(
        &self,
        pose: &CamFromMap,
        xy: (f64, f64),
        yaw_deg: (f64, f64),
        points: usize,
    ) -> Option<Verdict> {
        let c = pose.center();
        let (cam_h, pts) = self.disc_points(&c, 3 * points / 2);
        let footprint = self.p.blur_m / cam_h * self.focal;
        let steps = |(half, step): (f64, f64)| -> Vec<f64> {
            let m = if step > 0.0 {
                (half / step).round() as i64
            } else {
                0
            };
            (-m..=m).map(|k| k as f64 * step).collect()
        };
        let (xs, ys) = (steps(xy), steps(yaw_deg));
        let mut cells = Vec::with_capacity(xs.len() * xs.len() * ys.len());
        for &dx in &xs {
            for &dy in &xs {
                for &a in &ys {
                    cells.push((dx, dy, a));
                }
            }
        }
        cells
            .par_iter()
            .map(|&(dx, dy, a)| {
                let q = pose.perturbed(&Vector3::new(dx, dy, 0.0), a.to_radians());
                self.mi_at(&q, &pts, footprint, points)
                    .map(|(mi, n)| Verdict { mi, pose: q, n })
            })
            .collect::<Vec<_>>()
            .into_iter()
            .flatten()
            // First of equal scores: the cell order is fixed, so the result is deterministic.
            .fold(None, |best: Option<Verdict>, v| match best {
                Some(b) if b.mi >= v.mi => Some(b),
                _ => Some(v),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Mei;
    use crate::localize::synth::{render, Texture};
    use crate::map::{Crs, GeoGrid, Raster};

    /// A 400 px fisheye 6 m above a synthetic ground whose LiDAR reflectivity and camera gray are
    /// different (non-monotonic) functions of one texture, as `synth` builds them.
    fn scene() -> (Mei, Vec<u8>, Tile, CamFromMap) {
        let cam = Mei {
            width: 400,
            height: 400,
            fx: 115.0,
            fy: 115.0,
            cx: 200.0,
            cy: 200.0,
            skew: 0.0,
            xi: 1.0,
            k1: -0.02,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        };
        let tex = Texture::new(7);
        let pose = CamFromMap::from_center_ypr(&Point3::new(1.3, -0.7, 6.0), 0.6, 0.0, 0.0);
        let (gray, _) = render(&tex, &cam, &pose, 0.0, 4.0, 1);
        let grid = GeoGrid {
            crs: Crs::Local,
            x0: -40.0,
            y0: 40.0,
            res: 0.2,
            width: 400,
            height: 400,
        };
        let mut refl = Raster::filled(grid, 0u8, None);
        for row in 0..grid.height {
            for col in 0..grid.width {
                let (x, y) = grid.pixel_center(col, row);
                refl.data[row * grid.width + col] =
                    Texture::reflectivity(tex.value(x, y)).round() as u8;
            }
        }
        let tile = Tile {
            id: "synthetic".into(),
            satellite: Some(Raster::filled(grid, [0u8; 3], None)),
            reflectivity: refl,
            height: Raster::filled(grid, 0f32, None),
            control_points: Vec::new(),
        };
        (cam, gray, tile, pose)
    }

    /// The kernel's f32 projection pairs the disc's points with the gray the model's f64
    /// projection gives them: the same points seen, and the same gray but for a rare truncation
    /// across an integer (the sample positions differ by ~10⁻⁴ px).
    #[test]
    fn the_kernel_projection_pairs_as_the_model_does() {
        let (cam, gray, tile, truth) = scene();
        let v = MiVerifier::new(&cam, &gray, &tile, VerifyParams::default());
        let fast = v.fast.expect("a Mei camera has the kernel projection");
        let (cam_h, pts) = v.disc_points(&truth.center(), 20_000);
        assert!(pts.refl.len() > 5_000, "{} points", pts.refl.len());
        for level in [0, v.mip.level(v.p.blur_m / cam_h * v.focal), 3] {
            for q in [truth, truth.perturbed(&Vector3::new(0.3, -0.2, 0.0), 0.4)] {
                let a = v.pairs(&cam, &q, &pts, level);
                let b = v.pairs_fast(&fast, &q, &pts, level);
                let n = a.len().max(b.len());
                assert!(n > 1000, "{n} pairs");
                // The sets may differ by a point on the image's very edge.
                assert!(
                    a.len().abs_diff(b.len()) <= n / 1000,
                    "{} vs {}",
                    a.len(),
                    b.len()
                );
                let same = a.iter().zip(&b).filter(|(x, y)| x == y).count();
                assert!(same * 1000 >= 995 * n, "level {level}: {same} of {n} equal");
            }
        }
    }

    #[test]
    fn true_pose_beats_half_turn_and_displaced_hypotheses() {
        let (cam, gray, tile, truth) = scene();
        let v = MiVerifier::new(&cam, &gray, &tile, VerifyParams::default());
        // A start 0.25 m and 1.5° off, as a PnP pose is: the local grid recovers the peak.
        let near = truth.perturbed(&Vector3::new(0.25, -0.15, 0.0), 1.5f64.to_radians());
        let right = v.verify(&near).expect("enough points").mi;
        let half_turn = truth.perturbed(&Vector3::zeros(), std::f64::consts::PI);
        let wrong = v.verify(&half_turn).expect("enough points").mi;
        let moved = truth.perturbed(&Vector3::new(7.0, 3.0, 0.0), 0.0);
        let elsewhere = v.verify(&moved).expect("enough points").mi;
        assert!(
            right > 2.0 * wrong.max(elsewhere),
            "{right} {wrong} {elsewhere}"
        );
        // Deterministic: the same score twice.
        assert_eq!(v.verify(&near).map(|x| x.mi), Some(right));
    }

    #[test]
    fn climb_pulls_a_coarse_sweep_pose_into_reach() {
        let (cam, gray, tile, truth) = scene();
        let v = MiVerifier::new(&cam, &gray, &tile, VerifyParams::default());
        // As a coarse sweep candidate is off: 0.8 m, 5° and 8 % of the height (the synthetic
        // texture's finest octave is 0.35 m, its basin narrower than the simulator's).
        let start =
            CamFromMap::from_center_ypr(&Point3::new(2.0, -0.3, 5.5), 0.6 + 0.087, 0.0, 0.0);
        let up = v.climb(&start).expect("enough points");
        let (c, t) = (up.pose.center(), truth.center());
        let dyaw = crate::pose::angle_difference(up.pose.yaw_pitch_roll().0, 0.6).to_degrees();
        assert!(
            (c.x - t.x).hypot(c.y - t.y) < 0.3 && (c.z - t.z).abs() < 0.4 && dyaw.abs() < 1.5,
            "climbed to ({:.2}, {:.2}, {:.2}) yaw off {dyaw:.2}°",
            c.x,
            c.y,
            c.z
        );
        let again = v.climb(&start).map(|x| x.mi);
        assert_eq!(again, Some(up.mi), "deterministic");
        assert!(up.mi > v.screen(&start).map_or(0.0, |x| x.mi));
    }

    #[test]
    fn no_points_no_verdict() {
        let (cam, gray, tile, truth) = scene();
        let v = MiVerifier::new(&cam, &gray, &tile, VerifyParams::default());
        let far = truth.perturbed(&Vector3::new(500.0, 0.0, 0.0), 0.0);
        assert!(v.verify(&far).is_none());
        assert!(v.climb(&far).is_none());
    }
}
