#!/usr/bin/env python3
"""An independent simulation of a phone's ToF proximity scenes, written as
tofprox recordings (format version 1, docs/recording-format.md).

This is deliberately NOT tofprox-model: its own sensor formulation, written
from first principles, so that tofproxd is checked against data it was not
built around (issue 10, "independent replay"). What differs from the model:

* Correlation waveform: the illumination is a square wave (duty 50 %) through
  a first-order low pass (the VCSEL driver's rise time, tau_ns); the pixel
  demodulates with a square wave. The correlation of the two is computed
  numerically (a rounded triangle, odd harmonics 3, 5, 7, ...), not a sum of
  chosen harmonics.
* Timing: a global delay (driver + cabling) and a per-pixel delay that grows
  linearly with the column (the modulation clock tree) plus a random part.
* Radiometry: a Lambertian target of reflectivity rho at radial range d on a
  pixel's ray returns P * rho * cos^4(theta) / d^2 electrons per us (the
  cos^4 law of the lens instead of a vignetting table); PRNU 1.5 %.
* Noise: photon shot noise of signal + background light + the cover window
  (Poisson, drawn per tap), read noise 1.8 LSB, ADC rounding; codes clip at
  the rails. Background light adds only shot noise (the SBI circuit removes
  its common mode) plus a small tap mismatch (0.4 % of it leaks into the
  differential code).
* Cover window: a return at 2.5 mm of 4 e-/us (phone glass), falling off
  with cos(theta) across the field; calibrated from captures with nothing in
  range (``conditions.no_target = 1``), as docs/calibration.md says a phone is.
* Fabric pressed on the glass (a pocket): the glass (n = 1.52) reflects
  R = ((n - 1)/(n + 1))^2 of the light at normal incidence (Fresnel); the
  fabric behind it is lit through the glass (1 - R), scatters rho (a weave:
  rho varies +-20 % from pixel to pixel) and its light goes back through the
  glass (1 - R) along the path the window's own reflection takes to the
  pixels, so it adds (1 - R)^2 rho / R times the window's electrons, at the
  window's phase; nothing behind the fabric is seen.
* Modulation 60 MHz (unambiguous range 2.498 m), 12-bit ADC, 224 x 172,
  offset-binary codes around 2048 with per-pixel offsets (row + column
  patterns + random, sigma ~ 25 LSB).

Conventions shared with every tofprox recording (the format, not the model):
raw image k taken at phase shift theta_k holds
code_k = 2048 + offset + A * corr(phi - theta_k).

Output (``OUT``):

* ``OUT/calibration/``: dark captures (illumination off, 4 phases, 8 single
  acquisitions), one 24-phase (15 deg steps) correlation capture of a
  white wall (rho 0.9) at 0.6 m, ``conditions.distance_m`` and
  ``reflectivity`` set, and 8 illuminated 4-phase captures at 500 us facing
  the sky (``conditions.no_target = 1``): what ``tofprox calibrate fpn`` /
  ``crosstalk`` / ``wiggling`` take.
* ``OUT/scenes/NAME/``: one recording per scene, 2-phase (0, 90 deg) single
  acquisitions at 10 Hz, exposure ``--exposure-us``; every capture has
  ``conditions.truth_near`` (1: at least half of the central half of the
  field is within 10 cm; 0: all of it is beyond 15 cm; 0.5 otherwise) and
  ``conditions.distance_m`` (the median true range there).
* ``OUT/scenes.json``: the scene names and descriptions.

Usage: phone_sim.py OUT [--seed N] [--exposure-us T] [--seconds S] [--only NAME]
"""

import argparse
import json
import math
import os
import sys

import numpy as np

C_M_PER_S = 299_792_458.0
ROWS, COLS = 172, 224
ADC_BITS = 12
MID = 2 ** (ADC_BITS - 1)
MAX_CODE = 2 ** ADC_BITS - 1
F_MOD_HZ = 60e6
RATE_HZ = 10.0
NEAR_M, FAR_M = 0.10, 0.15

