use super::*;
use crate::camera::Mei;
use crate::map::GeoGrid;

/// A 185° fisheye on a 1000 × 800 sensor.
fn fisheye() -> Mei {
    Mei {
        width: 1000,
        height: 800,
        fx: 560.0,
        fy: 560.0,
        cx: 501.3,
        cy: 398.7,
        skew: 0.0,
        xi: 1.4,
        k1: -0.05,
        k2: 0.01,
        p1: 1e-4,
        p2: -2e-4,
        fov_deg: Some(185.0),
    }
}

fn grid(res: f64, width: usize, height: usize) -> GeoGrid {
    GeoGrid {
        crs: Crs::Local,
        x0: 500.0 - 0.5 * res * width as f64 - 0.013,
        y0: 300.0 + 0.5 * res * height as f64 + 0.021,
        res,
        width,
        height,
    }
}

/// A height layer sampled from `f(x, y)` at the cell centres.
fn layer(g: GeoGrid, f: impl Fn(f64, f64) -> f64) -> Raster<f32> {
    let mut r = Raster::filled(g, 0.0f32, Some(-9999.0));
    for row in 0..g.height {
        for col in 0..g.width {
            let (x, y) = g.pixel_center(col, row);
            r.data[row * g.width + col] = f(x, y) as f32;
        }
    }
    r
}

/// A bumpy road: camber, a ramp and ripples, so the bilinear surface has slopes everywhere.
fn bumpy(x: f64, y: f64) -> f64 {
    100.0 + 0.04 * (x - 500.0) - 0.02 * (y - 300.0)
        + 0.3 * ((x - 500.0) * 0.4).sin() * ((y - 300.0) * 0.3).cos()
}

fn pose(tilt: bool) -> CamFromMap {
    let (p, r) = if tilt { (4f64, -3f64) } else { (0.0, 0.0) };
    CamFromMap::from_center_ypr(
        &Point3::new(500.7, 299.2, 106.3),
        27f64.to_radians(),
        p.to_radians(),
        r.to_radians(),
    )
}

fn exact(p: CamFromMap) -> PoseWithCovariance {
    PoseWithCovariance {
        pose: p,
        covariance: None,
    }
}

/// No WGS84 and no height noise: the covariance tests below check the pose's and the pixel's
/// terms alone; the height term has its own tests.
const NO_WGS: Params = Params {
    max_off_nadir_deg: DEFAULT_MAX_OFF_NADIR_DEG,
    sigma_px: 0.0,
    wgs84: false,
    height_sigma_m: Some(0.0),
};

/// The layer's own samples, bilinear (no smoothing): the surface the exact tests check.
fn raw_surface(r: &Raster<f32>) -> Option<HeightSurface<'_>> {
    HeightSurface::with_smoothing(r, 0.0)
}

/// An independent intersection: march the ray in 1 mm steps on the bilinear surface (sampled
/// with the localizer's `height_at`), then bisect the first sign change.
fn marched(heights: &Raster<f32>, c: &Point3<f64>, d: &Vector3<f64>) -> Option<Point3<f64>> {
    let f = |t: f64| -> Option<f64> {
        let p = c + t * d;
        Some(p.z - crate::localize::init::ground::height_at(heights, p.x, p.y)?)
    };
    let step = 1e-3;
    let mut t = 0.0;
    let mut prev = f(t)?;
    loop {
        let next = f(t + step)?;
        if next <= 0.0 && prev > 0.0 {
            let (mut a, mut b) = (t, t + step);
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                if f(m)? > 0.0 {
                    a = m
                } else {
                    b = m
                }
            }
            return Some(c + 0.5 * (a + b) * d);
        }
        prev = next;
        t += step;
        if t > 200.0 {
            return None;
        }
    }
}

fn ray(cam: &Mei, p: &CamFromMap, px: [f64; 2]) -> Vector3<f64> {
    p.rotation.inverse()
        * cam
            .unproject(&Point2::new(px[0], px[1]))
            .unwrap()
            .into_inner()
}

