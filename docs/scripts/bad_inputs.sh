#!/usr/bin/env bash
# Re-run issue 19's table of a technician's bad inputs against a release binary and print
# PASS/FAIL per case: each must fail with one line naming the key, path or stage, with the right
# exit code (78 for config), and no failed localize may change the pose file.
#
#   cargo build --release && docs/scripts/bad_inputs.sh [target/release/infraloc]
#
# The socket cases (slow clients, 2,000 busy tries, panicking handlers) are a Rust test:
#   cargo test --release --test it control_socket::
set -u
BIN=$(realpath "${1:-target/release/infraloc}")
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
echo "scene: $BIN simulate --seed 3 --preset small"
"$BIN" simulate --out "$W/scene" --seed 3 --preset small >/dev/null || exit 2
S="$W/scene"
pass=0
fail=0

# A fresh config with the scene's absolute paths; then `sed` edits ($2...) applied.
mkcfg() {
  local d="$W/case"
  rm -rf "$d" && mkdir -p "$d"
  sed -e "s#\"camera.yaml\"#\"$S/camera.yaml\"#" -e "s#\"frames\"#\"$S/frames\"#" \
      -e "s#\"gps.nmea\"#\"$S/gps.nmea\"#" -e "s#\"tiles\"#\"$S/tiles\"#" \
      -e "s#pose = \"pose.json\"#pose = \"$d/pose.json\"#" \
      -e "s#socket = \"control.sock\"#socket = \"$d/run/control.sock\"#" \
      "$S/infraloc.toml" >"$d/infraloc.toml"
  shift_edits=("$@")
  for e in "${shift_edits[@]}"; do sed -i -e "$e" "$d/infraloc.toml"; done
  echo OLD >"$d/pose.json"
}

# check NAME EXIT 'WORD1|WORD2…' CMD…: exit code, one non-warning line, every word in it, the
# pose file still OLD.
check() {
  local name=$1 want=$2 words=$3
  shift 3
  local err code lines ok=1 why=""
  err=$("$@" 2>&1 >/dev/null)
  code=$?
  lines=$(printf '%s\n' "$err" | grep -v '^warning:' | grep -c .)
  [ "$code" = "$want" ] || { ok=0; why="exit $code, want $want"; }
  [ "$want" = 0 ] || [ "$lines" = 1 ] || { ok=0; why="$why; $lines lines"; }
  IFS='|' read -ra ws <<<"$words"
  for w in "${ws[@]}"; do
    [ -z "$w" ] || grep -qF -- "$w" <<<"$err" || { ok=0; why="$why; no '$w'"; }
  done
  if [ -f "$W/case/pose.json" ] && [ "$(cat "$W/case/pose.json")" != OLD ] && [ "$want" != 0 ]; then
    ok=0; why="$why; pose file changed"
  fi
  if [ $ok = 1 ]; then
    pass=$((pass + 1)); echo "PASS  $name"
  else
    fail=$((fail + 1)); echo "FAIL  $name: $why"; printf '      %s\n' "$err"
  fi
}

C="$W/case/infraloc.toml"
v() { "$BIN" validate --config "$C"; }

