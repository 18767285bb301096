//! The D-Bus publisher: what the clients see as `PropertiesChanged` of
//! `org.tofprox.Proximity1` (and of the compatibility object `net.hadess.SensorProxy`
//! when it is served), depth frames as `DepthFrame` signals unicast to the depth claimers.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Arc;

use zbus::names::{BusName, InterfaceName};
use zbus::object_server::SignalEmitter;
use zbus::{Connection, Variant, fdo};

use super::{PublishError, Publisher, StatusChange};
use crate::hub::{DepthMessage, Hub, Status};
use crate::service::{COMPAT_BUS_NAME, COMPAT_PATH, INTERFACE, OBJECT_PATH, Proximity, property};

/// Publishes on a D-Bus connection whose objects `run` serves.
pub struct DbusPublisher {
    conn: Connection,
    hub: Arc<Hub>,
    compat: bool,
}

impl DbusPublisher {
    /// On `conn`; `compat`: the compatibility object is served too.
    pub fn new(conn: Connection, hub: Arc<Hub>, compat: bool) -> Self {
        Self { conn, hub, compat }
    }
}

#[async_trait::async_trait]
impl Publisher for DbusPublisher {
    fn name(&self) -> &'static str {
        "dbus"
    }

    async fn status(&mut self, change: StatusChange<'_>) -> Result<(), PublishError> {
        // the compat object's changes go out even when the native signal failed
        let native = emit_changes(
            &self.conn,
            OBJECT_PATH,
            INTERFACE,
            native_changes(change.before, change.after),
        )
        .await;
        let compat = if self.compat {
            let changes = compat_changes(change.before, change.after);
            emit_changes(&self.conn, COMPAT_PATH, COMPAT_BUS_NAME, changes).await
        } else {
            Ok(())
        };
        native.map_err(|e| PublishError::new("dbus", e))?;
        compat.map_err(|e| PublishError::new("dbus (compat)", e))
    }

    async fn depth(&mut self, frame: &DepthMessage) -> Result<(), PublishError> {
        send_depth(&self.conn, &self.hub, frame).await;
        Ok(())
    }
}

/// Emit PropertiesChanged for `iface` with the given changes (one signal; none if empty).
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

/// Send a depth frame to each unique name holding a depth claim, and to no one else: a
/// unicast signal (with a destination) per claimer. A broadcast would reach every client
/// with a match rule — on a session bus anyone, on the system bus every member of the depth
/// group — so depth images never go out without a destination on a bus. On a peer-to-peer
/// connection the single peer is the only possible receiver.
async fn send_depth(conn: &Connection, hub: &Hub, d: &DepthMessage) {
    let Ok(emitter) = SignalEmitter::new(conn, OBJECT_PATH) else {
        return;
    };
    let emitters: Vec<SignalEmitter<'_>> = if conn.is_bus() {
        hub.depth_claimers()
            .into_iter()
            .filter_map(|name| match BusName::try_from(name) {
                Ok(dest) => Some(emitter.clone().set_destination(dest)),
                Err(e) => {
                    tracing::warn!("depth claimer with an invalid bus name: {e}");
                    None
                }
            })
            .collect()
    } else {
        vec![emitter]
    };
    for em in &emitters {
        if let Err(e) = Proximity::depth_frame(
            em,
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
}

/// The native interface's properties that changed between two public views of the status.
fn native_changes<'a>(before: &Status, after: &'a Status) -> HashMap<&'static str, Variant<'a>> {
    let mut ch: HashMap<&str, Variant<'_>> = HashMap::new();
    if before.has_sensor != after.has_sensor {
        ch.insert(property::HAS_SENSOR, Variant::from(after.has_sensor));
    }
    if before.state != after.state {
        ch.insert(property::STATE, Variant::from(after.state.as_str()));
    }
    if before.near != after.near {
        ch.insert(property::NEAR, Variant::from(after.near));
    }
    if before.near_changed_ns != after.near_changed_ns {
        ch.insert(
            property::NEAR_CHANGED_NS,
            Variant::from(after.near_changed_ns),
        );
    }
    if before.mode != after.mode {
        ch.insert(property::MODE, Variant::from(after.mode.as_str()));
    }
    if before.rate_hz != after.rate_hz {
        ch.insert(property::RATE_HZ, Variant::from(after.rate_hz));
    }
    if before.last_error != after.last_error {
        ch.insert(
            property::LAST_ERROR,
            Variant::from(after.last_error.as_str()),
        );
    }
    if before.power_mw != after.power_mw {
        ch.insert(property::POWER_ESTIMATE_MW, Variant::from(after.power_mw));
    }
    if before.reason != after.reason {
        ch.insert(property::REASON, Variant::from(after.reason.as_str()));
    }
    ch
}

/// The compatibility object's `ProximityNear`/`HasProximity` that changed.
fn compat_changes(before: &Status, after: &Status) -> HashMap<&'static str, Variant<'static>> {
    let mut c: HashMap<&str, Variant<'_>> = HashMap::new();
    if before.near != after.near {
        c.insert(property::COMPAT_PROXIMITY_NEAR, Variant::from(after.near));
    }
    if before.has_sensor != after.has_sensor {
        c.insert(
            property::COMPAT_HAS_PROXIMITY,
            Variant::from(after.has_sensor),
        );
    }
    c
}
