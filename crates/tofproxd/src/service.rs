//! The D-Bus service: `org.tofprox.Proximity1` (and the iio-sensor-proxy
//! compatible `net.hadess.SensorProxy`), claims per unique bus name, and the
//! publisher that turns loop events into property changes and signals.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use zbus::names::InterfaceName;
use zbus::object_server::SignalEmitter;
use zbus::{Connection, OwnedVariant, Str, Variant, fdo, interface, message::Header};

use crate::config::{Config, Mode};

/// Bus name of the native interface.
pub const BUS_NAME: &str = "org.tofprox.Proximity1";
/// Object path of the native interface.
pub const OBJECT_PATH: &str = "/org/tofprox/Proximity1";
/// Interface name.
pub const INTERFACE: &str = "org.tofprox.Proximity1";
/// iio-sensor-proxy bus name.
pub const COMPAT_BUS_NAME: &str = "net.hadess.SensorProxy";
/// iio-sensor-proxy object path.
pub const COMPAT_PATH: &str = "/net/hadess/SensorProxy";
/// iio-sensor-proxy compass object path.
pub const COMPAT_COMPASS_PATH: &str = "/net/hadess/SensorProxy/Compass";

/// Service state (the `State` property).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Sensor held in reset (no claim).
    Off,
    /// Claimed, no valid reading yet.
    Starting,
    /// Readings flowing.
    Running,
    /// The last cycle failed; retrying.
    Error,
    /// Several cycles in a row failed (device gone?); retrying.
    Unavailable,
}

impl State {
    /// The property string.
    pub fn as_str(self) -> &'static str {
        match self {
            State::Off => "off",
            State::Starting => "starting",
            State::Running => "running",
            State::Error => "error",
            State::Unavailable => "unavailable",
        }
    }
}

/// What the clients currently want from the loop.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Demand {
    /// Someone claims proximity (native or compat).
    pub proximity: bool,
    /// Someone claims depth frames.
    pub depth: bool,
}

impl Demand {
    /// Whether the loop must run.
    pub fn any(self) -> bool {
        self.proximity || self.depth
    }
}

/// Everything the properties show.
#[derive(Debug, Clone, PartialEq)]
pub struct Status {
    /// `HasSensor`.
    pub has_sensor: bool,
    /// `State`.
    pub state: State,
    /// `Near`.
    pub near: bool,
    /// `DistanceMm` (0 = unknown).
    pub distance_mm: u32,
    /// `NearThresholdMm`.
    pub near_threshold_mm: u32,
    /// `FarThresholdMm`.
    pub far_threshold_mm: u32,
    /// `Mode`.
    pub mode: Mode,
    /// `RateHz`.
    pub rate_hz: f64,
    /// `PowerEstimateMw`.
    pub power_mw: f64,
    /// `LastError`.
    pub last_error: String,
    /// Exposure per raw image (µs).
    pub exposure_us: f64,
    /// Cycles run.
    pub cycles: u64,
    /// Valid readings.
    pub valid_readings: u64,
    /// Failed cycles.
    pub errors: u64,
    /// Backend description.
    pub backend: String,
    /// How near readings are checked for plausibility (thesis 2.2.1): `"calibrated"` (the
    /// calibration's amplitude scale), `"nominal"` (no amplitude calibration: the config's
    /// nominal scale), `""` before the first cycle.
    pub amplitude_check: &'static str,
}

/// Per-client claims.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct ClientClaims {
    proximity: bool,
    depth: bool,
    compat_proximity: bool,
}

impl ClientClaims {
    fn any(self) -> bool {
        self.proximity || self.depth || self.compat_proximity
    }
}

struct HubInner {
    status: Status,
    claims: BTreeMap<String, ClientClaims>,
    /// A valid reading exists since the loop last started.
    have_reading: bool,
}