mkcfg "s#$S/camera.yaml#$W/nope.yaml#"; check "validate: intrinsics missing" 78 "[camera] intrinsics-file|nope.yaml" v
mkdir -p "$W/camdir"; mkcfg "s#$S/camera.yaml#$W/camdir#"; check "validate: intrinsics is a directory" 78 "[camera] intrinsics-file|is a directory" v
printf 'garbage: [1\n' >"$W/bad.yaml"; mkcfg "s#$S/camera.yaml#$W/bad.yaml#"; check "validate: intrinsics do not parse" 78 "[camera] intrinsics-file|bad.yaml" v
mkcfg "s#tiles = \"$S/tiles\"#tiles = \"$S/gps.nmea\"#"; check "validate: tile cache is a file" 78 "[map] tiles|not a directory" v
mkdir -p "$W/emptytiles/t1"; mkcfg "s#tiles = \"$S/tiles\"#tiles = \"$W/emptytiles\"#"; check "validate: no readable manifest" 78 "[map] tiles|no tile with a readable manifest" v
mkcfg "s#$S/frames#$W/noframes#"; check "validate: frames missing" 78 "[camera] frames|noframes" v
mkcfg "s#pose = \".*\"#pose = \"$W\"#"; check "validate: pose is a directory" 78 "[output] pose|is a directory" v
mkcfg "s#pose = \".*\"#pose = \"\"#"; check "validate: pose empty" 78 "[output] pose is empty" v
mkcfg "s#socket = \".*\"#socket = \"\"#"; check "validate: socket empty" 78 "[daemon] socket is empty" v
mkcfg "s#socket = \".*\"#socket = \"$S/gps.nmea\"#"; check "validate: socket path is a file" 78 "[daemon] socket|is not a socket" v
mkcfg "s#retry-attempts = .*#retry-attempts = 4294967295#"; check "validate: retry-attempts huge" 78 "[camera] retry-attempts = 4294967295" v
mkcfg "s#retry-backoff-ms = .*#retry-backoff-ms = 4294967295#"; check "validate: retry-backoff-ms huge" 78 "[camera] retry-backoff-ms = 4294967295" v
mkcfg "s#retry-max-s = .*#retry-max-s = inf#"; check "validate: retry-max-s inf" 78 "[daemon] retry-max-s = inf is not a finite number" v
mkcfg "s#\[output\]#[output]\nreport = \"$W/missing/dir/r.json\"#"; check "validate: report dir missing" 78 "[output] report|missing/dir" v
mkcfg "s#$S/gps.nmea#$W/none.nmea#"; check "validate: NMEA log missing" 78 "[gps] path|none.nmea" v
mkcfg "s#source = \"file\"#source = \"v4l2\"\ndevice = \"/dev/video-later\"#" "/^frames/d"
check "validate: absent device only warns" 0 "" v
mkcfg; check "daemon: bad config refused at start" 78 "[daemon] retry-max-s" \
  "$BIN" daemon --config <(sed 's#retry-max-s = .*#retry-max-s = inf#' "$C")

# localize: outputs checked before the work, pose untouched.
mkcfg
L() { "$BIN" localize --config "$C" --out "$W/case/pose.json" "$@"; }
check "localize: --report in a missing dir" 1 "--report $W/missing/dir/r.json|No such file" L --report "$W/missing/dir/r.json"
check "localize: --overlay is a directory" 1 "--overlay $W is a directory" L --overlay "$W"

# Map faults.
mkdir -p "$W/t-crs"; cp -r "$S/tiles/"* "$W/t-crs/"
sed -i 's#crs = "EPSG:32617"#crs = "EPSG:32618"#' "$W"/t-crs/*/tile.toml
check "localize: manifest in the wrong UTM zone" 1 "tile: |CRS mismatch|EPSG:32618" L --tiles "$W/t-crs"
mkdir -p "$W/t-bad"; cp -r "$S/tiles/"* "$W/t-bad/"
for t in "$W"/t-bad/*/height.tif; do head -c 200 "$t" >"$t.x" && mv "$t.x" "$t"; done
check "localize: truncated height layer" 1 "tile: |height.tif" L --tiles "$W/t-bad"

# The prior: every checksum wrong, no fallback.
mkcfg
sed 's#\*[0-9A-F][0-9A-F]\(\r\?\)$#*00\1#' "$S/gps.nmea" >"$W/bad.nmea"
check "localize: prior with checksum errors" 1 "prior: no position|with checksum errors|0 fixes" L --gps-nmea "$W/bad.nmea"

# gps decode | head: quiet.
mkcfg
for _ in $(seq 300); do cat "$S/gps.nmea"; done >"$W/big.nmea"
gh() { set -o pipefail; "$BIN" gps decode "$W/big.nmea" | head -1 >/dev/null; }
check "gps decode | head exits quietly" 0 "" gh
if "$BIN" gps decode "$W/big.nmea" 2>&1 >/dev/null | head -1 | grep -q "Broken pipe"; then
  fail=$((fail + 1)); echo "FAIL  gps decode | head printed Broken pipe"
fi

# rectify --rotation must be a rotation.
mkcfg
R() { "$BIN" rectify --camera "$S/camera.yaml" --image "$S/frames/000.png" --out "$W/r.png" --size 10,10 --k 1,1,1,1 --rotation "$1"; }
check "rectify: scaled rotation refused" 1 "--rotation is not a rotation matrix" R 2,0,0,0,2,0,0,0,2

echo "$pass passed, $fail failed"
[ "$fail" = 0 ]
