//! The two-step pipeline (pure): prior → initialization (satellite matching + PnP) → MI refinement →
//! quality gate (and, when the gate refuses a hypothesis the initializer's verifier could not tell
//! from its runner-up, the runner-up's refinement and the gate again). The shell (`infraloc
//! localize`, `demo`, the daemon) gathers the inputs and writes the outputs; the clock for stage
//! timings is injected.

use super::frame::{Frame, MapLayers};
use crate::error::{Error, Result};
use crate::localize::init::coarse::CoarseParams;
use crate::localize::init::matcher::{initialize_with, MatchQuery, Matcher};
use crate::localize::init::verify::MiVerifier;
use crate::localize::init::{initialize, FineParams, InitResult, SearchArea};
use crate::localize::mi::objective::View;
use crate::localize::mi::space::SearchConfig;
use crate::localize::refine::quality::QualityConfig;
use crate::localize::refine::{PolishedSearch, Refinement, Report, Round};
use crate::map::{ground_points, Tile};
use crate::pose::CamFromMap;
use crate::stage::StageName;
use rand::SeedableRng;
use serde::Serialize;
use serde_json::{json, Value};

/// Pipeline settings.
#[derive(Debug, Clone)]
pub struct Params {
    /// Coarse matching.
    pub coarse: CoarseParams,
    /// Fine matching + PnP.
    pub fine: FineParams,
    /// MI search.
    pub search: SearchConfig,
    /// MI quality gate.
    pub quality: QualityConfig,
    /// Seed of every random choice (RANSAC).
    pub seed: u64,
    /// GPS search radius = this many σ of the prior …
    pub prior_sigmas: f64,
    /// … clamped to this range, metres.
    pub search_radius_range_m: (f64, f64),
    /// LiDAR points used by MI lie within this radius of the nadir point, metres …
    pub mi_radius_m: f64,
    /// … and within this off-nadir angle, degrees (default [`MI_MAX_OFF_NADIR_DEG`]).
    pub mi_max_off_nadir_deg: f64,
    /// The local 6-DoF polish after the 4-DoF search and the search rounds (pitch/roll about the
    /// ground under the camera, see [`crate::localize::refine::polish`] and [`crate::localize::refine::refine_polished`]); `None` keeps
    /// PnP's roll and pitch and searches once.
    pub polish: Option<PolishedSearch>,
    /// Initialization's matcher: `None` = the built-in satellite matching (dense orientation
    /// sweep + patch stages, [`initialize`]); `Some` = PnP on that matcher's correspondences
    /// ([`crate::localize::init::matcher::initialize_with`]).
    pub matcher: Option<std::sync::Arc<dyn Matcher>>,
}

/// Default of [`Params::mi_max_off_nadir_deg`]. The far ground is what pins down tilt and yaw
/// (a tilt moves it most, and yaw has the longest lever arm there), and it is where the detection
/// pipeline's ground error grows fastest. At 84° the disc reaches [`Params::mi_radius_m`]'s 30 m
/// for every pole above 3.2 m, so MI sees the ground out to where vehicles are tracked instead of
/// extrapolating the tilt fitted nearer in. On the simulator's calibrated `hard` scenes it cuts
/// the tail of a low pole's ground error against 78° (which reaches 30 m only above 6.4 m), not
/// its median (docs/accuracy.md "Ground disc: 84° off nadir"). The price: a low pole's point set
/// grows to a tall pole's size (docs/benchmarks.md "Ground disc 84° on low poles").
pub(crate) const MI_MAX_OFF_NADIR_DEG: f64 = 84.0;

impl Default for Params {
    fn default() -> Self {
        Params {
            coarse: CoarseParams::default(),
            fine: FineParams::default(),
            search: SearchConfig::default(),
            quality: QualityConfig::default(),
            seed: 0,
            prior_sigmas: 3.0,
            search_radius_range_m: (5.0, 40.0),
            mi_radius_m: 30.0,
            mi_max_off_nadir_deg: MI_MAX_OFF_NADIR_DEG,
            polish: Some(PolishedSearch::default()),
            matcher: None,
        }
    }
}

