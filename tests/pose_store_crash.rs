//! Crash safety of the pose store: a child process rewrites the pose as fast as it can and is
//! killed with SIGKILL at a random moment, 1000 times. After every kill the served pose must parse
//! as a complete `infraloc.pose.v1` document (never partial, corrupt or missing) and the history
//! must parse too.

// Its own binary, not a module of tests/it: the soak kills its child within milliseconds of the
// child's ready line, which only holds when no other test competes for the CPU (cargo runs test
// binaries one after another). It shares the one binary's helpers.
#[path = "it/common/mod.rs"]
mod common;
use infraloc::map::Crs;
use infraloc::pose::CamFromMap;
use infraloc::posefile::{PoseFile, PoseQuality};
use infraloc::store::PoseStore;
use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use std::process::{Command, Stdio};
use std::time::Duration;

const CHILD_ENV: &str = "INFRALOC_CRASH_CHILD_DIR";
const BASE_ENV: &str = "INFRALOC_CRASH_CHILD_BASE";
const KILLS: usize = 1000;

fn pose(i: u64) -> PoseFile {
    let p = CamFromMap::from_center_ypr(
        &Point3::new(
            500_000.0 + (i % 1_000_000) as f64,
            4_700_000.0 + (i / 1_000_000) as f64,
            210.0,
        ),
        0.1,
        0.0,
        0.0,
    );
    let mut f = PoseFile::new(
        &p,
        Crs::Epsg(32617),
        "tile",
        format!("2026-11-21T12:00:{:02}Z", i % 60),
    );
    // Vary the size so a torn write could not pass for a complete one by accident.
    f.quality = PoseQuality::from_value(
        serde_json::json!({ "score": 0.5, "pad": "x".repeat((i % 997) as usize) }),
    );
    f
}

/// Runs only as the child (see `kill_nine_never_corrupts_the_pose`): write forever.
#[test]
#[ignore = "child process of kill_nine_never_corrupts_the_pose"]
fn writer_child() {
    let dir = std::env::var(CHILD_ENV).expect("child needs its directory");
    let store = PoseStore::new(std::path::Path::new(&dir), 20);
    // Tell the parent the writing loop is starting, so its kill lands among writes.
    println!("ready");
    // Each child writes numbers of its own, so the parent can tell whether it wrote anything.
    let base: u64 = std::env::var(BASE_ENV)
        .expect("base")
        .parse()
        .expect("base number");
    for i in base.. {
        store.offer(&pose(i), true).expect("write");
    }
}

#[test]
#[ignore = "slow tier: a soak of 1000 killed writers"]
fn kill_nine_never_corrupts_the_pose() {
    let dir = tempfile::tempdir().unwrap();
    let store = PoseStore::new(dir.path(), 20);
    store.offer(&pose(0), true).unwrap();
    let exe = std::env::current_exe().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    let mut changed = 0;
    let mut last = store.current().unwrap().unwrap();
    for k in 0..KILLS {
        let mut child = Command::new(&exe)
            .args([
                "--ignored",
                "--exact",
                // The child is a test of this binary.
                "writer_child",
                "--test-threads=1",
                "--nocapture",
            ])
            .env(CHILD_ENV, dir.path())
            .env(BASE_ENV, ((k as u64 + 1) * 1_000_000).to_string())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        common::wait_until_ready(&mut child);
        // Random moment within the writing loop (a write takes ~0.1–1 ms with its fsyncs).
        std::thread::sleep(Duration::from_micros(rng.random_range(0..3_000)));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        let cur = store
            .current()
            .unwrap_or_else(|e| panic!("after kill {k}: {e}"))
            .unwrap_or_else(|| panic!("after kill {k}: pose.json missing"));
        assert_eq!(cur.schema, "infraloc.pose.v1");
        if cur != last {
            changed += 1;
            last = cur;
        }
        store
            .history()
            .unwrap_or_else(|e| panic!("after kill {k}: {e}"));
    }
    // The kills really landed while writing was going on, not only before it started.
    assert!(
        changed > KILLS / 4,
        "only {changed} of {KILLS} runs wrote anything"
    );
    // No temp files leak into readers' way (they may remain from killed writers, but never as
    // the pose itself): the served pose and history are the only non-hidden files.
    let visible: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(visible.len(), 2, "{visible:?}");
}
