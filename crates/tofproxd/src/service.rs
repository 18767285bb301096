//! The D-Bus adapter: `org.tofprox.Proximity1` (and the iio-sensor-proxy compatible
//! `net.hadess.SensorProxy` with its absent compass) as thin zbus interfaces over the
//! [`Hub`], plus tracking of clients that leave the bus. Claims, demand and status live in
//! [`crate::hub`]; the D-Bus publisher (the signals) is `publisher::dbus`.

use std::collections::HashMap;
use std::pin::Pin;
use std::sync::Arc;

use zbus::message::{Flags, Message};
use zbus::names::{InterfaceName, MemberName};
use zbus::object_server::{DispatchResult, Interface, SignalEmitter};
use zbus::{
    BoxDBusError, Connection, ObjectServer, OwnedVariant, Str, Variant, fdo, interface,
    message::Header,
};

use crate::hub::{Claim, FirstReading, Hub};

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

/// `GetStatus()`'s key of the modelled energy since the daemon started (mJ,
/// [`crate::hub::Status::energy_mj`]): divided by a run's time, the run's exact average power.
pub const ENERGY_MJ_KEY: &str = "EnergyMj";

/// The D-Bus property names, spelled once: the publisher's `PropertiesChanged` and
/// `GetStatus` use these; zbus derives the served names from the getters below
/// (`fn near_threshold_mm` → `NearThresholdMm`), and a test holds the two together.
pub mod property {
    /// `org.tofprox.Proximity1.HasSensor`.
    pub const HAS_SENSOR: &str = "HasSensor";
    /// `org.tofprox.Proximity1.State`.
    pub const STATE: &str = "State";
    /// `org.tofprox.Proximity1.Near`.
    pub const NEAR: &str = "Near";
    /// `org.tofprox.Proximity1.NearChangedNs`.
    pub const NEAR_CHANGED_NS: &str = "NearChangedNs";
    /// `org.tofprox.Proximity1.ReadingTimestampNs`.
    pub const READING_TIMESTAMP_NS: &str = "ReadingTimestampNs";
    /// `org.tofprox.Proximity1.DistanceMm`.
    pub const DISTANCE_MM: &str = "DistanceMm";
    /// `org.tofprox.Proximity1.NearThresholdMm`.
    pub const NEAR_THRESHOLD_MM: &str = "NearThresholdMm";
    /// `org.tofprox.Proximity1.FarThresholdMm`.
    pub const FAR_THRESHOLD_MM: &str = "FarThresholdMm";
    /// `org.tofprox.Proximity1.Mode`.
    pub const MODE: &str = "Mode";
    /// `org.tofprox.Proximity1.RateHz`.
    pub const RATE_HZ: &str = "RateHz";
    /// `org.tofprox.Proximity1.PowerEstimateMw`.
    pub const POWER_ESTIMATE_MW: &str = "PowerEstimateMw";
    /// `org.tofprox.Proximity1.LastError`.
    pub const LAST_ERROR: &str = "LastError";
    /// `org.tofprox.Proximity1.Reason`.
    pub const REASON: &str = "Reason";
    /// Every property of `org.tofprox.Proximity1`.
    pub const ALL: [&str; 13] = [
        HAS_SENSOR,
        STATE,
        NEAR,
        NEAR_CHANGED_NS,
        READING_TIMESTAMP_NS,
        DISTANCE_MM,
        NEAR_THRESHOLD_MM,
        FAR_THRESHOLD_MM,
        MODE,
        RATE_HZ,
        POWER_ESTIMATE_MW,
        LAST_ERROR,
        REASON,
    ];
    /// `net.hadess.SensorProxy.HasProximity` (iio-sensor-proxy compatible).
    pub const COMPAT_HAS_PROXIMITY: &str = "HasProximity";
    /// `net.hadess.SensorProxy.ProximityNear` (iio-sensor-proxy compatible).
    pub const COMPAT_PROXIMITY_NEAR: &str = "ProximityNear";
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

/// Set one of the calling client's claims (dropped again if the caller has already left the
/// bus: checked once per client, when its first claim arrives, by a task of its own so the
/// dispatcher never waits on the bus; a flood of claims from one connection costs no bus
/// round trips). Returns the client's name.
fn claim_for_caller(
    hub: &Arc<Hub>,
    hdr: &Header<'_>,
    conn: &Connection,
    claim: Claim,
) -> fdo::Result<String> {
    let client = caller(hdr)?;
    if hub.set_claim(&client, claim, true) && conn.is_bus() {
        let (conn, hub, name) = (conn.clone(), hub.clone(), client.clone());
        tokio::spawn(async move { drop_if_gone(&conn, &hub, &name).await });
    }
    Ok(client)
}

/// A proximity claim (native or compat) as the interface method (p2p and introspection):
/// held at once, answered at once. On a bus the call is taken before the interface by
/// [`ReadOnlyProperties`] (`claim_proximity_deferred`), which waits for the first reading
/// off the dispatcher.
fn claim_proximity_for_caller(
    hub: &Arc<Hub>,
    hdr: &Header<'_>,
    conn: &Connection,
    claim: Claim,
) -> fdo::Result<()> {
    claim_for_caller(hub, hdr, conn, claim).map(drop)
}

/// `ClaimProximity` (native or compat) without queuing (issue 35, memory under pending
/// calls): the claim is held at once; if the caller wants a reply and one of the hub's
/// bounded waiting slots is free (per client and in total), a task of its own holds the slot
/// and sends the reply once the first valid reading exists (bounded wait); otherwise the
/// reply goes at once. The interfaces are dispatched one call at a time
/// (`spawn = false`), so no call of any client ever waits in a task of its own beyond these
/// bounded slots: a flood of calls is held back in the bus (its per-connection limits), not
/// in this process, and `GetStatus` is answered between them.
async fn claim_proximity_deferred(
    hub: Arc<Hub>,
    claim: Claim,
    conn: Connection,
    msg: Message,
) -> Result<(), BoxDBusError> {
    let hdr = msg.header();
    let client =
        claim_for_caller(&hub, &hdr, &conn, claim).map_err(|e| Box::new(e) as BoxDBusError)?;
    if hdr.primary().flags().contains(Flags::NO_REPLY_EXPECTED) {
        return Ok(());
    }
    let Some(slot) = hub.take_wait_slot(&client) else {
        tracing::debug!(
            "{client}: claim held, answered without waiting (waiting claims at their bound)"
        );
        conn.reply(&hdr, &()).await?;
        return Ok(());
    };
    tokio::spawn(async move {
        let hdr = msg.header();
        if slot.wait_first_reading().await != FirstReading::Ready {
            tracing::debug!("claim answered without a first reading (timed out)");
        }
        if let Err(e) = conn.reply(&hdr, &()).await {
            tracing::debug!("reply to a claim: {e}");
        }
    });
    Ok(())
}

/// The interfaces whose `ClaimProximity` [`ReadOnlyProperties`] takes before them
/// (`claim_proximity_deferred`).
pub trait ClaimWaits {
    /// The hub and the claim `ClaimProximity` sets; `None`: the interface has none.
    fn proximity_claim(&self) -> Option<(&Arc<Hub>, Claim)> {
        None
    }
}

impl ClaimWaits for Proximity {
    fn proximity_claim(&self) -> Option<(&Arc<Hub>, Claim)> {
        Some((&self.hub, Claim::Proximity))
    }
}

impl ClaimWaits for SensorProxyCompat {
    fn proximity_claim(&self) -> Option<(&Arc<Hub>, Claim)> {
        Some((&self.hub, Claim::CompatProximity))
    }
}

impl ClaimWaits for SensorProxyCompass {}

/// Clear one of the calling client's claims (no-op without one).
fn release_for_caller(hub: &Hub, hdr: &Header<'_>, claim: Claim) -> fdo::Result<()> {
    hub.set_claim(&caller(hdr)?, claim, false);
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

#[interface(name = "org.tofprox.Proximity1", spawn = false)]
impl Proximity {
    /// Claim proximity readings: starts the loop; returns once the first valid reading
    /// exists (bounded wait, `loop.first_reading_timeout_ms`; at once when too many claims
    /// already wait — the claim is held all the same).
    async fn claim_proximity(
        &self,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> fdo::Result<()> {
        claim_proximity_for_caller(&self.hub, &hdr, conn, Claim::Proximity)
    }

    /// Release the caller's proximity claim (no-op without one).
    async fn release_proximity(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        release_for_caller(&self.hub, &hdr, Claim::Proximity)
    }

    /// Claim depth frames (`DepthFrame` signals while held; bus policy limits this to a group).
    async fn claim_depth(
        &self,
        #[zbus(header)] hdr: Header<'_>,
        #[zbus(connection)] conn: &Connection,
    ) -> fdo::Result<()> {
        claim_for_caller(&self.hub, &hdr, conn, Claim::Depth).map(drop)
    }

    /// Release the caller's depth claim.
    async fn release_depth(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        release_for_caller(&self.hub, &hdr, Claim::Depth)
    }

    /// Every property plus counters, as a dictionary (public: nothing in it tells whether
    /// anyone holds a depth claim; `Clients` counts clients holding a proximity claim;
    /// `EnergyMj` is the modelled energy of the counted cycles since the daemon started, in mJ:
    /// two calls' difference over the time between them is the average power).
    async fn get_status(
        &self,
        #[zbus(header)] hdr: Header<'_>,
    ) -> fdo::Result<HashMap<String, OwnedVariant>> {
        no_args(&hdr)?;
        let s = self.hub.status();
        let c = self.hub.claim_counts();
        let mut m = HashMap::new();
        m.insert(
            property::HAS_SENSOR.into(),
            OwnedVariant::from(s.has_sensor),
        );
        m.insert(property::STATE.into(), variant_str(s.state.as_str()));
        m.insert(property::NEAR.into(), OwnedVariant::from(s.near));
        m.insert(
            property::NEAR_CHANGED_NS.into(),
            OwnedVariant::from(s.near_changed_ns),
        );
        m.insert(
            property::READING_TIMESTAMP_NS.into(),
            OwnedVariant::from(s.reading_ns),
        );
        m.insert(
            property::DISTANCE_MM.into(),
            OwnedVariant::from(s.distance_mm),
        );
        m.insert(
            property::NEAR_THRESHOLD_MM.into(),
            OwnedVariant::from(s.near_threshold_mm),
        );
        m.insert(
            property::FAR_THRESHOLD_MM.into(),
            OwnedVariant::from(s.far_threshold_mm),
        );
        m.insert(property::MODE.into(), variant_str(s.mode.as_str()));
        m.insert(property::RATE_HZ.into(), OwnedVariant::from(s.rate_hz));
        m.insert(
            property::POWER_ESTIMATE_MW.into(),
            OwnedVariant::from(s.power_mw),
        );
        m.insert(property::LAST_ERROR.into(), variant_str(&s.last_error));
        m.insert("ExposureUs".into(), OwnedVariant::from(s.exposure_us));
        m.insert(ENERGY_MJ_KEY.into(), OwnedVariant::from(s.energy_mj));
        m.insert("Cycles".into(), OwnedVariant::from(s.cycles));
        m.insert("ValidReadings".into(), OwnedVariant::from(s.valid_readings));
        m.insert("Errors".into(), OwnedVariant::from(s.errors));
        m.insert("Backend".into(), variant_str(&s.backend));
        m.insert("AmplitudeCheck".into(), variant_str(s.amplitude_check));
        m.insert(property::REASON.into(), variant_str(s.reason.as_str()));
        m.insert("Clients".into(), OwnedVariant::from(c.proximity_clients));
        m.insert(
            "ProximityClaims".into(),
            OwnedVariant::from(c.proximity + c.compat_proximity),
        );
        Ok(m)
    }

    /// Claim counts including depth (`DepthClaims`, `Clients` = every client holding any
    /// claim); the bus policy limits this, like `ClaimDepth`, to the depth group.
    async fn get_depth_status(
        &self,
        #[zbus(header)] hdr: Header<'_>,
    ) -> fdo::Result<HashMap<String, OwnedVariant>> {
        no_args(&hdr)?;
        let c = self.hub.claim_counts();
        let mut m = HashMap::new();
        m.insert("Clients".into(), OwnedVariant::from(c.clients));
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

    /// CLOCK_BOOTTIME (ns, the clock of Android's sensor events) of the capture whose reading
    /// last changed Near (0 = unchanged since start); its change signal comes with Near's.
    #[zbus(property)]
    fn near_changed_ns(&self) -> u64 {
        self.hub.status().near_changed_ns
    }

    /// CLOCK_BOOTTIME (ns) of the capture of the last valid reading (0 = none yet), the one
    /// DistanceMm shows. No change signal: poll it with DistanceMm.
    #[zbus(property(emits_changed_signal = "false"))]
    fn reading_timestamp_ns(&self) -> u64 {
        self.hub.status().reading_ns
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

    /// The rule that decided the last reading: distance, nothing_in_range, saturated,
    /// second_frequency, probe_unchanged, on_the_window, hold_expired, stopped ("" before the
    /// first reading; docs/daemon.md, "Why a reading").
    #[zbus(property)]
    fn reason(&self) -> String {
        self.hub.status().reason.as_str().to_string()
    }

    // Radial depth (mm along each pixel's ray, eq. 2.6 — not Z) and amplitude. (A plain
    // comment: doc comments go into the introspection data, which systemd/*.xml ships.)
    /// A depth frame (only while a depth claim is held; rate-limited).
    #[zbus(signal)]
    pub async fn depth_frame(
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

#[interface(name = "net.hadess.SensorProxy", spawn = false)]
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
        claim_proximity_for_caller(&self.hub, &hdr, conn, Claim::CompatProximity)
    }
    /// Releases it.
    async fn release_proximity(&self, #[zbus(header)] hdr: Header<'_>) -> fdo::Result<()> {
        release_for_caller(&self.hub, &hdr, Claim::CompatProximity)
    }
}

/// `net.hadess.SensorProxy.Compass` at `/net/hadess/SensorProxy/Compass` (absent compass).
pub struct SensorProxyCompass;

#[interface(name = "net.hadess.SensorProxy.Compass", spawn = false)]
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

/// A zbus interface whose properties are all read-only, answering a write with
/// `org.freedesktop.DBus.Error.PropertyReadOnly` (zbus alone answers `UnknownProperty` for a
/// property without a setter, which tells the caller the wrong thing), and whose
/// `ClaimProximity` is answered without queuing (`claim_proximity_deferred`). Everything
/// else is the wrapped interface's.
pub struct ReadOnlyProperties<I>(pub I);

#[async_trait::async_trait]
impl<I: Interface + ClaimWaits> Interface for ReadOnlyProperties<I> {
    fn name() -> InterfaceName<'static>
    where
        Self: Sized,
    {
        I::name()
    }

    fn spawn_tasks_for_methods(&self) -> bool {
        self.0.spawn_tasks_for_methods()
    }

    async fn get(
        &self,
        property_name: &str,
        server: &ObjectServer,
        connection: &Connection,
        header: Option<&Header<'_>>,
        emitter: &SignalEmitter<'_>,
    ) -> Option<Result<OwnedVariant, BoxDBusError>> {
        self.0
            .get(property_name, server, connection, header, emitter)
            .await
    }

    async fn get_all(
        &self,
        object_server: &ObjectServer,
        connection: &Connection,
        header: Option<&Header<'_>>,
        emitter: &SignalEmitter<'_>,
    ) -> fdo::Result<HashMap<String, OwnedVariant>> {
        self.0
            .get_all(object_server, connection, header, emitter)
            .await
    }

    fn set<'call>(
        &'call self,
        property_name: &'call str,
        _value: &'call Variant<'_>,
        object_server: &'call ObjectServer,
        connection: &'call Connection,
        header: Option<&'call Header<'_>>,
        emitter: &'call SignalEmitter<'_>,
    ) -> DispatchResult<'call> {
        DispatchResult::Async(Box::pin(async move {
            let exists = self
                .0
                .get(property_name, object_server, connection, header, emitter)
                .await
                .is_some();
            let e = if exists {
                fdo::Error::PropertyReadOnly(format!("property '{property_name}' is read-only"))
            } else {
                fdo::Error::UnknownProperty(format!("Unknown property '{property_name}'"))
            };
            Err(Box::new(e) as BoxDBusError)
        }))
    }

    async fn set_mut(
        &mut self,
        _property_name: &str,
        _value: &Variant<'_>,
        _object_server: &ObjectServer,
        _connection: &Connection,
        _header: Option<&Header<'_>>,
        _emitter: &SignalEmitter<'_>,
    ) -> Option<Result<(), BoxDBusError>> {
        None
    }

    fn call<'call>(
        &'call self,
        server: &'call ObjectServer,
        connection: &'call Connection,
        msg: &'call Message,
        name: MemberName<'call>,
    ) -> DispatchResult<'call> {
        // a call with arguments goes to the interface, which refuses it as zbus does
        // ("Signature mismatch") before any claim is made
        if name.as_str() == "ClaimProximity"
            && msg.header().signature().to_string().is_empty()
            && let Some((hub, claim)) = self.0.proximity_claim()
        {
            let fut = claim_proximity_deferred(hub.clone(), claim, connection.clone(), msg.clone());
            return DispatchResult::Async(Box::pin(fut));
        }
        self.0.call(server, connection, msg, name)
    }

    fn call_mut<'call>(
        &'call mut self,
        server: &'call ObjectServer,
        connection: &'call Connection,
        msg: &'call Message,
        name: MemberName<'call>,
    ) -> DispatchResult<'call> {
        self.0.call_mut(server, connection, msg, name)
    }

    fn introspect_to_writer(&self, writer: &mut dyn std::fmt::Write, level: usize) {
        self.0.introspect_to_writer(writer, level)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The property names zbus serves (from the introspection data of `iface`).
    fn served_properties(iface: &impl Interface) -> Vec<String> {
        let mut xml = String::new();
        iface.introspect_to_writer(&mut xml, 0);
        xml.split("<property name=\"")
            .skip(1)
            .filter_map(|rest| rest.split('"').next().map(str::to_string))
            .collect()
    }

    #[test]
    fn property_names_are_the_ones_zbus_serves() {
        let hub = Hub::new(&crate::config::Config::default(), "test".into()).0;
        let mut served = served_properties(&Proximity::new(hub.clone()));
        served.sort();
        let mut named: Vec<String> = property::ALL.iter().map(|s| s.to_string()).collect();
        named.sort();
        assert_eq!(served, named);
        let compat = served_properties(&SensorProxyCompat::new(hub));
        for name in [
            property::COMPAT_HAS_PROXIMITY,
            property::COMPAT_PROXIMITY_NEAR,
        ] {
            assert!(compat.iter().any(|p| p == name), "{name} in {compat:?}");
        }
    }
}
