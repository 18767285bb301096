//! Running the daemon: bus connection and names, the loop thread (blocking
//! bridge calls never run on the tokio runtime), the publisher, client
//! tracking, sd-notify (READY/STATUS/WATCHDOG) and the clean stop (the binary calls
//! [`Daemon::shutdown`] on every terminating signal).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc as stdmpsc;
use std::time::Duration;

use tokio::sync::watch;
use zbus::Connection;
use zbus::fdo::{RequestNameFlags, RequestNameReply};

use crate::config::{Config, DbusConfig, PublisherKind};
use crate::controller::Controller;
use crate::hub::{Demand, EventSender, Hub, State, StatusUpdate, event_channel};
use crate::input::{DeviceDescription, InputError, InputPublisher, SwitchDevice, UinputDevice};
use crate::publisher::dbus::DbusPublisher;
use crate::publisher::socket::{SocketError, SocketPublisher};
use crate::publisher::{Publisher, Publishers, run_publishers};
use crate::service::{
    self, COMPAT_BUS_NAME, COMPAT_COMPASS_PATH, COMPAT_PATH, OBJECT_PATH, Proximity,
    ReadOnlyProperties, SensorProxyCompass, SensorProxyCompat,
};
use crate::source::FrameSource;

/// Which bus to use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BusChoice {
    /// The session bus.
    Session,
    /// The system bus (default for the service).
    System,
    /// An explicit D-Bus address (`unix:path=…`).
    Address(String),
}

impl std::str::FromStr for BusChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "session" => BusChoice::Session,
            "system" => BusChoice::System,
            a if a.contains(':') => BusChoice::Address(a.to_string()),
            other => {
                return Err(format!(
                    "--bus: expected session, system or a D-Bus address, got {other:?}"
                ));
            }
        })
    }
}