# sensor constants of this simulation (assumptions, stated)
P_E_PER_US = 55.0  # e-/us of a rho = 1 target at 1 m on the optical axis
CONTRAST = 0.72  # demodulation contrast
LSB_PER_E = 3.6e-3  # ADC gain (differential), LSB per electron
READ_NOISE_LSB = 1.8
PRNU = 0.015
TAU_NS = 1.6  # illumination rise/fall time constant
GLOBAL_DELAY_NS = 2.4
COLUMN_DELAY_PS = 1.5  # per column, clock tree
AMBIENT_E_PER_US_PER_KLUX = 2.0  # background light, per pixel
TAP_MISMATCH = 0.004
WINDOW_E_PER_US = 4.0
WINDOW_M = 0.0025
FOV_H_DEG = 64.0
GLASS_N = 1.52
GLASS_R = ((GLASS_N - 1.0) / (GLASS_N + 1.0)) ** 2  # Fresnel, normal incidence


def correlation_harmonics(n_max=15):
    """(amplitude, phase lag) of the odd harmonics n of corr(x): a square illumination
    through a first-order low pass H(w) = 1/(1 + i w tau), correlated with a square
    demodulation. Each square wave has odd harmonics ~ 1/n, so their correlation has
    |H(n w)| / n^2 (a triangle rounded by the low pass), lagging by atan(n w tau).
    Normalised to a unit fundamental; its lag is kept (a real delay)."""
    w_tau = 2 * math.pi * F_MOD_HZ * TAU_NS * 1e-9
    h = lambda n: 1.0 / math.sqrt(1.0 + (n * w_tau) ** 2)
    return [(h(n) / (n * n * h(1)), math.atan(n * w_tau)) for n in range(1, n_max + 1, 2)]


class Sensor:
    def __init__(self, seed):
        rng = np.random.default_rng(seed)
        self.rng = np.random.default_rng(seed + 1000)
        self.harmonics = correlation_harmonics()
        rows = rng.normal(0.0, 8.0, size=(ROWS, 1))
        cols = rng.normal(0.0, 12.0, size=(1, COLS))
        self.offset = rows + cols + rng.normal(0.0, 20.0, size=(ROWS, COLS))
        self.gain = 1.0 + rng.normal(0.0, PRNU, size=(ROWS, COLS))
        col = np.arange(COLS)[None, :] - COLS / 2
        delay_s = (
            GLOBAL_DELAY_NS * 1e-9
            + COLUMN_DELAY_PS * 1e-12 * col
            + rng.normal(0.0, 8e-12, size=(ROWS, COLS))
        )
        self.delay_rad = 2 * np.pi * F_MOD_HZ * delay_s
        f = (COLS / 2) / math.tan(math.radians(FOV_H_DEG) / 2)
        r = np.arange(ROWS)[:, None] - (ROWS - 1) / 2
        c = np.arange(COLS)[None, :] - (COLS - 1) / 2
        self.ray_x = c / f + 0 * r
        self.ray_y = r / f + 0 * c
        norm = np.sqrt(1 + self.ray_x**2 + self.ray_y**2)
        self.cos_theta = 1.0 / norm
        # a fabric's weave: its reflectivity varies +-20 % from pixel to pixel
        self.weave = rng.uniform(-0.2, 0.2, size=(ROWS, COLS))

    def corr_at(self, x):
        """corr(x) = sum_n a_n cos(n x + lag_n), x = phi - theta (phi grows with range)."""
        return sum(a * np.cos(n * x + lag) for n, (a, lag) in zip(range(1, 99, 2), self.harmonics))

    def capture(self, phases_deg, exposure_us, range_m, rho, ambient_klux, illum=True,
                on_glass_rho=None):
        """Codes (K, ROWS, COLS) uint16 of one single acquisition; ``on_glass_rho``: the
        reflectivity per pixel of fabric pressed on the glass (None: nothing there)."""
        k_images = []
        if illum:
            sig_e = P_E_PER_US * rho * self.cos_theta**4 / np.maximum(range_m, 1e-3) ** 2
            sig_e = sig_e * self.gain * exposure_us
            win_e = WINDOW_E_PER_US * self.cos_theta * exposure_us * np.ones_like(sig_e)
            if on_glass_rho is not None:
                # through the glass and back along the window's path (module docstring)
                win_e = win_e * (1.0 + (1.0 - GLASS_R) ** 2 * on_glass_rho / GLASS_R)
            phi = 4 * np.pi * F_MOD_HZ * range_m / C_M_PER_S + self.delay_rad
            phi_w = 4 * np.pi * F_MOD_HZ * WINDOW_M / C_M_PER_S + self.delay_rad
        else:
            sig_e = np.zeros((ROWS, COLS))
            win_e = np.zeros((ROWS, COLS))
            phi = phi_w = np.zeros((ROWS, COLS))
        amb_e = AMBIENT_E_PER_US_PER_KLUX * ambient_klux * exposure_us * np.ones((ROWS, COLS))
        for theta in phases_deg:
            th = math.radians(theta)
            diff = CONTRAST * (sig_e * self.corr_at(phi - th) + win_e * self.corr_at(phi_w - th))
            total = sig_e + win_e + amb_e
            # taps: A gets (total + diff)/2, B gets (total - diff)/2; shot noise per tap
            tap_a = self.rng.poisson(np.clip((total + diff) / 2, 0, None)).astype(float)
            tap_b = self.rng.poisson(np.clip((total - diff) / 2, 0, None)).astype(float)
            d_e = tap_a - tap_b + TAP_MISMATCH * amb_e
            code = MID + self.offset + LSB_PER_E * d_e
            code += self.rng.normal(0.0, READ_NOISE_LSB, size=code.shape)
            k_images.append(np.clip(np.rint(code), 0, MAX_CODE))
        return np.ascontiguousarray(np.stack(k_images), dtype="<u2")


