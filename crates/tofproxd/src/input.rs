//! The `input` publisher (`publisher = "input"`): Near as the switch `SW_FRONT_PROXIMITY` of a
//! uinput device, the way a phone's proximity sensor with a kernel input driver reports it.
//!
//! Why: on a phone whose accelerometer and light sensor are served by iio-sensor-proxy, the
//! name `net.hadess.SensorProxy` is iio-sensor-proxy's; our compatibility mode must not take
//! it (`run::refuse_compat_beside_iio_sensor_proxy`). iio-sensor-proxy reads proximity from
//! IIO devices (`drv-iio-poll-proximity`) and — in the input-proximity driver of the Maemo
//! Leste fork (`drv-input-proximity.c`, 2023), not in the upstream releases we could read —
//! from any input device whose switch capabilities include `SW_FRONT_PROXIMITY` (initial
//! state by `EVIOCGSW`, then `EV_SW` events). The udev rule `systemd/70-tofprox.rules` tags
//! our device with `IIO_SENSOR_PROXY_TYPE=input-proximity`, so iio-sensor-proxy's own rule
//! (`80-iio-sensor-proxy.rules`) starts its service for it (docs/daemon.md, "Beside
//! iio-sensor-proxy").
//!
//! The device description and the event stream are pure ([`DeviceDescription`],
//! [`near_events`], [`encode_events`]) and reach the kernel through the [`SwitchDevice`]
//! seam: [`UinputDevice`] on `/dev/uinput`, a recording fake in the tests.

use std::fs::File;
use std::io::Write;
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};

/// `EV_SYN` (linux/input-event-codes.h).
pub const EV_SYN: u16 = 0x00;
/// `EV_SW`: switch events.
pub const EV_SW: u16 = 0x05;
/// `SYN_REPORT`: the end of one report.
pub const SYN_REPORT: u16 = 0x00;
/// `SW_FRONT_PROXIMITY`: set = something near the front (the screen side).
pub const SW_FRONT_PROXIMITY: u16 = 0x0b;
/// `BUS_VIRTUAL` (linux/input.h): a device made in software.
pub const BUS_VIRTUAL: u16 = 0x06;
/// The device's name; the udev rule matches it (`ATTRS{name}`, systemd/70-tofprox.rules).
pub const DEVICE_NAME: &str = "tofprox proximity";
/// Where the kernel's uinput device usually is.
pub const UINPUT_PATH: &str = "/dev/uinput";

/// What the uinput device says it is: identity and capabilities.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceDescription {
    /// Device name (at most 79 bytes: `UINPUT_MAX_NAME_SIZE` with its NUL).
    pub name: &'static str,
    /// `input_id.bustype`.
    pub bustype: u16,
    /// `input_id.vendor` (0: none registered).
    pub vendor: u16,
    /// `input_id.product`.
    pub product: u16,
    /// `input_id.version`.
    pub version: u16,
    /// Event types besides `EV_SYN` (which every device has).
    pub event_types: Vec<u16>,
    /// Switch codes (`EV_SW`).
    pub switches: Vec<u16>,
}

impl DeviceDescription {
    /// The proximity switch: a virtual device with the one switch `SW_FRONT_PROXIMITY`.
    pub fn proximity() -> Self {
        Self {
            name: DEVICE_NAME,
            bustype: BUS_VIRTUAL,
            vendor: 0,
            product: 0,
            version: 1,
            event_types: vec![EV_SW],
            switches: vec![SW_FRONT_PROXIMITY],
        }
    }
}

/// One input event as written to uinput (the kernel stamps the time on delivery: uinput
/// ignores a time from user space; the capture's time is on D-Bus, `NearChangedNs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputEvent {
    /// `type` (`EV_SW`, `EV_SYN`).
    pub kind: u16,
    /// `code` (`SW_FRONT_PROXIMITY`, `SYN_REPORT`).
    pub code: u16,
    /// `value` (switch: 1 set, 0 clear).
    pub value: i32,
}