impl Params {
    /// Radius around the prior that initialization searches, metres.
    pub fn search_radius_m(&self, prior_sigma_m: f64) -> f64 {
        let (lo, hi) = self.search_radius_range_m;
        (self.prior_sigmas * prior_sigma_m).clamp(lo, hi)
    }
}

/// One stage's record for the report and the pose file.
#[derive(Debug, Clone)]
pub struct Stage {
    /// `prior`, `pnp` or `mi`.
    pub name: StageName,
    /// The stage's pose, if it makes one.
    pub pose: Option<CamFromMap>,
    /// Wall time, seconds.
    pub seconds: f64,
    /// Stage-specific figures.
    pub detail: StageDetail,
}

/// A stage's own figures, one type per stage. Serialized (keys sorted, as the pose file and the
/// report have always shown them) under the stage's `detail`.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum StageDetail {
    /// `prior`: where the prior put the camera and how far initialization looks around it.
    Prior(PriorDetail),
    /// `pnp`: what initialization matched and solved.
    Pnp(PnpDetail),
    /// `mi`: the refinement's report and its search/polish rounds.
    Mi(Box<MiDetail>),
}

/// The `prior` stage's figures.
#[derive(Debug, Clone, Serialize)]
pub struct PriorDetail {
    /// Prior position, map CRS, metres.
    pub x: f64,
    /// Prior position, map CRS, metres.
    pub y: f64,
    /// Its horizontal standard deviation, metres.
    pub sigma_m: f64,
    /// Radius initialization searches around it, metres.
    pub search_radius_m: f64,
}

/// The `pnp` stage's figures.
#[derive(Debug, Clone, Serialize)]
pub struct PnpDetail {
    /// Correspondences given to the last PnP.
    pub matches: usize,
    /// Its inliers.
    pub inliers: usize,
    /// Its reprojection RMS, px (NaN → `null` for a verified sweep pose).
    pub rms_px: f64,
    /// Its tilt σ from the residuals, degrees (NaN → `null` for a verified sweep pose): a start
    /// whose 3σ exceeds the re-search threshold has its tilt polished
    /// before the first search ([`PolishedSearch::settle_uncertain_tilt`]).
    pub tilt_sigma_deg: f64,
    /// Its σ per axis ([`crate::localize::refine::uncertainty::initializer`]; absent for a
    /// verified sweep pose or where it cannot be had).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma: Option<crate::pose::Sigma>,
    /// Sweep candidates whose fine stage ran.
    pub candidates: usize,
    /// Rank of the chosen candidate in the sweep's list.
    pub candidate_rank: usize,
    /// The matcher's name (`dense-sweep` for the built-in one).
    pub matcher: String,
    /// With a verifier: the pose's MI with the LiDAR map, nats.
    pub mi: Option<f64>,
    /// … and the strongest competing hypothesis' MI (with `runner_up`, the verifier's first
    /// choice's).
    pub mi_runner_up: Option<f64>,
    /// The coarse candidate the pose grew from.
    pub coarse: CoarseDetail,
    /// Present (`true`) only when the pose is the initializer's last resort: no candidate's fine
    /// stage got through all its iterations, and this is the PnP pose of a coarser one.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub partial_fine_stage: bool,
    /// Present (`true`) only when the pose is the verifier's runner-up: the refinement of its
    /// first choice was refused (the `mi` stage's `other_hypothesis` says why) and this one's
    /// passed the gate.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub runner_up: bool,
}

impl PriorDetail {
    /// The prior at `xy` with σ `sigma_m`, searched within `p`'s radius for that σ.
    pub fn new(xy: (f64, f64), sigma_m: f64, p: &Params) -> Self {
        PriorDetail {
            x: xy.0,
            y: xy.1,
            sigma_m,
            search_radius_m: p.search_radius_m(sigma_m),
        }
    }
}