# --- scenes: per pixel true range and reflectivity at time t ------------------


def _ease(x):
    """A cosine ease from 0 to 1 over x in [0, 1]."""
    return 0.5 - 0.5 * math.cos(math.pi * min(max(x, 0.0), 1.0))


def _phases(u, phases):
    """The range at cycle fraction u: the first phase (until_u, range_of_u) with u < until_u;
    None (absent) past the last."""
    for until, range_m in phases:
        if u < until:
            return range_m(u)
    return None


def approach(t, period, near, far=0.6):
    """Absent 15 %, approaches far -> near (30 %), holds (20 %), leaves (20 %), absent."""
    return _phases((t / period) % 1.0, [
        (0.15, lambda u: None),
        (0.45, lambda u: far + (near - far) * _ease((u - 0.15) / 0.30)),
        (0.65, lambda u: near),
        (0.85, lambda u: near + (far - near) * _ease((u - 0.65) / 0.20)),
    ])


def pocket(t, period, near=0.02, far=0.6):
    """Into a pocket: absent 10 %, the fabric comes far -> near (25 %), is pressed on
    the glass (0.0, 40 %), lifted and gone near -> far (15 %), absent (10 %)."""
    return _phases((t / period) % 1.0, [
        (0.10, lambda u: None),
        (0.35, lambda u: far + (near - far) * _ease((u - 0.10) / 0.25)),
        (0.75, lambda u: 0.0),
        (0.90, lambda u: near + (far - near) * _ease((u - 0.75) / 0.15)),
    ])


class Scene:
    def __init__(self, name, desc, background_m, background_rho, ambient_klux=0.0,
                 obj=None, obj_rho=0.0, obj_half=(0.05, 0.05), motion=None):
        self.name, self.desc = name, desc
        self.bg_m, self.bg_rho, self.ambient = background_m, background_rho, ambient_klux
        self.obj, self.obj_rho, self.obj_half, self.motion = obj, obj_rho, obj_half, motion

    def at(self, sensor, t):
        """(range_m, rho, on_glass_rho) per pixel: a plane perpendicular to the axis at bg_m
        seen along each ray (range = z / cos theta), and the object (an ellipse in a plane at
        z; ``obj_half`` None: it fills the view); at z = 0 the object is fabric pressed on the
        glass (range 0 for the truth, no imaged return, its weave's rho on the glass)."""
        rng_m = self.bg_m / sensor.cos_theta
        rho = np.full((ROWS, COLS), self.bg_rho)
        z = self.motion(t) if self.motion else None
        if z == 0.0:
            weave = 1.0 + sensor.weave
            return np.zeros((ROWS, COLS)), np.zeros((ROWS, COLS)), self.obj_rho * weave
        if z is not None and self.obj_half is None:
            return z / sensor.cos_theta, np.full((ROWS, COLS), self.obj_rho), None
        if z is not None:
            hx, hy = self.obj_half
            inside = (sensor.ray_x * z / hx) ** 2 + (sensor.ray_y * z / hy) ** 2 <= 1.0
            rng_m = np.where(inside, z / sensor.cos_theta, rng_m)
            rho = np.where(inside, self.obj_rho, rho)
        return rng_m, rho, None


