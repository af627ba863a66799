//! Intrinsic calibration from planar boards (`infraloc calibrate`), pure: observations in, camera
//! and report out; the shell ([`crate::cli`]) reads and writes the files.
//!
//! 1. **Checks**: every view has as many object as image points, all finite, every corner inside
//!    the image, a planar board; at least [`MIN_VIEWS`] usable views.
//! 2. **Start** ([`init`]): Mei & Rives — ξ = 1, no distortion, generalised focal from the board's
//!    lines (and a logarithmic scan of it, whichever reprojects best), poses from the homography
//!    between board and lifted rays.
//! 3. **Refinement** ([`lm`]): Levenberg–Marquardt over the intrinsics (Mei: fx, fy, cx, cy, skew,
//!    k1, k2, p1, p2, ξ — OpenCV omnidir's set; equidistant: fx, fy, cx, cy, k1..k4, skew fixed at 0)
//!    and all view poses, Jacobian by forward-mode differentiation of the projection itself.
//! 4. **Outlier views** ([`OUTLIER_FACTOR`]): while the worst view's RMS exceeds both
//!    3 × the median view RMS and [`OUTLIER_FLOOR_PX`], that view is removed and the rest re-fitted
//!    (never below [`MIN_VIEWS`] views).
//! 5. **Uncertainty**: standard deviations σ·√diag((JᵀJ)⁻¹) with σ² = SSR / (2·points − parameters).

pub mod corners;
pub mod detect;
mod error;
mod init;
mod jet;
mod lm;
mod model;

pub use error::{CalibError, DetectError, GridProblem, PlaneError};
pub use init::InitInfo;
pub use model::LensModel;

use crate::camera::{Camera, CameraModel};
use init::{InitView, Plane, Pose};
use lm::{Obs, State};
use nalgebra::Vector3;
use serde::Serialize;

/// Fewest views a calibration accepts.
pub const MIN_VIEWS: usize = 3;
/// Fewest corners a view needs (a homography needs 4).
pub(crate) const MIN_CORNERS: usize = 4;
/// A view is an outlier when its RMS exceeds this multiple of the median view RMS …
pub(crate) const OUTLIER_FACTOR: f64 = 3.0;
/// … and this many pixels.
pub(crate) const OUTLIER_FLOOR_PX: f64 = 0.5;
/// Boards tilted less than this from fronto-parallel (degrees) do not constrain the focal length;
/// if every view is, the calibration is refused.
pub(crate) const MIN_TILT_DEG: f64 = 5.0;

/// Board observations: for each view, board-frame object points (metres, planar) and the pixels
/// they were detected at.
#[derive(Debug, Clone, PartialEq)]
pub struct Observations {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// The views.
    pub views: Vec<View>,
}

/// One view of the board.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Name used in messages and the report (`view 3`, or the image file name).
    pub name: String,
    /// Board points (board frame).
    pub object: Vec<[f64; 3]>,
    /// Detected pixels (OpenCV convention: the top-left pixel's centre is (0, 0)).
    pub image: Vec<[f64; 2]>,
}

/// One fitted intrinsic parameter.
#[derive(Debug, Clone, Serialize)]
pub struct Param {
    /// Name (`fx`, `xi`, …).
    pub name: &'static str,
    /// Value.
    pub value: f64,
    /// Standard deviation (from the Jacobian at the solution).
    pub std: f64,
}

/// The outcome for one view.
#[derive(Debug, Clone, Serialize)]
pub struct ViewResult {
    /// The view's name.
    pub name: String,
    /// Corners in the view.
    pub corners: usize,
    /// Whether the view is part of the final fit.
    pub used: bool,
    /// Why it was removed (`None` if used).
    pub rejected: Option<String>,
    /// RMS reprojection error under the final fit, px (`None` if it never had a pose).
    pub rms: Option<f64>,
    /// Board pose as OpenCV's rvec (Rodrigues, rad) and tvec (board units): camera = R·board + t.
    pub rvec: Option<[f64; 3]>,
    /// Translation part of the pose.
    pub tvec: Option<[f64; 3]>,
    /// Board tilt from fronto-parallel, degrees.
    pub tilt_deg: Option<f64>,
    /// Per-corner residual (projection − detection), px.
    #[serde(skip)]
    pub residuals: Vec<[f64; 2]>,
}

