#!/bin/bash
# Coverage-guided fuzzing of the input readers with AFL++ on stable Rust (docs/robustness.md).
#   scripts/fuzz.sh SECONDS [TARGET ...]    (targets: scene_xml obj ply exr png; default all)
# Installs cargo-afl if missing, builds fuzz/ with AFL instrumentation, runs each target for SECONDS
# from fuzz/corpus/<target> into target/fuzz/<target>, and exits 1 if any target saved a crash or hang
# (copied to fuzz/crashes/<target>/ so it can become a regression input in fuzz/regressions), or 2 if
# afl-fuzz could not run here at all (no crash found, but nothing fuzzed either).
# FUZZ_TIMEOUT_MS (default 2000): an input taking longer than this counts as a hang.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:?usage: scripts/fuzz.sh SECONDS [TARGET ...]}
shift
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then targets=(scene_xml obj ply exr png); fi
if ! cargo afl --version >/dev/null 2>&1; then
    cargo install --locked cargo-afl --version 0.18.2 || { echo "fuzz: cannot install cargo-afl here"; exit 2; }
fi
# cargo-afl builds AFL++ (afl-fuzz and its LLVM runtime) once per toolchain; a second build is refused
# with "already built", which is what we want.
if ! config=$(cargo afl config --build 2>&1); then
    case "$config" in
        *"already built"*) ;;
        *) echo "$config" | tail -n 5; echo "fuzz: cannot build AFL++ here"; exit 2 ;;
    esac
fi
# A harness that no longer builds is our bug (the fuzz workspace is outside `cargo test`): status 1.
(cd fuzz && cargo afl build --release --locked) || { echo "fuzz: the fuzz harness does not build"; exit 1; }
export AFL_SKIP_CPUFREQ=1 AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 AFL_NO_UI=1 AFL_NO_AFFINITY=1
timeout_ms=${FUZZ_TIMEOUT_MS:-2000}
status=0
not_started=0
for t in "${targets[@]}"; do
    out=target/fuzz/$t
    rm -rf "$out"
    mkdir -p "$out"
    stats=$out/default/fuzzer_stats
    if ! cargo afl fuzz -V "$seconds" -t "$timeout_ms" -i "fuzz/corpus/$t" -o "$out" \
        fuzz/target/release/hslt-fuzz "$t" >"$out/afl.log" 2>&1 || [ ! -s "$stats" ]; then
        echo "fuzz: afl-fuzz did not run for $t; the end of $out/afl.log:"
        tail -n 15 "$out/afl.log" | sed 's/^/    /'
        not_started=1
        continue
    fi
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
if [ $status -eq 0 ] && [ $not_started -ne 0 ]; then status=2; fi
exit $status
