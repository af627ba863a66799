//! Initialization from a GPS prior alone (the seed's step 1), learning-free: the coarse
//! stage's hypotheses ([`crate::localize::init::coarse`]), then per hypothesis the fine stage — ground patches
//! matched against the satellite, PnP + RANSAC on their bearings — judged on the LiDAR MI
//! ([`crate::localize::init::verify`]) when enabled.

use crate::camera::{CameraModel, PreparedMei};
use crate::localize::frame::{Frame, MapLayers};
use crate::localize::init::coarse::{coarse_candidates_mip, satellite_gray, CoarseParams};
use crate::localize::init::ground::{focal_px, ground_disc, height_at, Mip};
use crate::localize::init::sweep::{orientation_field, Candidate, Field, GrayF32};
use crate::localize::init::verify::{MiVerifier, Verdict};
use crate::map::Raster;
use crate::stage::StageName;
use rayon::prelude::*;

/// Where initialization looks: within `radius_m` of the prior position `center` (map CRS, metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchArea {
    /// The prior position.
    pub center: (f64, f64),
    /// Search radius, metres.
    pub radius_m: f64,
}

/// Settings of the fine stage (local patch matching → PnP).
#[derive(Debug, Clone, PartialEq)]
pub struct FineParams {
    /// Anchor spacing on the ground, metres.
    pub anchor_spacing_m: f64,
    /// Largest off-nadir angle of an anchor, degrees (oblique ground is smeared in the fisheye).
    pub max_off_nadir_deg: f64,
    /// Largest anchor distance from the nadir point, metres.
    pub max_radius_m: f64,
    /// Per iteration: (patch half-size m, search half-size m, resolution m/px, PnP inlier
    /// tolerance in metres on the ground at nadir distance — converted to pixels for the current
    /// height, because a fixed pixel threshold is metres on a 4 m pole and centimetres on a 15 m one).
    pub iterations: Vec<(f64, f64, f64, f64)>,
    /// Minimum correlation of an accepted patch match.
    pub min_score: f64,
    /// PnP / RANSAC settings (the threshold is overridden per iteration).
    pub pnp: crate::localize::pnp::PnpParams,
    /// Stop trying sweep candidates once one's PnP has at least this many inliers with ≥ 2/3 of
    /// its patch matches agreeing; `None` tries every candidate and keeps the most inliers.
    /// With a verifier ([`initialize`]'s `verifier`) the stop also needs the MI evidence, see there.
    pub convincing_inliers: Option<usize>,
    /// Independent verification of hypotheses against the LiDAR map, when [`initialize`] is given
    /// a verifier: how long a sweep list it screens and how many fine stages it may run.
    pub verify: VerifySchedule,
}

/// How [`initialize`] uses an [`MiVerifier`] (see there).
#[derive(Debug, Clone, PartialEq)]
pub struct VerifySchedule {
    /// Whether the pipeline verifies at all (off = the satellite-only initializer, for
    /// comparisons and for maps without usable reflectivity).
    pub enabled: bool,
    /// Sweep candidates screened by MI (the sweep list is lengthened to this; the satellite
    /// ranking alone often has no correct candidate in its top 10 on low poles).
    pub shortlist: usize,
    /// Most fine stages (satellite matching + PnP) run, in decreasing screening MI.
    pub max_fine: usize,
    /// A tried candidate stands for its sweep pose rather than its PnP pose only if the sweep
    /// pose's MI is higher by more than this fraction: the PnP pose carries tilt and height the
    /// sweep pose lacks, and MI is nearly flat over a few decimetres (a PnP pose 0.35 m off can
    /// score slightly below its sweep pose 1 m off).
    pub sweep_margin: f64,
    /// The runner-up hypothesis is kept ([`InitResult::runner_up`]) when the best one's MI is
    /// higher by less than this fraction: a margin that thin is within the verifier's own noise
    /// (the same scale as [`Self::sweep_margin`]), so the LiDAR map has not decided between
    /// them and the refinement's quality gate may (see [`crate::localize::pipeline`]).
    pub runner_up_margin: f64,
    /// The verifier's own settings.
    pub mi: crate::localize::init::verify::VerifyParams,
}

impl Default for VerifySchedule {
    fn default() -> Self {
        VerifySchedule {
            enabled: true,
            shortlist: 60,
            max_fine: 10,
            sweep_margin: 0.1,
            runner_up_margin: 0.1,
            mi: crate::localize::init::verify::VerifyParams::default(),
        }
    }
}

impl Default for FineParams {
    fn default() -> Self {
        FineParams {
            anchor_spacing_m: 1.5,
            max_off_nadir_deg: 65.0,
            max_radius_m: 25.0,
            iterations: vec![
                (3.0, 2.0, 0.2, 0.6),
                (3.0, 1.2, 0.2, 0.45),
                (2.0, 0.6, 0.1, 0.3),
                (2.0, 0.4, 0.1, 0.25),
            ],
            min_score: 0.35,
            pnp: crate::localize::pnp::PnpParams::default(),
            convincing_inliers: Some(CONVINCING_INLIERS),
            verify: VerifySchedule::default(),
        }
    }
}

/// Best-screened sweep candidates climbed on the LiDAR MI when no fine stage gave a pose.
pub(crate) const CLIMB_CANDIDATES: usize = 5;

/// One matched anchor: where the fisheye sees it, and where the satellite says it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorMatch {
    /// Correspondence for PnP.
    pub corr: crate::localize::pnp::Correspondence,
    /// Patch correlation at the best shift.
    pub score: f64,
}

/// Match ground patches seen through `pose` against the satellite; returns correspondences.
pub fn match_anchors(
    cam: &dyn CameraModel,
    image: &[u8],
    sat: &Raster<[u8; 3]>,
    heights: &Raster<f32>,
    pose: &crate::pose::CamFromMap,
    sizes: (f64, f64, f64),
    p: &FineParams,
) -> Vec<AnchorMatch> {
    let mip = Mip::new(image, cam.width() as usize, cam.height() as usize);
    match_anchors_mip(cam, &mip, sat, heights, pose, sizes, p)
}

