#!/usr/bin/env bash
# Build the aarch64 release binary and (optionally) run the test suite and the demo under qemu-user.
#   cross/build.sh            build target/aarch64-unknown-linux-gnu/release/infraloc
#   cross/build.sh --test     … and run the tests under qemu (baud-rate tests skip: qemu-user lacks TCGETS2)
#   cross/build.sh --demo     … and run `infraloc demo --preset small` under qemu
set -euo pipefail
cd "$(dirname "$0")/.."
TARGET=aarch64-unknown-linux-gnu
rustup target list --installed | grep -qx "$TARGET" || rustup target add "$TARGET"
CARGO=(cargo --config cross/config.toml)
"${CARGO[@]}" build --release --target "$TARGET"
file "target/$TARGET/release/infraloc" 2>/dev/null || true
for arg in "$@"; do
  case "$arg" in
    --test) INFRALOC_QEMU=1 "${CARGO[@]}" test --release --target "$TARGET" ;;
    --demo) qemu-aarch64 -L /usr/aarch64-linux-gnu "target/$TARGET/release/infraloc" demo --preset small ;;
    *) echo "unknown option $arg" >&2; exit 2 ;;
  esac
done