def scenes(seconds):
    p = seconds
    hand = (0.045, 0.06)
    head = (0.08, 0.11)
    card = (0.10, 0.125)
    d_u = C_M_PER_S / (2 * F_MOD_HZ)
    return [
        Scene("empty_room", "nothing within 20 m (only the cover window returns)", 20.0, 0.3),
        Scene("ceiling_white_120cm", "white ceiling at 1.2 m", 1.2, 0.9),
        Scene("wall_white_beyond_range", f"white wall at {d_u + 0.05:.2f} m, just beyond the "
              "unambiguous range: its phase wraps to ~5 cm", d_u + 0.05, 0.9),
        Scene("wall_white_twice_range", f"white wall at {2 * d_u + 0.04:.2f} m (wraps to ~4 cm)",
              2 * d_u + 0.04, 0.9),
        Scene("dark_wall_300cm", "dark wall at 3 m", 3.0, 0.08),
        Scene("sunlight_ground_80klux", "80 klux of sunlight on ground at 1.5 m", 1.5, 0.25, 80.0),
        Scene("face_30cm", "a face at 30 cm (reading)", 1.5, 0.5, 0.0, "face", 0.5, head,
              lambda t: 0.30 + 0.01 * math.sin(2 * math.pi * t / p)),
        Scene("hand_to_4cm", "a hand approaching to 4 cm and leaving", 1.5, 0.5, 0.0, "hand",
              0.45, hand, lambda t: approach(t, p, 0.04)),
        Scene("hand_to_2cm", "a hand approaching to 2 cm (saturates)", 1.5, 0.5, 0.0, "hand",
              0.45, hand, lambda t: approach(t, p, 0.02)),
        Scene("dark_hair_to_3cm", "a head with black hair (6 %) approaching to 3 cm", 2.0, 0.5,
              0.0, "head", 0.06, head, lambda t: approach(t, p, 0.03)),
        Scene("black_card_to_5cm", "a black card (5 %) approaching to 5 cm", 1.5, 0.5, 0.0,
              "card", 0.05, card, lambda t: approach(t, p, 0.05)),
        Scene("hand_to_5cm_under_bright_ceiling", "a hand to 5 cm under a white ceiling "
              "just beyond the range", d_u + 0.05, 0.9, 0.0, "hand", 0.45, hand,
              lambda t: approach(t, p, 0.05)),
        Scene("hand_to_4cm_60klux", "a hand to 4 cm in 60 klux of sunlight", 1.5, 0.3, 60.0,
              "hand", 0.45, hand, lambda t: approach(t, p, 0.04)),
        Scene("pocket_dark_lining", "into a pocket: a dark lining (3 %) over the view to 2 cm, "
              "pressed on the glass, and out", 1.5, 0.5, 0.0, "fabric", 0.03, None,
              lambda t: pocket(t, p)),
        Scene("pocket_light_fabric", "into a pocket: light fabric (50 %) over the view to 2 cm, "
              "pressed on the glass, and out", 1.5, 0.5, 0.0, "fabric", 0.5, None,
              lambda t: pocket(t, p)),
    ]


def truth(rng_m):
    """truth_near over the central half of the field: 1 / 0 / 0.5; median range there."""
    r0, r1 = ROWS // 4, ROWS - ROWS // 4
    c0, c1 = COLS // 4, COLS - COLS // 4
    roi = rng_m[r0:r1, c0:c1]
    near_share = float(np.mean(roi <= NEAR_M))
    if near_share >= 0.5:
        t = 1.0
    elif float(roi.min()) >= FAR_M:
        t = 0.0
    else:
        t = 0.5
    return t, float(np.median(roi))


