#!/usr/bin/env bash
# The "Times of day" table of docs/accuracy.md: frames from K hours of one low-sun day pooled
# (one histogram per time) against a single burst of the same scene. Per seed:
#   fisheye: `simulate --difficulty hard --low-sun --times K` (a burst of 5 per time), then
#            `study --attitude control-points` on the first time's burst median (single) and
#            with `--times` on all K medians (pooled), the same seeded start for both;
#   gantry:  `simulate --preset gantry --times K --frames 1`, then `study --sensor SENSOR`
#            on the first time's frame and sweep (single) and on all K pairs (pooled);
#            SENSOR is GANTRY_SENSOR, `perspective` (the gantry's side camera, files g-*) by
#            default or `fisheye` (the node's own camera on the gantry, files gf-*, with
#            `--attitude control-points` as for the fisheye scenes).
# Seeds are interleaved (fisheye s, gantry s) so a partial run has both; finished seeds are
# skipped on a rerun. Then the table rows.
#
#   cargo build --release && docs/scripts/times_study.sh [FIRST LAST [K [BIN [OUT]]]]
#
# Defaults: seeds 1–30, K = 6. GANTRY=0 skips the gantry scenes, FISHEYE=0 the fisheye ones.
set -eu
FIRST=${1:-1}
LAST=${2:-30}
K=${3:-6}
BIN=$(realpath "${4:-target/release/infraloc}")
OUT=${5:-/tmp/times-study}
SENSOR=${GANTRY_SENSOR:-perspective}
G=g ATT=
if [ "$SENSOR" != perspective ]; then G=gf ATT="--attitude control-points"; fi
mkdir -p "$OUT"
study() { # scene seed json [flags…]
  local scene=$1 seed=$2 json=$3
  shift 3
  "$BIN" study --scene "$scene" --trials 1 --seed "$seed" --json "$json" \
      --out "${json%.json}.png" "$@" >/dev/null
}
for s in $(seq "$FIRST" "$LAST"); do
  if [ "${FISHEYE:-1}" = 1 ] && [ ! -f "$OUT/f-$s-pooled.json" ]; then
    "$BIN" simulate --seed "$s" --difficulty hard --low-sun --times "$K" --out "$OUT/f-$s" >/dev/null
    study "$OUT/f-$s" "$s" "$OUT/f-$s-single.json" --attitude control-points
    study "$OUT/f-$s" "$s" "$OUT/f-$s-pooled.json" --attitude control-points --times
    cp "$OUT/f-$s/truth.json" "$OUT/f-$s-truth.json"
    rm -rf "$OUT/f-$s"
  fi
  if [ "${GANTRY:-1}" = 1 ] && [ ! -f "$OUT/$G-$s-pooled.json" ]; then
    "$BIN" simulate --preset gantry --seed "$s" --times "$K" --frames 1 --out "$OUT/$G-$s" >/dev/null
    # shellcheck disable=SC2086
    study "$OUT/$G-$s" "$s" "$OUT/$G-$s-single.json" --sensor "$SENSOR" $ATT
    # shellcheck disable=SC2086
    study "$OUT/$G-$s" "$s" "$OUT/$G-$s-pooled.json" --sensor "$SENSOR" --times $ATT
    cp "$OUT/$G-$s/truth.json" "$OUT/$G-$s-truth.json"
    rm -rf "$OUT/$G-$s"
  fi
done
python3 - "$OUT" "$FIRST" "$LAST" "$K" "$(dirname "$0")" "$G" "$SENSOR" <<'PY'
import json, math, os, sys
out, first, last, k = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
g, sensor = sys.argv[6], sys.argv[7]
sys.path.insert(0, sys.argv[5])
from sigma_ratio import median
AXES = ["x", "y", "z", "yaw"]

def trials(kind, how):
    t = []
    for s in range(first, last + 1):
        p = f"{out}/{kind}-{s}-{how}.json"
        if os.path.exists(p):
            t += json.load(open(p))["trials"]
    return t

def p95(v):
    v = sorted(v)
    return v[max(1, -(-95 * len(v) // 100)) - 1] if v else float("nan")

def row(kind, how, ts):
    acc = [t for t in ts if t["accepted"]]
    ground = [g * 100 for t in acc for g in t.get("ground_m", [])]
    sig = [t for t in acc if t.get("sigma")]
    cov = "/".join(
        f"{100 * sum(abs(t['result'][i]) <= 3 * t['sigma'][a] for t in sig) / len(sig):.0f}"
        if sig else "-" for i, a in enumerate(AXES))
    sigmas = " / ".join(
        f"{median([t['sigma'][a] * (100 if a != 'yaw' else 1) for t in sig]):.3g}"
        if sig else "-" for a in AXES)
    spread = lambda v: f"{median(v):.2f} / {p95(v):.2f}" if v else "-"
    g = spread(ground)
    h = spread([t["horizontal_m"] * 100 for t in ts])
    ha = spread([t["horizontal_m"] * 100 for t in acc])
    print(f"| {kind} | {how} | {len(acc)} / {len(ts)} | {g} | {h} | {ha} | {sigmas} | {cov} |")
    return sig

print(f"seeds {first}–{last}, K = {k}")
print("| scenes | frames | accepted / run | ground median / p95 (cm, accepted) | horizontal median / p95 (cm, all) "
      "| horizontal (cm, accepted) | median σ x, y, z (cm), yaw (°), accepted | 3σ coverage x/y/z/yaw (%) |")
print("|---|---|---|---|---|---|---|---|")
for kind, name in (("f", "fisheye, hard, low sun"), (g, f"gantry {sensor}")):
    single, pooled = trials(kind, "single"), trials(kind, "pooled")
    if not single:
        continue
    s1 = row(name, "1 burst", single)
    s6 = row(name, f"{k} hours pooled", pooled)
    # σ ratio pooled / single on the seeds accepted both ways, per axis, against 1/√K.
    both = []
    for s in range(first, last + 1):
        a, b = f"{out}/{kind}-{s}-single.json", f"{out}/{kind}-{s}-pooled.json"
        if os.path.exists(a) and os.path.exists(b):
            ta, tb = json.load(open(a))["trials"][0], json.load(open(b))["trials"][0]
            if ta["accepted"] and tb["accepted"] and ta.get("sigma") and tb.get("sigma"):
                both.append((ta, tb))
    if both:
        r = ", ".join(f"{a} {median([tb['sigma'][a] / ta['sigma'][a] for ta, tb in both]):.2f}" for a in AXES)
        print(f"{name}: σ pooled / single, median over {len(both)} seeds accepted both ways: {r}"
              f" (1/√{k} = {1 / math.sqrt(k):.2f})")
PY