impl PnpDetail {
    /// The figures of initialization result `init`, made by the matcher named `matcher`, its σ
    /// with the orthophoto's registration σ `orthophoto_sigma_m` (`[quality]`).
    pub fn new(init: &InitResult, matcher: &str, orthophoto_sigma_m: f64) -> Self {
        PnpDetail {
            matches: init.matches,
            inliers: init.inliers,
            rms_px: init.rms_px,
            tilt_sigma_deg: init.tilt_sigma_deg,
            sigma: init.covariance.as_ref().map(|c| {
                crate::pose::Sigma::of(&crate::localize::refine::uncertainty::initializer(
                    c,
                    orthophoto_sigma_m,
                    init.inliers,
                ))
            }),
            candidates: init.candidates_tried,
            candidate_rank: init.candidate_rank,
            matcher: matcher.to_string(),
            mi: init.mi.map(|m| m.0),
            mi_runner_up: init.mi.and_then(|m| m.1),
            coarse: CoarseDetail {
                yaw_deg: init.candidate.yaw.to_degrees(),
                height_m: init.candidate.height,
                offset_m: init.candidate.offset,
                score: init.candidate.score,
            },
            partial_fine_stage: init.partial_fine_stage,
            runner_up: false,
        }
    }
}

/// The coarse sweep candidate of a [`PnpDetail`].
#[derive(Debug, Clone, Serialize)]
pub struct CoarseDetail {
    /// Yaw, degrees.
    pub yaw_deg: f64,
    /// Camera height, metres.
    pub height_m: f64,
    /// Offset from the prior, metres.
    pub offset_m: [f64; 2],
    /// The sweep's score.
    pub score: f64,
}

/// The `mi` stage's figures.
#[derive(Debug, Clone, Serialize)]
pub struct MiDetail {
    /// The refinement's summary (offsets, points, counters, quality).
    #[serde(flatten)]
    pub report: Report,
    /// Each search and the polishes after it.
    pub rounds: Vec<Round>,
    /// The other hypothesis refined, when there were two (see [`OtherHypothesis`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub other_hypothesis: Option<OtherHypothesis>,
}

impl Stage {
    /// JSON form: name, seconds, detail, and the pose as centre + yaw/pitch/roll.
    pub fn to_json(&self) -> Value {
        let mut v =
            json!({ "name": self.name.name(), "seconds": self.seconds, "detail": self.detail });
        if let Some(p) = &self.pose {
            let (y, pi, r) = p.yaw_pitch_roll();
            v["camera_center"] = json!(<[f64; 3]>::from(p.center().coords));
            v["yaw_pitch_roll_deg"] = json!([y.to_degrees(), pi.to_degrees(), r.to_degrees()]);
        }
        v
    }
}

/// What the pipeline produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The final (MI-refined) pose.
    pub pose: CamFromMap,
    /// Initialization details.
    pub init: InitResult,
    /// Refinement details (quality included).
    pub refinement: Refinement,
    /// Per-stage records, in order.
    pub stages: Vec<Stage>,
}

impl Outcome {
    /// The other hypothesis refined, when there were two (the `mi` stage's record of it).
    pub fn other_hypothesis(&self) -> Option<&OtherHypothesis> {
        self.stages.iter().find_map(|s| match &s.detail {
            StageDetail::Mi(d) => d.other_hypothesis.as_ref(),
            _ => None,
        })
    }
}

/// The LiDAR ground points MI uses around `pose`: within [`Params::mi_radius_m`] of the nadir
/// point and within [`Params::mi_max_off_nadir_deg`] of nadir as seen from the camera's height.
pub fn mi_points(tile: &Tile, pose: &CamFromMap, p: &Params) -> Vec<crate::map::GroundPoint> {
    let c = pose.center();
    let (_, radius) = crate::localize::init::ground::ground_disc(
        &tile.height,
        &c,
        p.mi_max_off_nadir_deg,
        p.mi_radius_m,
    );
    ground_points(tile, (c.x, c.y), radius)
}

/// Run the pipeline on a (temporally median-filtered) gray frame. `now` returns seconds from any
/// fixed origin; `progress` is told each stage as it starts, `pnp` (initialization) and `mi`
/// (refinement and gate), for a terminal's status line or the service's status. Errors name the
/// stage and the numbers; a refinement the quality gate rejects is an error (see
/// [`quality_gate`]).
pub fn localize(
    frame: &Frame<'_>,
    tile: &Tile,
    prior_xy: (f64, f64),
    prior_sigma_m: f64,
    p: &Params,
    now: &dyn Fn() -> f64,
    progress: &dyn Fn(StageName),
) -> Result<Outcome> {
    localize_pooled(frame, &[], tile, prior_xy, prior_sigma_m, p, now, progress)
}

