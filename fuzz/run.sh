#!/usr/bin/env bash
# Build the fuzz targets on STABLE Rust and run each for SECONDS (default 7; .ci/run: 6
# targets × (7 s + ~1.5 s of start-up) ≤ 60 s) on a scratch copy of its corpus (the kept corpus is read, never
# written). A crash, a panic, a timeout (> 10 s for one input) or an RSS above 1 GiB fails
# the run; the input is saved as fuzz/artifacts/<target>-crash-… and reproduced with
# `fuzz/target/<host>/release/<target> fuzz/artifacts/<file>`.
#
# Harness: libFuzzer through libfuzzer-sys, with the coverage instrumentation that
# `cargo fuzz build --sanitizer none` passes — all of it stable rustc flags (-C passes,
# -C llvm-args); cargo-fuzz's default AddressSanitizer needs nightly's -Z sanitizer, which
# CI does not have. Memory safety is Rust's own here (no unsafe in the code under test); what
# the fuzzers find are panics, overflows (debug assertions on), hangs and runaway allocation.
set -euo pipefail
secs="${1:-7}"
here="$(cd "$(dirname "$0")" && pwd)"
host="$(rustc -vV | sed -n 's/^host: //p')"
# --target keeps the flags off build scripts and proc macros (as cargo-fuzz does)
RUSTFLAGS="--cfg fuzzing -Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares -Cdebug-assertions -Coverflow-checks" \
  cargo build --release --locked --manifest-path "$here/Cargo.toml" --target "$host" --bins
mkdir -p "$here/artifacts"
scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
for t in usbcap pixels device_decode reassembly recording_header npy; do
  mkdir -p "$scratch/$t"
  started=$(date +%s)
  "$here/target/$host/release/$t" -max_total_time="$secs" -timeout=10 -rss_limit_mb=1024 \
    -print_final_stats=1 -artifact_prefix="$here/artifacts/$t-" \
    "$scratch/$t" "$here/corpus/$t" 2>"$scratch/$t.log" || {
    tail -n 40 "$scratch/$t.log" >&2
    echo "fuzz: $t FAILED (input in fuzz/artifacts/)" >&2
    exit 1
  }
  runs="$(sed -n 's/^stat::number_of_executed_units: *//p' "$scratch/$t.log")"
  echo "fuzz: $t: ${runs:-?} inputs in $(( $(date +%s) - started )) s, no failure"
done
