//! The coarse stage of initialization (the seed's step 1), learning-free: the fisheye frame is
//! resampled once into the nominal bird's-eye view (see [`crate::localize::init::sweep`]), the satellite image
//! around the prior into an orientation field, and a dense yaw × height × translation sweep ranks
//! hypotheses; a second sweep over the taller mounting heights, with the larger template they
//! allow, adds its own few ([`CoarseParams::tall_from_m`]). Roll and pitch are taken as zero here
//! (the node is mounted nadir within a few degrees); PnP on the fine correspondences
//! ([`crate::localize::init`]) recovers them.

use crate::camera::CameraModel;
use crate::localize::init::ground::Mip;
use crate::localize::init::sweep::{
    orientation_field, Candidate, Field, GrayF32, NominalField, SearchField, SweepParams,
};
use crate::map::Raster;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Settings of the coarse stage.
#[derive(Debug, Clone, PartialEq)]
pub struct CoarseParams {
    /// Lowest and highest mounting height considered, metres.
    pub height_range_m: (f64, f64),
    /// Ratio between successive heights (scale step of the sweep).
    pub height_ratio: f64,
    /// Yaw step, degrees.
    pub yaw_step_deg: f64,
    /// Ground resolution of the sweep, metres per pixel.
    pub res_m: f64,
    /// Largest template radius, metres.
    pub template_radius_m: f64,
    /// Largest off-nadir ground angle used, degrees (beyond it ground is too oblique).
    pub max_off_nadir_deg: f64,
    /// Step of the nominal view in normalised ground units (metres per metre of height).
    pub nominal_dq: f64,
    /// Candidates kept for the fine stage.
    pub top_k: usize,
    /// A second sweep over the heights from this one up (`None`: none), with the larger template
    /// those heights allow (`SweepParams::effective_template_radius_m`); its best
    /// [`CoarseParams::tall_top_k`] candidates join the list. The main sweep's template is what
    /// the lowest height sees (8.2 m of ground at 3 m and 70°), so that no height is favoured by
    /// a smaller, noisier correlation; on a tall pole that is only the ground within ≈ 40° of
    /// nadir, and a road's edges and markings there can fit better at a wrong scale (every top
    /// candidate of a 10 m pole at 6.5 m). The tall sweep's candidates
    /// compete only in the LiDAR screening and the fine stage, not in the sweep's ranking.
    pub tall_from_m: Option<f64>,
    /// Candidates the tall sweep adds.
    pub tall_top_k: usize,
}

impl Default for CoarseParams {
    fn default() -> Self {
        CoarseParams {
            height_range_m: (3.0, 15.0),
            height_ratio: 1.05,
            yaw_step_deg: 3.0,
            res_m: 0.4,
            template_radius_m: 20.0,
            max_off_nadir_deg: 70.0,
            nominal_dq: 0.01,
            top_k: 10,
            tall_from_m: Some(6.0),
            tall_top_k: 10,
        }
    }
}

impl CoarseParams {
    /// The geometric sequence of heights swept.
    pub(crate) fn heights(&self) -> Vec<f64> {
        let (lo, hi) = self.height_range_m;
        let mut v = Vec::new();
        let mut h = lo;
        while h <= hi * (1.0 + 1e-9) {
            v.push(h);
            h *= self.height_ratio;
        }
        v
    }
}

/// The nominal bird's-eye view: the ground as a north-up nadir camera at unit height would see it,
/// over `|q| ≤ tan(max_off_nadir)`, step `dq`; and the pixels that are seen.
pub(crate) fn nominal_view(
    cam: &dyn CameraModel,
    mip: &Mip,
    p: &CoarseParams,
) -> (GrayF32, Vec<bool>) {
    let q_max = p.max_off_nadir_deg.to_radians().tan();
    let half = (q_max / p.nominal_dq).ceil() as usize;
    let n = 2 * half + 1;
    let rows: Vec<(Vec<f32>, Vec<bool>)> = (0..n)
        .into_par_iter()
        .map(|y| {
            let mut vals = vec![0.0; n];
            let mut ok = vec![false; n];
            for x in 0..n {
                let (qx, qy) = (
                    (x as f64 - half as f64) * p.nominal_dq,
                    (half as f64 - y as f64) * p.nominal_dq,
                );
                if qx * qx + qy * qy > q_max * q_max {
                    continue;
                }
                // Ground offset (qx, qy, −1) in the map; a north-up nadir camera's optical frame is
                // diag(1, −1, −1) of it.
                let ray = Vector3::new(qx, -qy, 1.0);
                if let Ok(px) = cam.project_visible(&ray) {
                    // Footprint of the cell in fisheye pixels, from its neighbours' projections.
                    let fp = [(p.nominal_dq, 0.0), (0.0, p.nominal_dq)]
                        .iter()
                        .filter_map(|(dx, dy)| {
                            cam.project(&Vector3::new(qx + dx, -(qy + dy), 1.0)).ok()
                        })
                        .map(|q| (q - px).norm())
                        .fold(1.0, f64::max);
                    if let Some(v) = mip.sample(px.x, px.y, fp) {
                        vals[x] = v;
                        ok[x] = true;
                    }
                }
            }
            (vals, ok)
        })
        .collect();
    let mut img = GrayF32::new(n, n);
    let mut valid = vec![false; n * n];
    for (y, (vals, ok)) in rows.into_iter().enumerate() {
        img.data[y * n..(y + 1) * n].copy_from_slice(&vals);
        valid[y * n..(y + 1) * n].copy_from_slice(&ok);
    }
    (img, valid)
}