/// Shared between the D-Bus interfaces, the publisher and the loop.
pub struct Hub {
    inner: Mutex<HubInner>,
    demand_tx: watch::Sender<Demand>,
    /// Incremented on every valid reading.
    reading_tx: watch::Sender<u64>,
    first_reading_timeout: Duration,
}

/// Claim counts (for `GetStatus` and leak checks).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClaimCounts {
    /// Clients with any claim.
    pub clients: u32,
    /// Proximity claims (native).
    pub proximity: u32,
    /// Depth claims.
    pub depth: u32,
    /// Compat proximity claims.
    pub compat_proximity: u32,
}

impl Hub {
    /// New hub for `cfg`, with the demand receiver for the loop.
    pub fn new(cfg: &Config, backend: String) -> (Arc<Self>, watch::Receiver<Demand>) {
        let (demand_tx, demand_rx) = watch::channel(Demand::default());
        let (reading_tx, _) = watch::channel(0u64);
        let status = Status {
            has_sensor: true,
            state: State::Off,
            near: false,
            distance_mm: 0,
            near_threshold_mm: cfg.proximity.near_mm,
            far_threshold_mm: cfg.proximity.far_mm,
            mode: cfg.processing.mode,
            rate_hz: 0.0,
            power_mw: 0.0,
            last_error: String::new(),
            exposure_us: cfg.exposure.initial_us,
            cycles: 0,
            valid_readings: 0,
            errors: 0,
            backend,
            amplitude_check: "",
        };
        let hub = Arc::new(Self {
            inner: Mutex::new(HubInner {
                status,
                claims: BTreeMap::new(),
                have_reading: false,
            }),
            demand_tx,
            reading_tx,
            first_reading_timeout: Duration::from_millis(cfg.loop_.first_reading_timeout_ms),
        });
        (hub, demand_rx)
    }

    fn lock(&self) -> MutexGuard<'_, HubInner> {
        // A poisoned lock only means a panic elsewhere while holding it; the data is plain values.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Snapshot of the status.
    pub fn status(&self) -> Status {
        self.lock().status.clone()
    }

    /// Claim counts.
    pub fn claim_counts(&self) -> ClaimCounts {
        let g = self.lock();
        let mut c = ClaimCounts::default();
        for cl in g.claims.values() {
            c.clients += 1;
            c.proximity += u32::from(cl.proximity);
            c.depth += u32::from(cl.depth);
            c.compat_proximity += u32::from(cl.compat_proximity);
        }
        c
    }

    /// Current demand.
    pub fn demand(&self) -> Demand {
        *self.demand_tx.borrow()
    }

    fn recompute_demand(&self, g: &HubInner) {
        let d = Demand {
            proximity: g.claims.values().any(|c| c.proximity || c.compat_proximity),
            depth: g.claims.values().any(|c| c.depth),
        };
        self.demand_tx.send_if_modified(|cur| {
            if *cur != d {
                *cur = d;
                true
            } else {
                false
            }
        });
    }

    fn modify_claim(&self, client: &str, f: impl FnOnce(&mut ClientClaims)) {
        let mut g = self.lock();
        let entry = g.claims.entry(client.to_string()).or_default();
        f(entry);
        if !entry.any() {
            g.claims.remove(client);
        }
        self.recompute_demand(&g);
    }

    /// Drop every claim of a client (it left the bus).
    pub fn client_gone(&self, client: &str) -> bool {
        let mut g = self.lock();
        let had = g.claims.remove(client).is_some();
        if had {
            self.recompute_demand(&g);
        }
        had
    }

    /// Names of clients holding claims.
    pub fn clients(&self) -> Vec<String> {
        self.lock().claims.keys().cloned().collect()
    }

    /// Wait (bounded) until a valid reading exists since the loop started.
    async fn wait_first_reading(&self) {
        let mut rx = self.reading_tx.subscribe();
        if self.lock().have_reading {
            return;
        }
        let start = *rx.borrow_and_update();
        let _ =
            tokio::time::timeout(self.first_reading_timeout, rx.wait_for(|n| *n != start)).await;
    }

