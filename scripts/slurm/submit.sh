#!/bin/bash
# Renders a scene on a Slurm cluster in N parts and merges them: an array job of N parts and a
# merge job that waits for all of them (docs/farm.md).
#   scripts/slurm/submit.sh -n N -d OUTDIR -o OUTPUT.exr SCENE [hslt render options...]
# Prints the two job ids. HSLT (default: hslt on the PATH) names the binary; sbatch passes the
# environment on. Extra sbatch options for both jobs go in SBATCH_OPTIONS (e.g. "--partition=gpu").
set -euo pipefail
usage() { echo "usage: submit.sh -n N -d OUTDIR -o OUTPUT SCENE [hslt render options...]" >&2; exit 2; }
n="" dir="" output=""
while getopts "n:d:o:" opt; do
    case $opt in
        n) n=$OPTARG ;;
        d) dir=$OPTARG ;;
        o) output=$OPTARG ;;
        *) usage ;;
    esac
done
shift $((OPTIND - 1))
[ -n "$n" ] && [ -n "$dir" ] && [ -n "$output" ] && [ $# -ge 1 ] || usage
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
scene=$(realpath "$1")
shift
# shellcheck disable=SC2086 # SBATCH_OPTIONS is a list of options
array=$(sbatch --parsable ${SBATCH_OPTIONS:-} --array="1-$n" --output="$dir/part_%a.log" \
    "$here/render-part.sbatch" "$dir" "$scene" "$@")
array=${array%%;*}
# afterany: merge what exists even when a part failed, rather than nothing.
# shellcheck disable=SC2086
merge=$(sbatch --parsable ${SBATCH_OPTIONS:-} --dependency="afterany:$array" --output="$dir/merge.log" \
    "$here/merge.sbatch" "$dir" "$output")
merge=${merge%%;*}
echo "parts: job $array (array 1-$n), merge: job $merge -> $output"
