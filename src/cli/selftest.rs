//! `infraloc self-test [--poses N] [--workload N [--reference]]` (hidden): checks that the MI
//! kernel's SIMD copy on this CPU (NEON on aarch64, AVX2 + FMA on x86-64) is bit-identical to the
//! plain reference loop, and so is the smooth (PV) estimator's chunk projection (NEON, AVX2 or
//! its portable lane loop). CI runs it on the aarch64 binary under qemu-user (`cross/build.sh
//! --check`). `--workload` instead evaluates N poses of the same scene on one thread, for the
//! instruction counts in docs/benchmarks.md (`--pv`: the smooth estimator's value and gradient).

use crate::error::{Error, Result};
use crate::localize::mi::kernel;

/// Arguments of `self-test`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Poses compared (nearest-pixel kernel).
    #[arg(long, default_value_t = 12)]
    pub poses: usize,
    /// Poses compared (smooth estimator: every point's projection and Jacobian, then the value
    /// and gradient; about 40× the nearest-pixel kernel's work per pose).
    #[arg(long, default_value_t = 3)]
    pub pv_poses: usize,
    /// Evaluate this many poses (no comparison) and print the points and a checksum.
    #[arg(long)]
    pub workload: Option<usize>,
    /// With --workload: the plain reference loop instead of the dispatched copy.
    #[arg(long, requires = "workload")]
    pub reference: bool,
    /// With --workload: the smooth (PV) estimator's value and gradient instead of the
    /// nearest-pixel kernel.
    #[arg(long, requires = "workload")]
    pub pv: bool,
}

/// Run the check (or the workload); a difference is an error naming the pose.
pub(crate) fn run(a: Args) -> Result<()> {
    if let Some(n) = a.workload {
        use crate::localize::mi::smooth;
        let (points, sum) = if a.pv {
            smooth::pv_workload(n, a.reference)
        } else {
            kernel::selftest::workload(n, a.reference)
        };
        let path = match (a.reference, a.pv) {
            (true, _) => "reference",
            (false, true) => smooth::lanes_path(),
            (false, false) => kernel::selftest::kernel_path(),
        };
        println!("workload: {n} poses × {points} points, {path}, checksum {sum}");
        return Ok(());
    }
    let r = kernel::selftest::self_test(a.poses)
        .map_err(|m| Error::command("self-test", m.to_string()))?;
    println!(
        "self-test OK: MI kernel ({}) bit-identical to the reference loop, {} poses × {} points",
        r.path, r.poses, r.points
    );
    let s = crate::localize::mi::smooth::lanes_self_test(a.pv_poses)
        .map_err(|m| Error::command("self-test", m.to_string()))?;
    println!(
        "self-test OK: PV projection ({}) bit-identical to the reference, {} poses × {} points",
        s.path, s.poses, s.points
    );
    Ok(())
}