#[test]
fn a_plane_layer_gives_the_analytic_intersection() {
    // A tilted plane sampled on the grid is its own bilinear interpolant.
    let g = grid(0.1, 900, 700);
    let plane = |x: f64, y: f64| 100.0 + 0.06 * (x - 500.0) - 0.035 * (y - 300.0);
    let h = layer(g, plane);
    let surf = Surface::Heights(raw_surface(&h).unwrap());
    let cam = fisheye();
    let p = pose(true);
    let c = p.center();
    let mut n = 0;
    for v in (0..800).step_by(23) {
        for u in (0..1000).step_by(29) {
            let px = [u as f64 + 0.37, v as f64 + 0.61];
            let m = georef(&cam, &exact(p), &surf, Crs::Local, px, &NO_WGS);
            if m.status != Status::Ok {
                continue;
            }
            // Ray–plane: z = a + bx·x + by·y.
            let d = ray(&cam, &p, px);
            let (bx, by) = (0.06, -0.035);
            let t = (plane(c.x, c.y) - c.z) / (d.z - bx * d.x - by * d.y);
            let want = c + t * d;
            let err = (Point3::from(m.enh) - want).norm();
            // f32 heights: ~4e-6 m of rounding, ×tan θ horizontally (≤ 11 at 85°).
            assert!(err < 2e-4, "pixel {px:?}: {err} m");
            n += 1;
        }
    }
    assert!(n > 300, "{n} pixels met the plane");
}

#[test]
fn the_walk_agrees_with_a_millimetre_march_on_a_bumpy_layer() {
    let g = grid(0.1, 900, 700);
    let h = layer(g, bumpy);
    let surf = Surface::Heights(raw_surface(&h).unwrap());
    let cam = fisheye();
    let p = pose(true);
    let mut n = 0;
    for v in (0..800).step_by(61) {
        for u in (0..1000).step_by(67) {
            let px = [u as f64 + 0.5, v as f64 + 0.25];
            let m = georef(&cam, &exact(p), &surf, Crs::Local, px, &NO_WGS);
            // Pixels without a descending ray to march are not compared.
            if matches!(
                m.status,
                Status::Grazing
                    | Status::AboveHorizon
                    | Status::OutsideCircle
                    | Status::OutsideImage
            ) {
                continue;
            }
            let want = marched(&h, &p.center(), &ray(&cam, &p, px));
            match (m.status, want) {
                (Status::Ok, Some(w)) => {
                    let err = (Point3::from(m.enh) - w).norm();
                    assert!(err < 1e-6, "pixel {px:?}: {err} m");
                    n += 1;
                }
                // Off the layer: neither finds ground.
                (Status::NoHeight, None) => {}
                (s, w) => panic!("pixel {px:?}: {s:?} against the march's {w:?}"),
            }
        }
    }
    assert!(n > 80, "{n} pixels compared");
}

#[test]
fn the_flat_plane_option_is_the_ray_plane_intersection() {
    let cam = fisheye();
    let p = pose(false);
    let c = p.center();
    let px = [612.0, 455.0];
    let m = georef(
        &cam,
        &exact(p),
        &Surface::Plane(100.0),
        Crs::Local,
        px,
        &NO_WGS,
    );
    let d = ray(&cam, &p, px);
    let want = c + ((100.0 - c.z) / d.z) * d;
    assert_eq!(m.status, Status::Ok);
    assert!((Point3::from(m.enh) - want).norm() < 1e-9);
    assert!((m.enh[2] - 100.0).abs() < 1e-9);
}

