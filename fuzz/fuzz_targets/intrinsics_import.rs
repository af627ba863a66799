//! Arbitrary text as an intrinsics file (OpenCV FileStorage YAML/XML, Kalibr camchain, KITTI-360
//! MEI YAML, TOML, KITTI calib): the importers never panic, and a camera they accept survives the
//! OpenCV YAML export and import (the format `infraloc` itself writes) as the same camera.
#![no_main]

use infraloc::camera::import::{parse_camera, to_opencv_yaml};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    for name in ["fuzz.yaml", "fuzz.xml", "fuzz.toml", "fuzz.txt"] {
        if let Ok(cam) = parse_camera(text, Path::new(name)) {
            let yaml = to_opencv_yaml(&cam);
            let back = parse_camera(&yaml, Path::new("back.yaml"))
                .unwrap_or_else(|e| panic!("{name}: exported camera does not re-import: {e}\n{yaml}"));
            assert_eq!(to_opencv_yaml(&back), yaml, "{name}: export → import changed the camera");
        }
    }
});
