#!/usr/bin/env bash
# The gantry table of docs/accuracy.md ("Gantry preset"): N seeded `simulate --preset gantry`
# scenes, `study --sensor perspective` with T seeded starts on each (the study's seed = the
# scene's), then the pooled trials as one table row.
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
mkdir -p "$OUT"
for s in $(seq "$FIRST" "$LAST"); do
  [ -f "$OUT/study-$s.json" ] && continue
  "$BIN" simulate --preset gantry --seed "$s" --frames 1 --out "$OUT/g-$s" >/dev/null
  # shellcheck disable=SC2086
  "$BIN" study --scene "$OUT/g-$s" --sensor perspective --trials "$TRIALS" --seed "$s" \
      ${STUDY_FLAGS:-} --out "$OUT/study-$s.png" --json "$OUT/study-$s.json" >/dev/null
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
PY