/// [`match_anchors`] of the frame whose mip pyramid is `mip`.
fn match_anchors_mip(
    cam: &dyn CameraModel,
    mip: &Mip,
    sat: &Raster<[u8; 3]>,
    heights: &Raster<f32>,
    pose: &crate::pose::CamFromMap,
    sizes: (f64, f64, f64),
    p: &FineParams,
) -> Vec<AnchorMatch> {
    // The patches project ~10⁵ ground cells per call: on the concrete model, not through `dyn`.
    match cam.as_mei() {
        Some(mei) => match_anchors_in(&PreparedMei::new(mei), mip, sat, heights, pose, sizes, p),
        None => match_anchors_in(cam, mip, sat, heights, pose, sizes, p),
    }
}

/// [`match_anchors_mip`] for camera model `C`.
fn match_anchors_in<C: CameraModel + ?Sized>(
    cam: &C,
    mip: &Mip,
    sat: &Raster<[u8; 3]>,
    heights: &Raster<f32>,
    pose: &crate::pose::CamFromMap,
    (patch_half, search_half, res): (f64, f64, f64),
    p: &FineParams,
) -> Vec<AnchorMatch> {
    let c = pose.center();
    let (_, radius) = ground_disc(heights, &c, p.max_off_nadir_deg, p.max_radius_m);
    let n = (radius / p.anchor_spacing_m).floor() as i64;
    let mut anchors = Vec::new();
    for j in -n..=n {
        for i in -n..=n {
            let (dx, dy) = (i as f64 * p.anchor_spacing_m, j as f64 * p.anchor_spacing_m);
            if dx * dx + dy * dy <= radius * radius {
                anchors.push((c.x + dx, c.y + dy));
            }
        }
    }
    let ph = (patch_half / res).round() as i64;
    let sh = (search_half / res).round() as i64;
    let side = (2 * ph + 1) as usize;
    let cos_max_theta = cam.max_theta().cos();
    anchors
        .par_iter()
        .filter_map(|&(ax, ay)| {
            let az = height_at(heights, ax, ay)?;
            // One pyramid level per patch: its cells' footprint in fisheye pixels at the anchor.
            let pa = cam
                .project_visible(&pose.transform(&nalgebra::Point3::new(ax, ay, az)).coords)
                .ok()?;
            let fp = [(res, 0.0), (0.0, res)]
                .iter()
                .filter_map(|(dx, dy)| {
                    cam.project(
                        &pose
                            .transform(&nalgebra::Point3::new(ax + dx, ay + dy, az))
                            .coords,
                    )
                    .ok()
                })
                .map(|q| (q - pa).norm())
                .fold(1.0, f64::max);
            // Fisheye patch resampled onto the ground around the anchor, through the current pose.
            let mut patch = GrayF32::new(side, side);
            let mut valid = vec![false; side * side];
            let mut n_valid = 0;
            let level = mip.level(fp);
            for r in 0..side {
                for col in 0..side {
                    let (x, y) = (
                        ax + (col as i64 - ph) as f64 * res,
                        ay - (r as i64 - ph) as f64 * res,
                    );
                    let z = height_at(heights, x, y).unwrap_or(az);
                    let pc = pose.transform(&nalgebra::Point3::new(x, y, z)).coords;
                    if let Ok(px) = cam.project_visible_cos(&pc, cos_max_theta) {
                        if let Some(v) = mip.sample_level(level, px.x, px.y) {
                            patch.data[r * side + col] = v;
                            valid[r * side + col] = true;
                            n_valid += 1;
                        }
                    }
                }
            }
            if n_valid < side * side * 9 / 10 {
                return None;
            }
            let pf = orientation_field(&patch, Some(&valid));
            let (sg, sv) = satellite_gray(sat, ax, ay, patch_half + search_half, res);
            let sf = orientation_field(&sg, Some(&sv));
            let (score, sx, sy) = best_shift(&pf, &sf, ph, sh)?;
            if score < p.min_score {
                return None;
            }
            // The fisheye shows at the anchor's pixel the world point shifted by (sx, −sy)·res.
            let (wx, wy) = (ax + sx * res, ay - sy * res);
            let wz = height_at(heights, wx, wy).unwrap_or(az);
            let pixel = cam
                .project_visible(&pose.transform(&nalgebra::Point3::new(ax, ay, az)).coords)
                .ok()?;
            Some(AnchorMatch {
                corr: crate::localize::pnp::Correspondence {
                    pixel,
                    world: nalgebra::Point3::new(wx, wy, wz),
                },
                score,
            })
        })
        .collect()
}

/// Best shift of `patch` (half-size `ph`) inside `search` (half-size `ph + sh`) by normalised
/// complex correlation, with a sub-pixel parabola fit; `None` if the peak is flat or on the edge.
fn best_shift(patch: &Field, search: &Field, ph: i64, sh: i64) -> Option<(f64, f64, f64)> {
    let side = (2 * ph + 1) as usize;
    let pn: f64 = patch.data.iter().map(|z| z.norm_sqr() as f64).sum();
    if pn <= 0.0 {
        return None;
    }
    let span = (2 * sh + 1) as usize;
    let scores = shift_scores(patch, search, side, span, pn);
    let (bi, &best) = scores
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))?;
    let (bx, by) = (bi % span, bi / span);
    if bx == 0 || by == 0 || bx + 1 == span || by + 1 == span {
        return None; // on the edge: the true shift may lie outside the window
    }
    let fit = |m: f64, c0: f64, p: f64| {
        let d = m - 2.0 * c0 + p;
        if d < 0.0 {
            (0.5 * (m - p) / d).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let dx = fit(scores[bi - 1], best, scores[bi + 1]);
    let dy = fit(scores[bi - span], best, scores[bi + span]);
    Some((best, bx as f64 + dx - sh as f64, by as f64 + dy - sh as f64))
}

/// Shifts of one search row that [`shift_scores`] scores together …
const SHIFT_LANES: usize = 4;
/// … and search rows.
const SHIFT_ROWS: usize = 2;

/// The normalised correlation of `patch` (`side` × `side`) at every shift of the `span` × `span`
/// window of `search` (row-major, −∞ where the search window has no energy):
/// `Re Σ s·t̄ / √(Σ|s|² · pn)`, both sums in f64 over the patch's rows and, within a row, its
/// columns. Each sum is one long chain of dependent additions, so one shift at a time waits on
/// the adder's latency; here a block of [`SHIFT_ROWS`] × [`SHIFT_LANES`] shifts shares each
/// patch sample and keeps its own accumulators, every one adding the same terms in the same
/// order as a lone shift would (the scores are bit-identical to the one-shift loop, unit test
/// `blocked_shift_scores_equal_the_one_shift_loop`). The search is split into real, imaginary
/// and squared-norm planes, padded with zeros so a block may run past the window's edge (those
/// lanes' scores are dropped).
///
/// On x86-64 CPUs with AVX2 and FMA a copy compiled for them runs (four f64 accumulators per
/// instruction instead of two); Rust never fuses a multiply and an add on its own, so its scores
/// are the same bits (the unit test compares with the one-shift loop on the CPU it runs on).
fn shift_scores(patch: &Field, search: &Field, side: usize, span: usize, pn: f64) -> Vec<f64> {
    #[cfg(target_arch = "x86_64")]
    if crate::localize::mi::kernel::has_avx2_fma() {
        // SAFETY: the CPU supports the features the function is compiled for (checked above).
        return unsafe { shift_scores_avx2(patch, search, side, span, pn) };
    }
    shift_scores_impl(patch, search, side, span, pn)
}

/// [`shift_scores`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn shift_scores_avx2(
    patch: &Field,
    search: &Field,
    side: usize,
    span: usize,
    pn: f64,
) -> Vec<f64> {
    shift_scores_impl(patch, search, side, span, pn)
}

