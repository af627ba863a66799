#!/usr/bin/env bash
# Build the aarch64 release binary and (optionally) run it under qemu-user.
#   cross/build.sh            build target/aarch64-unknown-linux-gnu/release/infraloc (features: v4l,
#                             the node's camera; the default build has no capture backend)
#   cross/build.sh --demo     … and run `infraloc demo --preset small` under qemu
#   cross/build.sh --check    … and run `infraloc self-test` under qemu (the NEON MI kernel and PV
#                             projection must be bit-identical to their references; so must the
#                             host binary's baseline and portable copies on an emulated CPU
#                             without AVX2 and FMA), then localize a host-simulated
#                             scene under qemu: the aarch64 pose must equal the host binary's and be
#                             within the demo's thresholds (CI runs this)
#   cross/build.sh --test     … and run the tests under qemu (baud-rate tests skip: qemu-user lacks TCGETS2)
# Env: INFRALOC_HOST_BIN = an already built host binary for --check (else `cargo build --release`).
# Needs: gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user (Debian), see docs/install.md.
set -euo pipefail
cd "$(dirname "$0")/.."
TARGET=aarch64-unknown-linux-gnu
QEMU=(qemu-aarch64 -L /usr/aarch64-linux-gnu)
BIN="target/$TARGET/release/infraloc"
for arg in "$@"; do
  case "$arg" in --test | --demo | --check) ;; *) echo "unknown option $arg" >&2; exit 2 ;; esac
done
rustup target list --installed | grep -qx "$TARGET" || rustup target add "$TARGET"
CARGO=(cargo --config cross/config.toml)
# The package's features ([package.metadata.deb] features in Cargo.toml; tests/it/packaging.rs checks).
FEATURES=(-p infraloc --features v4l)

t0=$SECONDS
"${CARGO[@]}" build --release --target "$TARGET" "${FEATURES[@]}"
echo "cross/build.sh: aarch64 build took $((SECONDS - t0)) s"
file "$BIN" 2>/dev/null || true

# --check: the NEON kernel against the reference loop, then simulate with the host binary (the
# reference scene) and localize with both binaries.
check() {
  # The explicit NEON copy is only exercised on aarch64, so this is where CI proves it bit-identical
  # (a difference exits non-zero and names the pose).
  local t=$SECONDS
  "${QEMU[@]}" "$BIN" self-test
  echo "cross/build.sh: self-test under qemu took $((SECONDS - t)) s"
  local host_bin="${INFRALOC_HOST_BIN:-}"
  if [ -z "$host_bin" ]; then
    cargo build --release
    host_bin=target/release/infraloc
  fi
  # The host binary on an emulated x86-64 CPU without AVX2 and FMA (Nehalem): the baseline copy,
  # which rounds the projection's multiply-adds separately, against its reference loop. No machine
  # CI runs on lacks FMA, so this is the one place that copy and its dispatch run.
  t=$SECONDS
  qemu-x86_64 -cpu Nehalem "$host_bin" self-test
  echo "cross/build.sh: x86-64 baseline self-test under qemu took $((SECONDS - t)) s"
  local work
  work="$(mktemp -d)"
  # shellcheck disable=SC2064  # expand now: $work is local
  trap "rm -rf '$work'" EXIT
  "$host_bin" simulate --out "$work/scene" --seed 1 --preset small --difficulty hard >/dev/null
  local args=(localize --config "$work/scene/infraloc.toml" --truth "$work/scene/truth.json")
  "$host_bin" "${args[@]}" --out "$work/host.json" --report "$work/host-report.json" >/dev/null
  t=$SECONDS
  "${QEMU[@]}" "$BIN" "${args[@]}" --out "$work/arm.json" --report "$work/arm-report.json"
  echo "cross/build.sh: aarch64 localize under qemu took $((SECONDS - t)) s"
  python3 - "$work" <<'EOF'
import json, sys
w = sys.argv[1]
host, arm = (json.load(open(f"{w}/{n}.json")) for n in ("host", "arm"))
keys = ["camera_center", "rotation_cam_from_map", "translation_cam_from_map"]
flat = lambda v: [x for r in v for x in (r if isinstance(r, list) else [r])]
diff = max(abs(a - b) for k in keys for a, b in zip(flat(host[k]), flat(arm[k])))
mi = json.load(open(f"{w}/arm-report.json"))["truth"]["mi"]
print(f"aarch64 vs host pose: max |diff| {diff:.3g}; aarch64 errors vs truth: "
      f"{mi['horizontal_m']:.3f} m horizontal, {mi['height_m']:.3f} m height, {mi['yaw_deg']:.3f} deg yaw")
# Thresholds of `infraloc demo` (src/cli/demo.rs).
ok = diff <= 1e-6 and mi["horizontal_m"] <= 0.10 and mi["height_m"] <= 0.10 and mi["yaw_deg"] <= 0.2
print("aarch64 check OK" if ok else "aarch64 check FAILED")
sys.exit(0 if ok else 1)
EOF
}

for arg in "$@"; do
  case "$arg" in
    --test)
      # Tests that start the infraloc binary exec an aarch64 ELF from inside qemu; qemu-user does not
      # follow execve, the kernel needs a binfmt_misc handler (Debian qemu-user-binfmt) for that.
      if ! grep -qs '^enabled' /proc/sys/fs/binfmt_misc/qemu-aarch64; then
        echo "cross/build.sh: warning: no binfmt_misc handler for aarch64: tests that run the" \
          "infraloc binary will fail with 'Exec format error' (apt-get install qemu-user-binfmt)" >&2
      fi
      t=$SECONDS
      INFRALOC_QEMU=1 "${CARGO[@]}" test --release --target "$TARGET" "${FEATURES[@]}"
      echo "cross/build.sh: tests under qemu took $((SECONDS - t)) s"
      ;;
    --demo)
      t=$SECONDS
      "${QEMU[@]}" "$BIN" demo --preset small
      echo "cross/build.sh: demo under qemu took $((SECONDS - t)) s"
      ;;
    --check) check ;;
    *) echo "unknown option $arg" >&2; exit 2 ;;
  esac
done
