//! The service's decisions, pure: what to run next, when to retry, whether a technician's
//! request joins the run in progress or waits for the next one, and whether a new result
//! replaces the served pose or the served pose is kept. No threads, no I/O and no clock: the
//! shell (`daemon/mod.rs`) hands in the events with the time they happened and carries out the
//! [`Action`]s, so every decision is unit-tested here without processes.

use super::status::{DriftSearch, JobKind};
use std::time::{Duration, Instant};

/// The schedule settings the decisions use (`[daemon]` of the config).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Timing {
    /// First wait after a failed localization, seconds.
    pub retry_initial_s: f64,
    /// Longest wait between retries, seconds.
    pub retry_max_s: f64,
    /// Periodic re-localization, seconds (0: none).
    pub relocalize_interval_s: f64,
    /// Periodic drift check, seconds (0: none).
    pub drift_check_interval_s: f64,
}

impl Timing {
    /// The timing of `cfg`.
    pub(super) fn of(cfg: &crate::config::Config) -> Timing {
        let d = &cfg.daemon;
        Timing {
            retry_initial_s: d.retry_initial_s,
            retry_max_s: d.retry_max_s,
            relocalize_interval_s: d.relocalize_interval_h * 3600.0,
            drift_check_interval_s: d.drift_check_interval_min * 60.0,
        }
    }
}

/// Something for the shell to start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Action {
    /// Start a localization; `force` serves its result even if it scores below the served pose.
    Localize {
        /// Serve whatever the score (it must still pass the quality gate).
        force: bool,
        /// Why it runs, for the log and the status.
        why: String,
    },
    /// Start a drift check of the served pose.
    DriftCheck,
}

/// What became of a technician's (or the drift alarm's) request for a localization.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Requested {
    /// A localization is running: its result answers this request too.
    Joined,
    /// A drift check is running: the localization starts when it ends.
    Queued,
    /// Nothing was running: start this.
    Start(Action),
}

/// The service's scheduling state.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Policy {
    /// The job running now.
    pub job: Option<JobKind>,
    /// Whether the running localization was forced.
    pub running_force: bool,
    /// A localization asked for while another job ran: (force, why).
    pub pending: Option<(bool, String)>,
    /// When the next scheduled localization (first, periodic or retry) is due.
    pub next_localize: Option<Instant>,
    /// When the next drift check is due.
    pub next_drift: Option<Instant>,
    /// Failed localizations since the last good one.
    pub failures_in_a_row: u32,
    /// Whether any localization has finished since the start.
    pub has_result: bool,
    /// Whether a pose is served.
    pub serving: bool,
}

/// The wait before the `n`-th retry in a row (n ≥ 1): `retry_initial_s` doubling up to
/// `retry_max_s` (never below the first wait).
pub(crate) fn backoff(t: &Timing, n: u32) -> f64 {
    (t.retry_initial_s * 2f64.powi(n.min(30) as i32 - 1)).min(t.retry_max_s.max(t.retry_initial_s))
}

impl Policy {
    /// At boot: the first localization is due at once.
    pub(super) fn new(now: Instant, serving: bool) -> Policy {
        Policy {
            job: None,
            running_force: false,
            pending: None,
            next_localize: Some(now),
            next_drift: None,
            failures_in_a_row: 0,
            has_result: false,
            serving,
        }
    }

    /// A request for a localization (`force`: serve the result whatever its score).
    pub(super) fn request(&mut self, force: bool, why: String) -> Requested {
        match self.job {
            Some(JobKind::Localize) => {
                self.running_force |= force;
                Requested::Joined
            }
            Some(JobKind::DriftCheck) => {
                let f = self.pending.as_ref().is_some_and(|p| p.0) || force;
                self.pending = Some((f, why));
                Requested::Queued
            }
            None => Requested::Start(self.start_localize(force, why)),
        }
    }