/// The body of [`shift_scores`].
#[inline(always)]
fn shift_scores_impl(patch: &Field, search: &Field, side: usize, span: usize, pn: f64) -> Vec<f64> {
    let (sw, sh) = (search.width, search.height);
    debug_assert!(sw >= side + span - 1 && sh >= side + span - 1);
    let pw = sw + SHIFT_LANES - 1;
    let rows = sh + SHIFT_ROWS - 1;
    let (mut re, mut im, mut ns) = (
        vec![0f32; pw * rows],
        vec![0f32; pw * rows],
        vec![0f32; pw * rows],
    );
    for y in 0..sh {
        for x in 0..sw {
            let z = search.data[y * sw + x];
            re[y * pw + x] = z.re;
            im[y * pw + x] = z.im;
            ns[y * pw + x] = z.norm_sqr();
        }
    }
    let mut scores = vec![f64::NEG_INFINITY; span * span];
    for oy in (0..span).step_by(SHIFT_ROWS) {
        for ox in (0..span).step_by(SHIFT_LANES) {
            let mut num = [[0.0f64; SHIFT_LANES]; SHIFT_ROWS];
            let mut e = [[0.0f64; SHIFT_LANES]; SHIFT_ROWS];
            for r in 0..side {
                let prow = &patch.data[r * side..(r + 1) * side];
                for (c, t) in prow.iter().enumerate() {
                    for j in 0..SHIFT_ROWS {
                        let i = (oy + j + r) * pw + ox + c;
                        let (sre, sim, sns) = (
                            &re[i..i + SHIFT_LANES],
                            &im[i..i + SHIFT_LANES],
                            &ns[i..i + SHIFT_LANES],
                        );
                        for k in 0..SHIFT_LANES {
                            // Re(s·t̄), as `(s * t.conj()).re` computes it.
                            num[j][k] += (sre[k] * t.re + sim[k] * t.im) as f64;
                            e[j][k] += sns[k] as f64;
                        }
                    }
                }
            }
            for j in 0..SHIFT_ROWS {
                for k in 0..SHIFT_LANES {
                    let (y, x) = (oy + j, ox + k);
                    if y < span && x < span && e[j][k] > 0.0 {
                        scores[y * span + x] = num[j][k] / (e[j][k] * pn).sqrt();
                    }
                }
            }
        }
    }
    scores
}

/// PnP inliers (with ≥ 2/3 of the patch matches agreeing) that end the candidate search early
/// (the default of [`FineParams::convincing_inliers`]).
pub(crate) const CONVINCING_INLIERS: usize = 30;

/// Result of [`initialize`].
#[derive(Debug, Clone)]
pub struct InitResult {
    /// World→camera pose from PnP.
    pub pose: crate::pose::CamFromMap,
    /// The coarse candidate it grew from.
    pub candidate: Candidate,
    /// Correspondences given to the last PnP (0 when the pose is a verified sweep pose).
    pub matches: usize,
    /// PnP inliers of the last iteration (0 when the pose is a verified sweep pose).
    pub inliers: usize,
    /// PnP reprojection RMS of the last iteration, px (NaN when the pose is a verified sweep pose).
    pub rms_px: f64,
    /// The last PnP's tilt σ from its residuals, degrees
    /// ([`crate::localize::pnp::tilt_sigma_deg`]; NaN when the pose is a verified sweep pose).
    pub tilt_sigma_deg: f64,
    /// The last PnP's covariance ([`crate::localize::pnp::pose_covariance`]; `None` when the
    /// pose is a verified sweep pose or it cannot be had).
    pub covariance: Option<crate::localize::pnp::PoseCovariance>,
    /// Candidates whose fine stage ran (fewer than the sweep kept when one was convincing early).
    pub candidates_tried: usize,
    /// Rank of [`Self::candidate`] in the sweep's list, 0 = the sweep's best.
    pub candidate_rank: usize,
    /// With a verifier: the pose's bias-corrected MI with the LiDAR map (nats), and the runner-up
    /// hypothesis' (another PnP pose or, if none, the best screened sweep candidate not tried).
    pub mi: Option<(f64, Option<f64>)>,
    /// The pose is the initializer's last resort: the PnP pose of a fine stage that stopped at a
    /// finer iteration ([`FineOutcome::partial`]).
    pub partial_fine_stage: bool,
    /// With a verifier: the runner-up hypothesis when the verifier's margin between it and this
    /// one is thin ([`VerifySchedule::runner_up_margin`]); its own `mi` is (its MI, this one's).
    pub runner_up: Option<Box<InitResult>>,
}

