#!/bin/bash
# Coverage-guided fuzzing of the input readers with AFL++ on stable Rust (docs/robustness.md).
#   scripts/fuzz.sh SECONDS [TARGET ...]    (targets: scene_xml obj ply exr png; default all)
# Installs cargo-afl if missing, builds fuzz/ with AFL instrumentation, runs each target for SECONDS
# from fuzz/corpus/<target> into target/fuzz/<target>, and exits 1 if any target saved a crash or hang
# (copied to fuzz/crashes/<target>/ so it can become a regression input in fuzz/corpus).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:?usage: scripts/fuzz.sh SECONDS [TARGET ...]}
shift
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then targets=(scene_xml obj ply exr png); fi
if ! cargo afl --version >/dev/null 2>&1; then
    cargo install --locked cargo-afl
fi
(cd fuzz && cargo afl build --release --locked)
export AFL_SKIP_CPUFREQ=1 AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 AFL_NO_UI=1 AFL_NO_AFFINITY=1
status=0
for t in "${targets[@]}"; do
    out=target/fuzz/$t
    rm -rf "$out"
    mkdir -p "$out"
    # -t: a scene that takes more than 2 s to load counts as a hang.
    cargo afl fuzz -V "$seconds" -t 2000 -i "fuzz/corpus/$t" -o "$out" fuzz/target/release/hslt-fuzz "$t" \
        >"$out/afl.log" 2>&1 || { echo "fuzz: afl-fuzz failed for $t (see $out/afl.log)"; status=1; continue; }
    stats=$out/default/fuzzer_stats
    execs=$(awk -F' *: *' '$1=="execs_done"{print $2}' "$stats")
    cov=$(awk -F' *: *' '$1=="bitmap_cvg"{print $2}' "$stats")
    crashes=$(awk -F' *: *' '$1=="saved_crashes"{print $2}' "$stats")
    hangs=$(awk -F' *: *' '$1=="saved_hangs"{print $2}' "$stats")
    corpus=$(awk -F' *: *' '$1=="corpus_count"{print $2}' "$stats")
    echo "fuzz: $t: ${seconds} s, $execs executions, corpus $corpus, coverage $cov, crashes $crashes, hangs $hangs"
    if [ "$crashes" != 0 ] || [ "$hangs" != 0 ]; then
        mkdir -p "fuzz/crashes/$t"
        cp "$out"/default/crashes/id* "$out"/default/hangs/id* "fuzz/crashes/$t/" 2>/dev/null || true
        status=1
    fi
done
exit $status