    /// What is due at `now` when nothing runs: a queued localization first, then a scheduled
    /// one (boot, periodic, retry), then a drift check. The job counts as started.
    pub(super) fn due(&mut self, now: Instant) -> Option<Action> {
        if self.job.is_some() {
            return None;
        }
        if let Some((force, why)) = self.pending.take() {
            return Some(self.start_localize(force, why));
        }
        if self.next_localize.is_some_and(|t| t <= now) {
            let why = if self.failures_in_a_row > 0 {
                "retry after failure"
            } else if self.has_result {
                "scheduled"
            } else {
                "boot"
            };
            return Some(self.start_localize(false, why.into()));
        }
        if self.next_drift.is_some_and(|t| t <= now) {
            self.next_drift = None;
            if !self.serving {
                // Nothing to check: the next served pose schedules the next check.
                return None;
            }
            self.job = Some(JobKind::DriftCheck);
            return Some(Action::DriftCheck);
        }
        None
    }

    fn start_localize(&mut self, force: bool, why: String) -> Action {
        self.job = Some(JobKind::Localize);
        self.running_force = force;
        self.next_localize = None;
        Action::Localize { force, why }
    }

    /// `secs` from `now`, when a pose is served and the period is on.
    fn period(&self, now: Instant, secs: f64) -> Option<Instant> {
        (secs > 0.0 && self.serving).then(|| now + Duration::from_secs_f64(secs))
    }

    /// The running localization ended; returns whether it was forced.
    fn end_localize(&mut self) -> bool {
        self.job = None;
        self.has_result = true;
        std::mem::take(&mut self.running_force)
    }

    /// Whether the running localization is forced (its result is then served whatever it
    /// scores, and needs no cross-check).
    pub(crate) fn forced(&self) -> bool {
        self.running_force
    }

    /// The running localization produced a pose (served or not; `serving`: whether a pose is
    /// served now, `coarse`: whether it is graded coarse). The periodic localization and drift
    /// check count from `now`; while the served pose is coarse the next localization comes
    /// after the longest retry wait at most (`retry-max-s`), so that later frames, pooled with
    /// this run's, can make it precise.
    pub(super) fn localized(&mut self, now: Instant, serving: bool, coarse: bool, t: &Timing) {
        self.end_localize();
        self.serving = serving;
        self.failures_in_a_row = 0;
        let every = match (coarse, t.relocalize_interval_s > 0.0) {
            (true, true) => t.relocalize_interval_s.min(t.retry_max_s),
            (true, false) => t.retry_max_s,
            (false, _) => t.relocalize_interval_s,
        };
        self.next_localize = self.period(now, every);
        self.next_drift = self.period(now, t.drift_check_interval_s);
    }

    /// The running localization failed: returns the wait before the retry, in seconds.
    pub(super) fn failed(&mut self, now: Instant, t: &Timing) -> f64 {
        self.end_localize();
        self.failures_in_a_row += 1;
        let wait = backoff(t, self.failures_in_a_row);
        self.next_localize = Some(now + Duration::from_secs_f64(wait));
        wait
    }

    /// The drift check ended; `moved`: it found the camera moved, which queues a forced
    /// localization (the served pose is known wrong, so the new result replaces it even if it
    /// scores lower; it still has to pass the quality gate).
    pub(crate) fn drift_checked(&mut self, now: Instant, moved: bool, t: &Timing) {
        self.job = None;
        self.next_drift = self.period(now, t.drift_check_interval_s);
        if moved {
            self.pending = Some((true, "drift check found the camera moved".into()));
        }
    }
}

/// How much lower the served pose's NMI on the new frames may be than the new result's and still
/// be preferred by the cross-check (point sets differ slightly between the two poses).
pub(crate) const CROSS_CHECK_NMI_SLACK: f64 = 0.002;

/// A new result compared with the served pose on the new frames.
#[derive(Debug, Clone)]
pub(crate) struct CrossCheck {
    /// The drift search around the served pose on the new frames, or why it could not run.
    pub search: Result<DriftSearch, String>,
    /// Horizontal distance between the new result and the served pose, metres.
    pub distance_m: f64,
    /// Their yaw difference, degrees.
    pub yaw_deg_apart: f64,
    /// The new result's NMI.
    pub new_nmi: f64,
}

