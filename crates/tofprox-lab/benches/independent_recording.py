#!/usr/bin/env python3
"""Write a recording (docs/recording-format.md, version 3) of a simulated
module whose physics is written here, not taken from tofprox: the speed
measurements of `tofprox lab diagnose` on recordings tofprox did not make
(issue 33 item 6; docs/lab.md "Speed and memory").

Standard library only (the .npy files are written by hand: NumPy format 1.0,
'<u2', C order). The module:

* a correlation of a square-ish wave: cos x + 0.08 cos 3x (the third harmonic
  of a non-sinusoidal illumination, thesis 3.3.3);
* per-pixel offset (FPN), gain (PRNU) and delay (FPPN), drawn once;
* signal ∝ exposure · reflectivity / d² (thesis 2.2.1), ambient light adding
  an offset ∝ ambient · exposure and its shot noise;
* optional effects: `droop` (the VCSEL's power falls over the raw images of a
  capture, P_k = P·(1 − D·(1 − exp(−(k+½)·t/τ)))), `temperature` (a delay
  that grows with the sensor temperature, 2 mrad/K + 0.05 mrad/K²), `supply`
  (a gain that follows a supply voltage, +3 %/V);
* Gaussian noise of a read floor and shot noise, averaged over `averaged`
  acquisitions.

Usage:
  independent_recording.py OUT --rows 16 --cols 16 --captures 900 \
      --phases 2,4 --conditions exposure,temperature,ambient \
      --effects droop,temperature [--seed 1]

Captures: 2 darks per exposure, one 24-phase correlation capture, then
distances × the conditions' levels, each capture repeated once, until
`--captures` are written. `--phases 2,4` alternates 2- and 4-phase captures.
"""
import argparse
import math
import os
import random
import struct

C_M_S = 299_792_458.0


def write_npy(path, k, rows, cols, codes):
    """NumPy format 1.0, dtype '<u2', shape (k, rows, cols), C order."""
    header = "{'descr': '<u2', 'fortran_order': False, 'shape': (%d, %d, %d), }" % (
        k,
        rows,
        cols,
    )
    # magic (6) + version (2) + header length (2) + header, padded to 64 with a newline
    pad = 64 - (10 + len(header) + 1) % 64
    header = header + " " * pad + "\n"
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00")
        f.write(struct.pack("<H", len(header)))
        f.write(header.encode("latin1"))
        f.write(struct.pack("<%dH" % len(codes), *codes))


def correlation(x):
    return math.cos(x) + 0.08 * math.cos(3.0 * x)