/// Orientation-field pyramid of the nominal view (`mip`: the frame's pyramid).
pub(crate) fn nominal_field(cam: &dyn CameraModel, mip: &Mip, p: &CoarseParams) -> NominalField {
    let (img, valid) = nominal_view(cam, mip, p);
    let mut levels = vec![orientation_field(&img, Some(&valid))];
    // Enough levels to reach the coarsest template step (res / lowest height).
    let coarsest = p.res_m / p.height_range_m.0.max(1e-3);
    while p.nominal_dq * 2f64.powi(levels.len() as i32) <= coarsest * 2.0 {
        let next = levels[levels.len() - 1].downsample2();
        levels.push(next);
    }
    NominalField {
        levels,
        dq: p.nominal_dq,
        q_max: p.max_off_nadir_deg.to_radians().tan(),
    }
}

/// Rec. 601 luma of a satellite pixel: the camera is a gray sensor with a broad response.
fn luma([r, g, b]: [u8; 3]) -> f32 {
    0.299 * r as f32 + 0.587 * g as f32 + 0.114 * b as f32
}

/// Luminance of the satellite layer, area-averaged to `res` m/px over a square of half-size
/// `half_m` centred on (cx, cy) (map coordinates); outside the layer the field is zero.
pub(crate) fn satellite_gray(
    sat: &Raster<[u8; 3]>,
    cx: f64,
    cy: f64,
    half_m: f64,
    res: f64,
) -> (GrayF32, Vec<bool>) {
    let n = 2 * (half_m / res).round() as usize + 1;
    let c = (n as f64 - 1.0) / 2.0;
    let g = &sat.grid;
    // Average the source pixels that fall inside each output cell (≥ 1 sample per cell).
    let sub = ((res / g.res).round() as usize).max(1);
    // The grid is axis-aligned, so a sample's column depends only on its cell's column and
    // sub-column, and its row only on the cell's row and sub-row: both computed once here, with
    // the same arithmetic as per sample (`None`: left of or above the grid; a NaN coordinate
    // reads column or row 0, as a cast of the sample's own NaN did).
    let axis = |m0: f64, sign: f64, to: &dyn Fn(f64) -> f64| -> Vec<Option<usize>> {
        let mut v = Vec::with_capacity(n * sub);
        for i in 0..n {
            let m = m0 + sign * (i as f64 - c) * res;
            for k in 0..sub {
                let o = (k as f64 + 0.5) / sub as f64 - 0.5;
                let p = to(m + sign * o * res).round();
                v.push(if p < 0.0 { None } else { Some(p as usize) });
            }
        }
        v
    };
    let cols = axis(cx, 1.0, &|x| g.to_pixel(x, cy).0);
    let rows = axis(cy, -1.0, &|y| g.to_pixel(cx, y).1);
    let mut img = GrayF32::new(n, n);
    let mut valid = vec![false; n * n];
    for y in 0..n {
        for x in 0..n {
            let mut acc = 0.0f32;
            let mut cnt = 0;
            for row in &rows[y * sub..(y + 1) * sub] {
                for col in &cols[x * sub..(x + 1) * sub] {
                    let (Some(col), Some(row)) = (*col, *row) else {
                        continue;
                    };
                    if let Some(rgb) = sat.get(col, row) {
                        acc += luma(rgb);
                        cnt += 1;
                    }
                }
            }
            if cnt == sub * sub {
                img.data[y * n + x] = acc / cnt as f32;
                valid[y * n + x] = true;
            }
        }
    }
    (img, valid)
}

/// Coarse stage: rank (yaw, height, position) hypotheses around the prior centre (cx, cy) within
/// `search_radius_m`. Offsets in the returned candidates are relative to (cx, cy).
pub fn coarse_candidates(
    cam: &dyn CameraModel,
    image: &[u8],
    sat: &Raster<[u8; 3]>,
    center: (f64, f64),
    search_radius_m: f64,
    p: &CoarseParams,
) -> Vec<Candidate> {
    let mip = Mip::new(image, cam.width() as usize, cam.height() as usize);
    coarse_candidates_mip(cam, &mip, sat, center, search_radius_m, p)
}

