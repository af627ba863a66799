//! How each sensor sees a ground material — the *modality gap*.
//!
//! The three ground-looking sensors measure different physical quantities of the same surface:
//!
//! * **LiDAR reflectivity** (905 nm active, near-normal incidence, retro-reflection matters):
//!   road paint with glass beads is far brighter than anything else, concrete is brighter than
//!   asphalt, new and old asphalt look alike, grass is bright but erratic; dirt, wetness and tyre
//!   rubber barely change it.
//! * **Fisheye gray** (visible band, passive, sun + sky lighting): paint is bright but dirt dulls
//!   it, a fresh asphalt patch is much darker than weathered asphalt, tyre marks, oil drips and wet
//!   gutters darken the road, grass is dark.
//! * **Satellite colour** (visible RGB, taken on another day): its own tone and colour per
//!   material, its own paint wear and dirt, no tyre marks at its resolution.
//!
//! Each band uses its own noise fields (distinct seeds), so only the *structure* (the material
//! map) is shared — mutual information, not equality.

use super::noise::{smoothstep, Field};
use super::world::{Material, Surface, World};

/// Per-band texture fields.
#[derive(Debug, Clone)]
pub(crate) struct Appearance {
    // LiDAR.
    l_agg: Field,
    l_grass: Field,
    l_drive: Field,
    // Visible (camera).
    v_stain: Field,
    v_agg: Field,
    v_grain: Field,
    v_grass: Field,
    v_wet: Field,
    v_streak: Field,
    v_dirt: Field,
    // Satellite.
    s_tone: Field,
    s_grass: Field,
    s_wear: Field,
}

/// LiDAR reflectivity of bead-glass white paint (0..255 scale).
const LIDAR_PAINT_WHITE: f64 = 205.0;
/// LiDAR reflectivity of yellow paint.
const LIDAR_PAINT_YELLOW: f64 = 165.0;
/// LiDAR reflectivity of weathered asphalt.
const LIDAR_ASPHALT: f64 = 24.0;
/// LiDAR reflectivity of concrete (sidewalk).
const LIDAR_CONCRETE: f64 = 62.0;

impl Appearance {
    /// Fields for a world seed.
    pub(crate) fn new(seed: u64) -> Self {
        let f = |k: u64, s: f64| Field::new(seed ^ (0xA000 + k), s);
        Appearance {
            l_agg: f(1, 0.4),
            l_grass: f(2, 1.5),
            l_drive: f(3, 25.0),
            v_stain: f(4, 6.0),
            v_agg: f(5, 0.25),
            v_grain: f(13, 0.012),
            v_grass: f(6, 1.2),
            v_wet: f(7, 4.0),
            v_streak: f(8, 1.5),
            v_dirt: f(9, 0.8),
            s_tone: f(10, 8.0),
            s_grass: f(11, 3.0),
            s_wear: f(12, 0.5),
        }
    }

    /// Noise-free LiDAR reflectivity (0..255) of the ground at (x, y) before speckle; the mapping
    /// drive's slow gain variation is included.
    pub(crate) fn lidar(&self, s: &Surface, x: f64, y: f64) -> f64 {
        let asphalt = LIDAR_ASPHALT + 4.0 * self.l_agg.at(x, y);
        let v = match s.mat {
            Material::Asphalt => asphalt,
            Material::Patch => asphalt - 2.0 + 3.0 * s.wear,
            Material::Crack => 15.0,
            Material::PaintWhite => {
                asphalt + (LIDAR_PAINT_WHITE - asphalt) * (1.0 - s.wear).powf(1.3)
            }
            Material::PaintYellow => {
                asphalt + (LIDAR_PAINT_YELLOW - asphalt) * (1.0 - s.wear).powf(1.3)
            }
            Material::Manhole => 48.0 + 10.0 * s.wear,
            Material::Drain => 30.0,
            Material::Curb => 70.0,
            Material::Sidewalk => LIDAR_CONCRETE + 8.0 * self.l_agg.at(x * 0.5, y * 0.5),
            Material::Grass => 45.0 + 30.0 * self.l_grass.fbm(x, y, 3),
        };
        v * (1.0 + 0.08 * self.l_drive.at(x, y))
    }

    /// Visible-band albedo (0..1) seen by the fisheye camera, including camera-only effects
    /// (tyre marks, oil drips, wet gutters, dirt on paint).
    pub(crate) fn visible(&self, w: &World, s: &Surface, x: f64, y: f64) -> f64 {
        let stain = self.v_stain.fbm(x, y, 2);
        // Stains (metres), texture (decimetres) and aggregate grain (about a centimetre).
        let asphalt =
            0.17 + 0.025 * stain + 0.02 * self.v_agg.fbm(x, y, 2) + 0.03 * self.v_grain.at(x, y);
        let dirt = 1.0 - 0.25 * smoothstep(0.0, 0.6, self.v_dirt.at(x, y));
        let mut a = match s.mat {
            Material::Asphalt => asphalt,
            Material::Patch => 0.075 + 0.05 * s.wear + 0.01 * self.v_agg.at(x, y),
            Material::Crack => 0.05,
            Material::PaintWhite => asphalt + (0.72 * dirt - asphalt) * (1.0 - s.wear),
            Material::PaintYellow => asphalt + (0.40 * dirt - asphalt) * (1.0 - s.wear),
            Material::Manhole => 0.11 + 0.04 * (((x + y) * 25.0).sin() > 0.0) as u8 as f64,
            Material::Drain => 0.04,
            Material::Curb => 0.42,
            Material::Sidewalk => {
                0.36 + 0.05 * stain + 0.015 * self.v_agg.at(x, y) + 0.02 * self.v_grain.at(x, y)
            }
            Material::Grass => {
                0.09 + 0.05 * self.v_grass.fbm(x, y, 3) + 0.08 * s.wear * stain.max(0.0)
            }
        };
        if s.d_curb < 0.0 {
            a *= self.road_darkening(w, s, x, y);
        }
        a.max(0.01)
    }

