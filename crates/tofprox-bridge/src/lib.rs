//! tofprox sensor bridge: USB transport, CX3 protocol, sensor driver,
//! emulated device.
//!
//! Layers, each behind a trait and tested without the one below:
//! 1. [`transport`]: [`UsbTransport`] (blocking control/bulk transfers with
//!    timeouts); [`usb::RusbTransport`] over libusb, `EmulatedDevice`.
//! 2. [`protocol`] (CX3 vendor requests: I2C, GPIO, streaming) and [`uvc`]
//!    (payload headers, frame reassembly), [`frame`] (status line, pixels).
//! 3. [`driver`]: [`SensorDriver`] runs the thesis's per-cycle sequence
//!    using the register map of [`regmap`] and the flash image of [`flash`].
//! 4. `emulated` (cargo feature `emulated`, on by default): the transfer-level
//!    emulated device with fault injection, synthesising frames with the
//!    physical model (`tofprox-model`). Without the feature the crate does
//!    not link the model: `cargo build -p tofprox-bridge --no-default-features`.
//!
//! 5. [`v4l2`]: a V4L2 capture device (a single-board computer's ToF kernel driver) behind
//!    the ioctl-level seam [`v4l2::V4l2Device`], the real device (`v4l2::sys`, Linux) and a
//!    fake (feature `v4l2-fake`, tests only); [`v4l2::camera::V4l2Camera`] captures one
//!    stacked buffer per cycle.
//!
//! Every call blocks (the daemon runs the driver on its own loop thread). All
//! waits sleep on an injected [`Clock`].

pub mod clock;
pub mod decode;
pub mod driver;
#[cfg(feature = "emulated")]
pub mod emulated;
pub mod error;
pub mod flash;
pub mod frame;
pub mod pixels;
pub mod protocol;
pub mod regmap;
pub mod transport;
pub mod usb;
pub mod usbcap;
pub mod uvc;
pub mod v4l2;

pub use clock::{Clock, SystemClock, VirtualClock};
pub use driver::{
    CycleOutput, CycleRequest, DeviceConfigFile, DriverConfig, DriverConfigFile, DriverStats,
    DriverTiming, SensorDriver, SensorMode, StateTimings,
};
#[cfg(feature = "emulated")]
pub use emulated::{EmulatedConfig, EmulatedDevice, FaultKind};
pub use error::{BridgeError, ErrorKind};
pub use protocol::ProtocolConfig;
pub use regmap::SensorMap;
/// The shared vocabulary the driver speaks (`tofprox-core`), re-exported for its callers.
pub use tofprox_core::{Algorithm, RowWindow, SensorGeometry};
pub use transport::{ControlSetup, UsbTransport};
pub use usb::{RusbTransport, UsbSelector};
