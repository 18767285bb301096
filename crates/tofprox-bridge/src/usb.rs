//! The real transport: libusb through `rusb` (libusb built from source, the
//! `vendored` feature, so no system headers are needed).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::error::{BridgeError, ErrorKind};
use crate::transport::{ControlSetup, UsbTransport};

/// Which USB device to use.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UsbSelector {
    /// Vendor id (default: Cypress 0x04b4).
    pub vendor_id: u16,
    /// Product id (default: CX3 UVC example firmware 0x00c3).
    pub product_id: u16,
    /// Only the device with this serial number string.
    pub serial: Option<String>,
    /// Only the device at this bus path, `BUS-PORT[.PORT...]` (as in sysfs,
    /// e.g. `1-2.3`).
    pub bus_path: Option<String>,
    /// Interface to claim (holds the bulk IN endpoint).
    pub interface: u8,
}

impl Default for UsbSelector {
    fn default() -> Self {
        UsbSelector {
            vendor_id: 0x04B4,
            product_id: 0x00C3,
            serial: None,
            bus_path: None,
            interface: 0,
        }
    }
}

/// A device found by [`probe`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ProbedDevice {
    /// Bus number.
    pub bus: u8,
    /// Device address on the bus.
    pub address: u8,
    /// `BUS-PORT.PORT` path.
    pub bus_path: String,
    /// Vendor id.
    pub vendor_id: u16,
    /// Product id.
    pub product_id: u16,
    /// Serial number string, if readable.
    pub serial: Option<String>,
    /// Product string, if readable.
    pub product: Option<String>,
}

fn map_rusb(e: rusb::Error, what: impl Into<String>) -> BridgeError {
    let kind = match e {
        rusb::Error::NoDevice => ErrorKind::Disconnected,
        rusb::Error::NotFound => ErrorKind::NotFound,
        rusb::Error::Timeout => ErrorKind::Timeout,
        rusb::Error::Pipe => ErrorKind::Stall,
        rusb::Error::Access | rusb::Error::Busy => ErrorKind::Access,
        _ => ErrorKind::Io,
    };
    BridgeError::with_source(kind, what, e)
}

fn bus_path(dev: &rusb::Device<rusb::Context>) -> String {
    let ports = dev.port_numbers().unwrap_or_default();
    let p: Vec<String> = ports.iter().map(|p| p.to_string()).collect();
    if p.is_empty() {
        format!("{}-0", dev.bus_number())
    } else {
        format!("{}-{}", dev.bus_number(), p.join("."))
    }
}

fn describe(dev: &rusb::Device<rusb::Context>) -> Option<ProbedDevice> {
    let d = dev.device_descriptor().ok()?;
    let (serial, product) = match dev.open() {
        Ok(h) => (
            h.read_serial_number_string_ascii(&d).ok(),
            h.read_product_string_ascii(&d).ok(),
        ),
        Err(_) => (None, None),
    };
    Some(ProbedDevice {
        bus: dev.bus_number(),
        address: dev.address(),
        bus_path: bus_path(dev),
        vendor_id: d.vendor_id(),
        product_id: d.product_id(),
        serial,
        product,
    })
}

fn context() -> Result<rusb::Context, BridgeError> {
    rusb::Context::new().map_err(|e| map_rusb(e, "cannot initialise libusb"))
}

/// List the devices matching `sel`. A machine without a USB stack (no
/// `/dev/bus/usb`, libusb cannot initialise) has no devices: an empty list,
/// not an error.
pub fn probe(sel: &UsbSelector) -> Result<Vec<ProbedDevice>, BridgeError> {
    use rusb::UsbContext as _;
    let ctx = match rusb::Context::new() {
        Ok(c) => c,
        Err(e) => {
            tracing::debug!("libusb unavailable ({e}): no USB devices");
            return Ok(Vec::new());
        }
    };
    let list = match ctx.devices() {
        Ok(l) => l,
        Err(e) => {
            tracing::debug!("cannot list USB devices ({e})");
            return Ok(Vec::new());
        }
    };
    let mut out = Vec::new();
    for dev in list.iter() {
        let Ok(d) = dev.device_descriptor() else {
            continue;
        };
        if d.vendor_id() != sel.vendor_id || d.product_id() != sel.product_id {
            continue;
        }
        let Some(p) = describe(&dev) else { continue };
        if sel.bus_path.as_deref().is_some_and(|b| b != p.bus_path) {
            continue;
        }
        if sel.serial.is_some() && sel.serial != p.serial {
            continue;
        }
        out.push(p);
    }
    Ok(out)
}

/// The CX3 over libusb.
pub struct RusbTransport {
    sel: UsbSelector,
    handle: Option<rusb::DeviceHandle<rusb::Context>>,
    info: Option<ProbedDevice>,
}

impl std::fmt::Debug for RusbTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RusbTransport")
            .field("sel", &self.sel)
            .field("info", &self.info)
            .finish()
    }
}

impl RusbTransport {
    /// Open the first device matching `sel` and claim its interface.
    /// `NotFound` when none matches.
    pub fn open(sel: UsbSelector) -> Result<Self, BridgeError> {
        let mut t = RusbTransport {
            sel,
            handle: None,
            info: None,
        };
        t.reopen()?;
        Ok(t)
    }