impl InitResult {
    /// A fine stage's PnP pose grown from `candidate` (rank `rank` in the sweep's list).
    fn from_fine(f: &FineOutcome, candidate: Candidate, rank: usize, mi: Option<f64>) -> Self {
        InitResult {
            pose: f.pose,
            candidate,
            matches: f.matches,
            inliers: f.inliers,
            rms_px: f.rms_px,
            tilt_sigma_deg: f.tilt_sigma_deg,
            covariance: f.covariance,
            candidates_tried: 0,
            candidate_rank: rank,
            mi: mi.map(|m| (m, None)),
            partial_fine_stage: f.partial,
            runner_up: None,
        }
    }
}

/// What the fine stage made of one sweep candidate.
#[derive(Debug, Clone)]
pub struct FineOutcome {
    /// World→camera pose of the last PnP.
    pub pose: crate::pose::CamFromMap,
    /// Correspondences given to the last PnP.
    pub matches: usize,
    /// Its inliers.
    pub inliers: usize,
    /// Its reprojection RMS, px.
    pub rms_px: f64,
    /// Its tilt σ, degrees ([`crate::localize::pnp::tilt_sigma_deg`]).
    pub tilt_sigma_deg: f64,
    /// Its covariance ([`crate::localize::pnp::pose_covariance`]).
    pub covariance: Option<crate::localize::pnp::PoseCovariance>,
    /// A later, finer iteration failed: this is the last iteration that gave a PnP pose.
    pub partial: bool,
}

/// Fine stage of one sweep candidate (offset relative to `prior_xy`): the iterations of local
/// patch matching + PnP of [`FineParams::iterations`], each from the previous pose. The error
/// says which PnP failed and on how many matches.
pub fn fine_stage<R: rand::Rng>(
    frame: &Frame<'_>,
    map: MapLayers<'_>,
    prior_xy: (f64, f64),
    cand: &Candidate,
    fine: &FineParams,
    rng: &mut R,
) -> std::result::Result<FineOutcome, FineError> {
    fine_stage_partial(&Sampled::new(frame), map, prior_xy, cand, fine, rng).0
}

/// Why one candidate's fine stage gave no pose.
#[derive(Debug, thiserror::Error)]
pub enum FineError {
    /// No iteration is configured.
    #[error("no fine iterations configured")]
    NoIterations,
    /// An iteration's PnP failed.
    #[error("{error} ({matches} patch matches)")]
    Pnp {
        /// The PnP's error.
        error: Box<crate::error::Error>,
        /// Patch matches it had.
        matches: usize,
    },
}

/// The last fine stage's failure in words (empty when none failed).
fn last_words(e: &Option<FineError>) -> String {
    e.as_ref().map_or(String::new(), ToString::to_string)
}

/// A frame with its mip pyramid: built once per initialization, for the nominal view and every
/// fine-stage iteration (which resample from it), and dropped with it (20–30 MB for a 5 MP
/// frame, which the refinement after it does not need).
struct Sampled<'f, 'a> {
    frame: &'f Frame<'a>,
    mip: Mip,
}

impl<'f, 'a> Sampled<'f, 'a> {
    fn new(frame: &'f Frame<'a>) -> Self {
        let cam = frame.camera();
        Sampled {
            frame,
            mip: Mip::new(frame.gray(), cam.width() as usize, cam.height() as usize),
        }
    }
}

/// [`fine_stage`], and on failure the last iteration that did give a PnP pose (`None` when the
/// first failed or all succeeded): the last resort of [`initialize`] with a verifier when no
/// candidate's fine stage gets through all its iterations.
fn fine_stage_partial<R: rand::Rng>(
    view: &Sampled<'_, '_>,
    map: MapLayers<'_>,
    prior_xy: (f64, f64),
    cand: &Candidate,
    fine: &FineParams,
    rng: &mut R,
) -> (
    std::result::Result<FineOutcome, FineError>,
    Option<FineOutcome>,
) {
    let cam: &dyn CameraModel = view.frame.camera();
    let (sat, heights) = (map.satellite, map.heights);
    let (cx, cy) = (prior_xy.0 + cand.offset[0], prior_xy.1 + cand.offset[1]);
    let zg = height_at(heights, cx, cy).unwrap_or(0.0);
    let mut pose = crate::pose::CamFromMap::from_center_ypr(
        &nalgebra::Point3::new(cx, cy, zg + cand.height),
        cand.yaw,
        0.0,
        0.0,
    );
    let mut outcome: std::result::Result<FineOutcome, FineError> = Err(FineError::NoIterations);
    for &(ph, sh, res, tol_m) in &fine.iterations {
        let m = match_anchors_mip(cam, &view.mip, sat, heights, &pose, (ph, sh, res), fine);
        let corr: Vec<_> = m.iter().map(|a| a.corr).collect();
        let c = pose.center();
        let cam_h = (c.z - height_at(heights, c.x, c.y).unwrap_or(c.z - cand.height)).max(1.0);
        let params = crate::localize::pnp::PnpParams {
            threshold_px: tol_m / cam_h * focal_px(cam),
            ..fine.pnp
        };
        match crate::localize::pnp::solve_pnp_ransac(cam, &corr, &params, rng) {
            Ok(r) => {
                pose = r.pose;
                outcome = Ok(FineOutcome {
                    pose,
                    matches: corr.len(),
                    inliers: r.inliers.len(),
                    rms_px: r.rms_px,
                    tilt_sigma_deg: r.tilt_sigma_deg,
                    covariance: r.covariance,
                    partial: false,
                });
            }
            Err(e) => {
                return (
                    Err(FineError::Pnp {
                        error: Box::new(e),
                        matches: corr.len(),
                    }),
                    outcome.ok().map(|f| FineOutcome { partial: true, ..f }),
                )
            }
        }
    }
    (outcome, None)
}

