//! The MI objective: an [`Evaluator`] scores candidate poses of a search space by the mutual
//! information of the LiDAR reflectivity with the image gray at the points' projections, over a
//! fixed point set (the bias remedy of `refine::search`), with its image pyramid and point
//! subsamples; [`ImageCache`] keeps prepared images between evaluators.

// Axis-indexed loops over parallel fixed-size arrays ([_; 6]) read clearer with the index.
#![allow(clippy::needless_range_loop)]

use super::space::{box_lattice, pose_at_pivot, Cell, Grid, SearchConfig};
use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::localize::error::LocalizeError;
use crate::localize::mi::kernel::{
    self, accumulate, visible, visible_from_all, BinnedImage, FastCamera, GrayLevel, PoseF32,
    Scratch,
};
use crate::localize::mi::points::{morton_order, validate, GroundPoint, PreparedPoints};
use crate::localize::mi::{bin_lut, pooled_information, JointHist, MiConfig, MiValue, Pooling};
use crate::pose::CamFromMap;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// One image and the points it sees, for a search whose pose all the views share: one frame and
/// its LiDAR sweep, or one of several frames of a static camera over one tile. Several views
/// feed one joint histogram per candidate pose (pooled refinement).
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// Gray image, row-major at the camera's size.
    pub gray: &'a [u8],
    /// Validity mask at the camera's size (non-zero = valid pixel).
    pub mask: &'a [u8],
    /// The points.
    pub points: &'a [GroundPoint],
}

/// Groups of an evaluator's level-0 points ([`Evaluator::folds`]), scored in parallel.
#[derive(Debug, Clone)]
pub(crate) struct Folds {
    parts: Vec<Vec<PreparedPoints>>,
    k: usize,
}

/// One view at one level of the evaluator: its image and its points at that resolution.
#[derive(Debug, Clone)]
pub(crate) struct Part {
    img: Arc<BinnedImage>,
    pts: PreparedPoints,
}

/// One level of the evaluator: the camera and every view at that resolution.
#[derive(Debug, Clone)]
pub(crate) struct Level {
    cam: FastCamera,
    parts: Vec<Part>,
}

/// Everything needed to score a grid cell: the problem prepared at every pyramid level.
#[derive(Debug, Clone)]
pub struct Evaluator {
    pub(crate) init: CamFromMap,
    pub(crate) origin: [f64; 3],
    pub(crate) grid: Grid,
    pub(crate) mi: MiConfig,
    pub(crate) levels: Vec<Level>,
    /// Points in the (fixed) set at level 0, all views together.
    pub n_points: usize,
    /// Points given, all views together.
    pub n_input: usize,
    /// Per view: points given and points in its fixed set.
    pub view_points: Vec<(usize, usize)>,
}

/// A scored cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scored {
    /// Cell number.
    pub idx: u64,
    /// Objective value.
    pub score: f64,
    /// Full statistics.
    pub value: MiValue,
}

/// Total order: higher score first, then lower cell number.
pub(crate) fn better(a: &Scored, b: &Scored) -> bool {
    a.score > b.score || (a.score == b.score && a.idx < b.idx)
}

pub(crate) fn best_of<'a>(it: impl IntoIterator<Item = &'a Scored>) -> Option<Scored> {
    it.into_iter()
        .fold(None, |acc: Option<Scored>, s| match acc {
            Some(a) if !better(s, &a) => Some(a),
            _ => Some(*s),
        })
}

/// The image side of a view's preparation: everything that depends on the frame, its mask and
/// the estimator's gray binning and visibility margin, but not on the pose or the points.
pub(crate) struct ViewImage {
    lut_gray: [u8; 256],
    /// The mask eroded by the visibility margin (as the binned image the fixed set is tested
    /// on) and its chessboard distance map; only with the fixed point set.
    eroded: Option<(BinnedImage, Vec<u16>)>,
    /// Level l's smoothed gray and mask with its binned image, from level 0 up to the deepest
    /// level asked for so far (levels are added on demand: only the search uses coarse ones).
    levels: Mutex<Vec<(GrayLevel, Arc<BinnedImage>)>>,
}

impl ViewImage {
    /// Binned images of levels 0..=`max_level`, building the missing coarse levels.
    pub(crate) fn binned_levels(&self, max_level: u32, invalid: u8) -> Vec<Arc<BinnedImage>> {
        let mut levels = self.levels.lock().unwrap_or_else(|e| e.into_inner());
        while levels.len() <= max_level as usize {
            let (prev, _) = &levels[levels.len() - 1];
            let g = prev.downsample();
            let img =
                BinnedImage::new(g.width, g.height, &g.gray, &g.mask, &self.lut_gray, invalid);
            levels.push((g, Arc::new(img)));
        }
        levels[..=max_level as usize]
            .iter()
            .map(|(_, img)| Arc::clone(img))
            .collect()
    }
}