/// A finished calibration.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// The model fitted.
    pub model: LensModel,
    /// The fitted camera.
    #[serde(skip)]
    pub camera: Camera,
    /// Image size, px.
    pub image_size: [u32; 2],
    /// Intrinsics with standard deviations.
    pub params: Vec<Param>,
    /// RMS reprojection error over the used views' corners: √(mean |projection − detection|²), px
    /// (what `cv::omnidir::calibrate` returns).
    pub rms: f64,
    /// Corners in the final fit.
    pub corners_used: usize,
    /// LM iterations of the final fit.
    pub iterations: usize,
    /// How the start was found.
    pub init: InitInfo,
    /// Every input view, used or not.
    pub views: Vec<ViewResult>,
    /// The outlier rule, in words.
    pub outlier_rule: String,
    /// Images in which no board was found, and why (`calibrate --images`; empty otherwise).
    pub not_found: Vec<NotFound>,
}

impl Calibration {
    /// The intrinsics uncertainty a camera file states for this fit
    /// ([`crate::camera::import::IntrinsicsSigma`]), from the parameters' standard deviations:
    /// the larger of the two focal lengths' relative σ, the larger principal-point coordinate's σ.
    pub fn stated_sigma(&self) -> crate::camera::import::IntrinsicsSigma {
        let p = |name: &str| self.params.iter().find(|p| p.name == name);
        let rel = |name: &str| p(name).map_or(0.0, |p| (p.std / p.value).abs());
        let std = |name: &str| p(name).map_or(0.0, |p| p.std);
        crate::camera::import::IntrinsicsSigma {
            focal_rel: rel("fx").max(rel("fy")),
            principal_point_px: std("cx").max(std("cy")),
        }
    }
}

/// An image without a usable board.
#[derive(Debug, Clone, Serialize)]
pub struct NotFound {
    /// The image's file name.
    pub name: String,
    /// Why no board was taken from it.
    pub reason: String,
}

/// Check the observations; the error names the view and point.
pub(crate) fn validate(obs: &Observations) -> Result<(), CalibError> {
    if obs.width == 0 || obs.height == 0 {
        return Err(CalibError::EmptySize {
            width: obs.width,
            height: obs.height,
        });
    }
    if obs.views.is_empty() {
        return Err(CalibError::NoViews);
    }
    let (w, h) = (obs.width as f64, obs.height as f64);
    for v in &obs.views {
        if v.object.len() != v.image.len() {
            return Err(CalibError::Counts {
                view: v.name.clone(),
                object: v.object.len(),
                image: v.image.len(),
            });
        }
        for (i, (x, p)) in v.object.iter().zip(&v.image).enumerate() {
            if !(x.iter().chain(p).all(|c| c.is_finite())) {
                return Err(CalibError::NotFinite {
                    view: v.name.clone(),
                    index: i,
                });
            }
            if !(p[0] >= -0.5 && p[0] <= w - 0.5 && p[1] >= -0.5 && p[1] <= h - 0.5) {
                return Err(CalibError::Outside {
                    view: v.name.clone(),
                    index: i,
                    x: p[0],
                    y: p[1],
                    width: obs.width,
                    height: obs.height,
                });
            }
        }
    }
    Ok(())
}

/// The outlier rule as stated in the report.
fn outlier_rule() -> String {
    format!(
        "while the worst view's RMS exceeds {OUTLIER_FACTOR} × the median view RMS and \
         {OUTLIER_FLOOR_PX} px, it is removed and the rest re-fitted (never below {MIN_VIEWS} views)"
    )
}

/// Tilt of a board from fronto-parallel: angle between its normal and the optical axis, degrees.
fn tilt_deg(pose: &Pose, plane_normal: Vector3<f64>) -> f64 {
    let n = pose.r * plane_normal;
    n.z.abs().min(1.0).acos().to_degrees()
}