/// Full initialization: coarse sweep around the prior, then per candidate local matching + PnP.
///
/// Without a verifier the candidate with the most inliers wins (sweep order, early stop on a
/// convincing PnP). With one ([`MiVerifier`], the LiDAR map), the hypotheses are judged by
/// evidence the satellite matching cannot fake: the sweep list is lengthened to
/// [`VerifySchedule::shortlist`], every candidate is screened by its MI with the LiDAR map, the
/// fine stages run in decreasing screening MI (at most [`VerifySchedule::max_fine`]), and the
/// hypothesis with the highest MI wins (a PnP pose, or a tried candidate's screened sweep pose
/// where that has the higher MI, see `initialize_verified`). The search stops once the best PnP pose is convincing (inliers
/// as above) and its MI is at least the screening MI of every candidate not yet tried — no
/// remaining hypothesis has better evidence. Errors name the stage and the numbers.
pub fn initialize<R: rand::Rng>(
    frame: &Frame<'_>,
    map: MapLayers<'_>,
    area: SearchArea,
    coarse: &CoarseParams,
    fine: &FineParams,
    verifier: Option<&MiVerifier>,
    rng: &mut R,
) -> crate::Result<InitResult> {
    let cam: &dyn CameraModel = frame.camera();
    let view = Sampled::new(frame);
    let sat = map.satellite;
    let (prior_xy, search_radius_m) = (area.center, area.radius_m);
    let cands = match verifier {
        Some(_) => {
            let longer = CoarseParams {
                top_k: coarse.top_k.max(fine.verify.shortlist),
                ..coarse.clone()
            };
            coarse_candidates_mip(cam, &view.mip, sat, prior_xy, search_radius_m, &longer)
        }
        None => coarse_candidates_mip(cam, &view.mip, sat, prior_xy, search_radius_m, coarse),
    };
    if cands.is_empty() {
        return Err(crate::Error::stage(
            StageName::Pnp,
            "satellite match: no hypothesis scored (featureless view or satellite?)",
        ));
    }
    if let Some(v) = verifier {
        return initialize_verified(&view, map, prior_xy, &cands, fine, v, rng);
    }
    let mut best: Option<InitResult> = None;
    let mut last_err: Option<FineError> = None;
    let mut tried = 0;
    for (rank, cand) in cands.iter().enumerate() {
        tried = rank + 1;
        let outcome = match fine_stage_partial(&view, map, prior_xy, cand, fine, rng).0 {
            Ok(f) => Some(f),
            Err(e) => {
                last_err = Some(e);
                None
            }
        };
        if let Some(f) = outcome {
            let convincing = fine
                .convincing_inliers
                .is_some_and(|n| f.inliers >= n && f.inliers * 3 >= f.matches * 2);
            if best.as_ref().is_none_or(|b| f.inliers > b.inliers) {
                best = Some(InitResult::from_fine(&f, *cand, rank, None));
            }
            // The sweep's ranking is only a shortlist; a candidate whose fine stage agrees this
            // well is the answer, and trying the rest would only cost time.
            if convincing {
                break;
            }
        }
    }
    if let Some(b) = best.as_mut() {
        b.candidates_tried = tried;
    }
    best.ok_or_else(|| {
        crate::Error::stage(
            StageName::Pnp,
            format!(
                "none of {} candidates gave a pose; last: {}",
                cands.len(),
                last_words(&last_err)
            ),
        )
    })
}

/// The pose a sweep candidate stands for (offset relative to `prior_xy`, roll = pitch = 0), as the
/// fine stage starts from it.
pub fn candidate_pose(
    heights: &Raster<f32>,
    prior_xy: (f64, f64),
    cand: &Candidate,
) -> crate::pose::CamFromMap {
    let (cx, cy) = (prior_xy.0 + cand.offset[0], prior_xy.1 + cand.offset[1]);
    let zg = height_at(heights, cx, cy).unwrap_or(0.0);
    crate::pose::CamFromMap::from_center_ypr(
        &nalgebra::Point3::new(cx, cy, zg + cand.height),
        cand.yaw,
        0.0,
        0.0,
    )
}

