#!/usr/bin/env bash
# The gantry tables of docs/accuracy.md ("Gantry preset"): N seeded `simulate --preset gantry`
# scenes, `study --sensor SENSOR` with T seeded starts on each (the study's seed = the scene's),
# then the pooled trials as one table row. SENSOR is `perspective` (the gantry's side camera
# against its own sweep) unless SENSOR=fisheye (the node's fisheye against the map tile, its
# starts' tilt from the control points as a perfect PnP would give it).
#
#   cargo build --release && docs/scripts/gantry_study.sh [FIRST LAST TRIALS [BIN [OUT]]]
#
# Defaults: scenes 1–100, 1 trial each (100 scene seeds); the table's rows used 1 20 5.
# Extra study flags (e.g. --grid-only, --bins 32) go in STUDY_FLAGS.
set -eu
FIRST=${1:-1}
LAST=${2:-100}
TRIALS=${3:-1}
BIN=$(realpath "${4:-target/release/infraloc}")
OUT=${5:-/tmp/gantry-study}
SENSOR=${SENSOR:-perspective}
ATT=
[ "$SENSOR" = perspective ] || ATT="--attitude control-points"
mkdir -p "$OUT"
for s in $(seq "$FIRST" "$LAST"); do
  [ -f "$OUT/study-$s.json" ] && continue
  "$BIN" simulate --preset gantry --seed "$s" --frames 1 --out "$OUT/g-$s" >/dev/null
  # shellcheck disable=SC2086
  "$BIN" study --scene "$OUT/g-$s" --sensor "$SENSOR" --trials "$TRIALS" --seed "$s" \
      $ATT ${STUDY_FLAGS:-} --out "$OUT/study-$s.png" --json "$OUT/study-$s.json" >/dev/null
  # Keep the study and the truth; the frames and tiles are 20 MB a scene.
  rm -rf "$OUT/g-$s/tiles" "$OUT/g-$s/frames"
done
python3 - "$OUT" "$FIRST" "$LAST" <<'PY'
import json, sys
out, first, last = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
trials = []
for s in range(first, last + 1):
    trials += json.load(open(f"{out}/study-{s}.json"))["trials"]
def spread(k, scale):
    v = sorted(t[k] * scale for t in trials)
    n = len(v)
    med = v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])
    p95 = v[max(1, -(-95 * n // 100)) - 1]
    return f"{med:.2f} / {p95:.2f} / {v[-1]:.2f}"
acc = [t for t in trials if t["accepted"]]
within = sum(t["success"] for t in trials)
within_acc = sum(t["success"] for t in acc)
print(f"| {last - first + 1} scenes | {len(trials)} | {spread('horizontal_m', 100)} | "
      f"{spread('height_m', 100)} | {spread('yaw_deg', 1)} | {100 * within / len(trials):.0f} % | "
      f"{len(trials) - len(acc)} | {within_acc} of {len(acc)} |")
# σ against the truth, per axis (x, y, z in m, yaw in °): 3σ coverage and the median of
# |error| / σ, over the accepted trials and over every trial that reported a σ.
axes = ["x", "y", "z", "yaw"]
for name, sel in (("accepted", acc), ("all with a σ", trials)):
    sel = [t for t in sel if t.get("sigma")]
    if not sel:
        print(f"{name}: no σ")
        continue
    cov, ratio = [], []
    for k, a in enumerate(axes):
        r = sorted(abs(t["result"][k]) / t["sigma"][a] for t in sel if t["sigma"][a] > 0)
        cov.append(f"{a} {100 * sum(v <= 3 for v in r) / len(sel):.0f} %")
        ratio.append(f"{a} {r[len(r) // 2]:.2f}" if r else f"{a} -")
    print(f"{name} ({len(sel)}): 3σ coverage {', '.join(cov)}; median |error|/σ {', '.join(ratio)}")
PY
