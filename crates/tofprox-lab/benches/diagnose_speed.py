#!/usr/bin/env python3
"""Speed of `tofprox lab diagnose` on recordings tofprox did not make (issue 33
item 6; docs/lab.md "Speed and memory").

Each shape is written by `independent_recording.py` (its physics written
there, not taken from tofprox), then diagnosed with the release binary against
`config/model/baseline.toml`, `--runs` times. Printed per shape: the median
wall time and its range, the CPU time (user + sys of the child), the verdict,
and the target (2 s wall for ~900-capture 16×16 recordings, 10 s for 700
captures of a 12×20 window with four conditions); before the table, the CPU
model, its core count and the load average (other builds on the machine
stretch the wall time; the CPU time is the steadier figure).

Usage (from the workspace root, after `cargo build --release -p tofprox`):
  python3 crates/tofprox-lab/benches/diagnose_speed.py [--runs 3] [--bin PATH]
      [--model PATH] [--dir DIR] [--only NAME]

Recordings are cached in `--dir` (default: /tmp/tofprox-diagnose-speed), one
directory per shape, and rewritten only when missing.
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
GENERATOR = os.path.join(HERE, "independent_recording.py")

# name, target wall s, rows, cols, captures, phases, conditions, effects
SHAPES = [
    ("16x16_4phase_exposure_none", 2.0, 16, 16, 900, "4", "exposure", ""),
    ("16x16_2phase_temperature_drift", 2.0, 16, 16, 900, "2", "exposure,temperature",
     "temperature"),
    ("16x16_mixed_3cond_droop_drift", 2.0, 16, 16, 900, "2,4", "exposure,temperature,ambient",
     "droop,temperature"),
    ("12x20_4phase_4cond_3effects", 10.0, 12, 20, 700, "4",
     "exposure,temperature,ambient,supply", "droop,temperature,supply"),
]


def generator_args(rows, cols, captures, phases, conditions, effects):
    """The arguments of `independent_recording.py` for one row of SHAPES."""
    return ["--rows", str(rows), "--cols", str(cols), "--captures", str(captures),
            "--phases", phases, "--conditions", conditions, "--effects", effects]


def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            info = f.read()
    except OSError:
        return "unknown CPU"
    name = next(
        (l.split(":", 1)[1].strip() for l in info.splitlines() if l.startswith("model name")),
        "unknown CPU",
    )
    fields = {}
    for key in ("cpu family", "model"):
        fields[key] = next(
            (l.split(":", 1)[1].strip() for l in info.splitlines() if l.split(":")[0].strip() == key),
            "?",
        )
    return f"{name} (family {fields['cpu family']} model {fields['model']}), {os.cpu_count()} cores"


def ensure_recording(out, args):
    if os.path.exists(os.path.join(out, "recording.toml")):
        return
    subprocess.run([sys.executable, GENERATOR, out, *args], check=True)


def child_cpu_s():
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def diagnose(binary, rec, model):
    """(wall s, CPU s, verdict) of one run."""
    cpu0, t0 = child_cpu_s(), time.perf_counter()
    p = subprocess.run(
        [binary, "lab", "diagnose", rec, "--model", model, "--json"],
        capture_output=True,
        text=True,
    )
    wall, cpu = time.perf_counter() - t0, child_cpu_s() - cpu0
    if p.returncode != 0:
        sys.exit(f"diagnose failed on {rec}:\n{p.stderr}")
    return wall, cpu, json.loads(p.stdout).get("verdict", "?")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "tofprox"))
    ap.add_argument("--model", default=os.path.join(ROOT, "config", "model", "baseline.toml"))
    ap.add_argument("--dir", default="/tmp/tofprox-diagnose-speed")
    ap.add_argument("--only", default=None, help="run only the shape of this name")
    a = ap.parse_args()
    if not os.path.exists(a.bin):
        sys.exit(f"{a.bin} not found: cargo build --release -p tofprox")
    print(f"CPU: {cpu_model()}")
    print("load average before: %.2f %.2f %.2f" % os.getloadavg())
    print(f"{'shape':34} {'wall s (median, range)':>24} {'CPU s':>7} {'target':>7}  verdict")
    for name, target, *spec in SHAPES:
        if a.only and name != a.only:
            continue
        rec = os.path.join(a.dir, name)
        ensure_recording(rec, generator_args(*spec))
        runs = [diagnose(a.bin, rec, a.model) for _ in range(max(1, a.runs))]
        walls = [w for w, _, _ in runs]
        cpu = statistics.median(c for _, c, _ in runs)
        med = statistics.median(walls)
        met = "met" if med <= target else "NOT met"
        print(
            f"{name:34} {med:8.2f} ({min(walls):.2f}–{max(walls):.2f}) {cpu:10.2f} {target:6.1f}s"
            f"  {runs[0][2]} ({met})"
        )
    print("load average after: %.2f %.2f %.2f" % os.getloadavg())


if __name__ == "__main__":
    main()