/// [`initialize`] with a verifier: screen, fine stages in screening order, best MI wins.
///
/// Each tried candidate stands for the better (by MI, with [`VerifySchedule::sweep_margin`] in
/// favour of PnP) of its PnP pose and its screened sweep pose:
/// on low poles the fine stage sometimes fails on, or tilts away from, the very candidate the
/// LiDAR map confirms best, and then the sweep pose (zero tilt, ≤ 0.2 m / 1° from the candidate)
/// is the better start for the refinement. At least one fine stage must give a pose: a frame
/// the satellite matching cannot confirm anywhere is an error, not a guess. When none does, the
/// [`CLIMB_CANDIDATES`] best-screened candidates get a second chance: climbed on the LiDAR MI
/// ([`MiVerifier::climb`]), then the fine stage again. When still none gets through all its
/// iterations, the last resort is the PnP poses of the iterations before the ones that failed
/// (satellite-confirmed at a coarser tolerance), each scored by the verifier.
fn initialize_verified<R: rand::Rng>(
    view: &Sampled<'_, '_>,
    map: MapLayers<'_>,
    prior_xy: (f64, f64),
    cands: &[Candidate],
    fine: &FineParams,
    verifier: &MiVerifier,
    rng: &mut R,
) -> crate::Result<InitResult> {
    let heights = map.heights;
    let (screened, order) = screen_candidates(heights, prior_xy, cands, verifier);
    let screen_mi = |i: usize| screened[i].map(|v| v.mi);
    // Every tried candidate's hypothesis, in try order (ties go to the earlier one).
    let mut pool: Vec<(f64, InitResult)> = Vec::new();
    let mut any_pnp = false;
    let mut last_err: Option<FineError> = None;
    let mut tried = 0;
    // Fine stages that failed after an earlier iteration gave a PnP pose: (rank, candidate, it).
    let mut partials: Vec<(usize, Candidate, FineOutcome)> = Vec::new();
    for (pos, &rank) in order.iter().enumerate().take(fine.verify.max_fine.max(1)) {
        tried = pos + 1;
        let cand = &cands[rank];
        // Re-scored with the full verification (more points, finer grid) so that it competes
        // with PnP poses on equal terms; the screening only orders.
        let sweep =
            screened[rank].and_then(|_| verifier.verify(&candidate_pose(heights, prior_xy, cand)));
        let (outcome, partial) = fine_stage_partial(view, map, prior_xy, cand, fine, rng);
        partials.extend(partial.map(|f| (rank, *cand, f)));
        let hyp = match outcome {
            Ok(f) => {
                any_pnp = true;
                let v = verifier.verify(&f.pose);
                let pnp = InitResult::from_fine(&f, *cand, rank, v.map(|v| v.mi));
                match (v, sweep) {
                    (Some(v), Some(s)) if s.mi > v.mi * (1.0 + fine.verify.sweep_margin) => {
                        Some((s.mi, sweep_result(cand, rank, &s)))
                    }
                    (Some(v), _) => Some((v.mi, pnp)),
                    (None, Some(s)) => Some((s.mi, sweep_result(cand, rank, &s))),
                    (None, None) => None,
                }
            }
            Err(e) => {
                last_err = Some(e);
                sweep.map(|s| (s.mi, sweep_result(cand, rank, &s)))
            }
        };
        let Some((mi, h)) = hyp else { continue };
        let convincing_pnp = h.inliers > 0
            && fine
                .convincing_inliers
                .is_none_or(|n| h.inliers >= n && h.inliers * 3 >= h.matches * 2);
        pool.push((mi, h));
        // Stop once a convincing PnP pose is the best of the pool and no untried candidate
        // screened better: the rest are in decreasing screening MI, so the next bounds them all.
        let best_mi = pool.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
        let next = order.get(pos + 1).and_then(|&i| screen_mi(i));
        if convincing_pnp && mi >= best_mi && next.is_none_or(|n| mi >= n) {
            break;
        }
    }
    if !any_pnp {
        // Second chance: the sweep found the view but too coarsely for patch matching (on low
        // poles a 1–3 m / 5–15° / one-height-step error leaves too few patches inside their
        // search windows). Climb the best-screened candidates on the LiDAR MI and run the fine
        // stage again from there; the satellite must still confirm (a PnP pose), so a frame it
        // cannot confirm anywhere stays an error.
        for &rank in order.iter().take(CLIMB_CANDIDATES) {
            let cand = &cands[rank];
            if screened[rank].is_none() {
                continue;
            }
            let Some(up) = verifier.climb(&candidate_pose(heights, prior_xy, cand)) else {
                continue;
            };
            let c = up.pose.center();
            // As `candidate_pose` rebuilds it: ground 0 where the height layer has no data.
            let ground = height_at(heights, c.x, c.y).unwrap_or(0.0);
            let climbed = Candidate {
                yaw: up.pose.yaw_pitch_roll().0,
                height: c.z - ground,
                offset: [c.x - prior_xy.0, c.y - prior_xy.1],
                score: cand.score,
            };
            let (outcome, partial) = fine_stage_partial(view, map, prior_xy, &climbed, fine, rng);
            partials.extend(partial.map(|f| (rank, climbed, f)));
            match outcome {
                Ok(f) => {
                    any_pnp = true;
                    push_verified(&mut pool, verifier, rank, climbed, f);
                }
                Err(e) => last_err = Some(e),
            }
        }
    }
    if !any_pnp {
        // Last resort: on low poles the finest iterations can run out of patches inside their
        // windows (fewer than PnP needs) after a coarser one already gave a PnP pose from the
        // satellite's patches. That pose is still the satellite's confirmation; the LiDAR MI
        // judges it against the other hypotheses, and the refinement and its gate after it.
        // Only a partial pose the verifier could score counts as a PnP pose.
        for (rank, cand, f) in partials {
            any_pnp |= push_verified(&mut pool, verifier, rank, cand, f);
        }
    }
    if !any_pnp {
        return Err(crate::Error::stage(
            StageName::Pnp,
            format!(
                "none of the {tried} best-screened of {} candidates, nor {CLIMB_CANDIDATES} of them climbed on the LiDAR map, gave a PnP pose; last: {}",
                cands.len(),
                last_words(&last_err)
            ),
        ));
    }
    choose(pool, &order, &screened, cands, tried, fine, verifier)
}

/// Screening: MI of each sweep candidate's own pose, and the order to try them in (best
/// screened first). Candidates whose view holds too few LiDAR points have no evidence and go
/// last, in sweep order.
fn screen_candidates(
    heights: &Raster<f32>,
    prior_xy: (f64, f64),
    cands: &[Candidate],
    verifier: &MiVerifier,
) -> (Vec<Option<Verdict>>, Vec<usize>) {
    // Candidates in parallel as well as each one's grid cells: a screening's LiDAR disc is
    // gathered serially, and the cells alone leave threads idle between candidates.
    let screened: Vec<Option<Verdict>> = cands
        .par_iter()
        .map(|c| verifier.screen(&candidate_pose(heights, prior_xy, c)))
        .collect();
    let screen_mi = |i: usize| screened[i].map(|v| v.mi);
    let mut order: Vec<usize> = (0..cands.len()).collect();
    order.sort_by(|&a, &b| {
        let key = |i: usize| screen_mi(i).unwrap_or(f64::NEG_INFINITY);
        key(b).total_cmp(&key(a)).then(a.cmp(&b))
    });
    (screened, order)
}

/// The chosen hypothesis of the `pool` (MI, hypothesis; in try order): the best MI (ties go to
/// the earlier), with its strongest rival kept as the runner-up when the margin is thin. `tried`
/// candidates of `order` were tried; the untried ones compete with their screening MI.
fn choose(
    mut pool: Vec<(f64, InitResult)>,
    order: &[usize],
    screened: &[Option<Verdict>],
    cands: &[Candidate],
    tried: usize,
    fine: &FineParams,
    verifier: &MiVerifier,
) -> crate::Result<InitResult> {
    let screen_mi = |i: usize| screened[i].map(|v| v.mi);
    let Some(bi) = pool
        .iter()
        .enumerate()
        .fold(None, |b: Option<usize>, (i, p)| match b {
            Some(j) if pool[j].0 >= p.0 => Some(j),
            _ => Some(i),
        })
    else {
        return Err(crate::Error::stage(
            StageName::Pnp,
            format!(
                "no hypothesis of {tried} tried sees enough LiDAR points ({} needed) to verify",
                verifier.params().min_points
            ),
        ));
    };
    // The strongest competitor: another tried hypothesis, or the best untried screening (ties go
    // to the tried one, then to the earlier).
    #[derive(Clone, Copy)]
    enum Rival {
        Tried(usize),
        Untried(usize),
    }
    let rival = pool
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != bi)
        .map(|(i, p)| (p.0, Rival::Tried(i)))
        .chain(
            order
                .iter()
                .skip(tried)
                .filter_map(|&i| screen_mi(i).map(|m| (m, Rival::Untried(i)))),
        )
        .fold(None, |m: Option<(f64, Rival)>, x| match m {
            Some(b) if b.0 >= x.0 => Some(b),
            _ => Some(x),
        });
    let mi = pool[bi].0;
    // A thin margin leaves the choice open: keep the rival as a hypothesis of its own (an untried
    // candidate as its screening's best pose, which the refinement's search box covers). A rival
    // without positive MI has no evidence and is never kept; nor is an untried screening whose
    // candidate is in the pool already (climbed: the same hypothesis, moved).
    let runner_up = rival
        .filter(|&(r, _)| mi < r * (1.0 + fine.verify.runner_up_margin))
        .and_then(|(r, which)| {
            let mut h = match which {
                Rival::Tried(i) => pool[i].1.clone(),
                Rival::Untried(rank) if pool.iter().any(|p| p.1.candidate_rank == rank) => {
                    return None
                }
                Rival::Untried(rank) => sweep_result(&cands[rank], rank, &screened[rank]?),
            };
            h.candidates_tried = tried;
            h.mi = Some((r, Some(mi)));
            Some(Box::new(h))
        });
    let (mi, mut best) = pool.swap_remove(bi);
    best.candidates_tried = tried;
    best.mi = Some((mi, rival.map(|r| r.0)));
    best.runner_up = runner_up;
    Ok(best)
}

