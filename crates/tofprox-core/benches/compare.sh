#!/usr/bin/env bash
# Speed comparison: the Rust 2-phase pipeline (divan bench `process_2phase_u16`,
# one core) against the same steps in numpy (numpy_reference.py), measured in the same run.
# Prints both medians and the ratio (target: Rust <= 50 us and >= 20x faster than numpy).
# Usage: crates/tofprox-core/benches/compare.sh
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../../.." && pwd)"
cd "$root"

if ! python3 -c 'import numpy' 2>/dev/null; then
    echo "numpy missing: pip install numpy" >&2
    python3 -m pip install --quiet numpy || python3 -m pip install --quiet --break-system-packages numpy
fi

echo "== divan (Rust) ==" >&2
rust_out="$(cargo bench -q -p tofprox-core --bench pipeline -- --exact pipeline::process_2phase_u16 --sample-count 1000 2>&1)"
echo "$rust_out" >&2
echo "== numpy ==" >&2
# numpy ufuncs are single-threaded; pin BLAS/OpenMP anyway so both sides use one core.
numpy_out="$(OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 python3 "$here/numpy_reference.py" 300)"
echo "$numpy_out" >&2

RUST_OUT="$rust_out" NUMPY_OUT="$numpy_out" python3 - <<'PY'
import os, re, sys
scale = {"ns": 1e-3, "µs": 1.0, "us": 1.0, "ms": 1e3, "s": 1e6}
rust_us = None
for line in os.environ["RUST_OUT"].splitlines():
    if "process_2phase_u16" in line and "│" in line:
        fields = line.split("│")
        m = re.search(r"([\d.]+)\s*(ns|µs|us|ms|s)\b", fields[2])  # fastest │ slowest │ median
        if m:
            rust_us = float(m.group(1)) * scale[m.group(2)]
m = re.search(r"numpy_2phase_median_us ([\d.]+)", os.environ["NUMPY_OUT"])
if rust_us is None or m is None:
    sys.exit("could not parse the benchmark output")
numpy_us = float(m.group(1))
print(f"rust  2-phase pipeline 224x172: median {rust_us:.1f} us (target <= 50 us)")
print(f"numpy 2-phase pipeline 224x172: median {numpy_us:.1f} us")
print(f"ratio numpy/rust: {numpy_us / rust_us:.1f}x (target >= 20x)")
PY