/// The events of one Near value: the switch, then the report that delivers it.
pub fn near_events(near: bool) -> [InputEvent; 2] {
    [
        InputEvent {
            kind: EV_SW,
            code: SW_FRONT_PROXIMITY,
            value: i32::from(near),
        },
        InputEvent {
            kind: EV_SYN,
            code: SYN_REPORT,
            value: 0,
        },
    ]
}

/// `struct input_event` bytes for `events` in this machine's layout: a zero `struct timeval`,
/// then `type`, `code` (u16) and `value` (i32), native byte order.
pub fn encode_events(events: &[InputEvent]) -> Vec<u8> {
    let time = std::mem::size_of::<libc::timeval>();
    let mut out = Vec::with_capacity(events.len() * (time + 8));
    for e in events {
        out.extend(std::iter::repeat_n(0u8, time));
        out.extend_from_slice(&e.kind.to_ne_bytes());
        out.extend_from_slice(&e.code.to_ne_bytes());
        out.extend_from_slice(&e.value.to_ne_bytes());
    }
    out
}

/// Where Near goes as input events: the uinput device, or a fake.
pub trait SwitchDevice: Send {
    /// Write these events (one report).
    fn write_events(&mut self, events: &[InputEvent]) -> std::io::Result<()>;
}

/// Publishes Near changes to a [`SwitchDevice`]. The device starts with the switch clear
/// (far), as Near does; only changes are written.
pub struct InputPublisher {
    device: Box<dyn SwitchDevice>,
    near: bool,
}

impl InputPublisher {
    /// Over a device just created (switch clear).
    pub fn new(device: Box<dyn SwitchDevice>) -> Self {
        Self {
            device,
            near: false,
        }
    }

    /// Publish `near` (written only when it changed).
    pub fn publish(&mut self, near: bool) -> std::io::Result<()> {
        if near == self.near {
            return Ok(());
        }
        self.device.write_events(&near_events(near))?;
        self.near = near;
        Ok(())
    }
}

#[async_trait::async_trait]
impl crate::publisher::Publisher for InputPublisher {
    fn name(&self) -> &'static str {
        "input"
    }

    async fn status(
        &mut self,
        change: crate::publisher::StatusChange<'_>,
    ) -> Result<(), crate::publisher::PublishError> {
        self.publish(change.after.near).map_err(|e| {
            crate::publisher::PublishError::new("input (writing Near to the uinput device)", e)
        })
    }
}

/// A [`SwitchDevice`] that keeps what it is sent: the stand-in for uinput where there is none
/// (the tests; clones share the record). Test machinery: only in the crate's own tests and
/// with the feature `testing`.
#[cfg(any(test, feature = "testing"))]
#[derive(Debug, Clone, Default)]
pub struct RecordingDevice(std::sync::Arc<std::sync::Mutex<Vec<InputEvent>>>);