/// What a [`ViewImage`] was prepared with, besides the frame and mask themselves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ImageKey {
    binning: crate::localize::mi::Binning,
    bins_gray: usize,
    fixed_point_set: bool,
    visibility_margin_px: usize,
}

impl ImageKey {
    pub(crate) fn of(cfg: &SearchConfig) -> Self {
        ImageKey {
            binning: cfg.mi.binning,
            bins_gray: cfg.mi.bins_gray,
            fixed_point_set: cfg.fixed_point_set,
            visibility_margin_px: cfg.visibility_margin_px,
        }
    }
}

/// Image preparations shared by the evaluators one refinement builds on the same frames (the
/// search's, the polish's, the smooth stage's): the blur, the gray binning, the
/// erosion with its distance map and the pyramid are the same for all of them, only the point
/// sets differ. Likewise the Morton order of a point set ([`morton_order`]), which
/// depends on the points alone while each evaluator's origin, bins and fixed set differ. An
/// entry is found by the very slices it was made from (same address and length, borrowed for
/// the cache's whole life so they cannot change) and the same settings; anything else is
/// prepared afresh, so the cache can only save work, never change a result.
#[derive(Default)]
pub(crate) struct ImageCache<'a> {
    entries: Mutex<Vec<CachedImage<'a>>>,
    orders: Mutex<Vec<CachedOrder<'a>>>,
}

/// A point set and its Morton order.
pub(crate) type CachedOrder<'a> = (&'a [GroundPoint], Arc<Vec<usize>>);

pub(crate) struct CachedImage<'a> {
    gray: &'a [u8],
    mask: &'a [u8],
    key: ImageKey,
    image: Arc<ViewImage>,
}

impl<'a> ImageCache<'a> {
    /// The preparation of `v`'s image under `cfg`, made now or earlier.
    pub(crate) fn get(
        &self,
        cam: &Camera,
        v: &View<'a>,
        cfg: &SearchConfig,
    ) -> std::result::Result<Arc<ViewImage>, LocalizeError> {
        let key = ImageKey::of(cfg);
        let same = |e: &CachedImage<'a>| {
            std::ptr::eq(e.gray, v.gray) && std::ptr::eq(e.mask, v.mask) && e.key == key
        };
        if let Some(e) = self.lock().iter().find(|e| same(e)) {
            return Ok(Arc::clone(&e.image));
        }
        let image = Arc::new(prepare_image(cam, v.gray, v.mask, cfg)?);
        self.lock().push(CachedImage {
            gray: v.gray,
            mask: v.mask,
            key,
            image: Arc::clone(&image),
        });
        Ok(image)
    }

    pub(crate) fn lock(&self) -> std::sync::MutexGuard<'_, Vec<CachedImage<'a>>> {
        self.entries.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The Morton order of `points`, computed now or earlier.
    pub(crate) fn order(&self, points: &'a [GroundPoint]) -> Arc<Vec<usize>> {
        let lock = || self.orders.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, o)) = lock().iter().find(|(p, _)| std::ptr::eq(*p, points)) {
            return Arc::clone(o);
        }
        let order = Arc::new(morton_order(points));
        lock().push((points, Arc::clone(&order)));
        order
    }
}

impl Evaluator {
    /// Prepare the problem: validate inputs, bin, build the pyramid (levels 0..=`max_level`) and the
    /// fixed point set. `gray`/`mask` are row-major at the camera's size (mask non-zero = valid
    /// pixel, e.g. [`CameraModel::valid_mask`]).
    pub fn new(
        cam: &Camera,
        gray: &[u8],
        mask: &[u8],
        points: &[GroundPoint],
        init: &CamFromMap,
        cfg: &SearchConfig,
        max_level: u32,
    ) -> Result<Self> {
        Self::pooled(cam, &[View { gray, mask, points }], init, cfg, max_level)
    }

