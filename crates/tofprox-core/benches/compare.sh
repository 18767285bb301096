#!/usr/bin/env bash
# Speed comparison: the Rust 2-phase pipeline at every kernel level this CPU runs (divan bench
# `process_2phase_u16_level`, one core) against the same steps in numpy (numpy_reference.py),
# measured in the same run. Prints the machine, the medians and the ratios.
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
# Every kernel level this CPU runs (generic, avx2, avx512 / neon), then numpy, in the same run.
rust_out="$(cargo bench -q -p tofprox-core --bench pipeline -- process_2phase_u16_level --sample-count 1000 2>&1)"
echo "$rust_out" >&2
echo "== numpy ==" >&2
# numpy ufuncs are single-threaded; pin BLAS/OpenMP anyway so both sides use one core.
numpy_out="$(OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 python3 "$here/numpy_reference.py" 300)"
echo "$numpy_out" >&2

cpu="$(grep -m1 'model name' /proc/cpuinfo 2>/dev/null | cut -d: -f2- | sed 's/^ *//')"
RUST_OUT="$rust_out" NUMPY_OUT="$numpy_out" CPU="${cpu:-unknown}" NPROC="$(nproc)" LOAD="$(cut -d' ' -f1-3 /proc/loadavg)" python3 - <<'PY'
import os, re, sys
scale = {"ns": 1e-3, "µs": 1.0, "us": 1.0, "ms": 1e3, "s": 1e6}
levels = {}
for line in os.environ["RUST_OUT"].splitlines():
    fields = line.split("│")
    # "├─ avx2   <fastest> │ <slowest> │ <median> │ …"
    m = re.match(r"[\s├╰─]*(generic|avx2|avx512|neon)\b", fields[0]) if len(fields) > 2 else None
    if m:
        t = re.search(r"([\d.]+)\s*(ns|µs|us|ms|s)\b", fields[2])  # fastest │ slowest │ median
        if t:
            levels[m.group(1)] = float(t.group(1)) * scale[t.group(2)]
m = re.search(r"numpy_2phase_median_us ([\d.]+)", os.environ["NUMPY_OUT"])
if not levels or m is None:
    sys.exit("could not parse the benchmark output")
numpy_us = float(m.group(1))
print(f"machine: {os.environ['CPU']}, {os.environ['NPROC']} cores, load average {os.environ['LOAD']}")
print(f"2-phase pipeline, 224x172 u16 frame, one core, medians of the same run:")
print(f"  numpy          {numpy_us:8.1f} us")
for name in ("avx512", "avx2", "neon", "generic"):
    if name in levels:
        us = levels[name]
        print(f"  rust {name:<9} {us:8.1f} us   {numpy_us / us:5.1f}x numpy")
print("targets: best level <= 50 us and >= 40x numpy")
PY
