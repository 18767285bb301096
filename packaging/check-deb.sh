#!/usr/bin/env bash
# Check a package built by packaging/build-deb.sh (called by .ci/run):
#
#   packaging/check-deb.sh target/debian/tofprox_<version>_<arch>.deb
#
# 1. its contents (`dpkg-deb -c`): binaries, unit, D-Bus policy and interface, udev rule,
#    sysusers/tmpfiles, /etc/tofprox/tofproxd.toml (a conffile), shipped data, man pages;
# 2. an install into a scratch root with dpkg itself (`dpkg --root`, maintainer scripts run
#    with DPKG_ROOT): the postinst made the user and groups and the calibration directory;
# 3. `systemd-analyze verify` of the installed unit against the installed binary;
# 4. the installed binaries run from another directory and find their data under the
#    install prefix, not in the source tree; the man pages are pages of both binaries (NAME
#    lines); `tofprox --help`; the README's tour's first steps from /usr/share/tofprox; the
#    daemon a production build (`--demo` refused: no emulated device), the installed
#    configuration refused without a calibration set and accepted with one.
# A missing tool is an error under CI=true and a loud skip otherwise.
set -euo pipefail
deb="$(realpath "$1")"
fail() { echo "check-deb: FAIL: $*" >&2; exit 1; }
for tool in dpkg dpkg-deb systemd-analyze systemd-sysusers systemd-tmpfiles; do
  if ! command -v "$tool" >/dev/null; then
    [ "${CI:-}" = true ] && fail "$tool not on PATH (package dpkg / systemd)"
    echo "SKIPPED check-deb: $tool not on PATH" >&2
    exit 0
  fi
done

# 1. contents
contents="$(dpkg-deb -c "$deb" | awk '{print $6}' | sed 's|^\./|/|')"
for f in /usr/bin/tofprox /usr/bin/tofproxd \
  /usr/lib/systemd/system/tofproxd.service \
  /usr/share/dbus-1/system.d/org.tofprox.Proximity1.conf \
  /usr/share/dbus-1/interfaces/org.tofprox.Proximity1.xml \
  /usr/lib/udev/rules.d/70-tofprox.rules \
  /usr/lib/sysusers.d/tofprox.conf /usr/lib/tmpfiles.d/tofprox.conf \
  /usr/share/tofprox/systemd/tofproxd.service.d/v4l2.conf \
  /etc/tofprox/tofproxd.toml \
  /usr/share/tofprox/config/tofproxd-emulated.toml \
  /usr/share/tofprox/calib/emulated/calibration.toml \
  /usr/share/man/man1/tofprox.1.gz /usr/share/man/man1/tofprox-monitor.1.gz \
  /usr/share/man/man8/tofproxd.8.gz /usr/share/doc/tofprox/docs/daemon.md \
  /usr/share/doc/tofprox/docs/lab-json.md /usr/share/tofprox/examples/recording/recording.toml \
  /usr/share/tofprox/calib/example/calibration.toml; do
  grep -qx "$f" <<<"$contents" || fail "$f missing from $deb"
done
if grep -q '/target/\|\.rs$\|make\.sh$' <<<"$contents"; then fail "build files in the package"; fi
[ "$(dpkg-deb -f "$deb" Package)" = tofprox ] || fail "Package field"
dpkg-deb -I "$deb" conffiles | grep -qx /etc/tofprox/tofproxd.toml || fail "tofproxd.toml is not a conffile"
echo "check-deb: contents ok ($(wc -l <<<"$contents") entries)"

# 2. install into a scratch root with dpkg
root="$(mktemp -d)"
trap 'rm -rf "$root"' EXIT
mkdir -p "$root/var/lib/dpkg/info" "$root/var/lib/dpkg/updates" "$root/etc"
touch "$root/var/lib/dpkg/status" "$root/etc/passwd" "$root/etc/group"
# (the scratch root has no libc6, dbus, systemd packages: --force-depends)
dpkg --root="$root" --log=/dev/null --force-script-chrootless --force-depends \
  --force-not-root -i "$deb" >"$root/dpkg.log" 2>&1 || fail "dpkg -i: $(cat "$root/dpkg.log")"
[ "$(dpkg --root="$root" -s tofprox | sed -n 's/^Status: //p')" = "install ok installed" ] ||
  fail "tofprox not installed in the scratch root"
grep -q '^tofprox:' "$root/etc/passwd" || fail "postinst made no user tofprox"
grep -q '^tofprox-depth:' "$root/etc/group" || fail "postinst made no group tofprox-depth"
[ -d "$root/var/lib/tofprox/calib" ] || fail "postinst made no /var/lib/tofprox/calib"
echo "check-deb: installed into a scratch root (user, groups, /var/lib/tofprox/calib made)"

# 3. the installed unit verifies against the installed binary
unit="$root/usr/lib/systemd/system/tofproxd.service"
sed "s|/usr/bin/tofproxd|$root/usr/bin/tofproxd|" "$unit" >"$root/tofproxd.service"
verify="$(systemd-analyze verify "$root/tofproxd.service" 2>&1)" || fail "systemd-analyze verify: $verify"
if grep -q 'tofproxd.service:' <<<"$verify"; then fail "systemd-analyze verify: $verify"; fi
echo "check-deb: systemd-analyze verify of the installed unit: clean"