    fn handle(&self) -> Result<&rusb::DeviceHandle<rusb::Context>, BridgeError> {
        self.handle
            .as_ref()
            .ok_or_else(|| BridgeError::new(ErrorKind::Disconnected, "device not open"))
    }
}

impl UsbTransport for RusbTransport {
    fn control_in(
        &mut self,
        s: ControlSetup,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        self.handle()?
            .read_control(s.request_type, s.request, s.value, s.index, buf, timeout)
            .map_err(|e| map_rusb(e, format!("control IN request {:#04x}", s.request)))
    }
    fn control_out(
        &mut self,
        s: ControlSetup,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        self.handle()?
            .write_control(s.request_type, s.request, s.value, s.index, data, timeout)
            .map_err(|e| map_rusb(e, format!("control OUT request {:#04x}", s.request)))
    }
    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, BridgeError> {
        self.handle()?
            .read_bulk(ep, buf, timeout)
            .map_err(|e| map_rusb(e, format!("bulk IN {ep:#04x}")))
    }
    fn bulk_out(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<usize, BridgeError> {
        self.handle()?
            .write_bulk(ep, data, timeout)
            .map_err(|e| map_rusb(e, format!("bulk OUT {ep:#04x}")))
    }
    fn clear_halt(&mut self, ep: u8) -> Result<(), BridgeError> {
        self.handle()?
            .clear_halt(ep)
            .map_err(|e| map_rusb(e, format!("clear halt {ep:#04x}")))
    }
    fn reopen(&mut self) -> Result<(), BridgeError> {
        use rusb::UsbContext as _;
        self.handle = None;
        let found = probe(&self.sel)?;
        let Some(want) = found.first().cloned() else {
            return Err(BridgeError::new(
                ErrorKind::NotFound,
                format!(
                    "no matching device found ({:04x}:{:04x}{}{})",
                    self.sel.vendor_id,
                    self.sel.product_id,
                    self.sel
                        .serial
                        .as_deref()
                        .map(|s| format!(" serial {s}"))
                        .unwrap_or_default(),
                    self.sel
                        .bus_path
                        .as_deref()
                        .map(|s| format!(" at {s}"))
                        .unwrap_or_default()
                ),
            ));
        };
        let ctx = context()?;
        let list = ctx.devices().map_err(|e| map_rusb(e, "list USB devices"))?;
        let dev = list
            .iter()
            .find(|d| d.bus_number() == want.bus && d.address() == want.address)
            .ok_or_else(|| {
                BridgeError::new(ErrorKind::Disconnected, "device vanished while opening")
            })?;
        let h = dev
            .open()
            .map_err(|e| map_rusb(e, format!("open {}", want.bus_path)))?;
        let _ = h.set_auto_detach_kernel_driver(true);
        h.claim_interface(self.sel.interface)
            .map_err(|e| map_rusb(e, format!("claim interface {}", self.sel.interface)))?;
        self.handle = Some(h);
        self.info = Some(want);
        Ok(())
    }
    fn describe(&self) -> String {
        match &self.info {
            Some(i) => format!(
                "{:04x}:{:04x} at {} (bus {} address {}){}",
                i.vendor_id,
                i.product_id,
                i.bus_path,
                i.bus,
                i.address,
                i.serial
                    .as_deref()
                    .map(|s| format!(" serial {s}"))
                    .unwrap_or_default()
            ),
            None => "USB device (not open)".into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn open_without_device_is_not_found() {
        // This machine (and CI) has no CX3 attached: a clear NotFound, or an
        // empty probe. A real bridge attached would make this test moot,
        // so only assert the no-device outcome when probe finds none.
        let sel = UsbSelector::default();
        let found = probe(&sel).unwrap();
        if found.is_empty() {
            let e = RusbTransport::open(sel).unwrap_err();
            assert!(
                matches!(e.kind(), ErrorKind::NotFound | ErrorKind::Io),
                "{e}"
            );
        }
    }

    #[test]
    fn libusb_errors_map_to_kinds() {
        let k = |e| map_rusb(e, "x").kind();
        assert_eq!(k(rusb::Error::NoDevice), ErrorKind::Disconnected);
        assert_eq!(k(rusb::Error::Timeout), ErrorKind::Timeout);
        assert_eq!(k(rusb::Error::Pipe), ErrorKind::Stall);
        assert_eq!(k(rusb::Error::Access), ErrorKind::Access);
        assert_eq!(k(rusb::Error::Busy), ErrorKind::Access);
        assert_eq!(k(rusb::Error::NotFound), ErrorKind::NotFound);
        assert_eq!(k(rusb::Error::Overflow), ErrorKind::Io);
    }

    #[test]
    fn selector_rejects_unknown_keys() {
        assert!(toml::from_str::<UsbSelector>("vendor = 1").is_err());
        let s: UsbSelector = toml::from_str("vendor_id = 0x1234\nserial = \"A1\"").unwrap();
        assert_eq!((s.vendor_id, s.serial.as_deref()), (0x1234, Some("A1")));
    }
}
