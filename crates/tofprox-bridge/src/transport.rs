//! Layer 1: the USB transport trait. Everything above (CX3 protocol, sensor
//! driver) talks to a [`UsbTransport`]; the real one is
//! [`crate::usb::RusbTransport`], the emulated one
//! `emulated::EmulatedDevice` (feature `emulated`), and tests use scripted fakes.
//!
//! All calls **block** until the transfer completes or its timeout expires.
//! In an async program run them off the runtime: the whole driver cycle on a
//! dedicated thread feeding a bounded channel (as the daemon's loop thread does), or
//! short control transfers on a blocking pool.

use std::time::Duration;

use crate::error::BridgeError;

/// bmRequestType direction bit: device-to-host.
pub const DIR_IN: u8 = 0x80;
/// bmRequestType type field: vendor request.
pub const TYPE_VENDOR: u8 = 0x40;
/// bmRequestType recipient field: device.
pub const RECIPIENT_DEVICE: u8 = 0x00;

/// The 8-byte SETUP packet of a control transfer, minus wLength (taken from
/// the buffer length).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ControlSetup {
    /// bmRequestType (direction | type | recipient).
    pub request_type: u8,
    /// bRequest.
    pub request: u8,
    /// wValue.
    pub value: u16,
    /// wIndex.
    pub index: u16,
}

impl ControlSetup {
    /// A vendor request to the device, host-to-device.
    pub fn vendor_out(request: u8, value: u16, index: u16) -> Self {
        ControlSetup {
            request_type: TYPE_VENDOR | RECIPIENT_DEVICE,
            request,
            value,
            index,
        }
    }

    /// A vendor request to the device, device-to-host.
    pub fn vendor_in(request: u8, value: u16, index: u16) -> Self {
        ControlSetup {
            request_type: DIR_IN | TYPE_VENDOR | RECIPIENT_DEVICE,
            request,
            value,
            index,
        }
    }

    /// True for device-to-host requests.
    pub fn is_in(&self) -> bool {
        self.request_type & DIR_IN != 0
    }

    /// The SETUP packet as it goes on the wire (little-endian fields, USB 2.0
    /// 9.3), with `length` as wLength.
    pub fn to_bytes(&self, length: u16) -> [u8; 8] {
        let v = self.value.to_le_bytes();
        let i = self.index.to_le_bytes();
        let l = length.to_le_bytes();
        [
            self.request_type,
            self.request,
            v[0],
            v[1],
            i[0],
            i[1],
            l[0],
            l[1],
        ]
    }
}

/// Blocking USB transfers with timeouts.
///
/// Errors use the kinds `Disconnected` (device gone: call [`reopen`]),
/// `Timeout`, `Stall` (call [`clear_halt`] for bulk endpoints; a stalled
/// control request is a protocol-level refusal), `Io`.
///
/// [`reopen`]: UsbTransport::reopen
/// [`clear_halt`]: UsbTransport::clear_halt
pub trait UsbTransport: Send {
    /// Control transfer device-to-host; returns the number of bytes read.
    fn control_in(
        &mut self,
        setup: ControlSetup,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError>;
    /// Control transfer host-to-device; returns the number of bytes written.
    fn control_out(
        &mut self,
        setup: ControlSetup,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError>;
    /// Bulk IN on `endpoint` (with the 0x80 bit); returns bytes read (one
    /// payload: a transfer ends at a short packet).
    fn bulk_in(
        &mut self,
        endpoint: u8,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError>;
    /// Bulk OUT on `endpoint`; returns bytes written.
    fn bulk_out(
        &mut self,
        endpoint: u8,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError>;
    /// Clear a halt (stall) on an endpoint.
    fn clear_halt(&mut self, endpoint: u8) -> Result<(), BridgeError>;
    /// Drop the current handle and open the device again (after an unplug or
    /// a `Disconnected` error). Fails with `NotFound` while it is absent.
    fn reopen(&mut self) -> Result<(), BridgeError>;
    /// One-line description of the device (for logs and `device probe`).
    fn describe(&self) -> String;
}

impl<T: UsbTransport + ?Sized> UsbTransport for Box<T> {
    fn control_in(
        &mut self,
        setup: ControlSetup,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        (**self).control_in(setup, buf, timeout)
    }
    fn control_out(
        &mut self,
        setup: ControlSetup,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        (**self).control_out(setup, data, timeout)
    }
    fn bulk_in(
        &mut self,
        endpoint: u8,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        (**self).bulk_in(endpoint, buf, timeout)
    }
    fn bulk_out(
        &mut self,
        endpoint: u8,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, BridgeError> {
        (**self).bulk_out(endpoint, data, timeout)
    }
    fn clear_halt(&mut self, endpoint: u8) -> Result<(), BridgeError> {
        (**self).clear_halt(endpoint)
    }
    fn reopen(&mut self) -> Result<(), BridgeError> {
        (**self).reopen()
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn setup_packet_bytes_are_little_endian() {
        let s = ControlSetup::vendor_in(0xB2, 0x003D, 0x9400);
        assert_eq!(
            s.to_bytes(4),
            [0xC0, 0xB2, 0x3D, 0x00, 0x00, 0x94, 0x04, 0x00]
        );
        assert!(s.is_in());
        let o = ControlSetup::vendor_out(0xB3, 1, 0);
        assert_eq!(
            o.to_bytes(0),
            [0x40, 0xB3, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00]
        );
        assert!(!o.is_in());
    }
}
