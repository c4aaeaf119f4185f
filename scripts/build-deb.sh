#!/bin/sh
# Builds target/debian/hslt_<version>_<arch>.deb for the Debian release this runs on:
#   1. `cargo fetch --locked` (the only step that may use the network),
#   2. a release build with `--frozen` (Cargo.lock as is, no network) and source paths remapped,
#   3. man pages and shell completions generated from the clap definition (`hslt generate-assets`),
#   4. `cargo deb --no-build`, whose Depends come from dpkg-shlibdeps (`depends = "$auto"`).
# Needs cargo-deb (`cargo install --locked cargo-deb`) and dpkg-dev (dpkg-shlibdeps).
# Extra arguments go to both cargo build and cargo deb, e.g. `--no-default-features`.
#
# Reproducibility: the build uses its own target directory (target/deb-build) because the remapping
# flags below change RUSTFLAGS, which would otherwise force a full rebuild of target/release every
# time this and scripts/setup.sh alternate. SOURCE_DATE_EPOCH (default: the last commit's time) fixes
# the timestamps inside the .deb.
set -eu
cd "$(dirname "$0")/.."

if ! cargo deb --version >/dev/null 2>&1; then
    echo "build-deb: cargo-deb is not installed; run: cargo install --locked cargo-deb" >&2
    exit 1
fi
if ! command -v dpkg-shlibdeps >/dev/null 2>&1; then
    echo "build-deb: dpkg-shlibdeps not found; install dpkg-dev (it computes the Depends line)" >&2
    exit 1
fi

src_dir=$(pwd -P)
version=$(sed -n 's/^version = "\(.*\)"$/\1/p' Cargo.toml | head -n 1)
cargo_home=${CARGO_HOME:-$HOME/.cargo}
if [ -z "${SOURCE_DATE_EPOCH:-}" ]; then
    SOURCE_DATE_EPOCH=$(git log -1 --format=%ct 2>/dev/null || stat -c %Y Cargo.toml)
fi
export SOURCE_DATE_EPOCH
export CARGO_TARGET_DIR="$src_dir/target/deb-build"

# Rust already writes workspace paths relative to the crate; the paths of dependencies (in panic
# messages) and of the build directory (in debug info) are absolute. Map them to fixed names so the
# binary does not depend on where or by whom it was built. The later prefix wins when both match,
# so CARGO_HOME comes last in case it lies inside the source tree. CARGO_ENCODED_RUSTFLAGS
# (separator 0x1f) keeps paths with spaces intact; any RUSTFLAGS the caller set are kept.
sep=$(printf '\037')
extra="--remap-path-prefix=$src_dir=/usr/src/hslt-$version$sep--remap-path-prefix=$cargo_home=/usr/src/cargo-home"
if [ -n "${CARGO_ENCODED_RUSTFLAGS:-}" ]; then
    CARGO_ENCODED_RUSTFLAGS="$CARGO_ENCODED_RUSTFLAGS$sep$extra"
elif [ -n "${RUSTFLAGS:-}" ]; then
    CARGO_ENCODED_RUSTFLAGS="$(printf '%s' "$RUSTFLAGS" | tr -s ' \t' "$sep" | sed "s/^$sep//;s/$sep\$//")$sep$extra"
else
    CARGO_ENCODED_RUSTFLAGS="$extra"
fi
export CARGO_ENCODED_RUSTFLAGS
unset RUSTFLAGS
# The OpenImageIO shim is C++ built by the cc crate, which appends CXXFLAGS.
export CXXFLAGS="${CXXFLAGS:+$CXXFLAGS }-ffile-prefix-map=$src_dir=/usr/src/hslt-$version"

cargo fetch --locked
cargo build --release --frozen "$@"

rm -rf target/assets
"$CARGO_TARGET_DIR/release/hslt" generate-assets target/assets

# A stale package of another version would make `apt-get install ./target/debian/hslt_*.deb` ambiguous.
rm -f target/debian/hslt_*.deb target/debian/hslt-dbgsym_*.ddeb
cargo deb --no-build --locked --output target/debian/ "$@"
ls -l target/debian/hslt_"$version"_*.deb