# 4. installed binaries, run elsewhere, find the installed data
mkdir "$root/elsewhere" && cd "$root/elsewhere"
# the packaged daemon is a production build: no emulated device, so the demo (found under the
# install prefix) is refused, naming the feature
"$root/usr/bin/tofproxd" --version | grep -q 'production build' || fail "tofproxd is not a production build"
if demo="$("$root/usr/bin/tofproxd" --demo --check-config 2>&1)"; then
  fail "the packaged tofproxd runs the emulated demo: $demo"
fi
grep -q "^error: $root/usr/share/tofprox/config/tofproxd-emulated.toml: .*emulated" <<<"$demo" ||
  fail "demo refusal not from the install prefix or not naming the feature: $demo"
# the installed configuration requires the module's factory calibration in /var/lib/tofprox/calib:
# without a set there it refuses, saying how to calibrate; with one (here the emulated sensor's,
# same array) it passes
if refused="$("$root/usr/bin/tofproxd" --check-config --config "$root/etc/tofprox/tofproxd.toml" 2>&1)"; then
  fail "the installed configuration passes --check-config without a calibration set: $refused"
fi
grep -q 'has not been calibrated.*tofprox calibrate' <<<"$refused" ||
  fail "the refusal without a set does not say how to calibrate: $refused"
cp "$root"/usr/share/tofprox/calib/emulated/*.npy "$root"/usr/share/tofprox/calib/emulated/calibration.toml \
  "$root/var/lib/tofprox/calib/"
sed "s|^calibration = \"/var/lib/tofprox/calib\"|calibration = \"$root/var/lib/tofprox/calib\"|" \
  "$root/etc/tofprox/tofproxd.toml" >"$root/calibrated.toml"
"$root/usr/bin/tofproxd" --check-config --config "$root/calibrated.toml" >/dev/null ||
  fail "the installed /etc/tofprox/tofproxd.toml with a set in /var/lib/tofprox/calib does not pass --check-config"
# tofprox finds the phone model and calibration there too (no scene selected: only the set-up)
scenes="$("$root/usr/bin/tofprox" scenes --only no-such-scene --json 2>&1)" || fail "tofprox scenes: $scenes"
[ "$scenes" = "[]" ] || fail "tofprox scenes: $scenes"
zcat "$root/usr/share/man/man8/tofproxd.8.gz" | grep -q '^\.TH tofproxd 8' || fail "tofproxd.8 is no man page"
zcat "$root/usr/share/man/man1/tofprox.1.gz" | grep -q '^\.TH tofprox 1' || fail "tofprox.1 is no man page"
zcat "$root/usr/share/man/man8/tofproxd.8.gz" | grep -q 'check\\-config' || fail "tofproxd.8 lacks --check-config"
# a system daemon's page: its configuration keys, interface, files, signals, exit status
for sec in CONFIGURATION "D-BUS INTERFACE" FILES SIGNALS "EXIT STATUS" "SEE ALSO"; do
  zcat "$root/usr/share/man/man8/tofproxd.8.gz" | grep -qx "\.SH $sec" || fail "tofproxd.8 lacks the section $sec"
done
zcat "$root/usr/share/man/man8/tofproxd.8.gz" | grep -q 'proximity\.near_mm' || fail "tofproxd.8 lacks proximity.near_mm"
for page in man8/tofproxd.8 man1/tofprox.1 man1/tofprox-lab-add.1; do # NAME: "prog - what it is"
  name="$(zcat "$root/usr/share/man/$page.gz" | sed -n '/^\.SH NAME/{n;s/\\-/-/g;p;q}')"
  prog="$(basename "$page" | sed 's/\.[0-9]$//')"
  grep -q "^$prog - [a-zA-Z]" <<<"$name" || fail "$page: NAME line '$name'"
  if grep -q -- "- $prog\b" <<<"$name"; then fail "$page: NAME repeats the program name: '$name'"; fi
done
help="$("$root/usr/bin/tofprox" --help)" || fail "tofprox --help: $help"
grep -q '^  lab  ' <<<"$help" || fail "tofprox --help lists no lab command: $help"
# the README's tour from the installed data (cd /usr/share/tofprox): the example recording
# with its calibration to depth, and the lab on it
cd "$root/usr/share/tofprox"
depth="$("$root/usr/bin/tofprox" process examples/recording --calib calib/example --algo 2phase \
  --out "$root/depth" --json 2>/dev/null)" || fail "tofprox process of the installed example: $depth"
grep -q '"index":2,.*"error_mm":' <<<"$depth" || fail "tofprox process of the installed example: $depth"
lab="$("$root/usr/bin/tofprox" lab compare examples/recording --model config/model/baseline.toml \
  --json 2>/dev/null)" || fail "tofprox lab compare of the installed example: $lab"
grep -q '"chi2_per_dof"' <<<"$lab" || fail "tofprox lab compare of the installed example: $lab"
echo "check-deb: the tour's first steps run from /usr/share/tofprox (process, lab compare)"
cd "$root/elsewhere"
echo "check-deb: installed binaries find their data under the prefix; man pages ok"
echo "check-deb: PASS $(basename "$deb")"
