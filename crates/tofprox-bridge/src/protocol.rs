//! Layer 2a: the CX3 bridge's vendor control requests (see `docs/protocol.md`).
//!
//! The request encoders are pure (`encode_*`: a setup packet plus payload
//! bytes), so every request is golden-byte tested; [`Cx3`] executes them on a
//! [`UsbTransport`]. Every request code, endpoint and timeout comes from
//! [`ProtocolConfig`] because bridge firmwares differ.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::error::{BridgeError, ErrorKind};
use crate::transport::{ControlSetup, UsbTransport};

/// Vendor request codes, GPIO numbers, endpoints and timeouts of the bridge
/// firmware. Defaults match the emulated device and `docs/protocol.md`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProtocolConfig {
    /// bRequest: I2C write (OUT; wValue = 7-bit address, wIndex = first
    /// register, data = big-endian 16-bit values, registers auto-increment).
    pub req_i2c_write: u8,
    /// bRequest: I2C read (IN; wValue = address, wIndex = first register,
    /// wLength = 2 × count, big-endian values).
    pub req_i2c_read: u8,
    /// bRequest: GPIO set (OUT; wValue = pin, wIndex = level 0/1, no data).
    pub req_gpio: u8,
    /// bRequest: start streaming on the bulk IN endpoint (OUT, no data).
    pub req_stream_start: u8,
    /// bRequest: stop streaming (OUT, no data).
    pub req_stream_stop: u8,
    /// bRequest: last-error status (IN, 4 bytes: code, i2c address,
    /// register high, register low). Read after a control request stalled.
    pub req_status: u8,
    /// GPIO number of the sensor's active-low reset pin.
    pub gpio_reset: u16,
    /// GPIO number of the sensor's standby pin (active high).
    pub gpio_standby: u16,
    /// Bulk IN endpoint address carrying the UVC-style payloads.
    pub bulk_in_endpoint: u8,
    /// Largest payload (one bulk transfer) the firmware sends, bytes.
    pub max_payload_bytes: usize,
    /// Most 16-bit values in one I2C write request (longer bursts are split).
    pub max_burst_words: usize,
    /// Most 16-bit values in one I2C read request.
    pub max_read_words: usize,
    /// Timeout of every control request, milliseconds.
    pub control_timeout_ms: u64,
    /// Timeout of one bulk IN transfer, milliseconds (must cover exposure +
    /// read-out of one raw frame).
    pub bulk_timeout_ms: u64,
}

impl Default for ProtocolConfig {
    fn default() -> Self {
        ProtocolConfig {
            req_i2c_write: 0xB1,
            req_i2c_read: 0xB2,
            req_gpio: 0xB3,
            req_stream_start: 0xB4,
            req_stream_stop: 0xB5,
            req_status: 0xBF,
            gpio_reset: 0,
            gpio_standby: 1,
            bulk_in_endpoint: 0x81,
            max_payload_bytes: 16384,
            max_burst_words: 64,
            max_read_words: 128,
            control_timeout_ms: 100,
            bulk_timeout_ms: 1000,
        }
    }
}

impl ProtocolConfig {
    /// Check ranges; errors name the key.
    pub fn validate(&self) -> Result<(), BridgeError> {
        if self.bulk_in_endpoint & 0x80 == 0 {
            return Err(BridgeError::config(format!(
                "protocol.bulk_in_endpoint = {:#04x} is not an IN endpoint (bit 7 clear)",
                self.bulk_in_endpoint
            )));
        }
        if !(16..=1 << 20).contains(&self.max_payload_bytes) {
            return Err(BridgeError::config(format!(
                "protocol.max_payload_bytes = {} out of range 16..=1048576",
                self.max_payload_bytes
            )));
        }
        for (k, v) in [
            ("max_burst_words", self.max_burst_words),
            ("max_read_words", self.max_read_words),
        ] {
            if !(1..=2048).contains(&v) {
                return Err(BridgeError::config(format!(
                    "protocol.{k} = {v} out of range 1..=2048"
                )));
            }
        }
        for (k, v) in [
            ("control_timeout_ms", self.control_timeout_ms),
            ("bulk_timeout_ms", self.bulk_timeout_ms),
        ] {
            if !(1..=60_000).contains(&v) {
                return Err(BridgeError::config(format!(
                    "protocol.{k} = {v} out of range 1..=60000"
                )));
            }
        }
        Ok(())
    }

    /// Control timeout as a duration.
    pub fn control_timeout(&self) -> Duration {
        Duration::from_millis(self.control_timeout_ms)
    }

