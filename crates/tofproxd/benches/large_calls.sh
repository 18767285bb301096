#!/usr/bin/env bash
# Memory of the real daemon under large D-Bus calls (issue: any user may send
# ClaimProximity with a body of ~31 MiB, just under the system bus's 32 MiB
# max_message_size). N senders in parallel, each sending R such calls; the
# daemon refuses every one (InvalidArgs: the method takes no arguments).
# Prints VmHWM (peak RSS) and VmRSS before, during and after. Run from the repo
# root after `cargo build --release -p tofproxd`:
#   crates/tofproxd/benches/large_calls.sh              # with the unit's malloc settings
#   PLAIN=1 crates/tofproxd/benches/large_calls.sh      # glibc defaults, for comparison
set -euo pipefail
BIN=${BIN:-target/release/tofproxd}
PY=${PY:-/usr/bin/python3}
SENDERS=${SENDERS:-10}
ROUNDS=${ROUNDS:-3}
MIB=${MIB:-31}
work=$(mktemp -d)
dpid=""; bpid=""
trap 'kill $dpid 2>/dev/null || true; kill $bpid 2>/dev/null || true; rm -rf "$work"' EXIT
# a bus with the system bus's message size limit (32 MiB)
cat > "$work/bus.conf" <<CONF
<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-BUS Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>session</type>
  <listen>unix:path=$work/bus</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow send_destination="*" eavesdrop="true"/>
    <allow eavesdrop="true"/>
    <allow own="*"/>
  </policy>
  <limit name="max_message_size">33554432</limit>
</busconfig>
CONF
out=$(dbus-daemon --config-file="$work/bus.conf" --fork --print-address=1 --print-pid=1)
addr=$(echo "$out" | sed -n 1p); bpid=$(echo "$out" | sed -n 2p)
cat > "$work/cfg.toml" <<CFG
backend = "emulated"
[emulated.device]
frame_source = "ideal"
[emulated.device.scene]
kind = "wall"
wall_distance_m = 1.0
CFG
if [ -n "${PLAIN:-}" ]; then
  "$BIN" --config "$work/cfg.toml" --bus "$addr" 2>"$work/log" &
else
  # the unit's Environment= lines (systemd/tofproxd.service)
  MALLOC_ARENA_MAX=2 MALLOC_MMAP_THRESHOLD_=131072 MALLOC_TRIM_THRESHOLD_=131072 \
    "$BIN" --config "$work/cfg.toml" --bus "$addr" 2>"$work/log" &
fi
dpid=$!
sleep 1.5
mem() { awk '/VmHWM|VmRSS/{printf "%s %s kB  ", $1, $2}' /proc/$dpid/status; echo; }
echo "start:  $(mem)"
busctl --address="$addr" call org.tofprox.Proximity1 /org/tofprox/Proximity1 org.tofprox.Proximity1 ClaimProximity
echo "after one claim (pipelines built): $(mem)"
cat > "$work/send.py" <<'PYS'
import sys, dbus
addr, mib, rounds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
bus = dbus.bus.BusConnection(addr)
body = dbus.ByteArray(b"\0" * (mib * 1024 * 1024 - 64))
refused = 0
for _ in range(rounds):
    try:
        bus.call_blocking("org.tofprox.Proximity1", "/org/tofprox/Proximity1",
                          "org.tofprox.Proximity1", "ClaimProximity", "ay", [body], timeout=60)
    except dbus.exceptions.DBusException as e:
        if e.get_dbus_name() == "org.freedesktop.DBus.Error.InvalidArgs":
            refused += 1
        else:
            print("unexpected:", e.get_dbus_name(), file=sys.stderr)
print(refused)
PYS
pids=()
for _ in $(seq "$SENDERS"); do "$PY" "$work/send.py" "$addr" "$MIB" "$ROUNDS" > "$work/r.$RANDOM" & pids+=($!); done
peak=0
while kill -0 "${pids[@]}" 2>/dev/null; do
  r=$(awk '/VmRSS/{print $2}' /proc/$dpid/status); [ "$r" -gt "$peak" ] && peak=$r; sleep 0.05
done
wait "${pids[@]}" || true
refused=$(cat "$work"/r.* | paste -sd+ | bc)
echo "$SENDERS senders x $ROUNDS calls of $MIB MiB: $refused refused with InvalidArgs; sampled peak VmRSS $peak kB"
echo "right after: $(mem)"
sleep 2
echo "2 s later:   $(mem)"
busctl --address="$addr" call org.tofprox.Proximity1 /org/tofprox/Proximity1 org.tofprox.Proximity1 ClaimProximity && echo "still answers claims"