    /// Apply a change to the status; returns the names of changed signalled properties.
    pub fn update(&self, f: impl FnOnce(&mut Status)) -> (Status, Status) {
        let mut g = self.lock();
        let before = g.status.clone();
        f(&mut g.status);
        let after = g.status.clone();
        if after.state == State::Off || after.state == State::Starting {
            g.have_reading = false;
        }
        (before, after)
    }

    /// Note a valid reading (wakes waiting claimers).
    pub fn note_valid_reading(&self) {
        self.lock().have_reading = true;
        self.reading_tx.send_modify(|n| *n = n.wrapping_add(1));
    }
}

/// Methods without arguments refuse a call that carries a body.
fn no_args(hdr: &Header<'_>) -> fdo::Result<()> {
    let sig = hdr.signature().to_string();
    if sig.is_empty() {
        Ok(())
    } else {
        Err(fdo::Error::InvalidArgs(format!(
            "this method takes no arguments, got signature `{sig}`"
        )))
    }
}

fn caller(hdr: &Header<'_>) -> fdo::Result<String> {
    no_args(hdr)?;
    Ok(hdr
        .sender()
        .map(|s| s.to_string())
        .unwrap_or_else(|| "p2p".to_string()))
}

/// Check that a caller still exists after its claim was registered (it may have left
/// between sending the call and our handling it; its NameOwnerChanged then came first).
async fn drop_if_gone(conn: &Connection, hub: &Hub, client: &str) {
    if !conn.is_bus() || !client.starts_with(':') {
        return;
    }
    let Ok(proxy) = fdo::DBusProxy::new(conn).await else {
        return;
    };
    let Ok(name) = zbus::names::BusName::try_from(client) else {
        return;
    };
    if let Ok(false) = proxy.name_has_owner(name).await {
        hub.client_gone(client);
    }
}

/// Set one of the calling client's claims (dropped again at once if the caller has
/// already left the bus).
async fn claim_for_caller(
    hub: &Hub,
    hdr: &Header<'_>,
    conn: &Connection,
    set: impl FnOnce(&mut ClientClaims),
) -> fdo::Result<()> {
    let client = caller(hdr)?;
    hub.modify_claim(&client, set);
    drop_if_gone(conn, hub, &client).await;
    Ok(())
}

/// Clear one of the calling client's claims (no-op without one).
fn release_for_caller(
    hub: &Hub,
    hdr: &Header<'_>,
    clear: impl FnOnce(&mut ClientClaims),
) -> fdo::Result<()> {
    hub.modify_claim(&caller(hdr)?, clear);
    Ok(())
}

/// `org.tofprox.Proximity1` at `/org/tofprox/Proximity1`.
pub struct Proximity {
    hub: Arc<Hub>,
}

impl Proximity {
    /// New interface object.
    pub fn new(hub: Arc<Hub>) -> Self {
        Self { hub }
    }
}

fn variant_str(s: &str) -> OwnedVariant {
    OwnedVariant::from(Str::from(s.to_string()))
}

