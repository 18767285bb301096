//! tofprox sensor bridge: USB transport, CX3 protocol, sensor driver,
//! emulated device.
//!
//! Layers, each behind a trait and tested without the one below:
//! 1. [`transport`]: [`UsbTransport`] (blocking control/bulk transfers with
//!    timeouts); [`usb::RusbTransport`] over libusb, [`EmulatedDevice`].
//! 2. [`protocol`] (CX3 vendor requests: I2C, GPIO, streaming) and [`uvc`]
//!    (payload headers, frame reassembly), [`frame`] (status line, pixels).
//! 3. [`driver`]: [`SensorDriver`] runs the thesis's per-cycle sequence
//!    using the register map of [`regmap`] and the flash image of [`flash`].
//! 4. [`emulated`]: the transfer-level emulated device with fault injection.
//!
//! Every call blocks; see [`stream::DriverThread`] for running the driver off
//! an async runtime. All waits sleep on an injected [`Clock`].

pub mod clock;
pub mod driver;
pub mod emulated;
pub mod error;
pub mod flash;
pub mod frame;
pub mod protocol;
pub mod regmap;
pub mod stream;
pub mod transport;
pub mod usb;
pub mod uvc;

pub use clock::{Clock, SystemClock, VirtualClock};
pub use driver::{
    CycleOutput, CycleRequest, DeviceConfigFile, DriverConfig, DriverConfigFile, DriverStats,
    DriverTiming, SensorDriver, SensorMode, StateTimings,
};
pub use emulated::{EmulatedConfig, EmulatedDevice, FaultKind};
pub use error::{BridgeError, ErrorKind};
pub use protocol::ProtocolConfig;
pub use regmap::SensorMap;
/// The shared vocabulary the driver speaks (`tofprox-core`), re-exported for its callers.
pub use tofprox_core::{Algorithm, RowWindow, SensorGeometry};
pub use transport::{ControlSetup, UsbTransport};
pub use usb::{RusbTransport, UsbSelector};
