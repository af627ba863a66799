//! The map tile's layers as an AV mapping pipeline would have produced them: LiDAR ground
//! reflectivity and height on one grid, a satellite orthophoto on its own grid.

use super::appearance::Appearance;
use super::noise::{gauss, hash3, Field};
use super::render::{gaussian_blur, ground_normal, sun_visibility, Light};
use super::solids::{nearest, Kind, Shape, Solid};
use super::world::{Footprint, World};
use crate::error::{Error, Result};
use crate::map::{GeoGrid, Raster};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Reflectivity no-data value (valid cells are clamped to ≥ 1).
pub(crate) const REFLECTIVITY_NODATA: u8 = 0;
/// Multiplicative speckle σ of LiDAR reflectivity.
const SPECKLE_MUL: f64 = 0.12;
/// Additive LiDAR reflectivity noise σ.
const SPECKLE_ADD: f64 = 3.0;
/// Sub-samples per LiDAR cell side (cells average the points that fell in them).
const LIDAR_SUB: usize = 2;
/// Grown margin of a parked car's LiDAR hole, metres.
const HOLE_MARGIN: f64 = 0.25;
/// Extra hole width on the car's curb side (the mapping vehicle could not see behind it), metres.
const HOLE_SHADOW: f64 = 1.3;

/// LiDAR layers on a shared grid.
#[derive(Debug, Clone)]
pub(crate) struct Lidar {
    /// Reflectivity 0..255, nodata 0.
    pub reflectivity: Raster<u8>,
    /// Height, metres; NaN = no data.
    pub height: Raster<f32>,
}

fn in_hole(w: &World, x: f64, y: f64) -> bool {
    let car = w.lidar_parked.iter().any(|f| {
        // Parked facing along the curb, so the curb is on the car's right (−b side).
        let (s, c) = f.yaw.sin_cos();
        let (dx, dy) = (x - f.x, y - f.y);
        let a = c * dx + s * dy;
        let b = -s * dx + c * dy;
        a.abs() <= f.hl + HOLE_MARGIN
            && b <= f.hw + HOLE_MARGIN
            && b >= -(f.hw + HOLE_MARGIN + HOLE_SHADOW)
    });
    // No ground returns under buildings either.
    car || w.statics.iter().any(|o| match (o.kind, o.shape) {
        (
            Kind::Building,
            Shape::Box {
                cx,
                cy,
                hl,
                hw,
                yaw,
                ..
            },
        ) => Footprint {
            x: cx,
            y: cy,
            yaw,
            hl,
            hw,
        }
        .contains(x, y, 0.0),
        _ => false,
    })
}

/// Build the LiDAR layers on `grid` (map CRS); `origin` is the map position of the world's
/// local (0, 0); `height_sigma` the height noise σ in metres.
pub(crate) fn lidar(
    w: &World,
    look: &Appearance,
    grid: &GeoGrid,
    origin: [f64; 2],
    height_sigma: f64,
) -> Lidar {
    let (gw, gh) = (grid.width, grid.height);
    let mut refl = vec![REFLECTIVITY_NODATA; gw * gh];
    let mut height = vec![f32::NAN; gw * gh];
    let seed = w.seed ^ 0x1D;
    refl.par_chunks_mut(gw)
        .zip(height.par_chunks_mut(gw))
        .enumerate()
        .for_each(|(row, (rr, hr))| {
            for col in 0..gw {
                let (mx, my) = grid.pixel_center(col, row);
                let (x, y) = (mx - origin[0], my - origin[1]);
                if in_hole(w, x, y) {
                    continue;
                }
                let mut acc = 0.0;
                for i in 0..LIDAR_SUB {
                    for j in 0..LIDAR_SUB {
                        let off = |k: usize| ((k as f64 + 0.5) / LIDAR_SUB as f64 - 0.5) * grid.res;
                        let (sx, sy) = (x + off(i), y + off(j));
                        acc += look.lidar(&w.surface(sx, sy), sx, sy);
                    }
                }
                let r = acc / (LIDAR_SUB * LIDAR_SUB) as f64;
                let h = hash3(seed, col as i64, row as i64);
                let noisy = r * (1.0 + SPECKLE_MUL * gauss(h)) + SPECKLE_ADD * gauss(h ^ 0x77);
                rr[col] = noisy.round().clamp(1.0, 255.0) as u8;
                hr[col] = (w.height(x, y) + height_sigma * gauss(h ^ 0x99)) as f32;
            }
        });
    Lidar {
        reflectivity: Raster {
            grid: *grid,
            data: refl,
            nodata: Some(REFLECTIVITY_NODATA),
        },
        height: Raster {
            grid: *grid,
            data: height,
            nodata: Some(f32::NAN),
        },
    }
}