/// The covariance's Jacobian against central differences of the georeference itself.
#[test]
fn the_covariance_propagates_the_pose_jacobian() {
    let g = grid(0.1, 900, 700);
    let h = layer(g, bumpy);
    let surf = Surface::Heights(raw_surface(&h).unwrap());
    let cam = fisheye();
    let p = pose(true);
    let (y0, p0, r0) = p.yaw_pitch_roll();
    let c0 = p.center();
    let at = |k: usize, e: f64| -> CamFromMap {
        let mut v = [
            c0.x,
            c0.y,
            c0.z,
            y0.to_degrees(),
            p0.to_degrees(),
            r0.to_degrees(),
        ];
        v[k] += e;
        CamFromMap::from_center_ypr(
            &Point3::new(v[0], v[1], v[2]),
            v[3].to_radians(),
            v[4].to_radians(),
            v[5].to_radians(),
        )
    };
    for px in [
        [520.0, 410.0],
        [650.3, 330.2],
        [380.5, 560.0],
        [300.0, 300.0],
    ] {
        // Finite-difference Jacobian, column per axis.
        let mut jac = [[0.0; 3]; 6];
        for (k, col) in jac.iter_mut().enumerate() {
            // 0.1 mm and 1e-4°: small enough for the curvature, large enough for rounding.
            let e = 1e-4;
            let a = georef(&cam, &exact(at(k, e)), &surf, Crs::Local, px, &NO_WGS);
            let b = georef(&cam, &exact(at(k, -e)), &surf, Crs::Local, px, &NO_WGS);
            assert_eq!((a.status, b.status), (Status::Ok, Status::Ok));
            for (c, (ea, eb)) in col.iter_mut().zip(a.enh.iter().zip(&b.enh)) {
                *c = (ea - eb) / (2.0 * e);
            }
        }
        // One axis at a time: the analytic covariance of a unit variance is J·Jᵀ of its column.
        for (k, col) in jac.iter().enumerate() {
            let mut sigma = [0.0; 6];
            sigma[k] = 1.0;
            let pc = PoseWithCovariance {
                pose: p,
                covariance: Some(PoseCovariance::from_sigma(sigma)),
            };
            let m = georef(&cam, &pc, &surf, Crs::Local, px, &NO_WGS);
            for i in 0..3 {
                for j in 0..3 {
                    let want = col[i] * col[j];
                    let got = m.covariance[i][j];
                    let scale = (col[i].abs().max(col[j].abs())).powi(2).max(1e-6);
                    assert!(
                        (got - want).abs() <= 1e-4 * scale,
                        "pixel {px:?}, axis {}, entry ({i},{j}): {got} against {want}",
                        POSE_AXES[k]
                    );
                }
            }
        }
    }
}

#[test]
fn pixel_noise_adds_the_pixel_jacobian() {
    let cam = fisheye();
    let p = pose(true);
    let surf = Surface::Plane(100.0);
    let px = [700.0, 250.0];
    let params = Params {
        sigma_px: 0.5,
        ..NO_WGS
    };
    let m = georef(&cam, &exact(p), &surf, Crs::Local, px, &params);
    // Central differences of the point over ±0.5 px per image axis.
    let at = |du: f64, dv: f64| {
        georef(
            &cam,
            &exact(p),
            &surf,
            Crs::Local,
            [px[0] + du, px[1] + dv],
            &NO_WGS,
        )
        .enh
    };
    let mut want = [[0.0; 3]; 3];
    for (a, b) in [
        (at(1e-3, 0.0), at(-1e-3, 0.0)),
        (at(0.0, 1e-3), at(0.0, -1e-3)),
    ] {
        let j: Vec<f64> = (0..3).map(|i| (a[i] - b[i]) / 2e-3 * 0.5).collect();
        for i in 0..3 {
            for k in 0..3 {
                want[i][k] += j[i] * j[k];
            }
        }
    }
    for i in 0..3 {
        for k in 0..3 {
            assert!(
                (m.covariance[i][k] - want[i][k]).abs() <= 1e-5 * want[0][0].max(want[1][1]),
                "({i},{k}): {} against {}",
                m.covariance[i][k],
                want[i][k]
            );
        }
    }
    assert!(m.ellipse().sigma_major_m > 0.0);
}