def write_recording(path, description, captures):
    """captures: list of dicts with frames (uint16 array), phases_deg, exposure_us,
    illumination, timestamp_ns, conditions."""
    os.makedirs(os.path.join(path, "frames"), exist_ok=True)
    lines = [
        'format = "tofprox-recording"',
        "version = 1",
        f"description = {json.dumps(description)}",
        "",
        "[sensor]",
        f"rows = {ROWS}",
        f"cols = {COLS}",
        "roi_origin = [0, 0]",
        f"full_rows = {ROWS}",
        f"full_cols = {COLS}",
        f"adc_bits = {ADC_BITS}",
        f"modulation_hz = {F_MOD_HZ:.1f}",
    ]
    for i, c in enumerate(captures):
        rel = f"frames/{i:06d}.npy"
        np.save(os.path.join(path, rel), c["frames"])
        phases = ", ".join(f"{p:.1f}" for p in c["phases_deg"])
        lines += [
            "",
            "[[capture]]",
            f'frames = "{rel}"',
            f"phases_deg = [{phases}]",
            f"exposure_us = {c['exposure_us']:.1f}",
            f"illumination = {'true' if c['illumination'] else 'false'}",
            "averaged = 1",
            f"timestamp_ns = {c['timestamp_ns']}",
            "",
            "[capture.conditions]",
        ]
        for k, v in sorted(c["conditions"].items()):
            lines.append(f"{k} = {float(v)!r}")
    with open(os.path.join(path, "recording.toml"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--exposure-us", type=float, default=250.0)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--only", default=None)
    a = ap.parse_args()
    if os.path.exists(os.path.join(a.out, "scenes.json")):
        sys.exit(f"error: {a.out} already holds a simulation (scenes.json); choose a new directory")
    sensor = Sensor(a.seed)

    # calibration captures beside the scenes: dark + 24-phase of a white wall at 0.6 m
    cal = []
    for i in range(8):
        cal.append(dict(frames=sensor.capture([0, 90, 180, 270], 250.0, np.ones((ROWS, COLS)),
                                              0.0, 0.0, illum=False),
                        phases_deg=[0.0, 90.0, 180.0, 270.0], exposure_us=250.0,
                        illumination=False, timestamp_ns=i * 100_000_000,
                        conditions={"ambient_klux": 0.0}))
    # a flat white wall perpendicular to the axis at 0.6 m (pixels off the axis see it
    # farther, 0.6 m / cos theta: what a real calibration rig gives)
    rng_m, rho, _ = Scene("cal", "", 0.6, 0.9).at(sensor, 0.0)
    phases24 = [15.0 * k for k in range(24)]
    cal.append(dict(frames=sensor.capture(phases24, 1000.0, rng_m, rho, 0.0),
                    phases_deg=phases24, exposure_us=1000.0, illumination=True,
                    timestamp_ns=10 * 100_000_000,
                    conditions={"distance_m": 0.6, "reflectivity": 0.9, "ambient_klux": 0.0}))
    # the cover window alone: the sky (nothing within 30 m, nothing returns), 4-phase
    sky_m, sky_rho, _ = Scene("sky", "", 30.0, 0.0).at(sensor, 0.0)
    for i in range(8):
        cal.append(dict(frames=sensor.capture([0, 90, 180, 270], 500.0, sky_m, sky_rho, 0.0),
                        phases_deg=[0.0, 90.0, 180.0, 270.0], exposure_us=500.0,
                        illumination=True, timestamp_ns=(11 + i) * 100_000_000,
                        conditions={"no_target": 1.0, "ambient_klux": 0.0}))
    write_recording(os.path.join(a.out, "calibration"),
                    "independent phone ToF simulation (phone_sim.py): dark + 24-phase + sky", cal)

    listing = []
    n = int(round(a.seconds * RATE_HZ))
    for sc in scenes(a.seconds):
        if a.only and a.only not in sc.name:
            continue
        caps = []
        for i in range(n):
            t = i / RATE_HZ
            rng_m, rho, on_glass = sc.at(sensor, t)
            tn, med = truth(rng_m)
            caps.append(dict(frames=sensor.capture([0.0, 90.0], a.exposure_us, rng_m, rho,
                                                   sc.ambient, on_glass_rho=on_glass),
                             phases_deg=[0.0, 90.0], exposure_us=a.exposure_us,
                             illumination=True, timestamp_ns=int(t * 1e9),
                             conditions={"truth_near": tn, "distance_m": med,
                                         "ambient_klux": sc.ambient}))
        write_recording(os.path.join(a.out, "scenes", sc.name),
                        f"independent phone ToF simulation (phone_sim.py): {sc.desc}", caps)
        listing.append({"name": sc.name, "description": sc.desc, "captures": n})
    with open(os.path.join(a.out, "scenes.json"), "w") as f:
        json.dump({"modulation_hz": F_MOD_HZ, "rate_hz": RATE_HZ, "scenes": listing}, f, indent=1)


if __name__ == "__main__":
    main()