/// Errors of the daemon run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Connecting to the bus failed.
    #[error("cannot connect to the {bus} bus: {source}")]
    Connect {
        /// Which bus.
        bus: String,
        /// zbus error.
        source: zbus::Error,
    },
    /// The bus name is owned by someone else.
    #[error(
        "the bus name {name} is already owned by another process (is another {what} running?); not taking it over"
    )]
    NameTaken {
        /// The name.
        name: &'static str,
        /// Likely owner.
        what: &'static str,
    },
    /// Compatibility mode asked for where iio-sensor-proxy is installed or running.
    #[error(
        "iio-sensor-proxy is {found}: the compatibility mode would take net.hadess.SensorProxy from it, and with it the accelerometer and light sensor it serves. Use the input publisher instead (`publisher = \"input\"`, `[dbus] iio_sensor_proxy_compat = false`): iio-sensor-proxy then reads our proximity from a uinput switch (docs/daemon.md, \"Beside iio-sensor-proxy\"). Installed means one of `[dbus] iio_sensor_proxy_paths` exists"
    )]
    BesideIioSensorProxy {
        /// "installed (`<path>`)" or "running (it owns net.hadess.SensorProxy)".
        found: String,
    },
    /// `publisher = "socket"`: the socket cannot be served.
    #[error("socket publisher: {0}")]
    Socket(#[from] SocketError),
    /// Started without a bus, but the configured publisher is D-Bus.
    #[error(
        "publisher = \"dbus\" and \"input\" publish on D-Bus: only publisher = \"socket\" runs without a bus"
    )]
    NeedsBus,
    /// The input publisher's uinput device could not be made.
    #[error("input publisher: {0}")]
    Input(#[from] InputError),
    /// Any other D-Bus failure.
    #[error("D-Bus: {0}")]
    Dbus(#[from] zbus::Error),
    /// The loop thread could not start.
    #[error("loop thread: {0}")]
    Thread(std::io::Error),
}

/// Connect to the chosen bus.
pub async fn connect(bus: &BusChoice) -> Result<Connection, RunError> {
    let (builder, what) = match bus {
        BusChoice::Session => (zbus::connection::Builder::session(), "session".to_string()),
        BusChoice::System => (zbus::connection::Builder::system(), "system".to_string()),
        BusChoice::Address(a) => (zbus::connection::Builder::address(a.as_str()), a.clone()),
    };
    builder
        .build()
        .await
        .map_err(|source| RunError::Connect { bus: what, source })
}

/// Request a name without queueing and without replacing anyone.
async fn request_name(
    conn: &Connection,
    name: &'static str,
    what: &'static str,
) -> Result<(), RunError> {
    match conn
        .request_name_with_flags(name, RequestNameFlags::DO_NOT_QUEUE)
        .await
    {
        Ok(RequestNameReply::PrimaryOwner | RequestNameReply::AlreadyOwner) => Ok(()),
        Ok(RequestNameReply::Exists | RequestNameReply::InQueue) | Err(zbus::Error::NameTaken) => {
            Err(RunError::NameTaken { name, what })
        }
        Err(e) => Err(e.into()),
    }
}

/// The first of `dbus.iio_sensor_proxy_paths` that exists: iio-sensor-proxy is installed.
pub fn iio_sensor_proxy_installed(dbus: &DbusConfig) -> Option<&Path> {
    dbus.iio_sensor_proxy_paths
        .iter()
        .map(PathBuf::as_path)
        .find(|p| p.symlink_metadata().is_ok())
}

/// The compatibility mode never starts beside iio-sensor-proxy: refused when it is installed
/// (a phone whose other sensors it serves would lose them whenever we start first).
pub fn refuse_compat_beside_iio_sensor_proxy(dbus: &DbusConfig) -> Result<(), RunError> {
    match iio_sensor_proxy_installed(dbus) {
        Some(p) if dbus.iio_sensor_proxy_compat => Err(RunError::BesideIioSensorProxy {
            found: format!("installed ({})", p.display()),
        }),
        _ => Ok(()),
    }
}

/// Why the daemon cannot start with a config (every check [`prepare`] runs).
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// The frame source cannot be built (replay directory, emulated device file or table,
    /// USB driver config).
    #[error("frame source: {0}")]
    Source(#[source] crate::source::SourceError),
    /// The calibration set cannot be loaded or does not fit the sensor or mode.
    #[error("calibration: {0}")]
    Calibration(#[source] crate::calibration::CalibrationError),
    /// The controller refused the config (ROI outside the sensor, calibration of the other mode).
    #[error("{0}")]
    Controller(#[source] crate::controller::ControllerError),
    /// The compatibility mode asked for where iio-sensor-proxy is installed.
    #[error("{0}")]
    Compat(#[source] RunError),
}

/// Everything the start does before touching the bus: refuse the compatibility mode beside an
/// installed iio-sensor-proxy, build the frame source (a USB
/// device is opened only at the first cycle), load and check the calibration against the
/// sensor, build the controller. `tofproxd --check-config` runs exactly this, so a config it
/// accepts is one the daemon starts with. `base`: the config file's directory.
pub fn prepare(
    cfg: &Config,
    base: &std::path::Path,
) -> Result<Controller<Box<dyn FrameSource>>, StartError> {
    refuse_compat_beside_iio_sensor_proxy(&cfg.dbus).map_err(StartError::Compat)?;
    let source = crate::backends::build_source(cfg, base).map_err(StartError::Source)?;
    let calib = crate::calibration::load_for(cfg, &*source).map_err(StartError::Calibration)?;
    Controller::new(cfg.clone(), source, calib).map_err(StartError::Controller)
}

/// Commands to the loop thread.
#[derive(Debug, Clone, Copy)]
pub enum LoopCmd {
    /// New client demand.
    Demand(Demand),
    /// Stop the loop (sensor to reset) and exit the thread.
    Shutdown,
}

/// The loop thread body: runs cycles while demanded (or always-on), sleeps between
/// cycles with exactly one timed wait per cycle, blocks without any timer while idle.
pub fn loop_thread<S: FrameSource>(
    mut ctl: Controller<S>,
    always_on: bool,
    cmds: stdmpsc::Receiver<LoopCmd>,
    mut events: EventSender,
    health: Arc<LoopHealth>,
) {
    let mut demand = Demand::default();
    let mut active = false;
    let mut next_at = std::time::Instant::now();
    loop {
        let want = always_on || demand.any();
        if !want {
            if active {
                events.status(ctl.stop());
                active = false;
            }
            // Idle: block without any timer until a client claims.
            match cmds.recv() {
                Ok(LoopCmd::Demand(d)) => demand = d,
                Ok(LoopCmd::Shutdown) | Err(_) => break,
            }
            match latest_demand(&cmds, demand) {
                Some(d) => demand = d,
                None => break,
            }
            continue;
        }
        // no cycle without a claim: the demand may have gone while the last one ran
        match latest_demand(&cmds, demand) {
            Some(d) => demand = d,
            None => break,
        }
        if !(always_on || demand.any()) {
            continue;
        }
        // Sleep until the cycle's time: one timed wait; a demand change wakes us early only
        // when it stops the loop. A claim right after a release waits for the time too, so a
        // churn of claims never runs the loop faster than its rate.
        match wait_until(&cmds, next_at, &mut demand, always_on) {
            Waited::Due => {}
            Waited::DemandGone => continue,
            Waited::Shutdown => break,
        }
        if !active {
            active = true;
            events.status(StatusUpdate {
                state: Some(State::Starting),
                ..StatusUpdate::default()
            });
        }
        health.enter();
        let out = ctl.step(demand.depth);
        health.leave();
        if let Some(d) = out.depth {
            events.depth(d);
        }
        events.status(out.update);
        // the energy meter's total (`GetStatus()["EnergyMj"]`)
        events.energy(ctl.energy().total_mj());
        if out.end_of_data {
            tracing::info!("source has no more data: loop stopped");
            events.status(ctl.stop());
            // Wait for shutdown only.
            loop {
                match cmds.recv() {
                    Ok(LoopCmd::Shutdown) | Err(_) => return,
                    Ok(LoopCmd::Demand(_)) => {}
                }
            }
        }
        // the next cycle's time: waited for at the top, also after a stop and a new claim
        next_at = std::time::Instant::now() + out.sleep;
    }
    events.status(ctl.stop());
}

/// How a wait for the next cycle ended.
enum Waited {
    /// The cycle's time came with a claim held.
    Due,
    /// The last claim went.
    DemandGone,
    /// Shut down.
    Shutdown,
}

/// Wait until `deadline` (one timed wait), following the latest demand on the way.
fn wait_until(
    cmds: &stdmpsc::Receiver<LoopCmd>,
    deadline: std::time::Instant,
    demand: &mut Demand,
    always_on: bool,
) -> Waited {
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            return Waited::Due;
        }
        match cmds.recv_timeout(left) {
            Ok(LoopCmd::Demand(d)) => {
                let Some(d) = latest_demand(cmds, d) else {
                    return Waited::Shutdown;
                };
                *demand = d;
                if !(always_on || demand.any()) {
                    return Waited::DemandGone;
                }
            }
            Ok(LoopCmd::Shutdown) | Err(stdmpsc::RecvTimeoutError::Disconnected) => {
                return Waited::Shutdown;
            }
            Err(stdmpsc::RecvTimeoutError::Timeout) => return Waited::Due,
        }
    }
}

/// The latest demand: every command already queued behind `current` is taken at once, so a
/// churn of claims and releases costs the loop nothing but this drain — it acts on the last
/// demand only, and never runs a cycle for a claim that is already gone (issue 34). `None`:
/// shut down.
fn latest_demand(cmds: &stdmpsc::Receiver<LoopCmd>, current: Demand) -> Option<Demand> {
    let mut demand = current;
    loop {
        match cmds.try_recv() {
            Ok(LoopCmd::Demand(d)) => demand = d,
            Ok(LoopCmd::Shutdown) | Err(stdmpsc::TryRecvError::Disconnected) => return None,
            Err(stdmpsc::TryRecvError::Empty) => return Some(demand),
        }
    }
}

/// Progress of the loop thread (for the watchdog).
#[derive(Debug)]
pub struct LoopHealth {
    start: std::time::Instant,
    /// ms since `start` when the current cycle began + 1; 0 = not inside a cycle.
    busy_since_ms: std::sync::atomic::AtomicU64,
}

impl LoopHealth {
    fn new() -> Self {
        Self {
            start: std::time::Instant::now(),
            busy_since_ms: std::sync::atomic::AtomicU64::new(0),
        }
    }
    fn now_ms(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_millis()).unwrap_or(u64::MAX - 1)
    }
    fn enter(&self) {
        self.busy_since_ms
            .store(self.now_ms() + 1, std::sync::atomic::Ordering::Relaxed);
    }
    fn leave(&self) {
        self.busy_since_ms
            .store(0, std::sync::atomic::Ordering::Relaxed);
    }
    /// How long the current cycle has been running, if inside one.
    pub fn busy_for(&self) -> Option<Duration> {
        match self
            .busy_since_ms
            .load(std::sync::atomic::Ordering::Relaxed)
        {
            0 => None,
            t => Some(Duration::from_millis(self.now_ms().saturating_sub(t - 1))),
        }
    }
}

/// A running daemon (for tests and the binary).
pub struct Daemon {
    /// The bus connection (none with [`Daemon::start_without_bus`]).
    conn: Option<Connection>,
    hub: Arc<Hub>,
    cmd_tx: stdmpsc::Sender<LoopCmd>,
    thread: Option<std::thread::JoinHandle<()>>,
    health: Arc<LoopHealth>,
    /// The publishing task: ends once the loop thread (the only event sender) has ended and
    /// every event it sent is published.
    publisher: Option<tokio::task::JoinHandle<()>>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    compat: bool,
}

impl Daemon {
    /// Serve on `conn`: export the objects, take the names, start the loop; with
    /// `publisher = "input"` also on a uinput device made here ([`crate::input`]), with
    /// `publisher = "socket"` also on the socket of `[socket]` (the binary starts that one with
    /// [`Daemon::start_without_bus`] instead: no bus at all).
    pub async fn start<S: FrameSource + 'static>(
        conn: Connection,
        cfg: &Config,
        ctl: Controller<S>,
    ) -> Result<Self, RunError> {
        refuse_compat_beside_iio_sensor_proxy(&cfg.dbus)?;
        let input: Option<Box<dyn SwitchDevice>> = match cfg.publisher {
            PublisherKind::Dbus | PublisherKind::Socket => None,
            PublisherKind::Input => Some(Box::new(UinputDevice::create(
                Path::new(crate::input::UINPUT_PATH),
                &DeviceDescription::proximity(),
            )?)),
        };
        Self::start_with_input(conn, cfg, ctl, input).await
    }

    /// [`Daemon::start`] with the input publisher's device given (`None`: D-Bus only); the
    /// loop then runs without a claim, as no claim reaches us through an input device.
    pub async fn start_with_input<S: FrameSource + 'static>(
        conn: Connection,
        cfg: &Config,
        ctl: Controller<S>,
        input: Option<Box<dyn SwitchDevice>>,
    ) -> Result<Self, RunError> {
        refuse_compat_beside_iio_sensor_proxy(&cfg.dbus)?;
        let input = input.map(|d| Box::new(InputPublisher::new(d)) as Box<dyn Publisher>);
        Self::launch(Some(conn), cfg, ctl, input).await
    }

    /// `publisher = "socket"` with no D-Bus at all: no bus connection is made, the readings
    /// go to the socket's clients only, and a connected client is the proximity claim.
    pub async fn start_without_bus<S: FrameSource + 'static>(
        cfg: &Config,
        ctl: Controller<S>,
    ) -> Result<Self, RunError> {
        if cfg.publisher != PublisherKind::Socket {
            return Err(RunError::NeedsBus);
        }
        Self::launch(None, cfg, ctl, None).await
    }

    /// Build the publishers (D-Bus on `conn`, then `extra` — the input switch, which claims
    /// for itself: the loop always runs —, then the socket with `publisher = "socket"`) and
    /// start the publishing task and the loop thread.
    async fn launch<S: FrameSource + 'static>(
        conn: Option<Connection>,
        cfg: &Config,
        ctl: Controller<S>,
        extra: Option<Box<dyn Publisher>>,
    ) -> Result<Self, RunError> {
        let backend = ctl.source().describe();
        let (hub, demand_rx) = Hub::new(cfg, backend);
        let compat = cfg.dbus.iio_sensor_proxy_compat;
        // the socket first: a path in use fails the start before any bus name is taken
        let socket = match cfg.publisher {
            PublisherKind::Socket => Some(SocketPublisher::bind(&cfg.socket, hub.clone())?),
            PublisherKind::Dbus | PublisherKind::Input => None,
        };
        let mut publishers: Publishers = Vec::new();
        let mut tasks = Vec::new();
        if let Some(conn) = &conn {
            tasks = serve_objects(conn, &hub, compat).await?;
            publishers.push(Box::new(DbusPublisher::new(
                conn.clone(),
                hub.clone(),
                compat,
            )));
        }
        let always_on = cfg.loop_.always_on || extra.is_some();
        publishers.extend(extra);
        publishers.extend(socket.map(|s| Box::new(s) as Box<dyn Publisher>));
        let (ev_tx, ev_rx) = event_channel();
        let publisher = Some(tokio::spawn(run_publishers(
            hub.clone(),
            ev_rx,
            publishers,
            cfg.dbus.depth_max_hz,
        )));
        let (cmd_tx, cmd_rx) = stdmpsc::channel();
        let health = Arc::new(LoopHealth::new());
        let loop_health = health.clone();
        let thread = std::thread::Builder::new()
            .name("tofproxd-loop".into())
            .spawn(move || loop_thread(ctl, always_on, cmd_rx, ev_tx, loop_health))
            .map_err(RunError::Thread)?;
        // Forward demand changes (async watch) to the loop thread (std channel).
        let fwd_tx = cmd_tx.clone();
        tasks.push(tokio::spawn(forward_demand(demand_rx, fwd_tx)));
        Ok(Self {
            conn,
            hub,
            cmd_tx,
            thread: Some(thread),
            health,
            publisher,
            tasks,
            compat,
        })
    }

    /// Whether the loop thread is healthy: not stuck inside one cycle for longer than
    /// `max` (the watchdog is only fed while this holds, so systemd restarts a hung loop).
    pub fn loop_healthy(&self, max: Duration) -> bool {
        self.health.busy_for().is_none_or(|d| d <= max)
    }

    /// The hub (status and claims).
    pub fn hub(&self) -> &Arc<Hub> {
        &self.hub
    }

    /// The bus connection (`None`: started without a bus).
    pub fn connection(&self) -> Option<&Connection> {
        self.conn.as_ref()
    }

    /// Stop the loop (sensor reset low), release the names.
    pub async fn shutdown(mut self) {
        let _ = self.cmd_tx.send(LoopCmd::Shutdown);
        if let Some(t) = self.thread.take() {
            let _ = tokio::task::spawn_blocking(move || t.join()).await;
        }
        // The loop thread held the only event sender: the publisher ends once it has
        // published the final Off state (bounded, should it be stuck on the bus).
        if let Some(mut p) = self.publisher.take()
            && tokio::time::timeout(Duration::from_secs(2), &mut p)
                .await
                .is_err()
        {
            p.abort();
        }
        if let Some(conn) = self.conn.as_ref().filter(|c| c.is_bus()) {
            let _ = conn.release_name(service::BUS_NAME).await;
            if self.compat {
                let _ = conn.release_name(COMPAT_BUS_NAME).await;
            }
        }
        for t in self.tasks.drain(..) {
            t.abort();
        }
    }
}

