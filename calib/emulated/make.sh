#!/bin/sh
# Regenerate the factory calibration of the emulated sensor (calib/emulated/),
# the way a factory calibrates a real module (thesis 4.3.2): dark frames for
# the fixed-pattern offset (FPN), a 24 x 15 deg correlation capture of a flat
# wall at a known distance for the 2- and 4-phase wiggling tables (global
# delay included), and a long-exposure 4-phase capture of the same wall for
# the per-pixel phase offsets (FPPN).
#
# The emulated sensor's fixed patterns are drawn from the device seed and the
# model: SEED and the model (wall-1m.toml: none given = the model baseline)
# must be the ones of config/tofproxd-emulated.toml ([emulated] seed, no
# [emulated.device] model). Run from anywhere:
#     calib/emulated/make.sh
# then `cargo test -p tofproxd --test emulated_calibration` and commit
# calib/emulated/.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
cd "$root"
SEED=${SEED:-1}
TOFPROX=${TOFPROX:-"cargo run -q -p tofprox --"}
work=target/calib-emulated
rm -rf "$work"
mkdir -p "$work"
dev="--emulated --config calib/emulated/wall-1m.toml --seed $SEED"

# Dark: the grey (illumination off) image of 16 4-phase+grey measurements at
# an exposure inside the daemon's range (dark current is negligible there).
$TOFPROX device capture $dev --mode 4phase-grey --exposure-us 250 --count 16 \
    --description "emulated sensor, dark frames for FPN" --out "$work/dark"
# Correlation: 24 phase steps of the wall at 1 m, long exposure (low noise).
$TOFPROX device capture $dev --mode correlation24 --exposure-us 2000 \
    --description "emulated sensor, correlation capture of a wall at 1 m" --out "$work/correlation"
# Flat target for FPPN: 4-phase at the longest exposure (per-pixel noise
# ~1 mm).
$TOFPROX device capture $dev --mode 4phase --exposure-us 4000 \
    --description "emulated sensor, flat wall at 1 m for FPPN" --out "$work/flat"

out=calib/emulated
rm -f "$out"/calibration.toml "$out"/*.npy
$TOFPROX calibrate fpn "$work/dark" --out "$out"
$TOFPROX calibrate wiggling "$work/correlation" --out "$out"
$TOFPROX calibrate fppn "$work/flat" --out "$out"
echo "calibration written to $out (seed $SEED)"