#[test]
fn every_failure_has_its_status_and_spares_the_rest() {
    let g = grid(0.1, 200, 200);
    let mut h = layer(g, |_, _| 100.0);
    // A hole under the camera's nadir area.
    let (c0, r0) = g.to_pixel(500.7, 299.2);
    for r in (r0 as usize - 3)..(r0 as usize + 4) {
        for c in (c0 as usize - 3)..(c0 as usize + 4) {
            h.data[r * g.width + c] = f32::NAN;
        }
    }
    let surf = Surface::Heights(raw_surface(&h).unwrap());
    let cam = fisheye();
    let p = pose(false);
    // The principal point looks straight down into the hole.
    let nadir = [cam.cx, cam.cy];
    let near = cam.project(&Vector3::new(0.2, 0.1, 1.0)).unwrap();
    let far = cam.project(&Vector3::new(1.0, 0.4, 0.5)).unwrap(); // ~63° off nadir, off the tile
    let grazing = cam.project(&Vector3::new(1.0, 0.0, 0.03)).unwrap();
    let above = cam.project(&Vector3::new(1.0, 0.0, -0.02)).unwrap();
    let beyond_fov = cam.project(&Vector3::new(1.0, 0.0, -0.2)).unwrap(); // ~101° off axis
    let pixels = [
        [near.x, near.y],
        nadir,
        [f64::NAN, 5.0],
        [5.0, f64::INFINITY],
        [-3.0, 400.0],
        [500.0, 800.0],
        [far.x, far.y],
        [grazing.x, grazing.y],
        [above.x, above.y],
        [beyond_fov.x, beyond_fov.y],
        [3.0, 3.0], // a corner of the sensor, outside the image circle
    ];
    let want = [
        Status::Ok,
        Status::NoHeight,
        Status::NonFinite,
        Status::NonFinite,
        Status::OutsideImage,
        Status::OutsideImage,
        Status::NoHeight,
        Status::Grazing,
        Status::AboveHorizon,
        Status::OutsideCircle,
        Status::OutsideCircle,
    ];
    let got = georef_batch(&cam, &exact(p), &surf, Crs::Local, &pixels, &NO_WGS);
    let got: Vec<Status> = got.iter().map(|m| m.status).collect();
    assert_eq!(got, want);
    // The good pixel's point is the one it has alone.
    let alone = georef(&cam, &exact(p), &surf, Crs::Local, pixels[0], &NO_WGS);
    let batch = georef_batch(&cam, &exact(p), &surf, Crs::Local, &pixels, &NO_WGS);
    assert_eq!(batch[0], alone);
    assert!((alone.enh[2] - 100.0).abs() < 1e-9);
    assert!(batch[1..].iter().all(|m| m.enh[0].is_nan()));
    assert!(georef_batch(&cam, &exact(p), &surf, Crs::Local, &[], &NO_WGS).is_empty());
    // Over a hole well below the ray (the camera 6 m up) the ray passes: a pixel just off the
    // hole's edge on the far side still meets the ground.
    let off = cam.project(&Vector3::new(0.08, 0.0, 1.0)).unwrap();
    let m = georef(&cam, &exact(p), &surf, Crs::Local, [off.x, off.y], &NO_WGS);
    assert_eq!(m.status, Status::Ok, "{m:?}");
}

#[test]
fn rays_pass_over_a_hole_the_block_lies_below() {
    // Flat ground at 100 m with a hole, and one 104 m cell in a far corner, so rays are walked
    // from 104 m down: the slanted ray crosses the hole ~3.7 m above it.
    let g = grid(0.1, 400, 400);
    let mut h = layer(g, |_, _| 100.0);
    h.data[0] = 104.0;
    let (hc, hr) = g.to_pixel(503.0, 299.2);
    for r in (hr as usize - 2)..(hr as usize + 3) {
        for c in (hc as usize - 2)..(hc as usize + 3) {
            h.data[r * g.width + c] = -9999.0;
        }
    }
    let surf = Surface::Heights(raw_surface(&h).unwrap());
    let cam = fisheye();
    let p = pose(false);
    let c = p.center();
    // The ray through (506.0, 299.2, 100): passes over the hole at x ≈ 503 halfway down.
    let target = Vector3::new(506.0, 299.2, 100.0) - c.coords;
    let px = cam.project(&(p.rotation * target)).unwrap();
    let m = georef(&cam, &exact(p), &surf, Crs::Local, [px.x, px.y], &NO_WGS);
    assert_eq!(m.status, Status::Ok);
    assert!((m.enh[0] - 506.0).abs() < 1e-6 && (m.enh[1] - 299.2).abs() < 1e-6);
}