/// Calibrate `model` from the observations.
pub fn calibrate(obs: &Observations, model: LensModel) -> Result<Calibration, CalibError> {
    validate(obs)?;
    let size = (obs.width, obs.height);
    let mut results: Vec<ViewResult> = obs
        .views
        .iter()
        .map(|v| ViewResult {
            name: v.name.clone(),
            corners: v.image.len(),
            used: false,
            rejected: None,
            rms: None,
            rvec: None,
            tvec: None,
            tilt_deg: None,
            residuals: Vec::new(),
        })
        .collect();
    // Planes; views too small for a homography are set aside, non-planar boards are an error.
    let mut planes: Vec<Option<Plane>> = Vec::with_capacity(obs.views.len());
    for (v, r) in obs.views.iter().zip(results.iter_mut()) {
        if v.image.len() < MIN_CORNERS {
            r.rejected = Some(format!("{} corners, need {MIN_CORNERS}", v.image.len()));
            planes.push(None);
            continue;
        }
        planes.push(Some(Plane::fit(&v.object).map_err(|reason| {
            CalibError::Plane {
                view: v.name.clone(),
                reason,
            }
        })?));
    }
    let usable: Vec<usize> = (0..obs.views.len())
        .filter(|i| planes[*i].is_some())
        .collect();
    let too_few = |n: usize, results: &[ViewResult]| {
        let rejected = results
            .iter()
            .filter_map(|r| r.rejected.as_ref().map(|m| format!("{}: {m}", r.name)))
            .collect();
        CalibError::TooFewViews {
            usable: n,
            min: MIN_VIEWS,
            rejected,
        }
    };
    if usable.len() < MIN_VIEWS {
        return Err(too_few(usable.len(), &results));
    }
    let init_views: Vec<InitView> = usable
        .iter()
        .map(|&i| InitView {
            plane: planes[i].as_ref().expect("usable views have a plane"),
            image: &obs.views[i].image,
        })
        .collect();
    let objects: Vec<&[[f64; 3]]> = usable.iter().map(|&i| &obs.views[i].object[..]).collect();
    let (intr0, init_info) =
        init::initial_intrinsics(model, size, &init_views, &objects).ok_or(CalibError::NoStart)?;

    // Initial poses; a view whose homography fails is rejected.
    let mut used: Vec<usize> = Vec::new();
    let mut poses: Vec<Pose> = Vec::new();
    for (&i, iv) in usable.iter().zip(&init_views) {
        match init::view_pose(model, &intr0, size, iv) {
            Some(p) => {
                used.push(i);
                poses.push(p);
            }
            None => results[i].rejected = Some("no pose from the board homography".into()),
        }
    }
    if used.len() < MIN_VIEWS {
        return Err(too_few(used.len(), &results));
    }
    let normal_of = |i: usize| -> Vector3<f64> {
        let pl = planes[i].as_ref().expect("used views have a plane");
        pl.normal()
    };
    let tilts: Vec<f64> = used
        .iter()
        .zip(&poses)
        .map(|(&i, p)| tilt_deg(p, normal_of(i)))
        .collect();
    let max_tilt = tilts.iter().cloned().fold(0.0, f64::max);
    if max_tilt < MIN_TILT_DEG {
        return Err(CalibError::FrontoParallel {
            views: used.len(),
            max_tilt_deg: max_tilt,
            min_tilt_deg: MIN_TILT_DEG,
        });
    }

    let mut state = State { intr: intr0, poses };
    let (run, final_used) =
        fit_rejecting_outliers(obs, model, &mut state, used, &mut results, &normal_of)?;
    let camera = model.camera(&state.intr, obs.width, obs.height);
    check_fitted(&camera, obs, &final_used, &state)?;
    let views = obs_views(obs, &final_used);
    let std = lm::intrinsic_std(model, &state, &views, run.cost)
        .unwrap_or_else(|| vec![f64::NAN; model.n_params()]);
    let corners_used: usize = views.iter().map(|v| v.object.len()).sum();
    let rms = (run.cost / corners_used as f64).sqrt();
    Ok(Calibration {
        model,
        camera,
        image_size: [obs.width, obs.height],
        params: model
            .names()
            .iter()
            .zip(&state.intr)
            .zip(&std)
            .map(|((name, v), s)| Param {
                name,
                value: *v,
                std: *s,
            })
            .collect(),
        rms,
        corners_used,
        iterations: run.iterations,
        init: init_info,
        views: results,
        outlier_rule: outlier_rule(),
        not_found: Vec::new(),
    })
}