#[interface(name = "org.tofprox.Proximity1")]
impl Proximity {
    /// Claim proximity readings: starts the loop; returns once the first valid reading
    /// exists (bounded wait, `loop.first_reading_timeout_ms`).
    async fn claim_proximity(
        &self,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> fdo::Result<()> {
        claim_for_caller(&self.hub, &hdr, conn, |c| c.proximity = true).await?;
        self.hub.wait_first_reading().await;
        Ok(())
    }

    /// Release the caller's proximity claim (no-op without one).
    async fn release_proximity(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        release_for_caller(&self.hub, &hdr, |c| c.proximity = false)
    }

    /// Claim depth frames (`DepthFrame` signals while held; bus policy limits this to a group).
    async fn claim_depth(
        &self,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> fdo::Result<()> {
        claim_for_caller(&self.hub, &hdr, conn, |c| c.depth = true).await
    }

    /// Release the caller's depth claim.
    async fn release_depth(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        release_for_caller(&self.hub, &hdr, |c| c.depth = false)
    }

    /// Every property plus counters, as a dictionary.
    async fn get_status(
        &self,
        #[zbus(header)] hdr: Header<'_>,
    ) -> fdo::Result<HashMap<String, OwnedVariant>> {
        no_args(&hdr)?;
        let s = self.hub.status();
        let c = self.hub.claim_counts();
        let mut m = HashMap::new();
        m.insert("HasSensor".into(), OwnedVariant::from(s.has_sensor));
        m.insert("State".into(), variant_str(s.state.as_str()));
        m.insert("Near".into(), OwnedVariant::from(s.near));
        m.insert("DistanceMm".into(), OwnedVariant::from(s.distance_mm));
        m.insert(
            "NearThresholdMm".into(),
            OwnedVariant::from(s.near_threshold_mm),
        );
        m.insert(
            "FarThresholdMm".into(),
            OwnedVariant::from(s.far_threshold_mm),
        );
        m.insert("Mode".into(), variant_str(s.mode.as_str()));
        m.insert("RateHz".into(), OwnedVariant::from(s.rate_hz));
        m.insert("PowerEstimateMw".into(), OwnedVariant::from(s.power_mw));
        m.insert("LastError".into(), variant_str(&s.last_error));
        m.insert("ExposureUs".into(), OwnedVariant::from(s.exposure_us));
        m.insert("Cycles".into(), OwnedVariant::from(s.cycles));
        m.insert("ValidReadings".into(), OwnedVariant::from(s.valid_readings));
        m.insert("Errors".into(), OwnedVariant::from(s.errors));
        m.insert("Backend".into(), variant_str(&s.backend));
        m.insert("AmplitudeCheck".into(), variant_str(s.amplitude_check));
        m.insert("Clients".into(), OwnedVariant::from(c.clients));
        m.insert(
            "ProximityClaims".into(),
            OwnedVariant::from(c.proximity + c.compat_proximity),
        );
        m.insert("DepthClaims".into(), OwnedVariant::from(c.depth));
        Ok(m)
    }

    /// Whether a sensor (or emulation/replay) is configured and answering.
    #[zbus(property)]
    fn has_sensor(&self) -> bool {
        self.hub.status().has_sensor
    }

    /// off, starting, running, error, unavailable.
    #[zbus(property)]
    fn state(&self) -> String {
        self.hub.status().state.as_str().to_string()
    }

    /// Near (entered at once, left after the debounce).
    #[zbus(property)]
    fn near(&self) -> bool {
        self.hub.status().near
    }

    /// Distance of the ROI (mm, 0 = unknown, 4294967295 = nothing in range: a valid far reading). No change signal: poll it.
    #[zbus(property(emits_changed_signal = "false"))]
    fn distance_mm(&self) -> u32 {
        self.hub.status().distance_mm
    }

    /// Near threshold (mm).
    #[zbus(property(emits_changed_signal = "const"))]
    fn near_threshold_mm(&self) -> u32 {
        self.hub.status().near_threshold_mm
    }

    /// Far threshold (mm).
    #[zbus(property(emits_changed_signal = "const"))]
    fn far_threshold_mm(&self) -> u32 {
        self.hub.status().far_threshold_mm
    }

    /// 2phase or 4phase.
    #[zbus(property)]
    fn mode(&self) -> String {
        self.hub.status().mode.as_str().to_string()
    }

    /// Current reading rate (Hz, 0 while off).
    #[zbus(property)]
    fn rate_hz(&self) -> f64 {
        self.hub.status().rate_hz
    }

    /// Modelled average power (mW), updated at most once per second.
    #[zbus(property)]
    fn power_estimate_mw(&self) -> f64 {
        self.hub.status().power_mw
    }

    /// Why the last cycle failed ("" when fine).
    #[zbus(property)]
    fn last_error(&self) -> String {
        self.hub.status().last_error
    }

    /// A depth frame (only while a depth claim is held; rate-limited).
    #[zbus(signal)]
    async fn depth_frame(
        emitter: &SignalEmitter<'_>,
        timestamp_ns: u64,
        width: u16,
        height: u16,
        depth_mm_u16_le: &[u8],
        amplitude_u16_le: &[u8],
    ) -> zbus::Result<()>;
}

/// `net.hadess.SensorProxy` at `/net/hadess/SensorProxy` (iio-sensor-proxy compatible).
pub struct SensorProxyCompat {
    hub: Arc<Hub>,
}

impl SensorProxyCompat {
    /// New compat interface.
    pub fn new(hub: Arc<Hub>) -> Self {
        Self { hub }
    }
}

#[interface(name = "net.hadess.SensorProxy")]
impl SensorProxyCompat {
    /// No accelerometer here.
    #[zbus(property)]
    fn has_accelerometer(&self) -> bool {
        false
    }
    /// "undefined" (no accelerometer).
    #[zbus(property)]
    fn accelerometer_orientation(&self) -> String {
        "undefined".into()
    }
    /// "undefined" (no accelerometer).
    #[zbus(property)]
    fn accelerometer_tilt(&self) -> String {
        "undefined".into()
    }
    /// No ambient light sensor.
    #[zbus(property)]
    fn has_ambient_light(&self) -> bool {
        false
    }
    /// "lux".
    #[zbus(property)]
    fn light_level_unit(&self) -> String {
        "lux".into()
    }
    /// 0.0 (no sensor).
    #[zbus(property)]
    fn light_level(&self) -> f64 {
        0.0
    }
    /// Backed by tofprox.
    #[zbus(property)]
    fn has_proximity(&self) -> bool {
        self.hub.status().has_sensor
    }
    /// Backed by tofprox's `Near`.
    #[zbus(property)]
    fn proximity_near(&self) -> bool {
        self.hub.status().near
    }

    /// Succeeds; there is no accelerometer to start.
    async fn claim_accelerometer(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        no_args(&hdr)
    }
    /// Succeeds.
    async fn release_accelerometer(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        no_args(&hdr)
    }
    /// Succeeds; there is no light sensor to start.
    async fn claim_light(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        no_args(&hdr)
    }
    /// Succeeds.
    async fn release_light(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        no_args(&hdr)
    }
    /// Claims tofprox proximity for the caller.
    async fn claim_proximity(
        &self,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> fdo::Result<()> {
        claim_for_caller(&self.hub, &hdr, conn, |c| c.compat_proximity = true).await?;
        self.hub.wait_first_reading().await;
        Ok(())
    }
    /// Releases it.
    async fn release_proximity(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        release_for_caller(&self.hub, &hdr, |c| c.compat_proximity = false)
    }
}

/// `net.hadess.SensorProxy.Compass` at `/net/hadess/SensorProxy/Compass` (absent compass).
pub struct SensorProxyCompass;

#[interface(name = "net.hadess.SensorProxy.Compass")]
impl SensorProxyCompass {
    /// No compass.
    #[zbus(property)]
    fn has_compass(&self) -> bool {
        false
    }
    /// -1.0 = unknown.
    #[zbus(property)]
    fn compass_heading(&self) -> f64 {
        -1.0
    }
    /// Succeeds.
    async fn claim_compass(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        no_args(&hdr)
    }
    /// Succeeds.
    async fn release_compass(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        no_args(&hdr)
    }
}

/// A depth frame to publish.
#[derive(Debug, Clone)]
pub struct DepthMessage {
    /// Capture time (ns).
    pub timestamp_ns: u64,
    /// Columns.
    pub width: u16,
    /// Rows.
    pub height: u16,
    /// depth (mm) as little-endian u16.
    pub depth_le: Vec<u8>,
    /// amplitude (LSB, saturating) as little-endian u16.
    pub amplitude_le: Vec<u8>,
}

/// What the loop reports to the publisher.
#[derive(Debug, Clone)]
pub enum Event {
    /// Apply a status change (the closure-free form: a full new status fragment).
    Status(StatusUpdate),
    /// A depth frame (sent only while a depth claim is held).
    Depth(DepthMessage),
}

/// A status fragment from the loop.
#[derive(Debug, Clone, Default)]
pub struct StatusUpdate {
    /// New state.
    pub state: Option<State>,
    /// New near.
    pub near: Option<bool>,
    /// New distance (0 = unknown).
    pub distance_mm: Option<u32>,
    /// New mode.
    pub mode: Option<Mode>,
    /// New rate.
    pub rate_hz: Option<f64>,
    /// New power estimate (the publisher limits updates to 1 Hz).
    pub power_mw: Option<f64>,
    /// New last error.
    pub last_error: Option<String>,
    /// New exposure.
    pub exposure_us: Option<f64>,
    /// New has_sensor.
    pub has_sensor: Option<bool>,
    /// How near readings are checked (see [`Status::amplitude_check`]).
    pub amplitude_check: Option<&'static str>,
    /// This update carries a valid reading.
    pub valid_reading: bool,
    /// This update is one completed cycle (counts).
    pub cycle: bool,
    /// This update is a failed cycle.
    pub error: bool,
}

/// Sender side for the loop.
pub type EventSender = mpsc::UnboundedSender<Event>;

/// Emit PropertiesChanged for `iface` with the given changes (one signal).
async fn emit_changes(
    conn: &Connection,
    path: &str,
    iface: &'static str,
    changes: HashMap<&str, Variant<'_>>,
) -> zbus::Result<()> {
    if changes.is_empty() {
        return Ok(());
    }
    let emitter = SignalEmitter::new(conn, path)?;
    fdo::Properties::properties_changed(
        &emitter,
        InterfaceName::from_static_str_unchecked(iface),
        changes,
        Cow::Borrowed(&[]),
    )
    .await
}

/// The publisher: applies loop events to the hub and emits signals. Runs until the
/// event channel closes.
pub async fn run_publisher(
    conn: Connection,
    hub: Arc<Hub>,
    mut events: mpsc::UnboundedReceiver<Event>,
    compat: bool,
    depth_max_hz: f64,
) {
    // PowerEstimateMw: at most one change signal per second, carried by the cycle's own
    // update (no timer of its own: no extra wake-up between cycles).
    let mut last_power_emit: Option<Instant> = None;
    let mut last_depth: Option<Instant> = None;
    let depth_interval = Duration::from_secs_f64(1.0 / depth_max_hz.max(0.001));
    loop {
        let ev = events.recv().await;
        let Some(ev) = ev else { break };
        match ev {
            Event::Depth(d) => {
                if !hub.demand().depth {
                    continue;
                }
                let now = Instant::now();
                if last_depth.is_some_and(|t| now.duration_since(t) < depth_interval) {
                    continue;
                }
                last_depth = Some(now);
                if let Ok(emitter) = SignalEmitter::new(&conn, OBJECT_PATH)
                    && let Err(e) = Proximity::depth_frame(
                        &emitter,
                        d.timestamp_ns,
                        d.width,
                        d.height,
                        &d.depth_le,
                        &d.amplitude_le,
                    )
                    .await
                {
                    tracing::warn!("DepthFrame emit failed: {e}");
                }
            }
            Event::Status(u) => {
                let power = u.power_mw;
                let (before, after) = hub.update(|s| {
                    if let Some(v) = u.state {
                        s.state = v;
                    }
                    if let Some(v) = u.near {
                        s.near = v;
                    }
                    if let Some(v) = u.distance_mm {
                        s.distance_mm = v;
                    }
                    if let Some(v) = u.mode {
                        s.mode = v;
                    }
                    if let Some(v) = u.rate_hz {
                        s.rate_hz = v;
                    }
                    if let Some(v) = &u.last_error {
                        s.last_error.clone_from(v);
                    }
                    if let Some(v) = u.exposure_us {
                        s.exposure_us = v;
                    }
                    if let Some(v) = u.has_sensor {
                        s.has_sensor = v;
                    }
                    if let Some(v) = u.amplitude_check {
                        s.amplitude_check = v;
                    }
                    if u.cycle {
                        s.cycles += 1;
                    }
                    if u.error {
                        s.errors += 1;
                    }
                    if u.valid_reading {
                        s.valid_readings += 1;
                    }
                });
                let mut ch: HashMap<&str, Variant<'_>> = HashMap::new();
                if before.has_sensor != after.has_sensor {
                    ch.insert("HasSensor", Variant::from(after.has_sensor));
                }
                if before.state != after.state {
                    ch.insert("State", Variant::from(after.state.as_str()));
                }
                if before.near != after.near {
                    ch.insert("Near", Variant::from(after.near));
                }
                if before.mode != after.mode {
                    ch.insert("Mode", Variant::from(after.mode.as_str()));
                }
                if before.rate_hz != after.rate_hz {
                    ch.insert("RateHz", Variant::from(after.rate_hz));
                }
                if before.last_error != after.last_error {
                    ch.insert("LastError", Variant::from(after.last_error.as_str()));
                }
                if let Some(p) = power
                    && p != after.power_mw
                {
                    let now = Instant::now();
                    if last_power_emit
                        .is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1))
                    {
                        hub.update(|s| s.power_mw = p);
                        ch.insert("PowerEstimateMw", Variant::from(p));
                        last_power_emit = Some(now);
                    }
                }
                let compat_near = before.near != after.near;
                let compat_has = before.has_sensor != after.has_sensor;
                if let Err(e) = emit_changes(&conn, OBJECT_PATH, INTERFACE, ch).await {
                    tracing::warn!("PropertiesChanged emit failed: {e}");
                }
                if compat && (compat_near || compat_has) {
                    let mut c: HashMap<&str, Variant<'_>> = HashMap::new();
                    if compat_near {
                        c.insert("ProximityNear", Variant::from(after.near));
                    }
                    if compat_has {
                        c.insert("HasProximity", Variant::from(after.has_sensor));
                    }
                    if let Err(e) = emit_changes(&conn, COMPAT_PATH, COMPAT_BUS_NAME, c).await {
                        tracing::warn!("compat PropertiesChanged emit failed: {e}");
                    }
                }
                if u.valid_reading {
                    hub.note_valid_reading();
                }
            }
        }
    }
}

/// Poll a stream once (zbus streams are `futures_core::Stream`).
pub async fn next_item<S: futures_core::Stream + Unpin>(s: &mut S) -> Option<S::Item> {
    std::future::poll_fn(|cx| Pin::new(&mut *s).poll_next(cx)).await
}

/// Subscribe to NameOwnerChanged (do this before the bus name is requested so no
/// departure is missed).
pub async fn subscribe_clients(conn: &Connection) -> zbus::Result<fdo::NameOwnerChangedStream> {
    let proxy = fdo::DBusProxy::new(conn).await?;
    proxy.receive_name_owner_changed().await
}

/// Drop claims of clients that leave the bus (NameOwnerChanged with an empty new owner).
pub async fn watch_clients(mut stream: fdo::NameOwnerChangedStream, hub: Arc<Hub>) {
    while let Some(sig) = next_item(&mut stream).await {
        let Ok(args) = sig.args() else { continue };
        let name = args.name().to_string();
        if name.starts_with(':') && args.new_owner().is_none() && hub.client_gone(&name) {
            tracing::info!("client {name} left the bus: its claims are released");
        }
    }
}
