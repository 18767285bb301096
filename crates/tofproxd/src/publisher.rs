//! The publisher: applies the loop's [`Event`]s to the [`Hub`] and turns them into D-Bus
//! property changes and `DepthFrame` signals (rate-limited). Runs as one tokio task.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use zbus::names::{BusName, InterfaceName};
use zbus::object_server::SignalEmitter;
use zbus::{Connection, Variant, fdo};

use crate::hub::{DepthMessage, Event, Hub, Status};
use crate::input::InputPublisher;
use crate::service::{COMPAT_BUS_NAME, COMPAT_PATH, INTERFACE, OBJECT_PATH, Proximity, property};

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

/// The publisher: applies loop events to the hub and emits signals (and, with the input
/// publisher, writes Near to its uinput switch). Runs until the event channel closes. The channel is bounded ([`crate::hub::event_channel`]): while
/// this task is behind, the loop waits to send status updates and drops depth frames.
pub async fn run_publisher(
    conn: Connection,
    hub: Arc<Hub>,
    mut events: mpsc::Receiver<Event>,
    compat: bool,
    depth_max_hz: f64,
    mut input: Option<InputPublisher>,
) {
    // PowerEstimateMw: at most one change signal per second, carried by the cycle's own
    // update (no timer of its own: no extra wake-up between cycles).
    let mut last_power_emit: Option<Instant> = None;
    let mut last_depth: Option<Instant> = None;
    let depth_interval = Duration::from_secs_f64(1.0 / depth_max_hz.max(0.001));
    let mut demand = hub.subscribe_demand();
    loop {
        let ev = tokio::select! {
            ev = events.recv() => ev,
            // a claim came or went: what clients see may change without a cycle (a depth
            // claim left alone shows the loop stopped, `Hub::update`)
            Ok(()) = demand.changed() => {
                let (before, after) = hub.update(|_| {});
                publish_changes(&conn, compat, &before, &after).await;
                publish_input(input.as_mut(), &after);
                continue;
            }
        };
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
                send_depth(&conn, &hub, &d).await;
            }
            Event::Status(u) => {
                let (before, mut after) = hub.apply(&u);
                if let Some(p) = u.power_mw
                    && p != after.power_mw
                {
                    let now = Instant::now();
                    if last_power_emit
                        .is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1))
                    {
                        after = hub.update(|s| s.power_mw = p).1;
                        last_power_emit = Some(now);
                    }
                }
                publish_changes(&conn, compat, &before, &after).await;
                publish_input(input.as_mut(), &after);
                if u.valid_reading {
                    hub.note_valid_reading();
                }
            }
        }
    }
}

/// Near to the input publisher's switch (written only when it changed).
fn publish_input(input: Option<&mut InputPublisher>, after: &Status) {
    if let Some(p) = input
        && let Err(e) = p.publish(after.near)
    {
        tracing::warn!("input publisher: writing Near to the uinput device failed: {e}");
    }
}

/// PropertiesChanged for what changed between two public views of the status (native, and
/// the compat object's `ProximityNear`/`HasProximity` when it is served).
async fn publish_changes(conn: &Connection, compat: bool, before: &Status, after: &Status) {
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
    if let Err(e) = emit_changes(conn, OBJECT_PATH, INTERFACE, ch).await {
        tracing::warn!("PropertiesChanged emit failed: {e}");
    }
    let compat_near = before.near != after.near;
    let compat_has = before.has_sensor != after.has_sensor;
    if compat && (compat_near || compat_has) {
        let mut c: HashMap<&str, Variant<'_>> = HashMap::new();
        if compat_near {
            c.insert(property::COMPAT_PROXIMITY_NEAR, Variant::from(after.near));
        }
        if compat_has {
            c.insert(
                property::COMPAT_HAS_PROXIMITY,
                Variant::from(after.has_sensor),
            );
        }
        if let Err(e) = emit_changes(conn, COMPAT_PATH, COMPAT_BUS_NAME, c).await {
            tracing::warn!("compat PropertiesChanged emit failed: {e}");
        }
    }
}
