#!/usr/bin/env python3
"""numpy version of exactly the steps of tofprox-core's 2-phase pipeline (benches/pipeline.rs,
`process_2phase_u16`), for the speed comparison in compare.sh (target: Rust >= 20x faster).

Same frame (224 x 172, uint16 codes, same deterministic generator), same steps, float32 like the
Rust kernel: saturation + finiteness on the raw codes, per-pixel dark-frame subtraction, eq. 2.2
phase (atan2 wrapped to [0, 2pi)), amplitude |z|, wiggling correction by linear periodic
interpolation in a 4096-bin value+slope table, FPPN subtraction, wrap, depth (eq. 2.6) in metres
and uint16 millimetres (0 = invalid), validity flags.

Prints one line: `numpy_2phase_median_us <median> min <min>`.
"""
import math
import sys
import time

import numpy as np

ROWS, COLS = 172, 224
C = 299_792_458.0
F_MOD = 80e6
LUT_BINS = 4096
TAU = np.float32(2.0 * math.pi)


def raw_frame(k):
    r = np.arange(ROWS).reshape(ROWS, 1)
    c = np.arange(COLS).reshape(1, COLS)
    fpn = ((r * 7919 + c * 104_729) % 97).astype(np.float64) - 48.0
    phi = (r * COLS + c).astype(np.float64) * 0.000_37
    amp = 200.0 + ((r + c) % 50).astype(np.float64) * 20.0
    out = np.empty((k, ROWS, COLS), dtype=np.uint16)
    sat = ((r * COLS + c) % 1009) == 0
    for i in range(k):
        v = 2048.0 + fpn + amp * np.cos(phi - i * math.pi / 2)
        out[i] = np.where(sat, 4095, np.clip(np.round(v), 0, 4095)).astype(np.uint16)
    return out


def calibration():
    r = np.arange(ROWS).reshape(ROWS, 1)
    c = np.arange(COLS).reshape(1, COLS)
    dark = (2048.0 + ((r * 7919 + c * 104_729) % 97) - 48.0).astype(np.float32)
    fppn = np.zeros((ROWS, COLS), dtype=np.float32)
    lut360 = 0.35 + 0.03 * np.sin(3.0 * np.arange(360) * 2 * math.pi / 360.0)
    # Resample to 4096 bins of value + slope (what the Rust pipeline does once at construction).
    x = np.arange(LUT_BINS) * 360.0 / LUT_BINS
    i0 = np.floor(x).astype(int) % 360
    fr = x - np.floor(x)
    vals = lut360[i0] + (lut360[(i0 + 1) % 360] - lut360[i0]) * fr
    lut_val = vals.astype(np.float32)
    lut_slope = (np.roll(vals, -1) - vals).astype(np.float32)
    return dark, fppn, lut_val, lut_slope


def process_2phase(raw, dark, fppn, lut_val, lut_slope, min_amp=np.float32(10.0), rail=np.float32(4095.0)):
    a0 = raw[0].astype(np.float32)
    a1 = raw[1].astype(np.float32)
    sat = (a0 <= 0) | (a0 >= rail) | (a1 <= 0) | (a1 >= rail)
    finite = np.isfinite(a0) & np.isfinite(a1)
    x = a0 - dark
    y = a1 - dark
    amp = np.sqrt(x * x + y * y)
    m = np.arctan2(y, x)
    m = np.where(m < 0, m + TAU, m)
    xf = m * np.float32(LUT_BINS / (2 * math.pi))
    xi = np.floor(xf).astype(np.int32)
    fr = xf - xi
    idx = xi & (LUT_BINS - 1)
    corr = lut_val[idx] + lut_slope[idx] * fr
    ph = np.mod(m - corr - fppn, TAU)
    d = ph * np.float32(C / (2 * F_MOD) / (2 * math.pi))
    in_range = d * 1000 < 65535.5
    low = amp < min_amp
    invalid = sat | low | ~finite | ~in_range
    flags = sat.astype(np.uint8) | (low.astype(np.uint8) << 1) | (invalid.astype(np.uint8) << 2) | ((~finite).astype(np.uint8) << 3)
    mm = np.maximum(np.rint(d * 1000), 1).astype(np.uint16)
    depth_mm = np.where(invalid, np.uint16(0), mm)
    depth_m = np.where(invalid, np.float32(0), d)
    return depth_m, depth_mm, amp, ph, flags


def main():
    iters = int(sys.argv[1]) if len(sys.argv) > 1 else 300
    raw = raw_frame(2)
    cal = calibration()
    out = process_2phase(raw, *cal)  # warm-up
    assert out[1].dtype == np.uint16 and out[1].shape == (ROWS, COLS)
    times = []
    for _ in range(iters):
        t0 = time.perf_counter()
        process_2phase(raw, *cal)
        times.append(time.perf_counter() - t0)
    times.sort()
    print(f"numpy_2phase_median_us {times[len(times) // 2] * 1e6:.1f} min {times[0] * 1e6:.1f}")


if __name__ == "__main__":
    main()
