#!/usr/bin/env bash
# Resident memory and wake-ups of the real daemon (emulated device, 1 Hz,
# private dbus-daemon). Run from the repo root after
#   cargo build --release -p tofproxd
# Wake-ups = voluntary context switches per thread (/proc/PID/task/*/status):
#  - idle (no claim, sensor in reset): expected 0 on every thread;
#  - claimed at 1 Hz: per cycle, the loop thread wakes once for the next cycle
#    (its only timed wait) plus the emulated hardware waits inside the cycle;
#    the runtime thread wakes only to publish the cycle's signals.
set -euo pipefail
BIN=${BIN:-target/release/tofproxd}
PY=${PY:-/usr/bin/python3}
SECS=${SECS:-10}
work=$(mktemp -d)
trap 'kill $dpid $cpid 2>/dev/null || true; kill $bpid 2>/dev/null || true; rm -rf "$work"' EXIT
cpid=""; dpid=""
out=$(dbus-daemon --session --fork --print-address=1 --print-pid=1)
addr=$(echo "$out" | sed -n 1p); bpid=$(echo "$out" | sed -n 2p)
cat > "$work/cfg.toml" <<CFG
backend = "emulated"
[loop]
rate_hz = 1.0
fast_rate_hz = 1.0
slow_rate_hz = 1.0
[emulated.device]
frame_source = "ideal"
[emulated.device.scene]
kind = "wall"
wall_distance_m = 1.0
CFG
"$BIN" --config "$work/cfg.toml" --bus "$addr" 2>"$work/log" &
dpid=$!
sleep 2
ctx() { for t in /proc/$dpid/task/*; do printf "%s:%s " "$(cat $t/comm)" "$(awk '/^voluntary_ctxt_switches/{print $2}' $t/status)"; done; }
cycles() { busctl --address="$addr" --json=short call org.tofprox.Proximity1 /org/tofprox/Proximity1 org.tofprox.Proximity1 GetStatus | $PY -c 'import json,sys; print(json.load(sys.stdin)["data"][0]["Cycles"]["data"])'; }
echo "idle ${SECS}s (no claim):"
a=$(ctx); sleep "$SECS"; b=$(ctx)
echo "  before: $a"; echo "  after:  $b"
echo "  VmRSS idle: $(awk '/VmRSS/{print $2, $3}' /proc/$dpid/status)"
$PY tests/dbus/client.py native --address "$addr" --timeout $((SECS + 10)) >/dev/null &
cpid=$!
sleep 3
c0=$(cycles); a=$(ctx); sleep "$SECS"; c1=$(cycles); b=$(ctx)
echo "claimed at 1 Hz, ${SECS}s: $((c1 - c0)) cycles"
echo "  before: $a"; echo "  after:  $b"
echo "  VmRSS running: $(awk '/VmRSS/{print $2, $3}' /proc/$dpid/status)"
