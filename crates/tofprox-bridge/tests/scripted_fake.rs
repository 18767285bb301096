//! Scripted-fake tests of the sensor sequence (in the style of probe-rs's
//! fake probe): the transport holds the exact list of expected operations
//! with their replies; the driver must perform exactly these, in order.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use tofprox_bridge::frame::{StatusLine, encode_frame};
use tofprox_bridge::protocol::{self, ProtocolConfig};
use tofprox_bridge::uvc::split_frame;
use tofprox_bridge::{
    Algorithm, BridgeError, Clock, ControlSetup, CycleRequest, DriverConfig, ErrorKind,
    SensorDriver, SensorMap, SensorMode, UsbTransport, VirtualClock,
};

/// One expected operation and the reply to give.
#[derive(Debug, Clone)]
enum Op {
    Out {
        setup: ControlSetup,
        data: Vec<u8>,
        reply: Result<(), ErrorKind>,
    },
    In {
        setup: ControlSetup,
        len: usize,
        reply: Result<Vec<u8>, ErrorKind>,
    },
    Bulk {
        payload: Vec<u8>,
    },
}

struct Scripted {
    ops: VecDeque<Op>,
    done: usize,
}

impl Scripted {
    fn next(&mut self, what: &str) -> Op {
        self.done += 1;
        self.ops
            .pop_front()
            .unwrap_or_else(|| panic!("operation {} ({what}) not in the script", self.done))
    }
}

impl UsbTransport for Scripted {
    fn control_in(
        &mut self,
        s: ControlSetup,
        buf: &mut [u8],
        _t: Duration,
    ) -> Result<usize, BridgeError> {
        match self.next(&format!("{s:?}")) {
            Op::In { setup, len, reply } => {
                assert_eq!((s, buf.len()), (setup, len), "operation {}", self.done);
                match reply {
                    Ok(b) => {
                        buf[..b.len()].copy_from_slice(&b);
                        Ok(b.len())
                    }
                    Err(k) => Err(BridgeError::new(k, "scripted")),
                }
            }
            other => panic!(
                "operation {}: control IN {s:?}, script has {other:?}",
                self.done
            ),
        }
    }
    fn control_out(
        &mut self,
        s: ControlSetup,
        d: &[u8],
        _t: Duration,
    ) -> Result<usize, BridgeError> {
        match self.next(&format!("{s:?}")) {
            Op::Out { setup, data, reply } => {
                assert_eq!((s, d), (setup, &data[..]), "operation {}", self.done);
                reply
                    .map(|()| d.len())
                    .map_err(|k| BridgeError::new(k, "scripted"))
            }
            other => panic!(
                "operation {}: control OUT {s:?} {d:02x?}, script has {other:?}",
                self.done
            ),
        }
    }
    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], _t: Duration) -> Result<usize, BridgeError> {
        assert_eq!(ep, 0x81);
        match self.next("bulk") {
            Op::Bulk { payload } => {
                buf[..payload.len()].copy_from_slice(&payload);
                Ok(payload.len())
            }
            other => panic!("operation {}: bulk IN, script has {other:?}", self.done),
        }
    }
    fn bulk_out(&mut self, _: u8, _: &[u8], _: Duration) -> Result<usize, BridgeError> {
        panic!("unexpected bulk OUT")
    }
    fn clear_halt(&mut self, _: u8) -> Result<(), BridgeError> {
        panic!("unexpected clear halt")
    }
    fn reopen(&mut self) -> Result<(), BridgeError> {
        panic!("unexpected reopen")
    }
    fn describe(&self) -> String {
        "scripted fake".into()
    }
}