/// Serve or keep: `Some(why)` when the served pose stays although a new result arrived — the
/// run was not forced and the cross-check found the served pose still the better MI peak on the
/// same frames (the search around it finds it steady and it scores at least as well, within
/// [`CROSS_CHECK_NMI_SLACK`]), so the new result is a different (wrong) optimum. `None`: offer the
/// new result to the pose store.
pub(crate) fn keep_served(cc: Option<&CrossCheck>, force: bool) -> Option<String> {
    let c = cc.filter(|_| !force)?;
    let s = c.search.as_ref().ok()?;
    // NMI of two poses on the same frame: the served one must be at least as good (within the
    // jitter of a slightly different point set) to be preferred.
    if s.verdict.moved || s.optimum.nmi < c.new_nmi - CROSS_CHECK_NMI_SLACK {
        return None;
    }
    Some(format!(
        "new result is {:.2} m / {:.2}° from the served pose, which is still the better MI peak on the same frames (NMI {:.4} vs {:.4}): served pose kept",
        c.distance_m, c.yaw_deg_apart, s.optimum.nmi, c.new_nmi,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::status::{DriftVerdict, Optimum};

    const T: Timing = Timing {
        retry_initial_s: 10.0,
        retry_max_s: 60.0,
        relocalize_interval_s: 3600.0,
        drift_check_interval_s: 600.0,
    };

    fn secs(s: f64) -> Duration {
        Duration::from_secs_f64(s)
    }

    #[test]
    fn backoff_doubles_from_the_first_wait_up_to_the_longest() {
        let waits: Vec<f64> = (1..=6).map(|n| backoff(&T, n)).collect();
        assert_eq!(waits, [10.0, 20.0, 40.0, 60.0, 60.0, 60.0]);
        // A huge count neither overflows nor exceeds the cap.
        assert_eq!(backoff(&T, u32::MAX), 60.0);
        // A cap below the first wait: the first wait stands.
        let low = Timing {
            retry_max_s: 5.0,
            ..T
        };
        assert_eq!(backoff(&low, 3), 10.0);
    }

    #[test]
    fn failures_retry_with_backoff_and_a_success_resets_it() {
        let t0 = Instant::now();
        let mut p = Policy::new(t0, false);
        assert_eq!(
            p.due(t0),
            Some(Action::Localize {
                force: false,
                why: "boot".into()
            })
        );
        // Nothing else starts while it runs.
        assert_eq!(p.due(t0 + secs(1e6)), None);
        assert_eq!(p.failed(t0, &T), 10.0);
        assert_eq!(p.due(t0 + secs(9.9)), None);
        let retry = p.due(t0 + secs(10.0));
        assert_eq!(
            retry,
            Some(Action::Localize {
                force: false,
                why: "retry after failure".into()
            })
        );
        let t1 = t0 + secs(10.0);
        assert_eq!(p.failed(t1, &T), 20.0);
        assert_eq!(p.failures_in_a_row, 2);
        assert!(p.due(t1 + secs(20.0)).is_some());
        p.localized(t1 + secs(30.0), true, false, &T);
        assert_eq!(p.failures_in_a_row, 0);
        // Periodic schedules count from the result.
        assert_eq!(p.next_localize, Some(t1 + secs(30.0 + 3600.0)));
        assert_eq!(p.next_drift, Some(t1 + secs(30.0 + 600.0)));
        assert_eq!(p.due(t1 + secs(30.0 + 600.0)), Some(Action::DriftCheck));
        p.drift_checked(t1 + secs(700.0), false, &T);
        assert_eq!(
            p.due(t1 + secs(30.0 + 3600.0)),
            Some(Action::Localize {
                force: false,
                why: "scheduled".into()
            })
        );
    }

    #[test]
    fn no_periodic_runs_without_a_served_pose() {
        let t0 = Instant::now();
        let mut p = Policy::new(t0, false);
        p.due(t0);
        // Localized, but the store kept nothing (no pose served): no periodic schedule.
        p.localized(t0, false, false, &T);
        assert_eq!((p.next_localize, p.next_drift), (None, None));
        assert_eq!(p.due(t0 + secs(1e6)), None);
    }

    #[test]
    fn a_request_joins_a_localization_and_queues_behind_a_drift_check() {
        let t0 = Instant::now();
        let mut p = Policy::new(t0, true);
        p.due(t0);
        // Joins the running localization; a forced request makes the run forced.
        assert_eq!(p.request(false, "technician".into()), Requested::Joined);
        assert!(!p.forced());
        assert_eq!(p.request(true, "technician".into()), Requested::Joined);
        assert!(p.forced());
        p.localized(t0, true, false, &T);
        assert!(!p.forced(), "the next run starts unforced");
        // During a drift check: queued, and forced if any queued request was.
        assert_eq!(p.due(t0 + secs(600.0)), Some(Action::DriftCheck));
        assert_eq!(p.request(true, "a".into()), Requested::Queued);
        assert_eq!(p.request(false, "b".into()), Requested::Queued);
        assert_eq!(p.due(t0 + secs(601.0)), None, "the drift check still runs");
        p.drift_checked(t0 + secs(602.0), false, &T);
        assert_eq!(
            p.due(t0 + secs(602.0)),
            Some(Action::Localize {
                force: true,
                why: "b".into()
            })
        );
        // Idle: starts at once.
        p.localized(t0 + secs(700.0), true, false, &T);
        assert_eq!(
            p.request(false, "c".into()),
            Requested::Start(Action::Localize {
                force: false,
                why: "c".into()
            })
        );
    }

    /// A coarse pose is re-localized after the longest retry wait at most, to be made precise;
    /// a precise one on the configured period (none here).
    #[test]
    fn a_coarse_pose_is_relocalized_to_make_it_precise() {
        let t0 = Instant::now();
        let no_period = Timing {
            relocalize_interval_s: 0.0,
            drift_check_interval_s: 0.0,
            ..T
        };
        let mut p = Policy::new(t0, false);
        p.due(t0);
        p.localized(t0, true, true, &no_period);
        assert_eq!(p.due(t0 + secs(59.0)), None);
        assert_eq!(
            p.due(t0 + secs(60.0)),
            Some(Action::Localize {
                force: false,
                why: "scheduled".into()
            })
        );
        p.localized(t0 + secs(90.0), true, false, &no_period);
        assert_eq!(p.due(t0 + secs(1e6)), None);
        // With a period shorter than the longest wait, the period.
        p.due(t0);
        p.localized(
            t0,
            true,
            true,
            &Timing {
                relocalize_interval_s: 30.0,
                ..no_period
            },
        );
        assert!(p.due(t0 + secs(30.0)).is_some());
    }

    #[test]
    fn a_moved_camera_queues_a_forced_localization_before_anything_else() {
        let t0 = Instant::now();
        let mut p = Policy::new(t0, true);
        p.due(t0);
        p.localized(t0, true, false, &T);
        assert_eq!(p.due(t0 + secs(600.0)), Some(Action::DriftCheck));
        p.drift_checked(t0 + secs(610.0), true, &T);
        assert_eq!(
            p.due(t0 + secs(610.0)),
            Some(Action::Localize {
                force: true,
                why: "drift check found the camera moved".into()
            })
        );
    }

    fn cc(moved: bool, served_nmi: f64, new_nmi: f64) -> CrossCheck {
        CrossCheck {
            search: Ok(DriftSearch {
                verdict: DriftVerdict {
                    moved,
                    reason: None,
                    shift_m: 0.0,
                    dz_m: 0.0,
                    yaw_deg: 0.0,
                },
                optimum: Optimum {
                    camera_center: [0.0; 3],
                    yaw_pitch_roll_deg: [0.0; 3],
                    nmi: served_nmi,
                },
            }),
            distance_m: 0.5,
            yaw_deg_apart: 0.1,
            new_nmi,
        }
    }

    #[test]
    fn the_served_pose_is_kept_only_when_it_is_still_the_better_peak_and_the_run_not_forced() {
        // No cross-check (the two agree, or no pose is served): offer the new result.
        assert_eq!(keep_served(None, false), None);
        // Steady and scoring as well (within the slack): kept, with both NMIs in the reason.
        let why = keep_served(Some(&cc(false, 1.0, 1.001)), false).expect("kept");
        assert!(why.contains("NMI 1.0000 vs 1.0010"), "{why}");
        // Forced: always offered.
        assert_eq!(keep_served(Some(&cc(false, 1.0, 1.0)), true), None);
        // The served pose scores clearly worse, or its search found it moved: offered.
        assert_eq!(keep_served(Some(&cc(false, 1.0, 1.01)), false), None);
        assert_eq!(keep_served(Some(&cc(true, 2.0, 1.0)), false), None);
        // The search could not run: offered.
        let mut failed = cc(false, 2.0, 1.0);
        failed.search = Err("no tile".into());
        assert_eq!(keep_served(Some(&failed), false), None);
    }
}