    /// [`Evaluator::new`] over several views that share the pose: each view is binned on its own
    /// (its gray and reflectivity bin edges come from its own data, so frames under different
    /// light are labelled alike) and keeps its own fixed point set; a candidate pose's joint
    /// histogram is the sum over the views. With one view this is exactly [`Evaluator::new`].
    pub fn pooled(
        cam: &Camera,
        views: &[View<'_>],
        init: &CamFromMap,
        cfg: &SearchConfig,
        max_level: u32,
    ) -> Result<Self> {
        Self::pooled_cached(cam, views, init, cfg, max_level, &ImageCache::default())
    }

    /// [`Evaluator::pooled`] taking the views' image preparations from `cache` (and leaving
    /// there the ones it makes), for a refinement that builds several evaluators on one frame.
    pub(crate) fn pooled_cached<'a>(
        cam: &Camera,
        views: &[View<'a>],
        init: &CamFromMap,
        cfg: &SearchConfig,
        max_level: u32,
        cache: &ImageCache<'a>,
    ) -> Result<Self> {
        if views.is_empty() {
            return Err(LocalizeError::NoPairs.into());
        }
        cfg.mi.validate()?;
        cfg.spec.validate()?;
        let grid = cfg.spec.grid();
        let c = init.center();
        let origin = [c.x, c.y, c.z];
        let pooled = views.len() > 1;
        // One error line per view: with several, it names the pair (1-based, as given).
        let name = |i: usize, e: LocalizeError| -> Error {
            if pooled {
                LocalizeError::Pair {
                    index: i + 1,
                    of: views.len(),
                    source: Box::new(e),
                }
                .into()
            } else {
                e.into()
            }
        };
        let invalid = cfg.mi.bins_gray as u8;
        // Per view: its binned image at every level, and its fixed point set.
        let mut prepared = Vec::with_capacity(views.len());
        for (i, v) in views.iter().enumerate() {
            validate(v.points, "points").map_err(|e| name(i, e))?;
            // The image's preparation and the points' order are independent (and each serial in
            // part: the erosion's sweep, the order's sort), so they run side by side.
            let (image, order) = rayon::join(|| cache.get(cam, v, cfg), || cache.order(v.points));
            let image = image.map_err(|m| name(i, m))?;
            let pts0 = prepare_points(cam, v.points, &order, &image, init, origin, &grid, cfg)
                .map_err(|m| name(i, m))?;
            prepared.push((image.binned_levels(max_level, invalid), pts0));
        }
        let n_points = prepared.iter().map(|(_, p)| p.len()).sum::<usize>();
        let view_points = views
            .iter()
            .zip(&prepared)
            .map(|(v, (_, p))| (v.points.len(), p.len()))
            .collect();
        // The coarse levels subsample the fixed sets first; level 0 then takes them as they are.
        let coarse: Vec<Level> = (1..=max_level)
            .map(|l| {
                let stride =
                    (1usize << (2 * l)).min((n_points / cfg.coarse_min_points.max(1)).max(1));
                Level {
                    cam: FastCamera::new(cam, l),
                    parts: prepared
                        .iter()
                        .map(|(imgs, pts0)| Part {
                            img: Arc::clone(&imgs[l as usize]),
                            pts: pts0.subsample(stride),
                        })
                        .collect(),
                }
            })
            .collect();
        let mut levels = vec![Level {
            cam: FastCamera::new(cam, 0),
            parts: prepared
                .into_iter()
                .map(|(mut imgs, pts)| Part {
                    img: imgs.swap_remove(0),
                    pts,
                })
                .collect(),
        }];
        levels.extend(coarse);
        Ok(Evaluator {
            init: *init,
            origin,
            grid,
            mi: cfg.mi,
            levels,
            n_points,
            n_input: views.iter().map(|v| v.points.len()).sum(),
            view_points,
        })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Points used at a level.
    pub(crate) fn points_at(&self, level: u32) -> usize {
        self.levels[level as usize]
            .parts
            .iter()
            .map(|p| p.pts.len())
            .sum()
    }

    /// Number of views (image/point-set pairs).
    pub fn views(&self) -> usize {
        self.view_points.len()
    }

    /// The pose of a cell.
    pub(crate) fn pose(&self, cell: &Cell) -> CamFromMap {
        pose_at_pivot(&self.init, &self.grid.offsets(cell), self.grid.pivot)
    }

    /// Joint histogram of a cell at a level.
    pub fn histogram(&self, level: u32, cell: &Cell, scratch: &mut Scratch) -> JointHist {
        self.histogram_at(level, &self.pose(cell), scratch)
    }

    /// Joint histogram of any pose at a level, on the fixed point set: the sum over the views
    /// (its invalid column counts the points of the set that pose loses). For diagnostics that
    /// score poses off the grid on one point set (`examples/diag_s11.rs`).
    pub fn histogram_at(&self, level: u32, pose: &CamFromMap, scratch: &mut Scratch) -> JointHist {
        let lv = &self.levels[level as usize];
        let mut h = JointHist::new(self.mi.bins_reflectivity, self.mi.bins_gray);
        let p = PoseF32::new(pose, self.origin);
        for part in &lv.parts {
            accumulate(&part.pts, &p, &lv.cam, &part.img, &mut h, scratch);
        }
        h
    }

    /// Histograms a pose is scored on under the estimator's pooling: one (joint, or a single
    /// view), or one per view.
    pub(crate) fn slots(&self) -> usize {
        match self.mi.pooling {
            Pooling::PerPair => self.views(),
            Pooling::Joint => 1,
        }
    }

    /// The histogram view `v` adds its points to.
    fn slot(&self, v: usize) -> usize {
        match self.mi.pooling {
            Pooling::PerPair => v,
            Pooling::Joint => 0,
        }
    }

    /// Empty histograms, one per slot.
    fn empty_slots(&self) -> Vec<JointHist> {
        vec![JointHist::new(self.mi.bins_reflectivity, self.mi.bins_gray); self.slots()]
    }

    /// The slots' histograms of a pose at a level, on the fixed point set (what
    /// [`pooled_information`] scores).
    pub(crate) fn histograms_at(
        &self,
        level: u32,
        pose: &CamFromMap,
        scratch: &mut Scratch,
    ) -> Vec<JointHist> {
        let lv = &self.levels[level as usize];
        let mut hs = self.empty_slots();
        let p = PoseF32::new(pose, self.origin);
        for (v, part) in lv.parts.iter().enumerate() {
            let h = &mut hs[self.slot(v)];
            accumulate(&part.pts, &p, &lv.cam, &part.img, h, scratch);
        }
        hs
    }

    /// MI and NMI at continuous offsets from the initial pose (not restricted to the grid's
    /// cells), on the fixed point set at `level`, pooled as configured; for local continuous
    /// polishing after the grid search ([`crate::localize::refine::polish`]).
    pub fn value_at(&self, level: u32, offsets: &[f64; 6], scratch: &mut Scratch) -> MiValue {
        let pose = pose_at_pivot(&self.init, offsets, self.grid.pivot);
        pooled_information(&self.histograms_at(level, &pose, scratch), self.mi.parzen)
    }

    /// The level-0 point sets cut into `k` groups: each view's fixed set, in Morton
    /// order, in `k` contiguous runs (compact patches of ground); group j is run j of every view.
    /// Indexed `[view][group]`.
    pub(crate) fn folds(&self, k: usize) -> Folds {
        let k = k.max(1);
        Folds {
            parts: self.levels[0]
                .parts
                .iter()
                .map(|p| {
                    let n = p.pts.len();
                    (0..k)
                        .map(|j| p.pts.range(j * n / k, (j + 1) * n / k))
                        .collect()
                })
                .collect(),
            k,
        }
    }

    /// This evaluator's level 0 on every `stride`-th point of each view's fixed set (Morton
    /// order, so the kept points spread evenly over the ground): a cheaper and noisier objective,
    /// for screening optimiser starts. The images are shared, not copied.
    pub(crate) fn thinned(&self, stride: usize) -> Evaluator {
        let lv = &self.levels[0];
        let parts: Vec<Part> = lv
            .parts
            .iter()
            .map(|p| Part {
                img: Arc::clone(&p.img),
                pts: p.pts.subsample(stride),
            })
            .collect();
        Evaluator {
            init: self.init,
            origin: self.origin,
            grid: self.grid,
            mi: self.mi,
            n_points: parts.iter().map(|p| p.pts.len()).sum(),
            n_input: self.n_input,
            view_points: self
                .view_points
                .iter()
                .zip(&parts)
                .map(|(v, p)| (v.0, p.pts.len()))
                .collect(),
            levels: vec![Level { cam: lv.cam, parts }],
        }
    }

    /// [`Evaluator::value_at`] at level 0 with the groups of `folds` scored in parallel: their
    /// histograms add up to the ones `value_at` scores (integer counts), so the value is the
    /// same; for a single optimiser run that should still use every thread.
    pub(crate) fn value_at_split(&self, folds: &Folds, offsets: &[f64; 6]) -> MiValue {
        let lv = &self.levels[0];
        let pose = PoseF32::new(
            &pose_at_pivot(&self.init, offsets, self.grid.pivot),
            self.origin,
        );
        let jobs: Vec<(usize, usize)> = (0..folds.parts.len())
            .flat_map(|v| (0..folds.k).map(move |g| (v, g)))
            .collect();
        let hs = jobs
            .par_iter()
            .fold(
                || (self.empty_slots(), Scratch::default()),
                |(mut hs, mut scratch), &(v, g)| {
                    let part = &lv.parts[v];
                    accumulate(
                        &folds.parts[v][g],
                        &pose,
                        &lv.cam,
                        &part.img,
                        &mut hs[self.slot(v)],
                        &mut scratch,
                    );
                    (hs, scratch)
                },
            )
            .map(|(hs, _)| hs)
            .reduce(
                || self.empty_slots(),
                |mut a, b| {
                    for (ha, hb) in a.iter_mut().zip(&b) {
                        ha.add(hb);
                    }
                    a
                },
            );
        pooled_information(&hs, self.mi.parzen)
    }

    /// Level 0 of every view (its binned image and fixed point set), the points' origin and the
    /// estimator's settings: what the smooth estimator ([`super::smooth`]) scores.
    pub(crate) fn level0(&self) -> (Vec<(&BinnedImage, &PreparedPoints)>, [f64; 3], MiConfig) {
        let parts = self.levels[0]
            .parts
            .iter()
            .map(|p| (p.img.as_ref(), &p.pts))
            .collect();
        (parts, self.origin, self.mi)
    }

    /// The objective the search maximises (MI or NMI, per the configuration).
    pub fn objective(&self) -> crate::localize::mi::Objective {
        self.mi.objective
    }

    /// Score a cell at a level.
    pub fn score(&self, level: u32, idx: u64, scratch: &mut Scratch) -> Scored {
        let pose = self.pose(&self.grid.cell(idx));
        let value = pooled_information(&self.histograms_at(level, &pose, scratch), self.mi.parzen);
        Scored {
            idx,
            score: value.get(self.mi.objective),
            value,
        }
    }

    /// Score cells (by number) at a level in parallel, in tiles of consecutive cells (one scratch
    /// per tile), order kept. A score is a pure function of (level, cell), so neither the tiling
    /// nor the thread count can change a result.
    pub(crate) fn score_cells(&self, level: u32, idxs: &[u64]) -> Vec<Scored> {
        // Up to 64 cells a tile, but at least ~4 tiles per thread so that the small batches of the
        // descent and the climb (tens to hundreds of cells) still keep every thread busy.
        let tile = (idxs.len() / (4 * rayon::current_num_threads()).max(1)).clamp(1, 64);
        idxs.par_chunks(tile)
            .flat_map_iter(|tile| {
                let mut s = Scratch::default();
                tile.iter()
                    .map(|&i| self.score(level, i, &mut s))
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// Score many cells in parallel (order kept), adding to the stats.
    pub(crate) fn score_many(
        &self,
        level: u32,
        idxs: &[u64],
        stats: &mut SearchStats,
    ) -> Vec<Scored> {
        let out = self.score_cells(level, idxs);
        let n = self.points_at(level) as u64;
        stats.poses += idxs.len() as u64;
        stats.point_evaluations += idxs.len() as u64 * n;
        let lost = out
            .iter()
            .map(|s| 1.0 - s.value.n as f64 / n.max(1) as f64)
            .fold(0.0, f64::max);
        if level == 0 {
            stats.max_lost_fraction = stats.max_lost_fraction.max(lost);
        }
        out
    }
}

/// Check one view's image against the camera, bin its gray levels and blur it (see
/// [`Evaluator::pooled`]); with the fixed point set, erode its mask too. Errors are the message
/// alone; the caller names the view.
pub(crate) fn prepare_image(
    cam: &Camera,
    gray: &[u8],
    mask: &[u8],
    cfg: &SearchConfig,
) -> std::result::Result<ViewImage, LocalizeError> {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    if gray.len() != w * h || mask.len() != w * h {
        return Err(LocalizeError::ImageSize {
            pixels: gray.len(),
            width: w,
            height: h,
        });
    }
    let invalid = cfg.mi.bins_gray as u8;

    // Gray LUT from the valid pixels: counts per block of rows on the pool (integer sums, the
    // same in any order).
    let gcounts = gray
        .par_chunks(w.max(1) * 64)
        .zip(mask.par_chunks(w.max(1) * 64))
        .fold(
            || [0u64; 256],
            |mut c, (g, m)| {
                for (&g, &m) in g.iter().zip(m) {
                    c[g as usize] += u64::from(m != 0);
                }
                c
            },
        )
        .reduce(
            || [0u64; 256],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
                a
            },
        );
    if gcounts.iter().sum::<u64>() == 0 {
        return Err(LocalizeError::NoValidPixel);
    }
    let lut_gray = bin_lut(cfg.mi.binning, cfg.mi.bins_gray, &gcounts);

    // Level 0 image (anti-aliased, see `blur3`), and the eroded one used to pick the fixed set.
    // The erosion's distance transform is a sequential sweep that needs only the mask: it runs
    // beside the blur and binning (which spread over the pool) rather than after them.
    let ((smooth, img0), erosion) = rayon::join(
        || {
            let smooth = blur3(gray, mask, w, h);
            let img0 = BinnedImage::new(w, h, &smooth, mask, &lut_gray, invalid);
            (smooth, img0)
        },
        || {
            cfg.fixed_point_set
                .then(|| erode_with_distance(mask, w, h, cfg.visibility_margin_px))
        },
    );
    let eroded = erosion.map(|(eroded, dist)| {
        let img_e = BinnedImage::new(w, h, &smooth, &eroded, &lut_gray, invalid);
        (img_e, dist)
    });
    let level0 = GrayLevel {
        width: w,
        height: h,
        gray: smooth,
        mask: mask.to_vec(),
    };
    Ok(ViewImage {
        lut_gray,
        eroded,
        levels: Mutex::new(vec![(level0, Arc::new(img0))]),
    })
}

/// Pick one view's fixed point set on its prepared `image` and bin the points' reflectivity
/// (see [`Evaluator::pooled`]). Errors are the message alone; the caller names the view.
#[allow(clippy::too_many_arguments)]
pub(crate) fn prepare_points(
    cam: &Camera,
    points: &[GroundPoint],
    order: &[usize],
    image: &ViewImage,
    init: &CamFromMap,
    origin: [f64; 3],
    grid: &Grid,
    cfg: &SearchConfig,
) -> std::result::Result<PreparedPoints, LocalizeError> {
    let w = cam.width() as usize;
    let invalid = cfg.mi.bins_gray as u8;
    let cam0 = FastCamera::new(cam, 0);

    // Points with raw reflectivity as "bin" first, to select the fixed set.
    let mut identity = [0u8; 256];
    for (i, v) in identity.iter_mut().enumerate() {
        *v = i as u8;
    }
    let raw = PreparedPoints::gather(points, order, origin, &identity);
    let keep = if let Some((img_e, dist)) = &image.eroded {
        // A point is kept when every pose of the 3^d lattice sees it. Blocks of points in
        // parallel, each tested against all the poses at once (`visible_from_all`): the flags do
        // not depend on how the work is split, since each point's flag is its own AND.
        let poses: Vec<PoseF32> = box_lattice(grid)
            .iter()
            .map(|cell| {
                PoseF32::new(
                    &pose_at_pivot(init, &grid.offsets(cell), grid.pivot),
                    origin,
                )
            })
            .collect();
        // Most points sit far inside the valid area from every pose of a small box: those are
        // settled by one projection per axis extreme (`surely_visible`), and only the rest are
        // tested against the whole lattice. The kept set is the lattice test's.
        let center = pose_at_pivot(init, &grid.offsets(&[0; 6]), grid.pivot);
        let extremes: Vec<CamFromMap> = (0..6)
            .filter(|&i| grid.m[i] != 0)
            .flat_map(|i| {
                [-grid.m[i], grid.m[i]].map(|k| {
                    let mut c = [0i64; 6];
                    c[i] = k;
                    pose_at_pivot(init, &grid.offsets(&c), grid.pivot)
                })
            })
            .collect();
        let sure = surely_visible(&cam0, &raw, origin, &center, &extremes, dist, w);
        let unsure: Vec<bool> = sure.iter().map(|s| !s).collect();
        let rest = raw.select(&unsure);
        const BLOCK: usize = 2048;
        let mut rest_keep = vec![true; rest.len()];
        rest_keep
            .par_chunks_mut(BLOCK)
            .enumerate()
            .for_each(|(b, k)| {
                visible_from_all(&rest, b * BLOCK, &poses, &cam0, img_e, invalid, k)
            });
        let mut rest_keep = rest_keep.into_iter();
        sure.iter()
            .map(|&s| s || rest_keep.next().unwrap_or(false))
            .collect()
    } else {
        let img0 = image.binned_levels(0, invalid);
        let mut vis = vec![false; raw.len()];
        let p = PoseF32::new(init, origin);
        visible(&raw, &p, &cam0, &img0[0], invalid, &mut vis);
        // The naive estimator uses every point; it only needs one visible to be meaningful.
        if !vis.iter().any(|&v| v) {
            vis.iter_mut().for_each(|v| *v = false);
        } else {
            vis.iter_mut().for_each(|v| *v = true);
        }
        vis
    };
    let mut pts0 = raw.select(&keep);
    if pts0.is_empty() {
        return Err(if cfg.fixed_point_set {
            LocalizeError::NoFixedPoints
        } else {
            LocalizeError::NoVisiblePoints
        });
    }
    let mut rcounts = [0u64; 256];
    for &b in &pts0.bin {
        rcounts[b as usize] += 1;
    }
    let lut_refl = bin_lut(cfg.mi.binning, cfg.mi.bins_reflectivity, &rcounts);
    pts0.bin.iter_mut().for_each(|b| *b = lut_refl[*b as usize]);
    Ok(pts0)
}

/// 3×3 binomial blur ([1 2 1]⊗[1 2 1]/16) over valid pixels only (weights renormalised at the
/// circle's edge). The sampler takes the nearest pixel; without this, a sub-pixel pose step moves
/// a point between pixels that may differ a lot (sensor noise, aliasing), and the objective over
/// the finest grid gets ripples that are not alignment information.
pub(crate) fn blur3(gray: &[u8], mask: &[u8], w: usize, h: usize) -> Vec<u8> {
    const K: [u32; 3] = [1, 2, 1];
    let mut out = gray.to_vec();
    // A valid pixel near the mask's edge or the image's averages its valid neighbours only.
    let edge = |u: usize, v: usize| -> u8 {
        let (mut acc, mut wsum) = (0u32, 0u32);
        for (j, kj) in K.iter().enumerate() {
            let y = v + j;
            if y < 1 || y > h {
                continue;
            }
            for (i, ki) in K.iter().enumerate() {
                let x = u + i;
                if x < 1 || x > w || mask[(y - 1) * w + x - 1] == 0 {
                    continue;
                }
                acc += kj * ki * gray[(y - 1) * w + x - 1] as u32;
                wsum += kj * ki;
            }
        }
        ((acc + wsum / 2) / wsum.max(1)) as u8
    };
    // Rows in parallel: each output row reads only the input, so the result is the same. Inside
    // the mask (all nine pixels valid, most of the image) the kernel is separable and its weights
    // sum to 16: the column sums once per pixel, then the row's; the same integers as the edge
    // formula.
    out.par_chunks_mut(w.max(1)).enumerate().for_each_init(
        || (vec![0u16; w], vec![false; w]),
        |(col, all), (v, row)| {
            let inner_row = v >= 1 && v + 1 < h;
            if inner_row {
                let r = |k: usize| k * w..(k + 1) * w;
                let (g0, g1, g2) = (&gray[r(v - 1)], &gray[r(v)], &gray[r(v + 1)]);
                let (m0, m1, m2) = (&mask[r(v - 1)], &mask[r(v)], &mask[r(v + 1)]);
                for u in 0..w {
                    col[u] = g0[u] as u16 + 2 * g1[u] as u16 + g2[u] as u16;
                    all[u] = m0[u] != 0 && m1[u] != 0 && m2[u] != 0;
                }
            }
            for (u, o) in row.iter_mut().enumerate() {
                if mask[v * w + u] == 0 {
                    continue;
                }
                *o = if inner_row && u >= 1 && u + 1 < w && all[u - 1] && all[u] && all[u + 1] {
                    let acc = col[u - 1] as u32 + 2 * col[u] as u32 + col[u + 1] as u32;
                    ((acc + 8) / 16) as u8
                } else {
                    edge(u, v)
                };
            }
        },
    );
    out
}

/// Erode a validity mask by `r` pixels (square window: a pixel stays valid only if every pixel
/// within `r`, and the image, reaches that far), and give the eroded mask's chessboard distance
/// map ([`chessboard_distance`]) with it. One distance transform gives both: a pixel survives the
/// erosion exactly when its distance exceeds `r`, and its distance in the eroded mask is `r` less.
pub(crate) fn erode_with_distance(
    mask: &[u8],
    w: usize,
    h: usize,
    r: usize,
) -> (Vec<u8>, Vec<u16>) {
    let r = r.min(u16::MAX as usize) as u16;
    let dist: Vec<u16> = chessboard_distance(mask, w, h)
        .into_iter()
        .map(|d| d.saturating_sub(r))
        .collect();
    let eroded = dist.iter().map(|&d| if d > 0 { 255 } else { 0 }).collect();
    (eroded, dist)
}

/// Points that every pose of a box certainly sees on a valid pixel of a mask whose chessboard
/// distance map (`w` wide) is `dist`: a point whose pixel at the box's `center` pose lies farther
/// from any invalid pixel (chessboard distance, a lower bound of the Euclidean one) than its pixel
/// moves over the box. The move is taken as the sum over the axes of the farther of its two axis
/// `extremes`' moves, exact for a map linear in the offsets; ×1.5 and 4 px more cover the
/// projection's curvature over a box and nearest-pixel rounding. That margin is measured, not
/// proven: the worst lattice move found over nadir to near-horizontal cameras, 4.5–10 m poles and
/// boxes up to ±2 m / ±6° was 0.74–1.09 times the sum (the unit test checks nadir and tilted
/// cameras pose by pose). A `false` means "test it", not "unseen". The projections are the
/// kernel's own ([`kernel::surely_visible_block`]), in blocks of points in parallel.
pub(crate) fn surely_visible(
    cam: &FastCamera,
    pts: &PreparedPoints,
    origin: [f64; 3],
    center: &CamFromMap,
    extremes: &[CamFromMap],
    dist: &[u16],
    w: usize,
) -> Vec<bool> {
    const BLOCK: usize = 4096;
    let extremes: Vec<PoseF32> = extremes.iter().map(|e| PoseF32::new(e, origin)).collect();
    let b = kernel::BoxView {
        center: PoseF32::new(center, origin),
        extremes: &extremes,
        cam: *cam,
        dist,
        width: w,
    };
    let mut out = vec![false; pts.len()];
    out.par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(i, o)| kernel::surely_visible_block(pts, i * BLOCK, &b, o));
    out
}

/// Per pixel, the chessboard distance to the nearest pixel whose `mask` is 0 or to the outside of
/// the image (1 on a valid pixel next to an invalid one, 0 on an invalid one). Two chamfer passes
/// with the image border handled apart, so that the inner loops read their neighbours without
/// bounds tests (a pixel on the border has an outside neighbour, so its distance is 1 when valid);
/// the unit tests keep the plain per-neighbour version as the reference.
pub(crate) fn chessboard_distance(mask: &[u8], w: usize, h: usize) -> Vec<u16> {
    let mut d = vec![0u16; w * h];
    if w < 3 || h < 3 {
        // Every pixel is on the border.
        d.iter_mut()
            .zip(mask)
            .for_each(|(d, &m)| *d = u16::from(m != 0));
        return d;
    }
    // Forward: left, up-left, up, up-right.
    for v in 0..h {
        let (done, rest) = d.split_at_mut(v * w);
        let cur = &mut rest[..w];
        let m = &mask[v * w..(v + 1) * w];
        if v == 0 {
            cur.iter_mut()
                .zip(m)
                .for_each(|(d, &m)| *d = u16::from(m != 0));
            continue;
        }
        let prev = &done[(v - 1) * w..];
        cur[0] = u16::from(m[0] != 0);
        for u in 1..w - 1 {
            if m[u] != 0 {
                let a = cur[u - 1].min(prev[u - 1]).min(prev[u]).min(prev[u + 1]);
                cur[u] = a.saturating_add(1);
            }
        }
        cur[w - 1] = u16::from(m[w - 1] != 0);
    }
    // Backward: right, down-right, down, down-left.
    for v in (0..h).rev() {
        let (head, below) = d.split_at_mut((v + 1) * w);
        let cur = &mut head[v * w..];
        if v == h - 1 {
            cur.iter_mut().for_each(|d| *d = (*d).min(1));
            continue;
        }
        let next = &below[..w];
        cur[w - 1] = cur[w - 1].min(1);
        for u in (1..w - 1).rev() {
            if cur[u] != 0 {
                let a = cur[u + 1].min(next[u + 1]).min(next[u]).min(next[u - 1]);
                cur[u] = cur[u].min(a.saturating_add(1));
            }
        }
        cur[0] = cur[0].min(1);
    }
    d
}

/// Counters of a search.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SearchStats {
    /// Poses scored.
    pub poses: u64,
    /// Point-pose evaluations (Σ over scored poses of the points used).
    pub point_evaluations: u64,
    /// What the exhaustive grid costs: cells × points.
    pub exhaustive_point_evaluations: u64,
    /// Coarsest level used (0 for exhaustive).
    pub coarsest_level: u32,
    /// Largest fraction of the fixed set not landing on a valid pixel at any level-0 pose.
    pub max_lost_fraction: f64,
}