def plan(args):
    """(phases, exposure_us, distance_m or None, conditions) of every capture."""
    cond = set(args.conditions)
    exposures = [250.0, 500.0, 1000.0] if "exposure" in cond else [500.0]
    temps = [15.0, 30.0, 45.0, 60.0] if "temperature" in cond else [30.0]
    ambients = [0.0, 10.0] if "ambient" in cond else [0.0]
    supplies = [3.1, 3.3, 3.5] if "supply" in cond else [3.3]
    four, two = [0.0, 90.0, 180.0, 270.0], [0.0, 90.0]
    out = []
    for t in exposures:
        for _ in range(2):
            out.append((four, t, None, {"temperature_c": temps[0]}))
    corr = [15.0 * i for i in range(24)]
    out.append((corr, exposures[0], 0.8, {"temperature_c": temps[0]}))
    levels = [
        (t, temp, amb, v)
        for t in exposures
        for temp in temps
        for amb in ambients
        for v in supplies
    ]
    remaining = args.captures - len(out)
    per_level = max(1, -(-remaining // (2 * len(levels))))
    dists = [0.25 + 1.25 * i / max(1, per_level - 1) for i in range(per_level)]
    n = 0
    for d in dists:
        for t, temp, amb, v in levels:
            phases = (two if n % 2 else four) if args.phases == [2, 4] else (
                two if args.phases == [2] else four
            )
            n += 1
            c = {"temperature_c": temp, "ambient_klux": amb}
            if "supply" in cond:
                c["supply_voltage_v"] = v
            for rep in range(2):
                if len(out) < args.captures:
                    out.append((phases, t, d, dict(c, repeat=rep)))
    return out


def simulate(args):
    rng = random.Random(args.seed)
    rows, cols, f_hz = args.rows, args.cols, args.modulation_hz
    npix = rows * cols
    mid, top = 2 ** (args.adc_bits - 1), 2**args.adc_bits - 1
    offset = [rng.gauss(0.0, 6.0) for _ in range(npix)]
    gain = [1.0 + rng.gauss(0.0, 0.03) for _ in range(npix)]
    delay = [0.3 + rng.gauss(0.0, 0.02) for _ in range(npix)]
    eff = set(args.effects)
    os.makedirs(os.path.join(args.out, "frames"), exist_ok=True)
    toml = [
        'format = "tofprox-recording"',
        "version = 3",
        'kind = "raw"',
        'description = "independent simulation (crates/tofprox-lab/benches/independent_recording.py)"',
        "",
        "[sensor]",
        f"rows = {rows}",
        f"cols = {cols}",
        f"adc_bits = {args.adc_bits}",
        f"modulation_hz = {f_hz}",
    ]
    averaged = 4
    for i, (phases, t_us, d, cond) in enumerate(plan(args)):
        t_ms = t_us / 1000.0
        temp = cond.get("temperature_c", 30.0)
        amb = cond.get("ambient_klux", 0.0)
        volt = cond.get("supply_voltage_v", 3.3)
        dt = temp - 30.0
        codes = []
        for k, th_deg in enumerate(phases):
            th = math.radians(th_deg)
            power = 1.0
            if "droop" in eff:
                power = 1.0 - 0.04 * (1.0 - math.exp(-(k + 0.5) * t_ms / 0.7))
            for p in range(npix):
                bg = 0.6 * amb * t_ms * gain[p]
                if d is None:
                    sig = 0.0
                    bg = 0.0
                else:
                    amp = 90.0 * gain[p] * t_ms * 0.8 / (d * d) * power
                    if "supply" in eff:
                        amp *= 1.0 + 0.03 * (volt - 3.3)
                    phi = 4.0 * math.pi * f_hz * d / C_M_S + delay[p]
                    if "temperature" in eff:
                        phi += 2e-3 * dt + 5e-5 * dt * dt
                    sig = amp * correlation(phi - th)
                var = (1.5 + 0.06 * (abs(sig) + bg)) / averaged
                v = mid + offset[p] + bg + sig + rng.gauss(0.0, math.sqrt(var))
                codes.append(min(top, max(0, int(round(v)))))
        name = f"frames/{i:06d}.npy"
        write_npy(os.path.join(args.out, name), len(phases), rows, cols, codes)
        toml += [
            "",
            "[[capture]]",
            f'frames = "{name}"',
            "phases_deg = [" + ", ".join(f"{x:.1f}" for x in phases) + "]",
            f"exposure_us = {t_us:.1f}",
            f"illumination = {'false' if d is None else 'true'}",
            f"averaged = {averaged}",
            "[capture.conditions]",
        ]
        if d is not None:
            toml += [f"distance_m = {d:.6f}", "reflectivity = 0.8"]
        toml += [f"{k} = {v}" for k, v in cond.items()]
    with open(os.path.join(args.out, "recording.toml"), "w") as f:
        f.write("\n".join(toml) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--rows", type=int, default=16)
    ap.add_argument("--cols", type=int, default=16)
    ap.add_argument("--captures", type=int, default=900)
    ap.add_argument("--phases", default="4", type=lambda s: sorted(int(x) for x in s.split(",")))
    ap.add_argument("--conditions", default="exposure", type=lambda s: [x for x in s.split(",") if x])
    ap.add_argument("--effects", default="", type=lambda s: [x for x in s.split(",") if x])
    ap.add_argument("--adc-bits", type=int, default=12)
    ap.add_argument("--modulation-hz", type=float, default=60e6)
    ap.add_argument("--seed", type=int, default=1)
    simulate(ap.parse_args())


if __name__ == "__main__":
    main()
