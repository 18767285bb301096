#!/usr/bin/env bash
# Build the Debian package `tofprox` from already-built binaries (no cargo-deb):
#
#   packaging/build-deb.sh [PROFILE_DIR]      # default target/release
#
# PROFILE_DIR holds `tofprox` and `tofproxd`. For a device build first run, as two commands
# (one `cargo build -p tofprox -p tofproxd` unifies features: the CLI's emulated device would
# be compiled into the daemon too):
#   cargo build --release --no-default-features -p tofproxd
#   cargo build --release -p tofprox
# The daemon must be a production build (`tofproxd --version` says so): a daemon linking the
# emulated device and the physical model is refused. (CI packages target/debug after building
# the production daemon there.)
# Output: target/debian/tofprox_<version>_<arch>.deb (path printed on stdout).
# Layout: docs/daemon.md, "Install". The man pages come from the binaries' clap
# definitions (`tofprox man --out DIR`, `tofproxd --man DIR`).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
profile="${1:-$repo/target/release}"
out_dir="$repo/target/debian"
for b in tofprox tofproxd; do
  [ -x "$profile/$b" ] || { echo "error: $profile/$b not found: build it first (cargo build -p tofprox -p tofproxd)" >&2; exit 2; }
done
if ! "$profile/tofproxd" --version | grep -q 'production build'; then
  echo "error: $profile/tofproxd links the emulated device (feature emulated): build the daemon alone with" >&2
  echo "  cargo build --release --no-default-features -p tofproxd" >&2
  exit 2
fi
command -v dpkg-deb >/dev/null || { echo "error: dpkg-deb not found (package dpkg)" >&2; exit 2; }

version="$(sed -n 's/^version = "\(.*\)"/\1/p' "$repo/Cargo.toml" | head -1)"
arch="$(dpkg --print-architecture)"
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
pkg="$stage/tofprox"

inst() { # MODE SRC DEST (DEST relative to the package root)
  install -D -m "$1" "$2" "$pkg/$3"
}
# binaries, without debug info (debug builds carry hundreds of MB of it)
for b in tofprox tofproxd; do
  inst 0755 "$profile/$b" "usr/bin/$b"
  strip --strip-debug "$pkg/usr/bin/$b" 2>/dev/null || true
done
# systemd, D-Bus, udev (install places as in docs/daemon.md)
inst 0644 "$repo/systemd/tofproxd.service" usr/lib/systemd/system/tofproxd.service
inst 0644 "$repo/systemd/org.tofprox.Proximity1.conf" usr/share/dbus-1/system.d/org.tofprox.Proximity1.conf
inst 0644 "$repo/systemd/org.tofprox.Proximity1.xml" usr/share/dbus-1/interfaces/org.tofprox.Proximity1.xml
inst 0644 "$repo/systemd/70-tofprox.rules" usr/lib/udev/rules.d/70-tofprox.rules
inst 0644 "$repo/systemd/tofproxd.sysusers.conf" usr/lib/sysusers.d/tofprox.conf
inst 0644 "$repo/systemd/tofproxd.tmpfiles.conf" usr/lib/tmpfiles.d/tofprox.conf
# the V4L2 backend's drop-in (/dev/videoN), shipped inactive: docs/daemon.md, V4L2 step 0
inst 0644 "$repo/systemd/tofproxd.service.d/v4l2.conf" usr/share/tofprox/systemd/tofproxd.service.d/v4l2.conf
# the default configuration (USB backend), a conffile
inst 0644 "$repo/config/tofproxd.toml" etc/tofprox/tofproxd.toml
# shipped data, laid out as in the repository (tofproxd::data): the demo configuration,
# model and sensor files, the emulated sensors' factory calibrations
mkdir -p "$pkg/usr/share/tofprox"
cp -r "$repo/config" "$pkg/usr/share/tofprox/config"
for set in emulated phone example; do
  mkdir -p "$pkg/usr/share/tofprox/calib/$set"
  find "$repo/calib/$set" -maxdepth 1 -type f ! -name make.sh \
    -exec install -m 0644 -t "$pkg/usr/share/tofprox/calib/$set" {} +
done
# the example recording the README's tour and docs/lab.md start from (as in the repository:
# from /usr/share/tofprox the tour's relative paths work)
cp -r "$repo/examples" "$pkg/usr/share/tofprox/examples"
# manual pages from the clap definitions
man_dir="$stage/man"
"$profile/tofprox" man --out "$man_dir/man1"
"$profile/tofproxd" --man "$man_dir/man8" >/dev/null
for f in "$man_dir"/man*/*; do
  sec="$(basename "$(dirname "$f")")"
  mkdir -p "$pkg/usr/share/man/$sec"
  gzip -9n <"$f" >"$pkg/usr/share/man/$sec/$(basename "$f").gz"
done
# documentation, laid out as in the repository so the README's links and the help texts'
# `docs/….md` resolve under /usr/share/doc/tofprox (the unit's Documentation= names
# docs/daemon.md)
inst 0644 "$repo/README.md" usr/share/doc/tofprox/README.md
cp -r "$repo/docs" "$pkg/usr/share/doc/tofprox/docs"
inst 0644 "$repo/packaging/copyright" usr/share/doc/tofprox/copyright
find "$pkg" -type d -exec chmod 0755 {} +
find "$pkg/usr/share" "$pkg/etc" -type f -exec chmod 0644 {} +

# control files
mkdir -p "$pkg/DEBIAN"
installed_kb="$(du -sk --exclude=DEBIAN "$pkg" | cut -f1)"
sed -e "s/@VERSION@/$version/" -e "s/@ARCH@/$arch/" -e "s/@SIZE@/$installed_kb/" \
  "$repo/packaging/control" >"$pkg/DEBIAN/control"
echo /etc/tofprox/tofproxd.toml >"$pkg/DEBIAN/conffiles"
for s in postinst prerm postrm; do
  install -m 0755 "$repo/packaging/$s" "$pkg/DEBIAN/$s"
done

mkdir -p "$out_dir"
deb="$out_dir/tofprox_${version}_${arch}.deb"
# gzip: a debug build's binaries would take minutes with xz; DEB_COMPRESS=xz for a release
dpkg-deb --root-owner-group -Z"${DEB_COMPRESS:-gzip}" --build "$pkg" "$deb" >/dev/null
echo "$deb"
