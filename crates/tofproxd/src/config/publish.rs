//! The publishers' tables: `[dbus]` and `[socket]`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::error::{ConfigError, finite_pos, range};

/// `[dbus]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DbusConfig {
    /// Also own `net.hadess.SensorProxy` (iio-sensor-proxy compatibility).
    pub iio_sensor_proxy_compat: bool,
    /// Files whose presence means iio-sensor-proxy is installed (its binary, its unit): the
    /// compatibility mode refuses to start beside it. A unit masked in `/etc/systemd/system`
    /// (a link to `/dev/null`) does not count. Empty: no check.
    pub iio_sensor_proxy_paths: Vec<PathBuf>,
    /// Maximum DepthFrame signal rate (Hz).
    pub depth_max_hz: f64,
}

impl Default for DbusConfig {
    fn default() -> Self {
        Self {
            iio_sensor_proxy_compat: false,
            iio_sensor_proxy_paths: [
                "/usr/libexec/iio-sensor-proxy",
                "/usr/sbin/iio-sensor-proxy",
                "/usr/lib/iio-sensor-proxy/iio-sensor-proxy",
                "/usr/lib/systemd/system/iio-sensor-proxy.service",
                "/lib/systemd/system/iio-sensor-proxy.service",
            ]
            .into_iter()
            .map(PathBuf::from)
            .collect(),
            depth_max_hz: 5.0,
        }
    }
}

/// `[socket]`: the socket publisher (`publisher = "socket"`, docs/daemon.md "The socket
/// publisher").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SocketConfig {
    /// The Unix stream socket's path (its directory must exist: systemd's
    /// `RuntimeDirectory=tofprox` makes `/run/tofprox`).
    pub path: PathBuf,
    /// The socket file's permission bits (TOML octal, `0o660`: the daemon's user and group
    /// may connect; `0o666`: anyone). At most `0o777`.
    pub mode: u32,
    /// Most clients connected at once (1–256).
    pub max_clients: usize,
    /// Lines queued per client before a client that does not read is disconnected
    /// (1–65536).
    pub queue_lines: usize,
}

impl Default for SocketConfig {
    fn default() -> Self {
        Self {
            path: PathBuf::from("/run/tofprox/proximity.sock"),
            mode: 0o660,
            max_clients: 16,
            queue_lines: 256,
        }
    }
}

/// Most clients `[socket] max_clients` allows.
pub const SOCKET_MAX_CLIENTS: usize = 256;
/// Most lines `[socket] queue_lines` allows per client.
pub const SOCKET_MAX_QUEUE_LINES: usize = 65_536;

impl SocketConfig {
    /// Range-check the `[socket]` table; the error names the key.
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        range(
            "socket.path",
            !self.path.as_os_str().is_empty(),
            "must not be empty",
        )?;
        range(
            "socket.mode",
            self.mode <= 0o777,
            format!("must be permission bits within 0o777, got {:#o}", self.mode),
        )?;
        range(
            "socket.max_clients",
            (1..=SOCKET_MAX_CLIENTS).contains(&self.max_clients),
            format!(
                "must be within 1..={SOCKET_MAX_CLIENTS}, got {}",
                self.max_clients
            ),
        )?;
        range(
            "socket.queue_lines",
            (1..=SOCKET_MAX_QUEUE_LINES).contains(&self.queue_lines),
            format!(
                "must be within 1..={SOCKET_MAX_QUEUE_LINES}, got {}",
                self.queue_lines
            ),
        )
    }
}

impl DbusConfig {
    /// Range-check the `[dbus]` table; the error names the key.
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        finite_pos("dbus.depth_max_hz", self.depth_max_hz)?;
        range(
            "dbus.depth_max_hz",
            self.depth_max_hz <= 60.0,
            "must be at most 60 Hz",
        )?;
        Ok(())
    }
}