/// Fit `state` to the `used` views, removing the worst view and fitting again while it is an
/// outlier (the report's rule), and record each view's result; the fit's run and the views it
/// kept. `normal_of` gives a used view's board normal.
fn fit_rejecting_outliers(
    obs: &Observations,
    model: LensModel,
    state: &mut State,
    mut used: Vec<usize>,
    results: &mut [ViewResult],
    normal_of: &dyn Fn(usize) -> Vector3<f64>,
) -> Result<(lm::LmRun, Vec<usize>), CalibError> {
    let first_used = used.len();
    loop {
        let views = obs_views(obs, &used);
        let mut run = lm::optimise(model, state, &views).ok_or(CalibError::Domain)?;
        if model == LensModel::Mei && used.len() == first_used {
            run = other_xi_starts(state, &views, run);
        }
        let res = lm::residuals(model, state, &views).ok_or(CalibError::Domain)?;
        let rms: Vec<f64> = res.iter().map(|r| rms_of(r)).collect();
        let mut sorted = rms.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let (worst, worst_rms) = rms
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, r)| (i, *r))
            .expect("at least MIN_VIEWS views");
        if used.len() > MIN_VIEWS
            && worst_rms > OUTLIER_FACTOR * median
            && worst_rms > OUTLIER_FLOOR_PX
        {
            results[used[worst]].rejected = Some(format!(
                "outlier: RMS {worst_rms:.3} px > {OUTLIER_FACTOR} × median {median:.3} px"
            ));
            results[used[worst]].rms = Some(worst_rms);
            used.remove(worst);
            state.poses.remove(worst);
            continue;
        }
        for ((&i, r), pose) in used.iter().zip(res).zip(&state.poses) {
            let vr = &mut results[i];
            vr.used = true;
            vr.rms = Some(rms_of(&r));
            let rv = pose.r.scaled_axis();
            vr.rvec = Some([rv.x, rv.y, rv.z]);
            vr.tvec = Some([pose.t.x, pose.t.y, pose.t.z]);
            vr.tilt_deg = Some(tilt_deg(pose, normal_of(i)));
            vr.residuals = r;
        }
        return Ok((run, used));
    }
}

/// The observations of the views `used`, as the fit takes them.
fn obs_views<'a>(obs: &'a Observations, used: &[usize]) -> Vec<Obs<'a>> {
    used.iter()
        .map(|&i| Obs {
            object: &obs.views[i].object,
            image: &obs.views[i].image,
        })
        .collect()
}

/// The fitted camera must be valid and accept every observation the fit used (no fold, not
/// behind the mirror), or the file would not describe what was fitted.
fn check_fitted(
    camera: &Camera,
    obs: &Observations,
    used: &[usize],
    state: &State,
) -> Result<(), CalibError> {
    camera.validate().map_err(CalibError::InvalidCamera)?;
    for (&i, pose) in used.iter().zip(&state.poses) {
        for (j, x) in obs.views[i].object.iter().enumerate() {
            if let Err(e) = camera.project(&pose.apply(x)) {
                return Err(CalibError::NotInvertible {
                    view: obs.views[i].name.clone(),
                    index: j,
                    reason: e.to_string(),
                });
            }
        }
    }
    Ok(())
}

/// Starting values of ξ tried besides the Mei & Rives start (ξ = 1).
const XI_STARTS: [f64; 5] = [0.6, 1.0, 1.6, 2.4, 3.5];

/// In the Mei model γ, ξ and k1 trade against each other so nearly that LM from ξ = 1 can settle
/// in a local minimum (seen on rendered boards: ξ 1.23 for a true 1.5, at 0.005 px RMS on exact
/// corners, with the mapping off by pixels near the edge). Restart from other ξ, with γ scaled to
/// keep the focal length near the axis (γ/(1+ξ)) and no radial distortion, and keep the lowest cost.
fn other_xi_starts(state: &mut State, views: &[Obs], run: lm::LmRun) -> lm::LmRun {
    let mut best = (run, state.clone());
    let xi0 = state.intr[9];
    for xi in XI_STARTS {
        if (xi - xi0).abs() < 0.05 {
            continue;
        }
        let mut s = state.clone();
        let scale = (1.0 + xi) / (1.0 + xi0);
        s.intr[0] *= scale;
        s.intr[1] *= scale;
        s.intr[5] = 0.0;
        s.intr[6] = 0.0;
        s.intr[9] = xi;
        if let Some(r) = lm::optimise(LensModel::Mei, &mut s, views) {
            if r.cost < best.0.cost {
                best = (r, s);
            }
        }
    }
    *state = best.1;
    best.0
}

/// RMS of residual vectors.
fn rms_of(r: &[[f64; 2]]) -> f64 {
    (r.iter().map(|e| e[0] * e[0] + e[1] * e[1]).sum::<f64>() / r.len().max(1) as f64).sqrt()
}

/// The calibration as OpenCV FileStorage YAML: the camera (docs/interfaces.md, "Camera intrinsics files"; read back by
/// [`crate::camera::load_camera`] and by `cv2.FileStorage`), `rms`, and the σ the fit states
/// ([`Calibration::stated_sigma`]: `sigma_focal_rel`, `sigma_principal_point_px`), which
/// `localize` carries into the pose's covariance.
pub fn to_yaml(c: &Calibration) -> String {
    let mut s = crate::camera::to_opencv_yaml(&c.camera);
    s.push_str(&format!("rms: {:e}\n", c.rms));
    s.push_str(&c.stated_sigma().yaml_lines());
    s
}

#[cfg(test)]
mod tests;