#[test]
fn the_ellipse_of_a_known_covariance() {
    // σ 3 along 30°, σ 1 across.
    let (s1, s2, a) = (3.0f64, 1.0f64, 30f64.to_radians());
    let (c, s) = (a.cos(), a.sin());
    let cov = [
        [
            s1 * s1 * c * c + s2 * s2 * s * s,
            (s1 * s1 - s2 * s2) * c * s,
            0.0,
        ],
        [
            (s1 * s1 - s2 * s2) * c * s,
            s1 * s1 * s * s + s2 * s2 * c * c,
            0.0,
        ],
        [0.0, 0.0, 1.0],
    ];
    let e = Ellipse::of(&cov);
    assert!((e.sigma_major_m - 3.0).abs() < 1e-12);
    assert!((e.sigma_minor_m - 1.0).abs() < 1e-12);
    assert!((e.angle_deg - 30.0).abs() < 1e-9);
    // 3 along the major axis is 1σ; 1 across it too.
    assert!((Ellipse::mahalanobis(&cov, 3.0 * c, 3.0 * s) - 1.0).abs() < 1e-12);
    assert!((Ellipse::mahalanobis(&cov, -s, c) - 1.0).abs() < 1e-12);
}

#[test]
fn pose_covariance_axes_are_checked() {
    let axes: Vec<String> = ["x", "y", "z", "yaw"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let m = vec![
        vec![1.0, 0.1, 0.0, 0.0],
        vec![0.1, 2.0, 0.0, 0.0],
        vec![0.0, 0.0, 3.0, 0.0],
        vec![0.0, 0.0, 0.0, 4.0],
    ];
    let c = PoseCovariance::from_axes(&axes, &m).unwrap();
    assert_eq!(c.matrix[1][0], 0.1);
    assert_eq!(c.matrix[3][3], 4.0);
    assert_eq!(c.matrix[4][4], 0.0);
    let bad = ["x", "y", "z", "spin"].map(String::from);
    assert!(PoseCovariance::from_axes(&bad, &m)
        .unwrap_err()
        .to_string()
        .contains("spin"));
    assert!(PoseCovariance::from_axes(&axes[..3], &m)
        .unwrap_err()
        .to_string()
        .contains("3×3"));
    let mut nan = m.clone();
    nan[2][2] = f64::NAN;
    assert!(PoseCovariance::from_axes(&axes, &nan)
        .unwrap_err()
        .to_string()
        .contains("not finite"));
}

#[test]
fn wgs84_is_added_on_epsg_tiles() {
    let cam = fisheye();
    // A pose in UTM 32N near 48.1° N, 11.6° E.
    let (e, n) = crate::geo::wgs84_to_map(Crs::Epsg(32632), 48.1, 11.6).unwrap();
    let p = CamFromMap::from_center_ypr(&Point3::new(e, n, 506.0), 0.3, 0.0, 0.0);
    let m = georef(
        &cam,
        &exact(p),
        &Surface::Plane(500.0),
        Crs::Epsg(32632),
        [cam.cx, cam.cy],
        &Params::default(),
    );
    let [lat, lon] = m.lat_lon.unwrap();
    let (be, bn) = crate::geo::wgs84_to_map(Crs::Epsg(32632), lat, lon).unwrap();
    assert!((be - m.enh[0]).abs() < 1e-6 && (bn - m.enh[1]).abs() < 1e-6);
    assert!((lat - 48.1).abs() < 1e-4 && (lon - 11.6).abs() < 1e-4);
}

#[test]
fn the_lookup_table_holds_each_step_pixels_georeference() {
    let g = grid(0.1, 240, 240);
    let h = layer(g, bumpy);
    let surf = Surface::Heights(raw_surface(&h).unwrap());
    let cam = fisheye();
    let pose = PoseWithCovariance {
        pose: pose(true),
        covariance: Some(PoseCovariance::from_sigma([
            0.01, 0.02, 0.01, 0.05, 0.0, 0.0,
        ])),
    };
    let lut = lookup_table(&cam, &pose, &surf, 7, &NO_WGS);
    // 1000 × 800 at a step of 7: columns 0, 7, …, 994 and rows 0, 7, …, 798.
    assert_eq!((lut.step, lut.cols, lut.rows), (7, 143, 115));
    assert_eq!(lut.cells.len(), lut.rows * lut.cols);
    let (mut ok, mut not) = (0, 0);
    for (k, cell) in lut.cells.iter().enumerate() {
        let px = [(k % lut.cols * 7) as f64, (k / lut.cols * 7) as f64];
        let m = georef(&cam, &pose, &surf, Crs::Local, px, &NO_WGS);
        if m.status == Status::Ok {
            ok += 1;
            let want = [m.enh[0], m.enh[1], m.enh[2], m.ellipse().sigma_major_m];
            assert_eq!(*cell, want, "pixel {px:?}");
        } else {
            not += 1;
            assert!(cell.iter().all(|v| v.is_nan()), "pixel {px:?}: {cell:?}");
        }
    }
    // Both kinds occur: the layer's 24 m square ends inside the image circle.
    assert!(ok > 1000 && not > 1000, "{ok} ok, {not} not");
    // A step of 0 is a step of 1.
    let one = lookup_table(&cam, &pose, &Surface::Plane(100.0), 0, &NO_WGS);
    assert_eq!((one.step, one.cols, one.rows), (1, 1000, 800));
}

#[test]
fn statuses_read_back_from_their_names() {
    for s in Status::ALL {
        assert_eq!(Status::from_name(s.name()), Some(s));
    }
    assert_eq!(Status::from_name("fine"), None);
}

/// A seeded standard normal (Box–Muller over a splitmix64 stream).
fn normals(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    move || {
        let (a, b) = (next().max(1e-300), next());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

#[test]
fn the_layer_noise_is_estimated_from_the_layer() {
    let g = grid(0.1, 400, 300);
    // A tilted, cambered road with 3 cm of independent noise per cell and a 15 cm kerb.
    for sigma in [0.01, 0.03] {
        let mut noise = normals(7);
        let mut r = layer(g, |x, y| {
            let kerb = if x > 510.0 { 0.15 } else { 0.0 };
            100.0 + 0.03 * (x - 500.0) + 0.002 * (y - 300.0).powi(2) + kerb
        });
        for v in &mut r.data {
            *v += (sigma * noise()) as f32;
        }
        let est = raw_surface(&r).unwrap().noise_sigma_m();
        assert!(
            (est / sigma - 1.0).abs() < 0.05,
            "σ {sigma}: estimated {est}"
        );
    }
    // Without noise the kerb and the camber alone leave it at (almost) nothing.
    let r = layer(g, |x, y| {
        100.0
            + 0.03 * (x - 500.0)
            + 0.002 * (y - 300.0).powi(2)
            + if x > 510.0 { 0.15 } else { 0.0 }
    });
    let est = raw_surface(&r).unwrap().noise_sigma_m();
    assert!(est < 1e-3, "noise-free layer: {est}");
}

/// The height term equals the variance of the point under independent noise of σ on each of the
/// four samples its height is interpolated from, by central differences of the georeference.
#[test]
fn the_height_term_is_the_samples_noise_carried_along_the_ray() {
    let g = grid(0.1, 900, 700);
    let base = layer(g, bumpy);
    let surf = Surface::Heights(raw_surface(&base).unwrap());
    let cam = fisheye();
    let p = pose(true);
    let sigma_h = 0.03;
    let with_h = Params {
        height_sigma_m: Some(sigma_h),
        ..NO_WGS
    };
    for px in [
        [520.0, 410.0],
        [650.3, 330.2],
        [380.5, 560.0],
        [300.0, 300.0],
    ] {
        let m = georef(&cam, &exact(p), &surf, Crs::Local, px, &with_h);
        assert_eq!(m.status, Status::Ok, "{px:?}");
        let m0 = georef(&cam, &exact(p), &surf, Crs::Local, px, &NO_WGS);
        // The four samples around the hit.
        let (fc, fr) = g.to_pixel(m.enh[0], m.enh[1]);
        let (c0, r0) = (fc.floor() as usize, fr.floor() as usize);
        let mut want = [[0.0; 3]; 3];
        for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let k = (r0 + dr) * g.width + c0 + dc;
            let shifted = |eps: f32| {
                let mut r = base.clone();
                r.data[k] += eps;
                let s = Surface::Heights(raw_surface(&r).unwrap());
                georef(&cam, &exact(p), &s, Crs::Local, px, &NO_WGS).enh
            };
            let eps = 1e-3f32;
            let (a, b) = (shifted(eps), shifted(-eps));
            let j: Vec<f64> = (0..3).map(|i| (a[i] - b[i]) / (2.0 * eps as f64)).collect();
            for r in 0..3 {
                for c in 0..3 {
                    want[r][c] += sigma_h * sigma_h * j[r] * j[c];
                }
            }
        }
        for r in 0..3 {
            for c in 0..3 {
                let got = m.covariance[r][c] - m0.covariance[r][c];
                let tol = 2e-3 * want[r][r].max(want[c][c]).max(1e-8);
                assert!(
                    (got - want[r][c]).abs() < tol,
                    "{px:?} [{r}][{c}]: {got} vs {want:?}"
                );
            }
        }
        // On flat ground the horizontal part is δh·tan θ: far pixels get more of it.
        let horiz = (want[0][0] + want[1][1]).sqrt();
        assert!(horiz > 0.0);
    }
}

#[test]
fn the_default_height_sigma_is_the_layers_and_none_for_a_plane() {
    let g = grid(0.1, 400, 300);
    let mut noise = normals(11);
    let mut r = layer(g, |_, _| 100.0);
    for v in &mut r.data {
        *v += (0.02 * noise()) as f32;
    }
    let hs = raw_surface(&r).unwrap();
    let est = hs.noise_sigma_m();
    let heights = Surface::Heights(hs);
    let cam = fisheye();
    let p = pose(false);
    let auto = Params {
        height_sigma_m: None,
        ..NO_WGS
    };
    let given = Params {
        height_sigma_m: Some(est),
        ..NO_WGS
    };
    let px = [300.0, 300.0];
    let a = georef(&cam, &exact(p), &heights, Crs::Local, px, &auto);
    let b = georef(&cam, &exact(p), &heights, Crs::Local, px, &given);
    assert_eq!(a.status, Status::Ok);
    assert_eq!(a.covariance, b.covariance);
    assert!(a.covariance[0][0] + a.covariance[1][1] > 0.0);
    let plane = Surface::Plane(100.0);
    let c = georef(&cam, &exact(p), &plane, Crs::Local, px, &auto);
    assert_eq!(c.covariance, [[0.0; 3]; 3]);
    let d = georef(&cam, &exact(p), &plane, Crs::Local, px, &given);
    // A plane's σ_h is the plane's own: the whole δh, along the ray.
    let tan = (c.enh[0] - p.center().x).hypot(c.enh[1] - p.center().y) / (p.center().z - 100.0);
    let horiz = (d.covariance[0][0] + d.covariance[1][1]).sqrt();
    assert!(
        (horiz / (est * tan) - 1.0).abs() < 1e-9,
        "{horiz} vs {}",
        est * tan
    );
}

#[test]
fn smoothing_keeps_a_plane_in_the_layers_interior() {
    let g = grid(0.1, 900, 700);
    let plane = |x: f64, y: f64| 100.0 + 0.06 * (x - 500.0) - 0.035 * (y - 300.0);
    let h = layer(g, plane);
    let surf = Surface::Heights(HeightSurface::new(&h).unwrap());
    let cam = fisheye();
    let p = pose(true);
    let c = p.center();
    let mut n = 0;
    for v in (250..560).step_by(40) {
        for u in (300..720).step_by(40) {
            let px = [u as f64 + 0.37, v as f64 + 0.61];
            let m = georef(&cam, &exact(p), &surf, Crs::Local, px, &NO_WGS);
            assert_eq!(m.status, Status::Ok, "{px:?}");
            let d = ray(&cam, &p, px);
            // The ray met with the plane analytically.
            let (a, b) = (0.06, -0.035);
            let t =
                (100.0 + a * (c.x - 500.0) + b * (c.y - 300.0) - c.z) / (d.z - a * d.x - b * d.y);
            let want = c + t * d;
            let err = (Vector3::new(m.enh[0], m.enh[1], m.enh[2]) - want.coords).norm();
            assert!(err < 5e-4, "{px:?}: {err}");
            n += 1;
        }
    }
    assert!(n > 50);
}

/// Far from nadir a height error moves the point by δh·tan θ; the smoothed surface's height
/// error is a fraction of the raw layer's, and the upward bias of the first crossing (the ray
/// meets the first bump that reaches it) goes with it.
#[test]
fn smoothing_cuts_the_height_error_of_grazing_rays() {
    let g = grid(0.1, 900, 700);
    let sigma = 0.03;
    let mut noise = normals(5);
    let mut h = layer(g, |_, _| 100.0);
    for v in &mut h.data {
        *v += (sigma * noise()) as f32;
    }
    let cam = fisheye();
    let p = pose(false);
    let stats = |surf: &Surface<'_>| {
        let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0);
        for v in (0..800).step_by(7) {
            for u in (0..1000).step_by(7) {
                let m = georef(
                    &cam,
                    &exact(p),
                    surf,
                    Crs::Local,
                    [u as f64, v as f64],
                    &NO_WGS,
                );
                if m.status == Status::Ok && (72.0..82.0).contains(&m.off_nadir_deg) {
                    sum += m.enh[2] - 100.0;
                    sum2 += (m.enh[2] - 100.0).powi(2);
                    n += 1;
                }
            }
        }
        assert!(n > 500, "{n} grazing pixels");
        (sum / n as f64, (sum2 / n as f64).sqrt())
    };
    let (raw_mean, raw_rms) = stats(&Surface::Heights(raw_surface(&h).unwrap()));
    let (mean, rms) = stats(&Surface::Heights(HeightSurface::new(&h).unwrap()));
    assert!(raw_mean > 0.1 * sigma, "raw layer: mean δh {raw_mean}");
    assert!(mean.abs() < 0.05 * sigma, "smoothed: mean δh {mean}");
    assert!(rms < raw_rms / 3.0, "rms δh: smoothed {rms}, raw {raw_rms}");
}