    /// Multiplicative darkening of the road seen by the camera only: tyre marks in the wheel paths
    /// near stop bars, oil drips in lane centres, wet gutters.
    fn road_darkening(&self, w: &World, s: &Surface, x: f64, y: f64) -> f64 {
        let mut f = 1.0;
        for a in &w.approaches {
            let (sa, l) = a.local(x, y);
            let from_bar = sa - a.s_stop;
            if !(-8.0..45.0).contains(&from_bar) || l < 0.0 || l > a.w_in {
                continue;
            }
            let lane_c = ((l / a.lane_w).floor() + 0.5) * a.lane_w;
            let off = l - lane_c;
            let near = 1.0 - smoothstep(5.0, 40.0, from_bar.abs());
            let streak = 0.5 + 0.5 * self.v_streak.at(sa * 0.3, l * 4.0);
            for wp in [-0.8, 0.8] {
                let q = (off - wp) / 0.22;
                f *= 1.0 - 0.45 * near * streak * (-q * q).exp();
            }
            let q = off / 0.35;
            f *= 1.0
                - 0.3 * near * (-q * q).exp() * (0.5 + 0.5 * self.v_stain.at(sa * 2.0, l * 2.0));
        }
        // Wet or dirty gutter strips where water collects.
        if s.d_curb > -1.2 {
            let wet = smoothstep(0.2, 0.45, self.v_wet.at(x, y));
            f *= 1.0 - 0.45 * wet * smoothstep(-1.2, -0.4, s.d_curb);
        }
        f
    }

    /// Satellite RGB albedo (linear, 0..1): its own colours and its own paint wear.
    pub(crate) fn satellite(&self, s: &Surface, x: f64, y: f64) -> [f64; 3] {
        let tone = 1.0 + 0.12 * self.s_tone.fbm(x, y, 2);
        let asphalt = [0.21 * tone, 0.21 * tone, 0.225 * tone];
        // The image was taken at another time: paint was fresher or more worn, unevenly.
        let wear_sat = |w: f64| (0.6 * w + 0.15 + 0.25 * self.s_wear.at(x, y)).clamp(0.0, 1.0);
        let mix = |a: [f64; 3], b: [f64; 3], t: f64| {
            [
                a[0] + (b[0] - a[0]) * t,
                a[1] + (b[1] - a[1]) * t,
                a[2] + (b[2] - a[2]) * t,
            ]
        };
        match s.mat {
            Material::Asphalt => asphalt,
            Material::Patch => mix(asphalt, [0.11, 0.11, 0.12], 1.0 - s.wear * 0.6),
            Material::Crack => [0.09, 0.09, 0.1],
            Material::PaintWhite => mix(asphalt, [0.82, 0.82, 0.8], 1.0 - wear_sat(s.wear)),
            Material::PaintYellow => mix(asphalt, [0.78, 0.62, 0.18], 1.0 - wear_sat(s.wear)),
            Material::Manhole => [0.16, 0.15, 0.14],
            Material::Drain => [0.08, 0.08, 0.08],
            Material::Curb => [0.62, 0.6, 0.56],
            Material::Sidewalk => [0.55 * tone, 0.53 * tone, 0.5 * tone],
            Material::Grass => {
                let g = self.s_grass.fbm(x, y, 3);
                let dry = smoothstep(0.2, 0.6, g) * (0.3 + s.wear);
                mix([0.13, 0.23 + 0.04 * g, 0.07], [0.32, 0.29, 0.17], dry)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::world::World;

    fn surf(mat: Material, wear: f64) -> Surface {
        Surface {
            mat,
            wear,
            d_curb: -5.0,
        }
    }

    #[test]
    fn modality_gap_orderings() {
        let w = World::generate(1);
        let a = Appearance::new(1);
        let avg = |f: &dyn Fn(f64, f64) -> f64| {
            (0..400)
                .map(|i| f(i as f64 * 0.37 + 200.0, i as f64 * 0.11 + 300.0))
                .sum::<f64>()
                / 400.0
        };
        let lid = |m, wr| avg(&|x, y| a.lidar(&surf(m, wr), x, y));
        let vis = |m, wr| avg(&|x, y| a.visible(&w, &surf(m, wr), x, y));
        // LiDAR: paint ≫ concrete > asphalt; worn paint less; patch ≈ asphalt.
        assert!(lid(Material::PaintWhite, 0.0) > 2.5 * lid(Material::Sidewalk, 0.0));
        assert!(lid(Material::Sidewalk, 0.0) > 2.0 * lid(Material::Asphalt, 0.0));
        assert!(lid(Material::PaintWhite, 0.6) < 0.6 * lid(Material::PaintWhite, 0.0));
        assert!((lid(Material::Patch, 0.5) / lid(Material::Asphalt, 0.0) - 1.0).abs() < 0.15);
        // Camera: the patch is clearly darker than the asphalt around it.
        assert!(vis(Material::Patch, 0.2) < 0.7 * vis(Material::Asphalt, 0.0));
        // Camera vs LiDAR ratios differ (paint/asphalt contrast ≈ 4 vs ≈ 8): not a rescaling.
        let rv = vis(Material::PaintWhite, 0.0) / vis(Material::Asphalt, 0.0);
        let rl = lid(Material::PaintWhite, 0.0) / lid(Material::Asphalt, 0.0);
        assert!(rl > 1.5 * rv, "{rl} {rv}");
    }
}
