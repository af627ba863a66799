//! MI refinement on synthetic scenes generated here: a procedural ground texture seen by the LiDAR
//! (reflectivity) and, through a different non-monotonic gray mapping, by a Mei fisheye at a known
//! pose; refinement starts from perturbed poses.

use infraloc::camera::{Camera, Mei};
use infraloc::localize::mi::objective::Evaluator;
use infraloc::localize::mi::points::GroundPoint;
use infraloc::localize::mi::space::{AxisRange, Mode, SearchConfig, SearchSpec};
use infraloc::localize::mi::Objective;
use infraloc::localize::refine::quality::{assess, QualityConfig};
use infraloc::localize::refine::search::{search, SearchResult};
use infraloc::localize::synth::{ground_points, render, Texture};
use infraloc::pose::{rotation_angle_between, CamFromMap};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn fisheye(size: u32, f: f64) -> Camera {
    Camera::Mei(Mei {
        width: size,
        height: size,
        fx: f,
        fy: f * 1.002,
        cx: size as f64 / 2.0 - 0.5 + 1.3,
        cy: size as f64 / 2.0 - 0.5 - 0.7,
        skew: 0.0,
        xi: 1.2,
        k1: -0.04,
        k2: 0.008,
        p1: 2e-4,
        p2: -1e-4,
        fov_deg: Some(185.0),
    })
}

struct Scene {
    cam: Camera,
    truth: CamFromMap,
    gray: Vec<u8>,
    mask: Vec<u8>,
    points: Vec<GroundPoint>,
}

fn scene(seed: u64, size: u32, f: f64, radius: f64, spacing: f64) -> Scene {
    let cam = fisheye(size, f);
    let tex = Texture::new(seed);
    let truth = CamFromMap::from_center_ypr(&Point3::new(37.0, -12.0, 6.0), 0.4, 0.01, -0.015);
    let (gray, mask) = render(&tex, &cam, &truth, 0.0, 4.0, seed + 100);
    let points = ground_points(&tex, (37.3, -12.2), radius, spacing, 0.0, 4.0, seed + 200);
    Scene {
        cam,
        truth,
        gray,
        mask,
        points,
    }
}

/// Offsets of the truth from an initial pose: (dx, dy, dz) of the centre, dyaw (deg).
fn truth_offset(init: &CamFromMap, truth: &CamFromMap) -> ([f64; 3], f64) {
    let d = truth.center() - init.center();
    let dyaw = (truth.yaw_pitch_roll().0 - init.yaw_pitch_roll().0).to_degrees();
    ([d.x, d.y, d.z], dyaw)
}

fn run(s: &Scene, init: &CamFromMap, cfg: &SearchConfig) -> (SearchResult, Evaluator) {
    let ev = Evaluator::new(&s.cam, &s.gray, &s.mask, &s.points, init, cfg, 6).unwrap();
    (search(&ev, cfg), ev)
}

#[test]
fn recovers_truth_from_perturbed_starts() {
    let s = scene(7, 768, 450.0, 14.0, 0.08);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let cfg = SearchConfig::default();
    for trial in 0..3 {
        let d = Vector3::new(
            rng.random_range(-0.6..0.6),
            rng.random_range(-0.6..0.6),
            rng.random_range(-0.3..0.3),
        );
        let dyaw = rng.random_range(-2.0f64..2.0).to_radians();
        let init = s.truth.perturbed(&d, dyaw);
        let (res, ev) = run(&s, &init, &cfg);
        let err = res.pose.center() - s.truth.center();
        let yaw_err = rotation_angle_between(&res.pose.rotation, &s.truth.rotation).to_degrees();
        let q = assess(&ev, &res, &QualityConfig::default());
        eprintln!(
            "trial {trial}: err ({:.3}, {:.3}, {:.3}) m, rot {:.3}°, evals {} vs exhaustive {} ({}×), quality {:?}",
            err.x,
            err.y,
            err.z,
            yaw_err,
            res.stats.point_evaluations,
            res.stats.exhaustive_point_evaluations,
            res.stats.exhaustive_point_evaluations / res.stats.point_evaluations.max(1),
            q.grade
        );
        assert!(
            err.x.abs() <= 0.02 && err.y.abs() <= 0.02,
            "trial {trial}: {err:?}"
        );
        assert!(err.z.abs() <= 0.02, "trial {trial}: z {}", err.z);
        assert!(yaw_err <= 0.05, "trial {trial}: rotation error {yaw_err}°");
        assert!(
            res.stats.point_evaluations * 50 <= res.stats.exhaustive_point_evaluations,
            "tiled must evaluate ≥ 50× fewer point-poses"
        );
        assert!(q.precise(), "{}", q.grade);
        assert!(q
            .axes
            .iter()
            .all(|a| a.fisher_sigma > 0.0 && a.fisher_sigma < 0.05));
    }
}