/// A fine stage's PnP pose into the hypotheses' `pool`, scored by the verifier (left out when it
/// sees too few LiDAR points to verify). Whether it went in.
fn push_verified(
    pool: &mut Vec<(f64, InitResult)>,
    verifier: &MiVerifier,
    rank: usize,
    candidate: Candidate,
    f: FineOutcome,
) -> bool {
    let v = verifier.verify(&f.pose);
    if let Some(v) = v {
        pool.push((v.mi, InitResult::from_fine(&f, candidate, rank, Some(v.mi))));
    }
    v.is_some()
}

/// The hypothesis a screened sweep candidate stands for: the verifier's best pose near it, no
/// PnP figures (0 matches and inliers).
fn sweep_result(
    cand: &Candidate,
    rank: usize,
    s: &crate::localize::init::verify::Verdict,
) -> InitResult {
    InitResult {
        pose: s.pose,
        candidate: *cand,
        matches: 0,
        inliers: 0,
        rms_px: f64::NAN,
        tilt_sigma_deg: f64::NAN,
        covariance: None,
        candidates_tried: 0,
        candidate_rank: rank,
        mi: Some((s.mi, None)),
        partial_fine_stage: false,
        runner_up: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-shift-at-a-time loop [`shift_scores`] blocks.
    fn shift_scores_reference(
        patch: &Field,
        search: &Field,
        side: usize,
        span: usize,
        pn: f64,
    ) -> Vec<f64> {
        let sw = search.width;
        let mut scores = vec![f64::NEG_INFINITY; span * span];
        for oy in 0..span {
            for ox in 0..span {
                let (mut num, mut e) = (0.0f64, 0.0f64);
                for r in 0..side {
                    let srow = &search.data[(oy + r) * sw + ox..(oy + r) * sw + ox + side];
                    let prow = &patch.data[r * side..(r + 1) * side];
                    for (s, t) in srow.iter().zip(prow) {
                        num += (s * t.conj()).re as f64;
                        e += s.norm_sqr() as f64;
                    }
                }
                if e > 0.0 {
                    scores[oy * span + ox] = num / (e * pn).sqrt();
                }
            }
        }
        scores
    }

    #[test]
    fn blocked_shift_scores_equal_the_one_shift_loop() {
        use rand::{Rng, SeedableRng};
        use rustfft::num_complex::Complex32;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(18);
        // The fine stage's sizes (patch side 31 and 41, spans 21, 13, 9) and odd small ones, with
        // zero stretches as a masked field has.
        for (side, span) in [
            (31usize, 21usize),
            (31, 13),
            (41, 13),
            (41, 9),
            (3, 1),
            (5, 2),
            (7, 6),
        ] {
            let field = |w: usize, rng: &mut rand_chacha::ChaCha8Rng| Field {
                width: w,
                height: w,
                data: (0..w * w)
                    .map(|_| {
                        if rng.random_bool(0.2) {
                            Complex32::new(0.0, 0.0)
                        } else {
                            Complex32::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))
                        }
                    })
                    .collect(),
            };
            let patch = field(side, &mut rng);
            let search = field(side + span - 1, &mut rng);
            let pn: f64 = patch.data.iter().map(|z| z.norm_sqr() as f64).sum();
            let got = shift_scores(&patch, &search, side, span, pn);
            let want = shift_scores_reference(&patch, &search, side, span, pn);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "side {side} span {span}");
        }
    }
    use crate::camera::Mei;
    use crate::localize::init::coarse::*;
    use crate::map::{Crs, GeoGrid};
    use crate::pose::CamFromMap;
    use nalgebra::Point2;
    use nalgebra::Point3;

    fn marking(x: f64, y: f64) -> f32 {
        // Two crossing roads with dashed centre lines, a zebra crossing and stop bars, hashed grain.
        let (cx, cy) = ((x * 2.0).floor() as i64, (y * 2.0).floor() as i64);
        let grain = (cx.wrapping_mul(73_856_093) ^ cy.wrapping_mul(19_349_663)).rem_euclid(1000)
            as f32
            / 1000.0;
        let mut v = 0.25 + 0.08 * grain;
        let road_ns = x.abs() < 7.0;
        let road_ew = (y - 0.3 * x).abs() < 6.0;
        if !(road_ns || road_ew) {
            v = 0.45 + 0.1 * grain; // sidewalk / grass
        }
        if road_ns && (x.abs() < 0.08) && (y.rem_euclid(6.0) < 3.0) && y.abs() > 8.0 {
            v = 0.9;
        }
        if road_ew && (y - 0.3 * x).abs() < 0.08 && x.rem_euclid(6.0) < 3.0 && x.abs() > 9.0 {
            v = 0.9;
        }
        if road_ns && (9.0..12.0).contains(&y) && (x + 10.0).rem_euclid(1.2) < 0.6 {
            v = 0.9; // zebra
        }
        if road_ew && (9.0..9.4).contains(&x) && (y - 0.3 * x) < 0.0 {
            v = 0.9; // stop bar
        }
        if (x - 3.0).powi(2) + (y + 14.0).powi(2) < 0.36 {
            v = 0.1; // manhole
        }
        v
    }

    struct Scene {
        cam: Mei,
        img: Vec<u8>,
        sat: Raster<[u8; 3]>,
        heights: Raster<f32>,
        yaw: f64,
        h: f64,
        centre: [f64; 2],
    }

    fn scene() -> Scene {
        let cam = Mei {
            width: 800,
            height: 800,
            fx: 230.0,
            fy: 230.0,
            cx: 400.0,
            cy: 400.0,
            skew: 0.0,
            xi: 1.0,
            k1: -0.02,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        };
        let (yaw, h, centre) = (211f64.to_radians(), 9.0, [2.3, -3.1]);
        let pose =
            CamFromMap::from_center_ypr(&Point3::new(centre[0], centre[1], h), yaw, 0.0, 0.0);
        let inv = pose.inverse();
        // Render the fisheye frame by casting each pixel's ray onto the ground plane z = 0.
        let mut img = vec![0u8; 800 * 800];
        for v in 0..800 {
            for u in 0..800 {
                if let Ok(b) = cam.unproject(&Point2::new(u as f64, v as f64)) {
                    let d = inv.rotate(&b.into_inner());
                    if d.z < -1e-3 {
                        let t = -h / d.z;
                        let g = marking(centre[0] + t * d.x, centre[1] + t * d.y);
                        img[v * 800 + u] = (g * 250.0) as u8;
                    }
                }
            }
        }
        // "Satellite": other polarity and brightness, 0.1 m/px, covering ±60 m.
        let grid = GeoGrid {
            crs: Crs::Local,
            x0: -60.0,
            y0: 60.0,
            res: 0.1,
            width: 1200,
            height: 1200,
        };
        let mut sat = Raster::filled(grid, [0u8; 3], None);
        for row in 0..1200 {
            for col in 0..1200 {
                let (x, y) = grid.pixel_center(col, row);
                let g = 1.0 - marking(x, y);
                sat.data[row * 1200 + col] =
                    [(g * 200.0) as u8, (g * 180.0) as u8, (g * 160.0) as u8];
            }
        }
        let heights = Raster::filled(GeoGrid { res: 0.1, ..grid }, 0.0f32, None);
        Scene {
            cam,
            img,
            sat,
            heights,
            yaw,
            h,
            centre,
        }
    }

    /// A sweep hypothesis within a yaw step, 1 m and 6 % of height of the scene's camera.
    fn assert_is_the_camera(best: &Candidate, yaw: f64, h: f64, centre: [f64; 2]) {
        let dyaw = crate::pose::angle_difference(best.yaw, yaw).abs();
        let dpos =
            ((best.offset[0] - centre[0]).powi(2) + (best.offset[1] - centre[1]).powi(2)).sqrt();
        assert!(
            dyaw.to_degrees() <= 3.0 && dpos <= 1.0 && (best.height / h - 1.0).abs() <= 0.06,
            "{best:?}"
        );
    }

    #[test]
    fn coarse_stage_finds_pose_without_heading() {
        let Scene {
            cam,
            img,
            sat,
            yaw,
            h,
            centre,
            ..
        } = scene();
        let p = CoarseParams {
            height_range_m: (6.0, 12.0),
            ..CoarseParams::default()
        };
        let best = coarse_candidates(&cam, &img, &sat, (0.0, 0.0), 12.0, &p)[0];
        assert_is_the_camera(&best, yaw, h, centre);
    }

    #[test]
    fn tall_sweep_appends_its_own_candidates_after_the_main_list() {
        let sc = scene();
        let main_only = CoarseParams {
            height_range_m: (3.0, 12.0),
            tall_from_m: None,
            ..CoarseParams::default()
        };
        let with_tall = CoarseParams {
            tall_from_m: Some(6.0),
            tall_top_k: 4,
            ..main_only.clone()
        };
        let main = coarse_candidates(&sc.cam, &sc.img, &sc.sat, (0.0, 0.0), 12.0, &main_only);
        let all = coarse_candidates(&sc.cam, &sc.img, &sc.sat, (0.0, 0.0), 12.0, &with_tall);
        assert_eq!(main.len(), main_only.top_k);
        // The main sweep's list is unchanged, first; the tall sweep's candidates follow, each a
        // height of at least 6 m and none a copy of one already listed.
        assert_eq!(&all[..main.len()], &main[..]);
        let tall = &all[main.len()..];
        assert!(!tall.is_empty() && tall.len() <= 4, "{tall:?}");
        assert!(tall.iter().all(|c| c.height >= 6.0 && !main.contains(c)));
        // The tall sweep's template sees 16.5 m of ground: its best hypothesis is the camera's.
        let best = tall
            .iter()
            .copied()
            .max_by(|a, b| a.score.total_cmp(&b.score))
            .expect("a tall candidate");
        assert_is_the_camera(&best, sc.yaw, sc.h, sc.centre);
    }

    #[test]
    fn initialize_reaches_the_refinement_basin() {
        let sc = scene();
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
        let coarse = CoarseParams {
            height_range_m: (6.0, 12.0),
            ..CoarseParams::default()
        };
        let cam = crate::camera::Camera::Mei(sc.cam.clone());
        let r = initialize(
            &Frame::new(&cam, &sc.img).unwrap(),
            MapLayers {
                satellite: &sc.sat,
                heights: &sc.heights,
            },
            SearchArea {
                center: (0.0, 0.0),
                radius_m: 12.0,
            },
            &coarse,
            &FineParams::default(),
            None,
            &mut rng,
        )
        .unwrap();
        let c = r.pose.center();
        let (yaw, _, _) = r.pose.yaw_pitch_roll();
        let dyaw = crate::pose::angle_difference(yaw, sc.yaw).abs();
        let dxy = ((c.x - sc.centre[0]).powi(2) + (c.y - sc.centre[1]).powi(2)).sqrt();
        assert!(
            dxy < 0.3 && (c.z - sc.h).abs() < 0.3 && dyaw.to_degrees() < 1.0,
            "{r:?}"
        );
    }
}