/// Satellite acquisition settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SatelliteShot {
    /// Sun of the acquisition.
    pub light: Light,
    /// Unit viewing direction (from the satellite down to the ground): off-nadir lean of tall
    /// objects.
    pub view: Vector3<f64>,
    /// Misregistration: the image shows the world point (x, y) at (x, y) + shift, metres.
    pub shift: [f64; 2],
    /// Blur σ, pixels.
    pub blur_px: f64,
    /// JPEG quality (1–100).
    pub jpeg_quality: u8,
}

/// Render the satellite orthophoto on `grid`. `parked` are the cars present that day.
pub(crate) fn satellite(
    w: &World,
    look: &Appearance,
    grid: &GeoGrid,
    origin: [f64; 2],
    shot: &SatelliteShot,
    parked: &[Solid],
) -> Result<Raster<[u8; 3]>> {
    let (gw, gh) = (grid.width, grid.height);
    let mut planes = vec![vec![0f32; gw * gh]; 3];
    let dapple = Field::new(w.seed ^ 0xD1, 0.5);
    let leaves = Field::new(w.seed ^ 0xD2, 0.35);
    let sets: [&[Solid]; 2] = [&w.statics, parked];
    let d = shot.view;
    let rows: Vec<Vec<[f32; 3]>> = (0..gh)
        .into_par_iter()
        .map(|row| {
            (0..gw)
                .map(|col| {
                    let (mx, my) = grid.pixel_center(col, row);
                    let (x, y) = (
                        mx - origin[0] - shot.shift[0],
                        my - origin[1] - shot.shift[1],
                    );
                    // Orthorectified to the ground: trace the view ray that ends at this ground point
                    // back up; the first solid it meets from above is what the satellite saw.
                    let g = Vector3::new(x, y, w.height(x, y));
                    let back = 150.0;
                    let o = g - d * back;
                    let mut best = None;
                    for set in sets {
                        if let Some((i, hit)) = nearest(set, &o, &d, back - 1e-3) {
                            if best.as_ref().is_none_or(
                                |(_, h, _): &(usize, super::solids::Hit, &[Solid])| hit.t < h.t,
                            ) {
                                best = Some((i, hit, set));
                            }
                        }
                    }
                    let (albedo, n, p) = match best {
                        Some((i, hit, set)) => {
                            let s = &set[i];
                            let p = o + hit.t * d;
                            let mut c = if hit.normal.z > 0.5 {
                                s.rgb_top
                            } else {
                                s.rgb_side
                            };
                            if s.kind == Kind::Crown {
                                let k =
                                    0.6 + 0.8 * (0.5 + 0.5 * leaves.fbm(p.x + p.z, p.y - p.z, 3));
                                c = [c[0] * k, c[1] * k, c[2] * k];
                            }
                            (c, hit.normal, p)
                        }
                        None => {
                            let s = w.surface(x, y);
                            (look.satellite(&s, x, y), ground_normal(w, x, y), g)
                        }
                    };
                    let cos = n.dot(&shot.light.sun).max(0.0);
                    let vis = if cos > 0.0 {
                        sun_visibility(&sets, &(p + n * 1e-3), &shot.light.sun, &dapple)
                    } else {
                        0.0
                    };
                    // Skylight is bluish, sunlight warm: shadows turn blue-gray as in real imagery.
                    let sky = [0.85, 0.95, 1.2];
                    let sunc = [1.05, 1.0, 0.92];
                    let mut out = [0f32; 3];
                    for k in 0..3 {
                        let e = shot.light.ambient * sky[k] * (0.5 + 0.5 * n.z)
                            + shot.light.sun_irr * sunc[k] * cos * vis;
                        out[k] = (albedo[k] * e) as f32;
                    }
                    out
                })
                .collect()
        })
        .collect();
    for (row, r) in rows.iter().enumerate() {
        for (col, v) in r.iter().enumerate() {
            for k in 0..3 {
                planes[k][row * gw + col] = v[k];
            }
        }
    }
    for p in planes.iter_mut() {
        gaussian_blur(p, gw, gh, shot.blur_px);
    }
    // Tone: exposure so that bright concrete is near 220, then sRGB-like gamma.
    let mut rgb = vec![0u8; gw * gh * 3];
    for i in 0..gw * gh {
        for k in 0..3 {
            let v = (planes[k][i] as f64 * 1.25).clamp(0.0, 1.0).powf(1.0 / 2.2);
            rgb[i * 3 + k] = (v * 255.0).round() as u8;
        }
    }
    // Through a real JPEG encoder/decoder: blocking and ringing as in served imagery.
    let mut buf = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, shot.jpeg_quality)
        .encode(&rgb, gw as u32, gh as u32, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::output("satellite JPEG encode", e))?;
    let dec = image::load_from_memory_with_format(&buf, image::ImageFormat::Jpeg)
        .map_err(|e| Error::output("satellite JPEG decode", e))?
        .to_rgb8();
    let data = dec.pixels().map(|p| p.0).collect();
    Ok(Raster {
        grid: *grid,
        data,
        nodata: None,
    })
}