const MAP: &str = r#"
[sensor]
name = "tiny"
i2c_address = 0x3D
rows = 4
cols = 16
adc_bits = 12
modulation_hz = 80e6
chip_id_register = 0xA0A4
chip_id_value = 0x1645
status_line = true
[sequences]
minimum = [[0x8000, 0x0001], [0x8001, 0x0C1C], [0x8020, 0x0001]]
flash_image = [[0x9000, 1000], [0x9001, 1000]]
start_measurement = [[0x9400, 1]]
stop_measurement = [[0x9400, 0]]
[raw]
exposure_base = 0x9000
exposure_lsb_us = 1.0
exposure_min_us = 10.0
exposure_max_us = 4000.0
phase_base = 0x9020
phase_lsb_deg = 15.0
illumination_base = 0x9040
count_register = 0x9060
max_count = 24
[flash]
load_register = 0xA000
load_value = 1
status_register = 0xA001
status_busy = 1
status_ok = 2
status_empty = 3
status_corrupt = 4
image_address = 0
[spi]
tx_base = 0xA100
rx_base = 0xA200
window_bytes = 264
length_register = 0xA010
trigger_register = 0xA011
busy_register = 0xA012
page_bytes = 256
sector_bytes = 4096
[use_cases.2phase]
phases_deg = [0, 90]
registers = [[0x9061, 2]]
"#;

fn p() -> ProtocolConfig {
    ProtocolConfig::default()
}
fn gpio_reset(high: bool) -> Op {
    Op::Out {
        setup: protocol::encode_gpio(&p(), 0, high).setup,
        data: vec![],
        reply: Ok(()),
    }
}
fn stream(on: bool) -> Op {
    Op::Out {
        setup: protocol::encode_stream(&p(), on).setup,
        data: vec![],
        reply: Ok(()),
    }
}
fn write(reg: u16, vals: &[u16]) -> Op {
    let r = &protocol::encode_i2c_write(&p(), 0x3D, reg, vals).unwrap()[0];
    Op::Out {
        setup: r.setup,
        data: r.data.clone(),
        reply: Ok(()),
    }
}
fn read(reg: u16, reply: Result<u16, ErrorKind>) -> Op {
    let r = protocol::encode_i2c_read(&p(), 0x3D, reg, 1).unwrap();
    Op::In {
        setup: r.setup,
        len: 2,
        reply: reply.map(|v| v.to_be_bytes().to_vec()),
    }
}
fn status(code: u8, reg: u16) -> Op {
    let r = reg.to_be_bytes();
    Op::In {
        setup: protocol::encode_status(&p()).setup,
        len: 4,
        reply: Ok(vec![code, 0x3D, r[0], r[1]]),
    }
}

fn frame_payloads(k: u16, counter: u16, fid: bool) -> Vec<Op> {
    let px: Vec<u16> = (0..64).map(|i| 2000 + i + 10 * k).collect();
    let st = StatusLine {
        frame_counter: counter,
        raw_index: k,
        row0: 0,
        rows: 4,
        exposure_reg: 250,
        phase_reg: 6 * k,
        illumination: true,
        crc32: 0,
    };
    split_frame(&encode_frame(&px, 16, Some(st)), fid, 0, 64)
        .into_iter()
        .map(|payload| Op::Bulk { payload })
        .collect()
}

fn start_of_cycle() -> Vec<Op> {
    vec![
        // restart: reset low, then high (thesis listing 4.11)
        stream(false),
        gpio_reset(false),
        gpio_reset(true),
        read(0xA0A4, Ok(0x1645)),
        // minimum configuration, consecutive registers as one burst
        write(0x8000, &[0x0001, 0x0C1C]),
        write(0x8020, &[0x0001]),
        // load configuration from flash and check its status
        write(0xA000, &[1]),
    ]
}

/// The tiny test map on top of the emulated defaults.
fn tiny_config() -> DriverConfig {
    let map = SensorMap::from_toml_str(MAP, "tiny").unwrap();
    DriverConfig {
        map,
        ..DriverConfig::emulated_default()
    }
}

/// The request every scripted cycle below performs.
const TWO_PHASE_250US: CycleRequest = CycleRequest {
    mode: SensorMode::Depth(Algorithm::TwoPhase),
    exposure_us: 250.0,
    row_window: None,
    modulation_hz: None,
    single_image: None,
};

fn driver(ops: Vec<Op>) -> (SensorDriver<Scripted>, Arc<VirtualClock>) {
    driver_with(ops, tiny_config())
}