#[test]
fn tiled_finds_the_exhaustive_cell() {
    let spec = SearchSpec {
        x: AxisRange {
            half: 0.1,
            step: 0.02,
        },
        y: AxisRange {
            half: 0.1,
            step: 0.02,
        },
        z: AxisRange {
            half: 0.06,
            step: 0.02,
        },
        yaw: AxisRange {
            half: 0.25,
            step: 0.05,
        },
        pitch: None,
        roll: None,
        tilt_pivot_m: None,
    };
    let mut agree = 0;
    let trials = 100;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut ratio_min = f64::MAX;
    for scene_seed in 0..4u64 {
        let s = scene(scene_seed + 20, 320, 190.0, 8.0, 0.25);
        for _ in 0..trials / 4 {
            let d = Vector3::new(
                rng.random_range(-0.08..0.08),
                rng.random_range(-0.08..0.08),
                rng.random_range(-0.03..0.03),
            );
            let init = s
                .truth
                .perturbed(&d, rng.random_range(-0.2f64..0.2).to_radians());
            let tiled_cfg = SearchConfig {
                spec,
                coarse_budget: 64,
                ..Default::default()
            };
            let ex_cfg = SearchConfig {
                mode: Mode::Exhaustive,
                ..tiled_cfg
            };
            let ev =
                Evaluator::new(&s.cam, &s.gray, &s.mask, &s.points, &init, &tiled_cfg, 6).unwrap();
            let t = search(&ev, &tiled_cfg);
            let e = search(&ev, &ex_cfg);
            assert!(t.stats.coarsest_level >= 2, "tiled must be coarse-to-fine");
            ratio_min =
                ratio_min.min(e.stats.point_evaluations as f64 / t.stats.point_evaluations as f64);
            if t.best.idx == e.best.idx {
                agree += 1;
            } else {
                eprintln!(
                    "miss: tiled {:?} {:.5} vs exhaustive {:?} {:.5}",
                    t.offsets, t.best.score, e.offsets, e.best.score
                );
            }
        }
    }
    eprintln!(
        "tiled == exhaustive in {agree}/{trials}; exhaustive/tiled evaluations ≥ {ratio_min:.1}"
    );
    // The target (99/100); measured 100/100 (docs/refine.md "Search"). The misses this
    // guards against are near-ties (≤ 0.1 % below the exhaustive maximum, a few yaw steps away).
    assert!(
        agree >= 99,
        "tiled found the exhaustive argmax in only {agree}/{trials}"
    );
}

#[test]
fn same_result_regardless_of_thread_count() {
    let s = scene(3, 256, 150.0, 8.0, 0.2);
    let init = s
        .truth
        .perturbed(&Vector3::new(0.3, -0.2, 0.1), 1f64.to_radians());
    let cfg = SearchConfig {
        coarse_min_points: 500,
        ..Default::default()
    };
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let a = one.install(|| run(&s, &init, &cfg).0);
    let b = run(&s, &init, &cfg).0;
    assert_eq!(a.best.idx, b.best.idx);
    assert_eq!(a.best.score.to_bits(), b.best.score.to_bits());
    assert_eq!(a.stats, b.stats);
    let _ = truth_offset(&init, &s.truth);
}