/// [`coarse_candidates`] of the frame whose mip pyramid is `mip`.
pub(crate) fn coarse_candidates_mip(
    cam: &dyn CameraModel,
    mip: &Mip,
    sat: &Raster<[u8; 3]>,
    (cx, cy): (f64, f64),
    search_radius_m: f64,
    p: &CoarseParams,
) -> Vec<Candidate> {
    let nominal = nominal_field(cam, mip, p);
    let heights = p.heights();
    let sweep = |heights: Vec<f64>, top_k: usize, res: f64| {
        let params = SweepParams {
            yaw_step_deg: p.yaw_step_deg,
            heights,
            template_radius_m: p.template_radius_m,
            top_k,
            max_offset_m: search_radius_m,
        };
        // The field holds the search disk plus the template the sweep really uses (one pixel of
        // slack for rounding): a larger one only costs FFT time.
        let half = search_radius_m + params.effective_template_radius_m(nominal.q_max) + res;
        let (gray, valid) = satellite_gray(sat, cx, cy, half, res);
        let field: Field = orientation_field(&gray, Some(&valid));
        let search = SearchField::new(&field, res);
        crate::localize::init::sweep::sweep(&search, &nominal, &params)
    };
    let tall: Vec<f64> = match p.tall_from_m {
        Some(from) => heights.iter().copied().filter(|h| *h >= from).collect(),
        None => Vec::new(),
    };
    let tall_sweep = !tall.is_empty() && tall.len() < heights.len() && p.tall_top_k > 0;
    // Both sweeps at once: each one's satellite field is built serially and its heights end
    // unevenly, and the other's work fills those gaps. The lists are merged as before.
    let (mut cands, tall) = rayon::join(
        || sweep(heights, p.top_k, p.res_m),
        || {
            if tall_sweep {
                sweep(tall, p.tall_top_k, p.res_m)
            } else {
                Vec::new()
            }
        },
    );
    for c in tall {
        if !cands.contains(&c) {
            cands.push(c);
        }
    }
    cands
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{Crs, GeoGrid};

    /// [`satellite_gray`] as it computed every sample's pixel on its own.
    fn satellite_gray_per_sample(
        sat: &Raster<[u8; 3]>,
        cx: f64,
        cy: f64,
        half_m: f64,
        res: f64,
    ) -> (GrayF32, Vec<bool>) {
        let n = 2 * (half_m / res).round() as usize + 1;
        let c = (n as f64 - 1.0) / 2.0;
        let g = &sat.grid;
        let sub = ((res / g.res).round() as usize).max(1);
        let mut img = GrayF32::new(n, n);
        let mut valid = vec![false; n * n];
        for y in 0..n {
            for x in 0..n {
                let (mx, my) = (cx + (x as f64 - c) * res, cy + (c - y as f64) * res);
                let (mut acc, mut cnt) = (0.0f32, 0);
                for sy in 0..sub {
                    for sx in 0..sub {
                        let ox = (sx as f64 + 0.5) / sub as f64 - 0.5;
                        let oy = (sy as f64 + 0.5) / sub as f64 - 0.5;
                        let (px, py) = g.to_pixel(mx + ox * res, my - oy * res);
                        let (col, row) = (px.round(), py.round());
                        if col < 0.0 || row < 0.0 {
                            continue;
                        }
                        if let Some(rgb) = sat.get(col as usize, row as usize) {
                            acc += luma(rgb);
                            cnt += 1;
                        }
                    }
                }
                if cnt == sub * sub {
                    img.data[y * n + x] = acc / cnt as f32;
                    valid[y * n + x] = true;
                }
            }
        }
        (img, valid)
    }

    #[test]
    fn separable_sample_positions_give_the_per_sample_image() {
        let grid = GeoGrid {
            crs: Crs::Local,
            x0: 274_760.0,
            y0: 4_684_360.0,
            res: 0.1,
            width: 700,
            height: 650,
        };
        let mut sat = Raster::filled(grid, [0u8; 3], None);
        for (i, px) in sat.data.iter_mut().enumerate() {
            *px = [
                (i * 7 % 251) as u8,
                (i * 13 % 241) as u8,
                (i * 29 % 239) as u8,
            ];
        }
        // Centres inside, near and beyond the edges (cells partly or wholly off the grid), the
        // resolutions the sweep and the fine stage use, and an off-grid phase.
        for (cx, cy) in [
            (274_801.29, 4_684_313.17),
            (274_762.03, 4_684_357.5),
            (274_826.95, 4_684_296.02),
        ] {
            for (half, res) in [(25.2, 0.4), (5.0, 0.2), (2.6, 0.1), (3.0, 0.3)] {
                let (a, va) = satellite_gray(&sat, cx, cy, half, res);
                let (b, vb) = satellite_gray_per_sample(&sat, cx, cy, half, res);
                let bits = |g: &GrayF32| g.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a), bits(&b), "({cx}, {cy}) half {half} res {res}");
                assert_eq!(va, vb, "({cx}, {cy}) half {half} res {res}");
            }
        }
    }
}
