//! A private `dbus-daemon` per test: a session bus, or a bus of a configuration the test
//! writes (the shipped system-bus policy). Killed when dropped.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};

use crate::ci::require_program;

/// A running private bus and its address (`unix:path=…`).
pub struct PrivateBus {
    child: Child,
    address: String,
    /// The directory of its configuration and socket (configured buses).
    _dir: Option<tempfile::TempDir>,
}

impl Drop for PrivateBus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl PrivateBus {
    /// A private session bus; `None` without `dbus-daemon` (the missing-tool rule:
    /// [`crate::require_program`]).
    pub fn session() -> Option<Self> {
        let dbus_daemon = require_program("dbus-daemon", "dbus-daemon")?;
        let mut cmd = Command::new(dbus_daemon);
        cmd.args(["--session", "--print-address", "--nofork"])
            .stderr(Stdio::null());
        Some(Self::start(cmd, None))
    }

    /// A bus of the configuration `config(socket)` returns for a socket path in a fresh
    /// directory readable by every user (clients may run as `nobody`); the bus's own
    /// messages go to the test's stderr. `None` without `dbus-daemon`.
    pub fn configured(config: impl FnOnce(&Path) -> String) -> Option<Self> {
        use std::os::unix::fs::PermissionsExt;
        let dbus_daemon = require_program("dbus-daemon", "dbus-daemon")?;
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755))
            .expect("chmod");
        let conf = dir.path().join("bus.conf");
        std::fs::write(&conf, config(&dir.path().join("bus"))).expect("write bus config");
        let mut cmd = Command::new(dbus_daemon);
        cmd.arg(format!("--config-file={}", conf.display()))
            .args(["--nofork", "--print-address"])
            .stderr(Stdio::inherit());
        Some(Self::start(cmd, Some(dir)))
    }

    /// Spawn the daemon and read the address it prints first.
    fn start(mut cmd: Command, dir: Option<tempfile::TempDir>) -> Self {
        let mut child = cmd
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn dbus-daemon");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("piped stdout"))
            .read_line(&mut line)
            .expect("bus address");
        let address = line.trim().to_string();
        assert!(!address.is_empty(), "dbus-daemon printed no address");
        PrivateBus {
            child,
            address,
            _dir: dir,
        }
    }

    /// The bus's address, for `--bus`, `busctl --address`, `DBUS_*_BUS_ADDRESS`.
    pub fn address(&self) -> &str {
        &self.address
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A session bus answers: `dbus-send` lists its names (the bus's own among them).
    #[test]
    fn a_session_bus_answers_at_its_address() {
        let Some(send) = require_program("dbus-send", "dbus-bin") else {
            return;
        };
        let Some(bus) = PrivateBus::session() else {
            return;
        };
        assert!(bus.address().starts_with("unix:"), "{}", bus.address());
        let out = Command::new(send)
            .arg(format!("--bus={}", bus.address()))
            .args([
                "--print-reply",
                "--dest=org.freedesktop.DBus",
                "/org/freedesktop/DBus",
                "org.freedesktop.DBus.ListNames",
            ])
            .output()
            .expect("dbus-send");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{text}");
        assert!(text.contains("org.freedesktop.DBus"), "{text}");
    }
}
