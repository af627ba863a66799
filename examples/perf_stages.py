#!/usr/bin/env python3
"""Measurement aid (not part of the product): where a localization's CPU goes, by stage, from a
`perf record --call-graph dwarf` of `infraloc localize` (docs/benchmarks.md "Against the build
before the smooth estimator").

Each sample counts once, under the first stage below whose function appears on its stack (so a
Nelder–Mead run inside the jackknife counts as the jackknife's, not the polish's). Stacks cut short
by perf's copy of the stack fall under "the rest".

usage:
    RAYON_NUM_THREADS=1 perf record -F 400 --call-graph dwarf,16384 -o P.data -- \\
        taskset -c 1 target/release/infraloc localize --config SCENE/infraloc.toml
    perf script -i P.data > P.txt
    python3 examples/perf_stages.py P.txt
"""
import sys

# (stage, substrings of a function on the stack), first match wins.
STAGES = [
    ("initializer: coarse sweep", ["init::coarse::"]),
    ("initializer: fine patches", ["init::fine::match_anchors"]),
    ("initializer: LiDAR verifier", ["init::verify::"]),
    ("initializer: the rest", ["localize::init::"]),
    ("intrinsics propagation", ["uncertainty::intrinsics_deltas"]),
    ("jackknife region", ["refine::uncertainty::region"]),
    ("jackknife groups", ["refine::uncertainty::"]),
    ("smooth stage", ["mi::smooth::", "refine::ascent::", "refine::information::"]),
    ("polish (Nelder-Mead)", ["refine::polish::"]),
    ("grid searches", ["refine::search::", "Evaluator::score"]),
    ("decoding frames and tiles", ["capture::file::", "map::geotiff::", "png::"]),
]


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: perf_stages.py PERF_SCRIPT_OUTPUT")
    with open(sys.argv[1], errors="replace") as f:
        samples = [s for s in f.read().split("\n\n") if s.strip()]
    if not samples:
        sys.exit(f"{sys.argv[1]}: no samples")
    counts = {name: 0 for name, _ in STAGES}
    rest = 0
    for s in samples:
        for name, keys in STAGES:
            if any(k in s for k in keys):
                counts[name] += 1
                break
        else:
            rest += 1
    n = len(samples)
    for name, _ in STAGES:
        print(f"{name:30s} {100 * counts[name] / n:5.1f} %")
    print(f"{'the rest':30s} {100 * rest / n:5.1f} %")
    print(f"{n} samples")


if __name__ == "__main__":
    main()