/// [`localize`] with `earlier` frames of the same camera at the same pose pooled into the MI
/// stage: initialization matches `frame` alone; the refinement scores every frame on its own
/// histogram ([`crate::localize::mi::Pooling::PerPair`], whatever `p.search` says) against the same ground
/// points, so that shadows which move between the frames' hours stop agreeing with the map and
/// the road that does not move keeps agreeing. The node pools the frames of its earlier runs
/// this way. Each earlier frame must be the camera's size (one line naming it otherwise).
#[allow(clippy::too_many_arguments)]
pub fn localize_pooled(
    frame: &Frame<'_>,
    earlier: &[Frame<'_>],
    tile: &Tile,
    prior_xy: (f64, f64),
    prior_sigma_m: f64,
    p: &Params,
    now: &dyn Fn() -> f64,
    progress: &dyn Fn(StageName),
) -> Result<Outcome> {
    let outcome = localize_ungated(
        frame,
        earlier,
        tile,
        prior_xy,
        prior_sigma_m,
        p,
        now,
        progress,
    )?;
    quality_gate(&outcome)?;
    Ok(outcome)
}

/// The MI quality gate's verdict on an outcome as the error [`localize`] returns.
pub fn quality_gate(o: &Outcome) -> Result<()> {
    if o.refinement.quality.served() {
        return Ok(());
    }
    // Both hypotheses refused: the first choice's reason, then the runner-up's.
    let also = o
        .other_hypothesis()
        .map(|h| {
            format!(
                "; the runner-up hypothesis at ({:.1}, {:.1}), yaw {:.1}°, refused too: {}",
                h.camera_center[0], h.camera_center[1], h.yaw_deg, h.refused
            )
        })
        .unwrap_or_default();
    Err(Error::stage(
        StageName::Mi,
        format!("quality gate: {}{also}", refusal(&o.refinement)),
    ))
}

/// The MI stage from `start`, whose tilt σ is `tilt_sigma_deg` (NaN: unknown): the nearest-pixel
/// search rounds ([`crate::localize::refine::refine_polished`]) on the ground points around it, stopping at the basin
/// ([`PolishedSearch::basin`]) with the start's tilt polished first when its σ says it is
/// uncertain ([`PolishedSearch::settle_uncertain_tilt`]), then the smooth estimator's stage: its
/// 4-DoF gradient ascent, its information over all six axes, the competing optima (the σ) and
/// its gate ([`crate::localize::refine::local::smooth_stage`]).
fn refine_at(
    frame: &Frame<'_>,
    earlier: &[Frame<'_>],
    tile: &Tile,
    p: &Params,
    start: &CamFromMap,
    tilt_sigma_deg: f64,
) -> Result<(Refinement, Vec<Round>)> {
    let camera = frame.camera();
    // Pitch and roll pivot about the ground under the camera (the tile's height layer).
    let pivot = |pose: &CamFromMap| {
        let c = pose.center();
        crate::localize::init::ground::height_at(&tile.height, c.x, c.y).map(|g| (c.z - g).max(1.0))
    };
    let points = mi_points(tile, start, p);
    let views: Vec<View<'_>> = std::iter::once(frame)
        .chain(earlier)
        .map(|f| View {
            gray: f.gray(),
            mask: f.mask(),
            points: &points,
        })
        .collect();
    // Frames of other hours each keep their own gray–reflectivity relation: one histogram per
    // frame, whatever the search's pooling (its default is one joint histogram).
    let mut search = p.search;
    if !earlier.is_empty() {
        search.mi.pooling = crate::localize::mi::Pooling::PerPair;
    }
    // The searches find the basin; the polish and the gradient ascent take it from there.
    let polish = p
        .polish
        .map(|q| q.basin().settle_uncertain_tilt(tilt_sigma_deg));
    // The searches, polishes and the smooth stage share one preparation of each frame.
    let cache = crate::localize::mi::objective::ImageCache::default();
    let (r, rounds) = crate::localize::refine::rounds::refine_polished_cached(
        camera,
        &views,
        start,
        &search,
        &p.quality,
        polish.as_ref(),
        &pivot,
        &cache,
    )?;
    // The polish estimated the tilt: the information covers it too.
    let free = if polish.is_some_and(|q| q.polish.frees_tilt()) {
        crate::localize::refine::local::SmoothFree::FourAfterSix
    } else {
        crate::localize::refine::local::SmoothFree::Four
    };
    let (r, _) = crate::localize::refine::local::smooth_stage(
        camera, &views, start, r, &search, &p.quality, free, &cache,
    )?;
    Ok((r, rounds))
}

/// Every earlier frame the camera's size, and a usable prior: one line naming the frame or the
/// prior otherwise.
fn check_inputs(
    frame: &Frame<'_>,
    earlier: &[Frame<'_>],
    prior_xy: (f64, f64),
    prior_sigma_m: f64,
) -> Result<()> {
    use crate::camera::CameraModel;
    let camera = frame.camera();
    if let Some((i, f)) = earlier.iter().enumerate().find(|(_, f)| {
        (f.camera().width(), f.camera().height()) != (camera.width(), camera.height())
    }) {
        return Err(Error::stage(
            StageName::Mi,
            format!(
                "pooled frame {} is {}×{}, the camera is {}×{}",
                i + 1,
                f.camera().width(),
                f.camera().height(),
                camera.width(),
                camera.height()
            ),
        ));
    }
    if !(prior_sigma_m > 0.0 && prior_xy.0.is_finite() && prior_xy.1.is_finite()) {
        return Err(Error::stage(
            StageName::Prior,
            format!("unusable prior {prior_xy:?} σ {prior_sigma_m}"),
        ));
    }
    Ok(())
}

/// [`localize`] without the quality gate: the outcome whatever the gate would say, so that an
/// evaluation can still see the stages of a rejected run (`examples/pipeline_accuracy.rs`);
/// `progress` as there, and `earlier` as [`localize_pooled`] pools them.
#[allow(clippy::too_many_arguments)]
pub(crate) fn localize_ungated(
    frame: &Frame<'_>,
    earlier: &[Frame<'_>],
    tile: &Tile,
    prior_xy: (f64, f64),
    prior_sigma_m: f64,
    p: &Params,
    now: &dyn Fn() -> f64,
    progress: &dyn Fn(StageName),
) -> Result<Outcome> {
    let (camera, image) = (frame.camera(), frame.gray());
    check_inputs(frame, earlier, prior_xy, prior_sigma_m)?;
    let radius = p.search_radius_m(prior_sigma_m);
    let mut stages = vec![Stage {
        name: StageName::Prior,
        pose: None,
        seconds: 0.0,
        detail: StageDetail::Prior(PriorDetail::new(prior_xy, prior_sigma_m, p)),
    }];
    // A LiDAR-only tile (no orthophoto, no colour) has nothing for the initializer to match.
    let Some(satellite) = tile.satellite.as_ref() else {
        return Err(Error::stage(
            StageName::Tile,
            format!(
                "tile {:?} has no satellite layer: the initializer needs one; add an orthophoto \
                 with `infraloc tile build --orthophoto FILE` or `infraloc tile import --satellite FILE`",
                tile.id
            ),
        ));
    };
    if !satellite.grid.contains(prior_xy.0, prior_xy.1, 0.0) {
        return Err(Error::stage(
            StageName::Prior,
            format!(
                "prior ({:.1}, {:.1}) is outside tile {:?}",
                prior_xy.0, prior_xy.1, tile.id
            ),
        ));
    }
    progress(StageName::Pnp);
    let t0 = now();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed);
    // The LiDAR map judges the satellite matching's hypotheses (independent evidence).
    let verifier = p.fine.verify.enabled.then(|| {
        MiVerifier::new(camera, image, tile, p.fine.verify.mi.clone())
            .for_search_area(prior_xy, radius)
    });
    let init = match &p.matcher {
        None => initialize(
            frame,
            MapLayers {
                satellite,
                heights: &tile.height,
            },
            SearchArea {
                center: prior_xy,
                radius_m: radius,
            },
            &p.coarse,
            &p.fine,
            verifier.as_ref(),
            &mut rng,
        )?,
        Some(m) => {
            let q = MatchQuery {
                camera,
                image,
                satellite,
                heights: &tile.height,
                prior_xy,
                search_radius_m: radius,
            };
            initialize_with(m.as_ref(), &q, &p.fine, verifier.as_ref(), &mut rng)?
        }
    };
    // The verifier holds its own image pyramid (≈ 20 MB at 5 MP); the MI stage does not use it.
    drop(verifier);
    let t1 = now();
    progress(StageName::Mi);
    let refine =
        |start: &InitResult| refine_at(frame, earlier, tile, p, &start.pose, start.tilt_sigma_deg);
    let mut init = init;
    let (mut refinement, mut rounds) = refine(&init)?;
    // The verifier could not tell two hypotheses apart (see `VerifySchedule::runner_up_margin`)
    // and the gate refused the one it preferred: where the runner-up lies outside that search's
    // box, the refinement there is new evidence, and the gate chooses. A first refinement that
    // fails outright (an error, not a verdict) ends the run as before.
    let mut other = None;
    let runner_up = init.runner_up.take();
    if let Some(alt) = runner_up.filter(|a| {
        !refinement.quality.precise() && outside_box(&p.search.spec, &init.pose, &a.pose)
    }) {
        match refine(&alt) {
            Ok((second, second_rounds))
                if second.quality.grade.rank() > refinement.quality.grade.rank() =>
            {
                other = Some(OtherHypothesis::new(&init, refusal(&refinement), true));
                (init, refinement, rounds) = (*alt, second, second_rounds);
                init.runner_up = None;
            }
            Ok((second, _)) => other = Some(OtherHypothesis::new(&alt, refusal(&second), false)),
            Err(e) => other = Some(OtherHypothesis::new(&alt, e.to_string(), false)),
        }
    }
    let t2 = now();
    let served = serve_initializer(&init, &refinement, &p.quality);
    let mut pnp = PnpDetail::new(
        &init,
        p.matcher.as_ref().map_or("dense-sweep", |m| m.name()),
        p.quality.orthophoto_sigma_m,
    );
    pnp.runner_up = other.as_ref().is_some_and(|o| o.accepted_instead);
    stages.push(Stage {
        name: StageName::Pnp,
        pose: Some(init.pose),
        seconds: t1 - t0,
        detail: StageDetail::Pnp(pnp),
    });
    stages.push(Stage {
        name: StageName::Mi,
        pose: Some(refinement.pose),
        seconds: t2 - t1,
        detail: StageDetail::Mi(Box::new(MiDetail {
            report: refinement.report(p.search.mode),
            rounds,
            other_hypothesis: other,
        })),
    });
    let refinement = served.unwrap_or(refinement);
    Ok(Outcome {
        pose: refinement.pose,
        init,
        refinement,
        stages,
    })
}

/// The initializer's own pose as the served result, when the refinement was refused and the
/// initializer's σ ([`crate::localize::refine::uncertainty::initializer`]) grades it served:
/// its quality carries that σ, its grade and the refinement's refusal
/// ([`crate::localize::refine::quality::Quality::initializer`]); its score (NMI) is 0, below
/// any refined result's. `None` when the refinement was served, the initializer has no
/// covariance (a verified sweep pose), its σ is refused too, the refinement's optimum lay on
/// its search box's edge, or the refused refinement's answer lies beyond its 3σ on x, y, z or
/// yaw.
fn serve_initializer(
    init: &InitResult,
    refinement: &Refinement,
    q: &crate::localize::refine::quality::QualityConfig,
) -> Option<Refinement> {
    use crate::localize::refine::quality::{FromInitializer, Quality, Sigma};
    let stop = refinement.quality.grade.stop()?.clone();
    // An optimum on the search box's edge says the data prefer a pose beyond it: the start is
    // off, and its own σ cannot say by how much.
    if matches!(
        stop,
        crate::localize::refine::verdict::Stop::Grid(
            crate::localize::error::Refusal::OnEdge { .. }
        )
    ) {
        return None;
    }
    let u = crate::localize::refine::uncertainty::initializer(
        init.covariance.as_ref()?,
        q.orthophoto_sigma_m,
        init.inliers,
    );
    let grade = crate::localize::refine::verdict::judge(&u, &q.limits());
    // The refused refinement is no proof, but where its answer lies beyond the initializer's
    // 3σ the two disagree, and a wrong hypothesis (a matching that fits itself well in the
    // wrong place) is what that disagreement most often is.
    let d = crate::pose::offsets_between(&init.pose, &refinement.pose);
    let agree = (0..4).all(|k| d[k].abs() <= 3.0 * u.sigma[k]);
    if !grade.served() || !agree {
        return None;
    }
    Some(Refinement {
        pose: init.pose,
        offsets: [0.0; 6],
        quality: Quality {
            mi: 0.0,
            nmi: 0.0,
            points: init.inliers as u64,
            background: 0.0,
            second_peak_ratio: None,
            second_peak_contrast: None,
            second_peak_offset: None,
            axes: Vec::new(),
            poses: 0,
            sigma: Some(Sigma::of(&u)),
            covariance: Some(u),
            information: None,
            optima: None,
            region: None,
            grade,
            initializer: Some(FromInitializer(stop)),
        },
        peaks: Vec::new(),
        ..refinement.clone()
    })
}

/// Why `r` is not precise: its refusal, or its coarse grade, in words.
fn refusal(r: &Refinement) -> String {
    match &r.quality.grade {
        crate::localize::refine::verdict::Grade::Refused(s) => s.to_string(),
        g => g.to_string(),
    }
}

/// Whether `b`'s camera lies outside the search box `spec` around `a` (in x, y, height or yaw):
/// a refinement from `a` has not searched there.
fn outside_box(
    spec: &crate::localize::mi::space::SearchSpec,
    a: &CamFromMap,
    b: &CamFromMap,
) -> bool {
    let d = crate::pose::offsets_between(a, b);
    d[0].abs() > spec.x.half
        || d[1].abs() > spec.y.half
        || d[2].abs() > spec.z.half
        || d[3].abs() > spec.yaw.half
}

/// The hypothesis whose refinement the gate refused, when the initializer's verifier kept two
/// (a thin MI margin between them, see [`crate::localize::init::VerifySchedule::runner_up_margin`]) and
/// both were refined.
#[derive(Debug, Clone, Serialize)]
pub struct OtherHypothesis {
    /// Its initial pose's camera centre, map CRS, metres.
    pub camera_center: [f64; 3],
    /// Its initial yaw, degrees.
    pub yaw_deg: f64,
    /// Its verifier MI, nats.
    pub mi: Option<f64>,
    /// Why its refinement was refused (the gate's reason, or the refinement's error).
    pub refused: String,
    /// `true`: it was the verifier's first choice, and the runner-up's refinement passed the gate
    /// and is the result; `false`: it is the runner-up, refused as well as the first choice.
    pub accepted_instead: bool,
}

impl OtherHypothesis {
    fn new(h: &InitResult, refused: String, accepted_instead: bool) -> Self {
        let (y, _, _) = h.pose.yaw_pitch_roll();
        OtherHypothesis {
            camera_center: h.pose.center().coords.into(),
            yaw_deg: y.to_degrees(),
            mi: h.mi.map(|m| m.0),
            refused,
            accepted_instead,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::localize::mi::space::SearchSpec;
    use nalgebra::Point3;

    fn pose(x: f64, y: f64, z: f64, yaw_deg: f64) -> CamFromMap {
        CamFromMap::from_center_ypr(&Point3::new(x, y, z), yaw_deg.to_radians(), 0.0, 0.0)
    }

    #[test]
    fn a_second_hypothesis_counts_only_outside_the_first_ones_search_box() {
        let spec = SearchSpec::default();
        let a = pose(100.0, 200.0, 10.0, 359.0);
        // Inside on every axis, yaw across the wrap included: the first search has been there.
        assert!(!outside_box(&spec, &a, &pose(100.9, 199.1, 10.4, 1.5)));
        // Outside on one axis each.
        for b in [
            pose(101.1, 200.0, 10.0, 359.0),
            pose(100.0, 198.9, 10.0, 359.0),
            pose(100.0, 200.0, 10.6, 359.0),
            pose(100.0, 200.0, 10.0, 2.5),
        ] {
            assert!(outside_box(&spec, &a, &b), "{:?}", b.center());
        }
    }
}
