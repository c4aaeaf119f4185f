#!/bin/sh
# Regenerates vendor-bindings/embree3.rs from the Embree 3 headers that the build script finds
# (EMBREE_DIR, pkg-config, or /usr/include/embree3). The bindgen options and the stamp block live in
# build-support/embree.rs, so the vendored file and a `--features bindgen` build are produced by the
# same code. Needs libclang (Debian: libclang-dev) and jq.
set -eu
cd "$(dirname "$0")/.."

out_dir=$(cargo check --lib --no-default-features --features bindgen --message-format=json \
    | jq -r 'select(.reason == "build-script-executed" and (.package_id | test("hslt"))) | .out_dir' \
    | tail -n 1)

if [ -z "$out_dir" ] || [ ! -f "$out_dir/embree3.rs" ]; then
    echo "regen-embree-bindings: the build script did not produce embree3.rs (out_dir='$out_dir')" >&2
    exit 1
fi

cp "$out_dir/embree3.rs" vendor-bindings/embree3.rs
echo "wrote vendor-bindings/embree3.rs from $out_dir/embree3.rs"
sed -n '/hslt-embree-bindings-stamp-begin/,/hslt-embree-bindings-stamp-end/p' vendor-bindings/embree3.rs
