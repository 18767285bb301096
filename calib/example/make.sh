#!/bin/sh
# Rebuild the example calibration set (calib/example/) from the example
# recording (examples/recording/) with the commands of docs/calibration.md:
# the dark capture for the offset (FPN), the 24-phase correlation capture at
# 0.5 m for the 2- and 4-phase wiggling tables and the amplitude scale, the
# 4-phase wall for the FPPN maps. A 16x16 window: no lens part (nearly on-axis).
#
#     calib/example/make.sh                  # writes a fresh set under $OUT (default: a new
#                                            # temporary directory), prints `tofprox info` of it
#     calib/example/make.sh --regenerate     # and then replaces calib/example/ with it
#     TOFPROX=target/debug/tofprox calib/example/make.sh   (skip cargo)
#
# Without --regenerate nothing tracked is touched.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
cd "$root"
TOFPROX=${TOFPROX:-"cargo run -q -p tofprox --"}
OUT=${OUT:-$(mktemp -d "${TMPDIR:-/tmp}/tofprox-example-calib.XXXXXX")/example}
case "${1:-}" in
    "" | --regenerate) ;;
    *) echo "usage: $0 [--regenerate]" >&2; exit 2 ;;
esac
if [ -e "$OUT/calibration.toml" ]; then
    echo "$OUT already holds a set; choose another OUT" >&2
    exit 2
fi
$TOFPROX calibrate fpn      examples/recording --out "$OUT"
$TOFPROX calibrate wiggling examples/recording --out "$OUT"
$TOFPROX calibrate fppn     examples/recording --out "$OUT"
$TOFPROX info "$OUT"
if [ "${1:-}" = "--regenerate" ]; then
    rm -f calib/example/calibration.toml calib/example/*.npy
    cp "$OUT"/calibration.toml "$OUT"/*.npy calib/example/
    echo "calib/example regenerated from $OUT"
else
    echo "set written to $OUT (calib/example untouched; --regenerate replaces it)"
fi
