//! The quality gate's basin rule on a synthetic scene: the true optimum's basin is many cells wide
//! on every axis (accepted); the same result under a minimum wider than the profile can ever show
//! is refused with a reason naming the axis.

use infraloc::camera::{Camera, Mei};
use infraloc::localize::quality::{assess, QualityConfig, MIN_BASIN_STEPS};
use infraloc::localize::search::{search, AxisRange, Evaluator, SearchConfig, SearchSpec};
use infraloc::localize::synth::{ground_points, render, Texture};
use infraloc::pose::CamFromMap;
use nalgebra::{Point3, Vector3};

#[test]
fn basin_rule_accepts_a_true_peak_and_names_the_axis_when_refusing() {
    let cam = Camera::Mei(Mei {
        width: 480,
        height: 480,
        fx: 280.0,
        fy: 280.0,
        cx: 239.5,
        cy: 239.5,
        skew: 0.0,
        xi: 1.2,
        k1: -0.04,
        k2: 0.008,
        p1: 0.0,
        p2: 0.0,
        fov_deg: Some(185.0),
    });
    let tex = Texture::new(9);
    let truth = CamFromMap::from_center_ypr(&Point3::new(5.0, 3.0, 6.0), -0.8, 0.0, 0.0);
    let (gray, mask) = render(&tex, &cam, &truth, 0.0, 4.0, 3);
    let points = ground_points(&tex, (5.0, 3.0), 12.0, 0.1, 0.0, 4.0, 4);
    let start = truth.perturbed(&Vector3::new(0.06, -0.04, 0.02), 0.2f64.to_radians());
    let r = |half, step| AxisRange { half, step };
    let cfg = SearchConfig {
        spec: SearchSpec {
            x: r(0.3, 0.02),
            y: r(0.3, 0.02),
            z: r(0.2, 0.02),
            yaw: r(1.0, 0.05),
            ..SearchSpec::default()
        },
        ..SearchConfig::default()
    };
    let ev = Evaluator::new(&cam, &gray, &mask, &points, &start, &cfg, 6).unwrap();
    let res = search(&ev, &cfg);
    let q = assess(&ev, &res, &QualityConfig::default());
    assert!(q.accepted, "{:?}", q.reason);
    for a in &q.axes {
        let step = if a.unit == "m" { 0.02 } else { 0.05 };
        assert!(
            a.basin_width / step >= 2.0 * MIN_BASIN_STEPS as f64,
            "{} basin {} {}",
            a.axis,
            a.basin_width,
            a.unit
        );
    }
    let strict = QualityConfig {
        min_basin_steps: 1000,
        ..QualityConfig::default()
    };
    let q = assess(&ev, &res, &strict);
    let reason = q.reason.unwrap_or_default();
    assert!(
        !q.accepted && reason.starts_with("no basin along x"),
        "{reason}"
    );
}