/// Export the objects and, on a bus, follow client departures and take the names (the
/// compat name never from a running iio-sensor-proxy). Returns the client-tracking task.
async fn serve_objects(
    conn: &Connection,
    hub: &Arc<Hub>,
    compat: bool,
) -> Result<Vec<tokio::task::JoinHandle<()>>, RunError> {
    let server = conn.object_server();
    server
        .at(OBJECT_PATH, ReadOnlyProperties(Proximity::new(hub.clone())))
        .await?;
    if compat {
        server
            .at(
                COMPAT_PATH,
                ReadOnlyProperties(SensorProxyCompat::new(hub.clone())),
            )
            .await?;
        server
            .at(COMPAT_COMPASS_PATH, ReadOnlyProperties(SensorProxyCompass))
            .await?;
    }
    let mut tasks = Vec::new();
    if conn.is_bus() {
        // Subscribe before taking the name so no departing client is missed.
        let stream = service::subscribe_clients(conn).await?;
        tasks.push(tokio::spawn(service::watch_clients(stream, hub.clone())));
        request_name(conn, service::BUS_NAME, "tofproxd").await?;
        if compat && let Err(e) = request_name(conn, COMPAT_BUS_NAME, "iio-sensor-proxy").await {
            let _ = conn.release_name(service::BUS_NAME).await;
            return Err(match e {
                RunError::NameTaken { .. } => RunError::BesideIioSensorProxy {
                    found: format!("running (it owns {COMPAT_BUS_NAME})"),
                },
                e => e,
            });
        }
    }
    Ok(tasks)
}

async fn forward_demand(mut rx: watch::Receiver<Demand>, tx: stdmpsc::Sender<LoopCmd>) {
    loop {
        let d = *rx.borrow_and_update();
        if tx.send(LoopCmd::Demand(d)).is_err() {
            break;
        }
        if rx.changed().await.is_err() {
            break;
        }
    }
}

/// sd-notify helpers (no-ops outside systemd).
pub mod notify {
    /// READY=1 with a status line.
    pub fn ready(status: &str) {
        let _ = sd_notify::notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(status),
        ]);
    }
    /// STATUS=…
    pub fn status(status: &str) {
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(status)]);
    }
    /// STOPPING=1
    pub fn stopping() {
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    }
    /// WATCHDOG=1
    pub fn watchdog() {
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
    }
    /// The watchdog interval systemd asked for, if any.
    pub fn watchdog_interval() -> Option<std::time::Duration> {
        sd_notify::watchdog_enabled()
    }
}
