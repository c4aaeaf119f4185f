#!/bin/sh
# Installs the system packages hslt needs on Debian bookworm, builds it in release mode and renders
# the bundled default scene to cbox.exr and cbox.png. Safe to run again.
set -eu
cd "$(dirname "$0")/.."

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    SUDO="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update
$SUDO apt-get install -y --no-install-recommends \
    build-essential pkg-config libembree-dev libopenimageio-dev

if ! command -v cargo >/dev/null 2>&1; then
    echo "error: cargo not found; install a Rust toolchain (https://rustup.rs or Debian's 'cargo')" >&2
    exit 1
fi

cargo build --release --locked
./target/release/hslt render scenes/cornell-box/scene.xml -o cbox.exr -o cbox.png