#[cfg(any(test, feature = "testing"))]
impl RecordingDevice {
    /// Every event written so far, in order.
    pub fn events(&self) -> Vec<InputEvent> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

#[cfg(any(test, feature = "testing"))]
impl SwitchDevice for RecordingDevice {
    fn write_events(&mut self, events: &[InputEvent]) -> std::io::Result<()> {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .extend_from_slice(events);
        Ok(())
    }
}

/// Why the uinput device could not be made.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// `/dev/uinput` cannot be opened (missing module `uinput`, or no write permission).
    #[error(
        "cannot open {path} for the input publisher (is the uinput module loaded, and may this user write it? docs/daemon.md, \"Beside iio-sensor-proxy\"): {source}"
    )]
    Open {
        /// The device node.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// An ioctl setting up the device failed.
    #[error("uinput {step} failed: {source}")]
    Setup {
        /// Which request.
        step: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
    /// The name does not fit `UINPUT_MAX_NAME_SIZE`.
    #[error("uinput device name `{0}` is longer than 79 bytes")]
    NameTooLong(String),
}

/// `struct uinput_setup` (linux/uinput.h).
#[repr(C)]
struct UinputSetup {
    id: [u16; 4],
    name: [u8; 80],
    ff_effects_max: u32,
}

// ioctl requests of linux/uinput.h ('U' = 0x55): _IO(U, 1), _IO(U, 2), _IOW(U, 3, uinput_setup),
// _IOW(U, 100, int), _IOW(U, 109, int).
const UI_DEV_CREATE: libc::c_ulong = 0x5501;
const UI_DEV_DESTROY: libc::c_ulong = 0x5502;
const UI_DEV_SETUP: libc::c_ulong =
    0x4000_0000 | ((std::mem::size_of::<UinputSetup>() as libc::c_ulong) << 16) | 0x5503;
const UI_SET_EVBIT: libc::c_ulong = 0x4004_5564;
const UI_SET_SWBIT: libc::c_ulong = 0x4004_556d;

/// The kernel's uinput device: created on [`UinputDevice::create`], destroyed on drop.
pub struct UinputDevice {
    file: File,
}

impl UinputDevice {
    /// Open `path` (normally [`UINPUT_PATH`]) and create the device `desc` describes.
    pub fn create(path: &Path, desc: &DeviceDescription) -> Result<Self, InputError> {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(|source| InputError::Open {
                path: path.to_path_buf(),
                source,
            })?;
        let dev = Self { file };
        for &t in &desc.event_types {
            dev.ioctl_int("UI_SET_EVBIT", UI_SET_EVBIT, t)?;
        }
        for &s in &desc.switches {
            dev.ioctl_int("UI_SET_SWBIT", UI_SET_SWBIT, s)?;
        }
        let mut setup = UinputSetup {
            id: [desc.bustype, desc.vendor, desc.product, desc.version],
            name: [0; 80],
            ff_effects_max: 0,
        };
        let name = desc.name.as_bytes();
        if name.len() >= setup.name.len() {
            return Err(InputError::NameTooLong(desc.name.to_string()));
        }
        setup.name[..name.len()].copy_from_slice(name);
        #[allow(unsafe_code)]
        // SAFETY: UI_DEV_SETUP reads one `struct uinput_setup`, which `UinputSetup` lays out
        // (repr(C), same fields and size); the pointer is valid for the call.
        let rc = unsafe { libc::ioctl(dev.file.as_raw_fd(), UI_DEV_SETUP, &setup) };
        check("UI_DEV_SETUP", rc)?;
        #[allow(unsafe_code)]
        // SAFETY: UI_DEV_CREATE takes no argument.
        let rc = unsafe { libc::ioctl(dev.file.as_raw_fd(), UI_DEV_CREATE) };
        check("UI_DEV_CREATE", rc)?;
        Ok(dev)
    }

    fn ioctl_int(&self, step: &'static str, req: libc::c_ulong, v: u16) -> Result<(), InputError> {
        #[allow(unsafe_code)]
        // SAFETY: the UI_SET_*BIT requests take an int by value; no memory is passed.
        let rc = unsafe { libc::ioctl(self.file.as_raw_fd(), req, libc::c_int::from(v)) };
        check(step, rc)
    }
}

fn check(step: &'static str, rc: libc::c_int) -> Result<(), InputError> {
    if rc < 0 {
        return Err(InputError::Setup {
            step,
            source: std::io::Error::last_os_error(),
        });
    }
    Ok(())
}

impl SwitchDevice for UinputDevice {
    fn write_events(&mut self, events: &[InputEvent]) -> std::io::Result<()> {
        self.file.write_all(&encode_events(events))
    }
}

impl Drop for UinputDevice {
    fn drop(&mut self) {
        #[allow(unsafe_code)]
        // SAFETY: UI_DEV_DESTROY takes no argument; the fd is still open.
        let _ = unsafe { libc::ioctl(self.file.as_raw_fd(), UI_DEV_DESTROY) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_device_is_a_virtual_front_proximity_switch() {
        let d = DeviceDescription::proximity();
        // the numbers of linux/input-event-codes.h and linux/input.h, written out here
        assert_eq!(
            (d.bustype, d.event_types.clone(), d.switches.clone()),
            (6, vec![5], vec![11])
        );
        assert!(d.name.len() < 80);
    }

    /// The shipped udev rule tags this very device for iio-sensor-proxy: its event node, by
    /// the name the device is made with, with the type iio-sensor-proxy's rule starts it for.
    #[test]
    fn the_udev_rule_tags_the_device_for_iio_sensor_proxy() {
        let rules =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../systemd/70-tofprox.rules");
        let text = std::fs::read_to_string(rules).unwrap();
        let name = format!("ATTRS{{name}}==\"{}\"", DeviceDescription::proximity().name);
        let line = text
            .lines()
            .find(|l| !l.starts_with('#') && l.contains(&name))
            .expect("a rule for the device");
        for part in [
            "SUBSYSTEM==\"input\"",
            "KERNEL==\"event*\"",
            "ENV{IIO_SENSOR_PROXY_TYPE}+=\"input-proximity\"",
        ] {
            assert!(line.contains(part), "{part} in {line}");
        }
    }

    #[test]
    fn only_near_changes_are_written_each_as_switch_then_report() {
        let seen = RecordingDevice::default();
        let mut p = InputPublisher::new(Box::new(seen.clone()));
        for near in [false, true, true, false, false, true] {
            p.publish(near).unwrap();
        }
        let ev = |kind, code, value| InputEvent { kind, code, value };
        let (sw, syn) = (|v| ev(5, 11, v), ev(0, 0, 0));
        assert_eq!(
            seen.events(),
            vec![sw(1), syn, sw(0), syn, sw(1), syn],
            "far at creation: the first far is not written"
        );
    }

    /// The bytes match the C layout of `struct input_event` (libc's definition of it).
    #[test]
    fn events_encode_as_struct_input_event() {
        let bytes = encode_events(&near_events(true));
        let size = std::mem::size_of::<libc::input_event>();
        assert_eq!(bytes.len(), 2 * size);
        let at = |i: usize, off: usize, n: usize| &bytes[i * size + off..i * size + off + n];
        let t = std::mem::offset_of!(libc::input_event, type_);
        let c = std::mem::offset_of!(libc::input_event, code);
        let v = std::mem::offset_of!(libc::input_event, value);
        assert_eq!(at(0, t, 2), 5u16.to_ne_bytes());
        assert_eq!(at(0, c, 2), 11u16.to_ne_bytes());
        assert_eq!(at(0, v, 4), 1i32.to_ne_bytes());
        assert_eq!(at(1, t, 2), 0u16.to_ne_bytes());
        assert!(
            at(0, 0, t).iter().all(|&b| b == 0),
            "time left to the kernel"
        );
    }

    #[test]
    fn uinput_setup_has_the_kernel_size_and_a_missing_node_is_a_clear_error() {
        assert_eq!(std::mem::size_of::<UinputSetup>(), 92);
        assert_eq!(UI_DEV_SETUP, 0x405c_5503);
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("uinput");
        let e = UinputDevice::create(&missing, &DeviceDescription::proximity())
            .err()
            .expect("no device node");
        let msg = e.to_string();
        assert!(
            msg.contains("uinput") && msg.contains(&missing.display().to_string()),
            "{msg}"
        );
        // a node that is no uinput device refuses the first request
        std::fs::write(&missing, b"").unwrap();
        let e = UinputDevice::create(&missing, &DeviceDescription::proximity())
            .err()
            .expect("not a uinput device");
        assert!(
            e.to_string().starts_with("uinput UI_SET_EVBIT failed"),
            "{e}"
        );
    }
}
