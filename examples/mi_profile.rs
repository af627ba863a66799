//! Diagnostics: the argmax of MI over a lateral (y) × yaw grid through a pose, for several
//! estimator settings, on pooled image/point pairs:
//! `cargo run --release --example mi_profile -- CAMERA POSE.json IMAGE POINTS [IMAGE POINTS]…`.
use infraloc::camera::load_camera;
use infraloc::camera::CameraModel;
use infraloc::localize::mi::kernel::Scratch;
use infraloc::localize::mi::objective::{Evaluator, View};
use infraloc::localize::mi::space::{AxisRange, SearchConfig, SearchSpec};
use infraloc::localize::mi::{mutual_information, Binning, JointHist, MiConfig};
use infraloc::points_io::read_points;
use infraloc::posefile::read_pose;
use std::path::Path;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let cam = load_camera(Path::new(&a[1])).unwrap();
    let pose = read_pose(Path::new(&a[2])).unwrap().pose;
    let mask = cam.valid_mask();
    let mut imgs = Vec::new();
    let mut pts = Vec::new();
    for pair in a[3..].chunks(2) {
        imgs.push(image::open(&pair[0]).unwrap().to_luma8().into_raw());
        pts.push(read_points(Path::new(&pair[1])).unwrap());
    }
    let views: Vec<View> = imgs
        .iter()
        .zip(&pts)
        .map(|(g, p)| View {
            gray: g,
            mask: &mask,
            points: p,
        })
        .collect();
    let r = |h: f64, s: f64| AxisRange { half: h, step: s };
    let variants = [
        ("32 eq parzen", 32, Binning::Equalized, true, true),
        ("32 eq parzen nofix", 32, Binning::Equalized, true, false),
        ("64 uniform", 64, Binning::Uniform, false, true),
        ("64 uniform nofix", 64, Binning::Uniform, false, false),
    ];
    for (name, bins, binning, parzen, fixed) in variants {
        let cfg = SearchConfig {
            spec: SearchSpec {
                x: r(0.3, 0.1),
                y: r(1.0, 0.02),
                z: r(0.3, 0.1),
                yaw: r(3.0, 0.05),
                pitch: None,
                roll: None,
                tilt_pivot_m: None,
            },
            mi: MiConfig {
                bins_gray: bins,
                bins_reflectivity: bins,
                binning,
                parzen,
                ..Default::default()
            },
            fixed_point_set: fixed,
            ..Default::default()
        };
        let ev = Evaluator::pooled(&cam, &views, &pose, &cfg, 0).unwrap();
        let mut s = Scratch::default();
        for mm in [false, true] {
            if mm && fixed {
                continue;
            }
            let f = |c: [i64; 6], s: &mut Scratch| {
                let h = ev.histogram(0, &c, s);
                if mm {
                    // The unseen points as one more gray category: N constant.
                    let mut e = JointHist::new(h.rows, h.cols + 1);
                    for r in 0..h.rows {
                        for j in 0..=h.cols {
                            let es = e.stride();
                            e.counts[r * es + j] = h.counts[r * h.stride() + j];
                        }
                    }
                    mutual_information(&e, false).mi
                } else {
                    mutual_information(&h, parzen).mi
                }
            };
            let mut best = (f64::MIN, 0.0, 0.0);
            let truth = f([0; 6], &mut s);
            for iy in -50..=50 {
                for iw in -60..=60 {
                    let v = f([0, iy, 0, iw, 0, 0], &mut s);
                    if v > best.0 {
                        best = (v, iy as f64 * 0.02, iw as f64 * 0.05);
                    }
                }
            }
            println!("{name:>20} outcat {mm}: points {:>6}; argmax y {:+.2} m yaw {:+.2}°, MI {:.4} vs {:.4} at the pose", ev.n_points, best.1, best.2, best.0, truth);
        }
    }
}
