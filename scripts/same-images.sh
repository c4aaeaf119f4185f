#!/bin/bash
# Checks that two builds render identical images: every bundled scene with every integrator (and the
# pure-Rust BVH, and the furnaces) at 24x18 pixels with seed 7, pixel for pixel. For refactorings
# that must not change behaviour.
#   scripts/same-images.sh OLD_HSLT NEW_HSLT      (needs idiff: apt-get install openimageio-tools)
set -uo pipefail
cd "$(dirname "$0")/.."
old=${1:?usage: scripts/same-images.sh OLD_HSLT NEW_HSLT}
new=${2:?usage: scripts/same-images.sh OLD_HSLT NEW_HSLT}
command -v idiff >/dev/null || { echo "same-images: needs idiff (apt-get install openimageio-tools)" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
render_all() {
    local bin=$1 out=$2
    mkdir -p "$out"
    for xml in scenes/*/scene.xml; do
        local name
        name=$(basename "$(dirname "$xml")")
        for i in pt bdpt pssmlt mlt memlt hslt hslt+mlt; do
            case $i in
                pt | bdpt) extra=(--spp 4) ;;
                *) extra=(--spp 2 --seed-paths 16384 --chains 8 --direct-samples 1) ;;
            esac
            "$bin" render "$xml" -D resx=24 -D resy=18 "${extra[@]}" --seed 7 --threads 2 --integrator "$i" \
                -q -o "$out/$name-$i.exr" || echo "same-images: $bin failed on $name $i" >&2
        done
        "$bin" render "$xml" -D resx=24 -D resy=18 --spp 4 --seed 7 --threads 2 --accel bvh -q \
            -o "$out/$name-bvh.exr" || echo "same-images: $bin failed on $name bvh" >&2
    done
    for xml in scenes/furnace/*.xml; do
        "$bin" render "$xml" -D resx=16 -D resy=16 --spp 4 --seed 7 --threads 2 -q \
            -o "$out/furnace-$(basename "$xml" .xml).exr" || echo "same-images: $bin failed on $xml" >&2
    done
}
render_all "$old" "$work/old"
render_all "$new" "$work/new"
total=0
differ=0
for f in "$work"/old/*.exr; do
    total=$((total + 1))
    g=$work/new/$(basename "$f")
    if [ ! -f "$g" ] || ! idiff -a -fail 0 -warn 0 "$f" "$g" >/dev/null 2>&1; then
        echo "differs: $(basename "$f")"
        differ=$((differ + 1))
    fi
done
echo "same-images: $total images, $differ differ"
[ "$differ" -eq 0 ] && [ "$total" -gt 0 ]