/// The trap: MI on fewer points is biased upward. A pinhole (Mei ξ = 0) looking down sees a ground
/// footprint ∝ z², so the naive estimator (every point that happens to be visible) is pulled to the
/// lowest z of the box when the real signal is weak; the fixed point set is not.
#[test]
fn fixed_point_set_removes_the_fewer_points_bias() {
    let cam = Camera::Mei(Mei::pinhole(320, 240, 180.0, 180.0, 159.5, 119.5));
    let tex = Texture::new(42);
    let truth = CamFromMap::from_center_ypr(&Point3::new(5.0, 5.0, 6.0), 0.2, 0.0, 0.0);
    // Heavy image noise: the true dependence is weak.
    let (gray, mask) = render(&tex, &cam, &truth, 0.0, 75.0, 1);
    let points = ground_points(&tex, (5.0, 5.0), 9.0, 0.2, 0.0, 40.0, 2);
    let spec = SearchSpec {
        x: AxisRange {
            half: 0.02,
            step: 0.02,
        },
        y: AxisRange {
            half: 0.02,
            step: 0.02,
        },
        z: AxisRange {
            half: 1.5,
            step: 0.1,
        },
        yaw: AxisRange {
            half: 0.05,
            step: 0.05,
        },
        pitch: None,
        roll: None,
        tilt_pivot_m: None,
    };
    let mut picks = Vec::new();
    for fixed in [false, true] {
        let cfg = SearchConfig {
            spec,
            mode: Mode::Exhaustive,
            fixed_point_set: fixed,
            ..Default::default()
        };
        let ev = Evaluator::new(&cam, &gray, &mask, &points, &truth, &cfg, 0).unwrap();
        let r = search(&ev, &cfg);
        eprintln!(
            "fixed={fixed}: dz = {:.2} m, n = {}, lost ≤ {:.3}",
            r.offsets[2], r.best.value.n, r.stats.max_lost_fraction
        );
        picks.push(r);
    }
    // Naive: the argmax is at the bottom of the box (fewest points), far from the truth.
    assert!(
        picks[0].offsets[2] <= -1.0,
        "naive dz {}",
        picks[0].offsets[2]
    );
    // Fixed set: every pose sees the same points, and the truth wins.
    assert!(picks[1].stats.max_lost_fraction == 0.0);
    // The loss the gate reads covers every level-0 pose the tiled search scored, the climbs'
    // included: at least the loss at its answer (always a climb's end), at most the exhaustive's.
    // A 1 cm z step makes the naive objective's slope towards the box's bottom a long climb
    // past the descent's windows (before the climbs counted, this reported 0.796 < 0.800).
    let fine_z = SearchSpec {
        z: AxisRange {
            half: 1.5,
            step: 0.01,
        },
        ..spec
    };
    for budget in [2, 8] {
        let cfg = SearchConfig {
            spec: fine_z,
            coarse_budget: budget,
            coarse_min_points: 500,
            fixed_point_set: false,
            ..Default::default()
        };
        let ev = Evaluator::new(&cam, &gray, &mask, &points, &truth, &cfg, 6).unwrap();
        let t = search(&ev, &cfg);
        let at_best = 1.0 - t.best.value.n as f64 / ev.n_points as f64;
        eprintln!(
            "tiled naive, budget {budget}: dz = {:.2}, lost at the answer {at_best:.3}, reported {:.3}",
            t.offsets[2], t.stats.max_lost_fraction
        );
        assert!(at_best > 0.0);
        assert!(t.stats.max_lost_fraction >= at_best);
        assert!(t.stats.max_lost_fraction <= picks[0].stats.max_lost_fraction);
    }
    assert!(
        picks[1].offsets[2].abs() <= 0.1,
        "fixed dz {}",
        picks[1].offsets[2]
    );
    // NMI is also offered; check it is selectable and finite.
    let cfg = SearchConfig {
        spec,
        mode: Mode::Exhaustive,
        mi: infraloc::localize::mi::MiConfig {
            objective: Objective::Nmi,
            ..Default::default()
        },
        ..Default::default()
    };
    let ev = Evaluator::new(&cam, &gray, &mask, &points, &truth, &cfg, 0).unwrap();
    assert!(search(&ev, &cfg).best.score > 1.0);
}

#[test]
fn bad_inputs_are_one_line_errors() {
    let s = scene(1, 128, 75.0, 5.0, 0.5);
    let cfg = SearchConfig::default();
    let e = |r: Result<Evaluator, infraloc::error::CoreError>| r.unwrap_err().to_string();
    assert!(e(Evaluator::new(
        &s.cam,
        &s.gray,
        &s.mask,
        &[],
        &s.truth,
        &cfg,
        0
    ))
    .contains("no ground points"));
    let mut bad = s.points.clone();
    bad[3].z = f64::NAN;
    assert!(e(Evaluator::new(
        &s.cam, &s.gray, &s.mask, &bad, &s.truth, &cfg, 0
    ))
    .contains("non-finite"));
    assert!(e(Evaluator::new(
        &s.cam,
        &s.gray[1..],
        &s.mask[1..],
        &s.points,
        &s.truth,
        &cfg,
        0
    ))
    .contains("camera is 128"));
    // Points far away from the camera: none visible from every pose.
    let far: Vec<GroundPoint> = s
        .points
        .iter()
        .map(|p| GroundPoint {
            z: p.z + 100.0,
            ..*p
        })
        .collect();
    assert!(e(Evaluator::new(
        &s.cam, &s.gray, &s.mask, &far, &s.truth, &cfg, 0
    ))
    .contains("none is visible"));
    for spec in ["x=0:0.02", "yaw=500:1", "z=1:0", "x=1", "q=1:1", "x=1:2"] {
        let r: Result<SearchSpec, infraloc::error::CoreError> = spec.parse();
        let msg = r.unwrap_err().to_string();
        assert!(
            !msg.contains('\n') && msg.contains("--search"),
            "{spec}: {msg}"
        );
    }
    let ok: SearchSpec = "x=0.5:0.01,yaw=2:0.1".parse().unwrap();
    assert_eq!(
        (ok.x.half, ok.x.step, ok.yaw.half, ok.y.half),
        (0.5, 0.01, 2.0, 1.0)
    );
}
