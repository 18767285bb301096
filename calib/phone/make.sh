#!/bin/sh
# Regenerate the factory calibration of the emulated phone sensor
# (calib/phone/): the emulated sensor as built into a phone, i.e. the model
# config/model/phone.toml behind a clean cover window (wall-1m.toml,
# empty.toml), seed 1. As a phone maker calibrates (thesis 4.3.2 plus the
# cover window): dark frames for the offset (FPN); captures with nothing in
# range for the cover-window crosstalk; a 24 x 15 deg correlation capture of a
# wall at 1 m for the 2- and 4-phase wiggling tables; a long-exposure 4-phase
# capture of the wall for the FPPN maps (both with the crosstalk subtracted).
#     calib/phone/make.sh            (TOFPROX=target/debug/tofprox to skip cargo)
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
cd "$root"
SEED=${SEED:-1}
TOFPROX=${TOFPROX:-"cargo run -q -p tofprox --"}
work=target/calib-phone
rm -rf "$work"
mkdir -p "$work"
wall="--emulated --config calib/phone/wall-1m.toml --seed $SEED"
empty="--emulated --config calib/phone/empty.toml --seed $SEED"

$TOFPROX device capture $wall --mode 4phase-grey --exposure-us 250 --count 16 \
    --description "emulated phone sensor, dark frames for FPN" --out "$work/dark"
# nothing in range at the daemon's longest exposure, marked no_target = 1
$TOFPROX device capture $empty --mode 4phase --exposure-us 500 --count 8 --condition no_target=1 \
    --description "emulated phone sensor, nothing in range (crosstalk)" --out "$work/empty"
$TOFPROX device capture $wall --mode correlation24 --exposure-us 2000 \
    --description "emulated phone sensor, correlation capture of a wall at 1 m" --out "$work/correlation"
$TOFPROX device capture $wall --mode 4phase --exposure-us 4000 \
    --description "emulated phone sensor, flat wall at 1 m for FPPN" --out "$work/flat"

out=calib/phone
rm -f "$out"/calibration.toml "$out"/*.npy
$TOFPROX calibrate fpn "$work/dark" --out "$out"
$TOFPROX calibrate crosstalk "$work/empty" --out "$out"
$TOFPROX calibrate wiggling "$work/correlation" --out "$out"
$TOFPROX calibrate fppn "$work/flat" --out "$out"
echo "calibration written to $out (seed $SEED)"
