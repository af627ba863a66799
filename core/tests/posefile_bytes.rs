//! Pose files written by infraloc read into a [`PoseFile`] and write back byte for byte: the
//! typed `quality` block keeps the untyped one's sorted keys and every figure it does not type.
//!
//! The fixtures are untrimmed outputs of the binary before the block was typed, on
//! `infraloc simulate --preset small --seed 1`: `localize-pose.json` by `infraloc localize`,
//! `refine-pose.json` by `infraloc refine --init` that pose with the first frame.

use infraloc_core::posefile::PoseFile;

fn round_trip(text: &str) -> PoseFile {
    let f: PoseFile = serde_json::from_str(text).unwrap();
    let again = f.to_json();
    // On a mismatch, show where rather than two pages of JSON.
    if let Some(i) = text.bytes().zip(again.bytes()).position(|(a, b)| a != b) {
        let from = i.saturating_sub(200);
        panic!(
            "differs at byte {i}:\n--- read\n{}\n--- written\n{}",
            &text[from..(i + 200).min(text.len())],
            &again[from..(i + 200).min(again.len())]
        );
    }
    assert_eq!(again.len(), text.len());
    f
}

#[test]
fn a_localize_pose_file_writes_back_the_same_bytes() {
    let f = round_trip(include_str!("data/localize-pose.json"));
    let q = &f.quality;
    assert_eq!(f.score(), Some(1.0616555853094591));
    assert_eq!(q.accepted, Some(true));
    assert_eq!(q.reason, None);
    let s = f.sigma().unwrap();
    assert!(s.x > 0.0 && s.yaw > 0.0, "{s:?}");
    let c = q.covariance.as_ref().unwrap();
    assert_eq!(c.axes, ["x", "y", "z", "yaw", "pitch", "roll"]);
    assert_eq!(c.matrix.len(), 6);
    assert!(c.rest.contains_key("units") && c.rest.contains_key("sigma"));
    assert!(f.pose_covariance().unwrap().is_some());
    // Typed figures are out of `rest`, which keeps the rest; `reason: null` stays as written.
    for k in ["score", "sigma", "covariance", "accepted"] {
        assert!(!q.rest.contains_key(k), "{k}");
    }
    assert_eq!(q.rest.get("reason"), Some(&serde_json::Value::Null));
    for k in ["mi", "nmi", "axes", "information", "optima", "pnp_inliers"] {
        assert!(q.rest.contains_key(k), "{k}");
    }
}

#[test]
fn a_refine_pose_file_writes_back_the_same_bytes() {
    let f = round_trip(include_str!("data/refine-pose.json"));
    // refine writes no score.
    assert_eq!(f.score(), None);
    assert!(f.sigma().is_some());
    assert_eq!(f.quality.accepted, Some(true));
    assert!(f.pose_covariance().unwrap().is_some());
}