    /// Bulk timeout as a duration.
    pub fn bulk_timeout(&self) -> Duration {
        Duration::from_millis(self.bulk_timeout_ms)
    }
}

/// Status codes of the `req_status` reply.
pub mod status {
    /// No error.
    pub const OK: u8 = 0x00;
    /// The I2C target did not acknowledge (address or data phase).
    pub const I2C_NAK: u8 = 0x01;
    /// I2C bus error / arbitration lost.
    pub const I2C_BUS: u8 = 0x02;
    /// I2C clock stretching exceeded the firmware's limit.
    pub const I2C_TIMEOUT: u8 = 0x03;
    /// Request not understood (bad arguments).
    pub const BAD_REQUEST: u8 = 0x04;
}

/// One encoded control request: the setup packet, data for OUT requests, the
/// length to read for IN requests.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControlRequest {
    /// SETUP fields.
    pub setup: ControlSetup,
    /// OUT payload (empty for IN requests).
    pub data: Vec<u8>,
    /// wLength of an IN request (0 for OUT).
    pub in_len: usize,
}

impl ControlRequest {
    /// The request as wire bytes: the 8-byte SETUP packet followed by the OUT
    /// data stage (what the golden tests compare).
    #[cfg(test)]
    fn wire_bytes(&self) -> Vec<u8> {
        let len = if self.setup.is_in() {
            self.in_len
        } else {
            self.data.len()
        };
        let mut v = self
            .setup
            .to_bytes(u16::try_from(len).unwrap_or(u16::MAX))
            .to_vec();
        v.extend_from_slice(&self.data);
        v
    }
}

fn check_addr(addr: u8) -> Result<(), BridgeError> {
    if addr > 0x7F {
        return Err(BridgeError::config(format!(
            "I2C address {addr:#04x} is not a 7-bit address"
        )));
    }
    Ok(())
}

/// Encode an I2C burst write of `values` to consecutive 16-bit registers
/// starting at `reg`, split into requests of at most `max_burst_words`.
pub fn encode_i2c_write(
    cfg: &ProtocolConfig,
    addr: u8,
    reg: u16,
    values: &[u16],
) -> Result<Vec<ControlRequest>, BridgeError> {
    check_addr(addr)?;
    if values.is_empty() {
        return Err(BridgeError::config(format!(
            "empty I2C write to register {reg:#06x}"
        )));
    }
    let last = usize::from(reg) + values.len() - 1;
    if last > usize::from(u16::MAX) {
        return Err(BridgeError::config(format!(
            "I2C burst from {reg:#06x} of {} words runs past register 0xffff",
            values.len()
        )));
    }
    let chunk = cfg.max_burst_words.max(1);
    let mut out = Vec::with_capacity(values.len().div_ceil(chunk));
    for (i, part) in values.chunks(chunk).enumerate() {
        // cannot overflow: checked `last` above
        let start = reg.wrapping_add(u16::try_from(i * chunk).unwrap_or(0));
        let mut data = Vec::with_capacity(part.len() * 2);
        for v in part {
            data.extend_from_slice(&v.to_be_bytes());
        }
        out.push(ControlRequest {
            setup: ControlSetup::vendor_out(cfg.req_i2c_write, u16::from(addr), start),
            data,
            in_len: 0,
        });
    }
    Ok(out)
}

/// Encode an I2C read of `count` consecutive 16-bit registers from `reg`
/// (one request; callers split at `max_read_words`).
pub fn encode_i2c_read(
    cfg: &ProtocolConfig,
    addr: u8,
    reg: u16,
    count: usize,
) -> Result<ControlRequest, BridgeError> {
    check_addr(addr)?;
    if count == 0 || count > cfg.max_read_words {
        return Err(BridgeError::config(format!(
            "I2C read of {count} words from {reg:#06x}: allowed 1..={}",
            cfg.max_read_words
        )));
    }
    if usize::from(reg) + count - 1 > usize::from(u16::MAX) {
        return Err(BridgeError::config(format!(
            "I2C read from {reg:#06x} of {count} words runs past register 0xffff"
        )));
    }
    Ok(ControlRequest {
        setup: ControlSetup::vendor_in(cfg.req_i2c_read, u16::from(addr), reg),
        data: Vec::new(),
        in_len: count * 2,
    })
}

/// Encode a GPIO level change.
pub fn encode_gpio(cfg: &ProtocolConfig, pin: u16, high: bool) -> ControlRequest {
    ControlRequest {
        setup: ControlSetup::vendor_out(cfg.req_gpio, pin, u16::from(high)),
        data: Vec::new(),
        in_len: 0,
    }
}