fn driver_with(ops: Vec<Op>, cfg: DriverConfig) -> (SensorDriver<Scripted>, Arc<VirtualClock>) {
    let clock = Arc::new(VirtualClock::new());
    let d = SensorDriver::new(
        Scripted {
            ops: ops.into(),
            done: 0,
        },
        cfg,
        clock.clone(),
    )
    .unwrap();
    (d, clock)
}

#[test]
fn two_phase_cycle_performs_exactly_the_thesis_sequence() {
    let mut ops = start_of_cycle();
    ops.extend([
        read(0xA001, Ok(1)), // busy: poll again after a sleep
        read(0xA001, Ok(2)), // ok
        // exposure (after the load, which overwrote it), phases, illumination, count, use case
        write(0x9000, &[250, 250]),
        write(0x9020, &[0, 6]),
        write(0x9040, &[1, 1]),
        write(0x9060, &[2, 2]),
        stream(true),
        write(0x9400, &[1]),
    ]);
    ops.extend(frame_payloads(0, 0, true));
    ops.extend(frame_payloads(1, 1, false));
    ops.extend([write(0x9400, &[0]), stream(false), gpio_reset(false)]);
    let (mut d, clock) = driver(ops);
    let o = d.cycle(&TWO_PHASE_250US).unwrap();
    assert!(
        d.transport().ops.is_empty(),
        "not performed: {:?}",
        d.transport().ops
    );
    assert_eq!(o.frames.dim(), (2, 4, 16));
    assert_eq!(o.frames[[1, 0, 0]], 2010);
    assert_eq!(o.frames[[0, 3, 15]], 2063);
    assert!(!o.flash_written);
    // reset low 2 µs (the public record's pulse) + start-up delay 1 ms + one 200 µs poll: all
    // slept on the clock (this map has no [bring_up]: no PLL/imager waits)
    assert_eq!(o.timings.startup, Duration::from_micros(1002));
    assert!(clock.now() >= Duration::from_micros(1202));
}

#[test]
fn nak_during_start_up_is_polled_then_stuck_sensor_is_reset_stuck() {
    let mut ops = vec![stream(false), gpio_reset(false), gpio_reset(true)];
    // the sensor never answers: every chip-id read stalls with status NAK,
    // polled every 200 µs until the 20 ms start-up timeout
    for _ in 0..101 {
        ops.push(read(0xA0A4, Err(ErrorKind::Stall)));
        ops.push(status(protocol::status::I2C_NAK, 0xA0A4));
    }
    // cleanup after the error: stop streaming, reset low
    ops.extend([stream(false), gpio_reset(false)]);
    let (mut d, _clock) = driver(ops);
    let e = d.cycle(&TWO_PHASE_250US).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::ResetStuck, "{e}");
    assert!(e.to_string().contains("did not come out of reset"), "{e}");
    assert!(
        d.transport().ops.is_empty(),
        "not performed: {}",
        d.transport().ops.len()
    );
}

#[test]
fn empty_flash_without_write_permission_is_flash_empty_and_sensor_is_reset() {
    let mut ops = start_of_cycle();
    ops.extend([read(0xA001, Ok(3)), stream(false), gpio_reset(false)]);
    let mut cfg = tiny_config();
    cfg.timing.write_flash_if_missing = false;
    let (mut d, _clock) = driver_with(ops, cfg);
    let e = d.cycle(&TWO_PHASE_250US).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::FlashEmpty);
    assert!(d.transport().ops.is_empty());
}

#[test]
fn i2c_nak_mid_sequence_is_a_typed_error_naming_the_register() {
    let mut ops = start_of_cycle();
    ops.pop(); // the load command NAKs instead
    let r = &protocol::encode_i2c_write(&p(), 0x3D, 0xA000, &[1]).unwrap()[0];
    ops.push(Op::Out {
        setup: r.setup,
        data: r.data.clone(),
        reply: Err(ErrorKind::Stall),
    });
    ops.push(status(protocol::status::I2C_NAK, 0xA000));
    ops.extend([stream(false), gpio_reset(false)]);
    let (mut d, _c) = driver(ops);
    let e = d.cycle(&TWO_PHASE_250US).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Nak);
    let msg = e.to_string();
    assert!(
        msg.contains("flash load command") && msg.contains("0xa000"),
        "{msg}"
    );
}