/// The height term of a smoothed surface is the kernel's share of the layer's noise: over many
/// noise draws the hit's height varies as the covariance says.
#[test]
fn the_smoothed_height_term_matches_the_scatter_over_noise_draws() {
    let g = grid(0.1, 300, 300);
    let sigma = 0.03;
    let cam = fisheye();
    let p = CamFromMap::from_center_ypr(&Point3::new(500.0, 300.0, 106.0), 0.3, 0.0, 0.0);
    let params = Params {
        height_sigma_m: Some(sigma),
        ..NO_WGS
    };
    let px = [640.0, 470.0];
    let (mut sum2, mut var_pred) = (0.0, 0.0);
    let draws = 60;
    for seed in 0..draws {
        let mut noise = normals(1000 + seed);
        let mut h = layer(g, |_, _| 100.0);
        for v in &mut h.data {
            *v += (sigma * noise()) as f32;
        }
        let surf = Surface::Heights(HeightSurface::new(&h).unwrap());
        let m = georef(&cam, &exact(p), &surf, Crs::Local, px, &params);
        assert_eq!(m.status, Status::Ok);
        // Off nadir the error runs along the ray: its vertical part is the height error.
        sum2 += (m.enh[2] - 100.0).powi(2);
        var_pred = m.covariance[2][2];
    }
    let ratio = sum2 / draws as f64 / var_pred;
    // χ² with 60 degrees of freedom: 99 % of draws fall in [0.61, 1.47]; the kernel's own sum
    // is a little above the variance between samples.
    assert!(
        (0.4..1.5).contains(&ratio),
        "scatter / predicted variance {ratio}"
    );
}

#[test]
fn smoothing_out_of_range_is_refused() {
    let g = grid(0.1, 50, 50);
    let h = layer(g, |_, _| 100.0);
    for bad in [-0.1, f64::NAN, MAX_SMOOTHING_M + 0.1, f64::INFINITY] {
        assert!(HeightIndex::with_smoothing(&h, bad).is_none(), "{bad}");
    }
    assert_eq!(
        HeightIndex::with_smoothing(&h, 0.0).unwrap().smoothing_m(),
        0.0
    );
}