/// Encode stream start (`true`) or stop.
pub fn encode_stream(cfg: &ProtocolConfig, start: bool) -> ControlRequest {
    let req = if start {
        cfg.req_stream_start
    } else {
        cfg.req_stream_stop
    };
    ControlRequest {
        setup: ControlSetup::vendor_out(req, 0, 0),
        data: Vec::new(),
        in_len: 0,
    }
}

/// Encode the last-error status read.
pub fn encode_status(cfg: &ProtocolConfig) -> ControlRequest {
    ControlRequest {
        setup: ControlSetup::vendor_in(cfg.req_status, 0, 0),
        data: Vec::new(),
        in_len: 4,
    }
}

/// Decode big-endian 16-bit words.
pub fn decode_words(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks_exact(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect()
}

/// The CX3 bridge on top of a transport: executes the encoded requests and
/// turns a stalled I2C request into a typed `Nak` error by reading the status.
#[derive(Debug, Clone)]
pub struct Cx3 {
    cfg: ProtocolConfig,
}

impl Cx3 {
    /// A bridge speaking `cfg`.
    pub fn new(cfg: ProtocolConfig) -> Result<Self, BridgeError> {
        cfg.validate()?;
        Ok(Cx3 { cfg })
    }

    /// The protocol settings.
    pub fn config(&self) -> &ProtocolConfig {
        &self.cfg
    }

    fn run_out<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        r: &ControlRequest,
        what: &dyn Fn() -> String,
    ) -> Result<(), BridgeError> {
        match t.control_out(r.setup, &r.data, self.cfg.control_timeout()) {
            Ok(n) if n == r.data.len() => Ok(()),
            Ok(n) => Err(BridgeError::new(
                ErrorKind::Protocol,
                format!(
                    "{}: short control write ({n} of {} bytes)",
                    what(),
                    r.data.len()
                ),
            )),
            Err(e) if e.kind() == ErrorKind::Stall => Err(self.explain_stall(t, e, what)),
            Err(e) => Err(e.context_prefix(what())),
        }
    }

    /// After a control request stalled, ask the firmware why.
    fn explain_stall<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        stall: BridgeError,
        what: &dyn Fn() -> String,
    ) -> BridgeError {
        let req = encode_status(&self.cfg);
        let mut buf = [0u8; 4];
        match t.control_in(req.setup, &mut buf, self.cfg.control_timeout()) {
            Ok(4) => {
                let reg = u16::from_be_bytes([buf[2], buf[3]]);
                match buf[0] {
                    status::I2C_NAK => BridgeError::new(
                        ErrorKind::Nak,
                        format!(
                            "{}: I2C target {:#04x} did not acknowledge (register {reg:#06x})",
                            what(),
                            buf[1]
                        ),
                    ),
                    status::I2C_BUS => BridgeError::new(
                        ErrorKind::Nak,
                        format!("{}: I2C bus error at register {reg:#06x}", what()),
                    ),
                    status::I2C_TIMEOUT => BridgeError::new(
                        ErrorKind::Timeout,
                        format!(
                            "{}: I2C clock stretching timeout at register {reg:#06x}",
                            what()
                        ),
                    ),
                    code => BridgeError::new(
                        ErrorKind::Stall,
                        format!(
                            "{}: request refused by the bridge (status {code:#04x})",
                            what()
                        ),
                    ),
                }
            }
            _ => stall.context_prefix(what()),
        }
    }

    /// Write `values` to consecutive registers from `reg` of I2C target `addr`.
    pub fn i2c_write<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        addr: u8,
        reg: u16,
        values: &[u16],
    ) -> Result<(), BridgeError> {
        let chunk = self.cfg.max_burst_words.max(1);
        for (i, r) in encode_i2c_write(&self.cfg, addr, reg, values)?
            .iter()
            .enumerate()
        {
            let first = usize::from(reg) + i * chunk;
            self.run_out(t, r, &|| {
                format!("I2C write {addr:#04x} register {first:#06x}")
            })?;
        }
        Ok(())
    }

    /// Read `count` consecutive registers from `reg`.
    pub fn i2c_read<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        addr: u8,
        reg: u16,
        count: usize,
    ) -> Result<Vec<u16>, BridgeError> {
        // checked before allocating: `count` may come straight from a user
        if usize::from(reg)
            .checked_add(count)
            .is_none_or(|end| end > 0x1_0000)
        {
            return Err(BridgeError::config(format!(
                "I2C read of {count} registers from {reg:#06x} runs past register 0xffff"
            )));
        }
        let mut out = Vec::with_capacity(count);
        let step = self.cfg.max_read_words.max(1);
        let mut done = 0usize;
        while done < count {
            let n = step.min(count - done);
            let start = usize::from(reg) + done;
            let start16 = u16::try_from(start).map_err(|_| {
                BridgeError::config(format!("I2C read past register 0xffff (from {reg:#06x})"))
            })?;
            let r = encode_i2c_read(&self.cfg, addr, start16, n)?;
            let mut buf = vec![0u8; r.in_len];
            let what = || format!("I2C read {addr:#04x} register {start:#06x}");
            match t.control_in(r.setup, &mut buf, self.cfg.control_timeout()) {
                Ok(got) if got == r.in_len => out.extend(decode_words(&buf)),
                Ok(got) => {
                    return Err(BridgeError::new(
                        ErrorKind::Protocol,
                        format!("{}: short reply ({got} of {} bytes)", what(), r.in_len),
                    ));
                }
                Err(e) if e.kind() == ErrorKind::Stall => {
                    return Err(self.explain_stall(t, e, &what));
                }
                Err(e) => return Err(e.context_prefix(what())),
            }
            done += n;
        }
        Ok(out)
    }

    /// Read one register.
    pub fn i2c_read1<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        addr: u8,
        reg: u16,
    ) -> Result<u16, BridgeError> {
        let v = self.i2c_read(t, addr, reg, 1)?;
        v.first().copied().ok_or_else(|| {
            BridgeError::new(ErrorKind::Protocol, format!("empty read of {reg:#06x}"))
        })
    }

    /// Set a GPIO pin level.
    pub fn gpio<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        pin: u16,
        high: bool,
    ) -> Result<(), BridgeError> {
        let r = encode_gpio(&self.cfg, pin, high);
        self.run_out(t, &r, &|| {
            format!("GPIO {pin} {}", if high { "high" } else { "low" })
        })
    }

    /// Drive the sensor's reset pin: `true` holds it in reset (pin low).
    pub fn set_reset<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        in_reset: bool,
    ) -> Result<(), BridgeError> {
        self.gpio(t, self.cfg.gpio_reset, !in_reset)
    }

    /// Start or stop streaming on the bulk endpoint.
    pub fn stream<T: UsbTransport + ?Sized>(
        &self,
        t: &mut T,
        start: bool,
    ) -> Result<(), BridgeError> {
        let r = encode_stream(&self.cfg, start);
        self.run_out(t, &r, &|| {
            format!("stream {}", if start { "start" } else { "stop" })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(v: &[u8]) -> String {
        v.iter()
            .map(|b| format!("{b:02x}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    // Golden bytes: the SETUP packet (bmRequestType bRequest wValue wIndex
    // wLength, little-endian) followed by the data stage.
    #[test]
    fn golden_i2c_write_single() {
        let c = ProtocolConfig::default();
        let r = encode_i2c_write(&c, 0x3D, 0x9400, &[0x0001]).unwrap();
        assert_eq!(r.len(), 1);
        assert_eq!(hex(&r[0].wire_bytes()), "40 b1 3d 00 00 94 02 00 00 01");
    }

    #[test]
    fn golden_i2c_burst_write_split() {
        let c = ProtocolConfig {
            max_burst_words: 2,
            ..ProtocolConfig::default()
        };
        let r = encode_i2c_write(&c, 0x3D, 0x9000, &[0x1234, 0xABCD, 0x00FF]).unwrap();
        assert_eq!(r.len(), 2);
        assert_eq!(
            hex(&r[0].wire_bytes()),
            "40 b1 3d 00 00 90 04 00 12 34 ab cd"
        );
        assert_eq!(hex(&r[1].wire_bytes()), "40 b1 3d 00 02 90 02 00 00 ff");
    }

    #[test]
    fn golden_i2c_read() {
        let c = ProtocolConfig::default();
        let r = encode_i2c_read(&c, 0x3D, 0xA0A4, 3).unwrap();
        assert_eq!(hex(&r.wire_bytes()), "c0 b2 3d 00 a4 a0 06 00");
    }

    #[test]
    fn golden_gpio_stream_status() {
        let c = ProtocolConfig::default();
        assert_eq!(
            hex(&encode_gpio(&c, 0, false).wire_bytes()),
            "40 b3 00 00 00 00 00 00"
        );
        assert_eq!(
            hex(&encode_gpio(&c, 0, true).wire_bytes()),
            "40 b3 00 00 01 00 00 00"
        );
        assert_eq!(
            hex(&encode_gpio(&c, 1, true).wire_bytes()),
            "40 b3 01 00 01 00 00 00"
        );
        assert_eq!(
            hex(&encode_stream(&c, true).wire_bytes()),
            "40 b4 00 00 00 00 00 00"
        );
        assert_eq!(
            hex(&encode_stream(&c, false).wire_bytes()),
            "40 b5 00 00 00 00 00 00"
        );
        assert_eq!(
            hex(&encode_status(&c).wire_bytes()),
            "c0 bf 00 00 00 00 04 00"
        );
    }

    #[test]
    fn request_codes_follow_config() {
        let c = ProtocolConfig {
            req_i2c_write: 0x10,
            req_gpio: 0x22,
            ..ProtocolConfig::default()
        };
        assert_eq!(
            hex(&encode_i2c_write(&c, 0x10, 1, &[2]).unwrap()[0].wire_bytes()),
            "40 10 10 00 01 00 02 00 00 02"
        );
        assert_eq!(
            hex(&encode_gpio(&c, 3, true).wire_bytes()),
            "40 22 03 00 01 00 00 00"
        );
    }

    /// A transport that must never be used: the request is refused first.
    struct Untouched;
    impl UsbTransport for Untouched {
        fn control_in(
            &mut self,
            _: ControlSetup,
            _: &mut [u8],
            _: Duration,
        ) -> Result<usize, BridgeError> {
            panic!("control_in on a refused request")
        }
        fn control_out(
            &mut self,
            _: ControlSetup,
            _: &[u8],
            _: Duration,
        ) -> Result<usize, BridgeError> {
            panic!("control_out on a refused request")
        }
        fn bulk_in(&mut self, _: u8, _: &mut [u8], _: Duration) -> Result<usize, BridgeError> {
            panic!("bulk_in on a refused request")
        }
        fn bulk_out(&mut self, _: u8, _: &[u8], _: Duration) -> Result<usize, BridgeError> {
            panic!("bulk_out on a refused request")
        }
        fn clear_halt(&mut self, _: u8) -> Result<(), BridgeError> {
            panic!("clear_halt on a refused request")
        }
        fn reopen(&mut self) -> Result<(), BridgeError> {
            panic!("reopen on a refused request")
        }
        fn describe(&self) -> String {
            "untouched".into()
        }
    }

    #[test]
    fn oversized_register_reads_are_refused_before_any_transfer() {
        let cx3 = Cx3::new(ProtocolConfig::default()).unwrap();
        for (reg, count) in [(0u16, usize::MAX), (0xFFFF, 2), (1, 0x1_0000)] {
            let e = cx3.i2c_read(&mut Untouched, 0x3D, reg, count).unwrap_err();
            assert_eq!(e.kind(), ErrorKind::Config, "{reg:#x} +{count}: {e}");
            assert!(e.to_string().contains("past register 0xffff"), "{e}");
        }
    }

    #[test]
    fn bad_requests_are_config_errors() {
        let c = ProtocolConfig::default();
        assert_eq!(
            encode_i2c_write(&c, 0x80, 0, &[1]).unwrap_err().kind(),
            ErrorKind::Config
        );
        assert_eq!(
            encode_i2c_write(&c, 0x3D, 0, &[]).unwrap_err().kind(),
            ErrorKind::Config
        );
        assert_eq!(
            encode_i2c_write(&c, 0x3D, 0xFFFF, &[1, 2])
                .unwrap_err()
                .kind(),
            ErrorKind::Config
        );
        assert_eq!(
            encode_i2c_read(&c, 0x3D, 0, 0).unwrap_err().kind(),
            ErrorKind::Config
        );
        assert_eq!(
            encode_i2c_read(&c, 0x3D, 0, 129).unwrap_err().kind(),
            ErrorKind::Config
        );
        let bad = ProtocolConfig {
            bulk_in_endpoint: 0x01,
            ..ProtocolConfig::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("bulk_in_endpoint")
        );
    }

    #[test]
    fn config_rejects_unknown_keys() {
        let e = toml::from_str::<ProtocolConfig>("req_i2c_wrte = 1").unwrap_err();
        assert!(e.to_string().contains("req_i2c_wrte"));
        let ok: ProtocolConfig = toml::from_str("req_gpio = 0x20").unwrap();
        assert_eq!(ok.req_gpio, 0x20);
    }
}
