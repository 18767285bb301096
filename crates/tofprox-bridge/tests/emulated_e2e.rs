//! End-to-end: the driver stack against the emulated device.

use std::sync::Arc;

use std::time::Duration;

use tofprox_bridge::emulated::{BusEvent, EmulatedConfig, FaultKind, FrameSource, TraceEvent};
use tofprox_bridge::{
    Algorithm, Clock, CycleRequest, DriverConfig, EmulatedDevice, ErrorKind, RowWindow,
    SensorDriver, SensorMode, VirtualClock,
};

fn driver(cfg: EmulatedConfig, seed: u64) -> (SensorDriver<EmulatedDevice>, Arc<VirtualClock>) {
    let clock = Arc::new(VirtualClock::new());
    let dev = EmulatedDevice::new(cfg, clock.clone(), seed).unwrap();
    let d = SensorDriver::new(dev, DriverConfig::emulated_default(), clock.clone()).unwrap();
    (d, clock)
}

/// The fast frame source (fault and soak tests do not need model realism).
fn fast() -> EmulatedConfig {
    EmulatedConfig {
        frame_source: FrameSource::Ideal,
        ..EmulatedConfig::default()
    }
}

fn req(mode: SensorMode, exposure_us: f64) -> CycleRequest {
    CycleRequest {
        mode,
        exposure_us,
        row_window: None,
        modulation_hz: None,
        single_image: None,
    }
}

#[test]
fn first_cycle_writes_flash_second_loads_it() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = EmulatedConfig {
        flash_file: Some(dir.path().join("flash.bin")),
        ..EmulatedConfig::default()
    };
    let (mut d, _c) = driver(cfg.clone(), 1);
    let o1 = d
        .cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 300.0))
        .unwrap();
    assert!(o1.flash_written);
    assert!(o1.timings.flash_write > std::time::Duration::ZERO);
    assert_eq!(o1.frames.dim(), (2, 172, 224));
    assert_eq!(o1.phases_deg, vec![0.0, 90.0]);
    assert!(
        d.transport().in_reset(),
        "sensor left in reset after the cycle"
    );
    assert_eq!(o1.timings.idle, std::time::Duration::ZERO);
    _c.sleep(std::time::Duration::from_millis(700)); // the daemon's sleep between readings
    let o2 = d
        .cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 300.0))
        .unwrap();
    assert_eq!(o2.timings.idle, std::time::Duration::from_millis(700));
    let t = o2.timings;
    assert_eq!(
        t.total,
        t.startup + t.config_load + t.exposure + t.readout + t.shutdown
    );
    assert!(t.startup >= std::time::Duration::from_micros(800), "{t:?}");
    assert!(!o2.flash_written);
    assert_eq!(o2.timings.flash_write, std::time::Duration::ZERO);
    assert_eq!(d.stats().flash_writes, 1);
    // a new process (new device + driver) with the persisted flash loads it
    let (mut d2, _c) = driver(cfg, 2);
    let o3 = d2
        .cycle(&req(SensorMode::Depth(Algorithm::FourPhase), 300.0))
        .unwrap();
    assert!(!o3.flash_written);
    assert_eq!(o3.frames.dim().0, 4);
}

/// Mean 4-phase amplitude (eq. 2.4): offsets cancel.
fn amplitude(o: &tofprox_bridge::CycleOutput) -> f64 {
    let f = |k: usize| o.frames.index_axis(ndarray::Axis(0), k).mapv(f64::from);
    let (a, b) = (f(0) - f(2), f(1) - f(3));
    (a.mapv(|x| x * x) + b.mapv(|x| x * x))
        .mapv(f64::sqrt)
        .mean()
        .unwrap()
        / 2.0
}

#[test]
fn exposure_change_visible_in_frames() {
    let (mut d, _c) = driver(EmulatedConfig::default(), 3);
    let lo = d
        .cycle(&req(SensorMode::Depth(Algorithm::FourPhase), 100.0))
        .unwrap();
    let hi = d
        .cycle(&req(SensorMode::Depth(Algorithm::FourPhase), 400.0))
        .unwrap();
    assert_eq!((lo.exposure_us, hi.exposure_us), (100.0, 400.0));
    // the flash image holds 1000 µs: the requested exposure must win (thesis 3.5.3)
    let (a, b) = (amplitude(&lo), amplitude(&hi));
    assert!(
        b > 3.0 * a && b < 5.0 * a,
        "amplitude at 400 µs: {b}, at 100 µs: {a}"
    );
    assert!(hi.timings.exposure > lo.timings.exposure);
}

#[test]
fn row_window_reduces_frame_size() {
    let (mut d, _c) = driver(EmulatedConfig::default(), 4);
    let full = d
        .cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
        .unwrap();
    let r = CycleRequest {
        row_window: Some(RowWindow::rows_only(60, 40)),
        ..req(SensorMode::Depth(Algorithm::TwoPhase), 200.0)
    };
    let win = d.cycle(&r).unwrap();
    assert_eq!(win.frames.dim(), (2, 40, 224));
    assert_eq!(win.geometry.roi_origin, [60, 0]);
    assert!(win.timings.readout < full.timings.readout);
    // misaligned / out of range windows are config errors, device untouched
    let bad = CycleRequest {
        row_window: Some(RowWindow::rows_only(161, 40)),
        ..r
    };
    assert_eq!(d.cycle(&bad).unwrap_err().kind(), ErrorKind::Config);
}

#[test]
fn all_modes_have_their_frame_counts() {
    let (mut d, _c) = driver(fast(), 5);
    for (m, k) in [
        (SensorMode::FourPhaseGrey, 5),
        (SensorMode::Correlation24, 24),
    ] {
        let o = d.cycle(&req(m, 200.0)).unwrap();
        assert_eq!(o.frames.dim().0, k);
        assert_eq!(o.illuminated.len(), k);
    }
}

#[test]
fn every_fault_gives_typed_error_and_next_cycle_recovers() {
    let cases = [
        (FaultKind::Unplug, &[ErrorKind::Disconnected][..]),
        (FaultKind::ControlTimeout, &[ErrorKind::Timeout]),
        (FaultKind::Stall, &[ErrorKind::Stall]),
        (FaultKind::I2cNak, &[ErrorKind::Nak, ErrorKind::ResetStuck]),
        (FaultKind::CorruptPayload, &[ErrorKind::CorruptFrame]),
        (FaultKind::ShortPayload, &[ErrorKind::CorruptFrame]),
        (FaultKind::OutOfOrder, &[ErrorKind::CorruptFrame]),
        (FaultKind::ResetStuck, &[ErrorKind::ResetStuck]),
    ];
    for (kind, expect) in cases {
        for seed in 0..25u64 {
            let mut cfg = fast();
            cfg.faults.spec_mut(kind).at_cycles = vec![2];
            let (mut d, clock) = driver(cfg, seed);
            d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
                .unwrap();
            let t = clock.now();
            let r = d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0));
            let Err(e) = r else {
                panic!(
                    "{kind:?} seed {seed}: no error, injected {:?}",
                    d.transport().injected_this_cycle()
                )
            };
            assert!(
                expect.contains(&e.kind()),
                "{kind:?} seed {seed}: got {:?}: {e}",
                e.kind()
            );
            assert!(e.to_string().starts_with("cycle 2"), "context: {e}");
            assert!(
                d.transport()
                    .stats()
                    .faults
                    .get(&kind)
                    .copied()
                    .unwrap_or(0)
                    >= 1
            );
            assert!(clock.now() > t);
            let o = d
                .cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
                .unwrap_or_else(|e| panic!("{kind:?}: no recovery: {e}"));
            assert_eq!(o.frames.dim(), (2, 172, 224));
        }
    }
}

#[test]
fn flash_faults_are_repaired_in_the_same_cycle() {
    for kind in [FaultKind::FlashEmpty, FaultKind::FlashCorrupt] {
        let mut cfg = fast();
        cfg.faults.spec_mut(kind).at_cycles = vec![2];
        let (mut d, _c) = driver(cfg.clone(), 9);
        assert!(
            d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
                .unwrap()
                .flash_written
        );
        let o = d
            .cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
            .unwrap();
        assert!(o.flash_written, "{kind:?}: flash not rewritten");
        assert_eq!(d.transport().stats().faults[&kind], 1);
        // with rewriting disabled the fault is a typed error
        let clock = Arc::new(VirtualClock::new());
        let dev = EmulatedDevice::new(cfg, clock.clone(), 9).unwrap();
        let mut dc = DriverConfig::emulated_default();
        dc.timing.write_flash_if_missing = false;
        let mut d = SensorDriver::new(dev, dc, clock).unwrap();
        assert_eq!(
            d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
                .unwrap_err()
                .kind(),
            ErrorKind::FlashEmpty
        );
    }
}

/// Many cycles at a high fault rate: no panic, every delivered frame equals
/// the clean frame the device produced (no torn/corrupt data gets through),
/// errors are typed, and with faults switched off the next cycle succeeds.
#[test]
fn soak_no_corrupt_frame_reaches_the_caller() {
    for retries in [0u32, 1] {
        let cfg = EmulatedConfig {
            faults: tofprox_bridge::emulated::FaultConfig::uniform(0.6),
            ..EmulatedConfig::default()
        };
        let clock = Arc::new(VirtualClock::new());
        let dev = EmulatedDevice::new(cfg, clock.clone(), 77 + u64::from(retries)).unwrap();
        let mut dc = DriverConfig::emulated_default();
        dc.timing.frame_retries = retries;
        let mut d = SensorDriver::new(dev, dc, clock).unwrap();
        let (mut ok, mut failed) = (0, 0);
        for i in 0..300 {
            let r = CycleRequest {
                mode: if i % 3 == 0 {
                    SensorMode::Depth(Algorithm::FourPhase)
                } else {
                    SensorMode::Depth(Algorithm::TwoPhase)
                },
                exposure_us: 100.0 + f64::from(i % 5) * 50.0,
                row_window: (i % 4 == 0).then_some(RowWindow::rows_only(40, 60)),
                modulation_hz: None,
                single_image: None,
            };
            match d.cycle(&r) {
                Ok(o) => {
                    ok += 1;
                    let clean = d.transport().last_superframe().unwrap();
                    assert_eq!(clean.len(), o.frames.dim().0);
                    for (k, f) in clean.iter().enumerate() {
                        let got = o.frames.index_axis(ndarray::Axis(0), k);
                        assert!(
                            got.iter().eq(f.iter()),
                            "cycle {i}: raw {k} differs from the device's frame"
                        );
                    }
                }
                Err(e) => {
                    failed += 1;
                    assert!(e.kind().is_transient(), "{e}");
                }
            }
        }
        assert!(ok > 100 && failed > 10, "ok {ok} failed {failed}");
        d.transport_mut().set_faults(Default::default());
        d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
            .unwrap();
        assert!(d.stats().reassembly.frames_dropped > 0);
    }
}

#[test]
fn unplugged_device_is_not_found_until_replugged() {
    let mut cfg = fast();
    cfg.faults.unplug.at_cycles = vec![2];
    cfg.timing.replug_after_ms = 500.0;
    let (mut d, clock) = driver(cfg, 12);
    d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
        .unwrap();
    assert_eq!(
        d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
            .unwrap_err()
            .kind(),
        ErrorKind::Disconnected
    );
    // still gone: the reopen fails cleanly, and is tried again next time
    let e = d
        .cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::NotFound, "{e}");
    clock.sleep(std::time::Duration::from_millis(600));
    d.cycle(&req(SensorMode::Depth(Algorithm::TwoPhase), 200.0))
        .unwrap();
    assert_eq!(d.stats().reopens, 1);
}

// The public record's IRS16x5 bring-up (docs/bridge.md, "Public facts"), written here from the
// facts, not from the map: the imager state machine's EN/CTRL, LPFSMEN's start value.
const EN: u16 = 0xB400;
const CTRL: u16 = 0xB401;
const LPFSMEN: u16 = 0x9000;
const LPFSMEN_START: u16 = 5;

/// Clock time of the first write to `reg` (with `value`, when given) in the trace.
fn written_at(trace: &[TraceEvent], reg: u16, value: Option<u16>) -> (usize, Duration) {
    trace
        .iter()
        .enumerate()
        .find_map(|(i, e)| match e.event {
            BusEvent::Write { reg: r, value: v } if r == reg && value.is_none_or(|w| w == v) => {
                Some((i, e.at))
            }
            _ => None,
        })
        .unwrap_or_else(|| panic!("no write to {reg:#06x} in the trace"))
}

#[test]
fn bring_up_follows_the_public_order_and_waits() {
    let (mut d, _c) = driver(fast(), 5);
    let two = req(SensorMode::Depth(Algorithm::TwoPhase), 300.0);
    d.cycle(&two).unwrap();
    let o = d.cycle(&two).unwrap(); // the flash holds the image: a cycle as the loop runs it
    let dev = d.transport();
    assert!(
        dev.bring_up_violations().is_empty(),
        "{:?}",
        dev.bring_up_violations()
    );
    let tr = dev.bus_trace();
    // the reset pulse: commanded low, released ≥ 2 µs later (~2 µs: not the old 100 µs)
    assert_eq!(
        (tr[0].event, tr[1].event),
        (BusEvent::ResetLow, BusEvent::ResetReleased)
    );
    let pulse = tr[1].at - tr[0].at;
    assert!(
        pulse >= Duration::from_micros(2) && pulse < Duration::from_micros(10),
        "{pulse:?}"
    );
    // the PLL registers, then 2 ms, CTRL, EN, 2 ms, and only then the sequencer starts
    let pll = d.config().map.sequences.minimum.clone();
    let (i_pll, t_pll) = pll
        .iter()
        .map(|[r, v]| written_at(tr, *r, Some(*v)))
        .max()
        .unwrap();
    let (i_ctrl, t_ctrl) = written_at(tr, CTRL, None);
    let (i_en, t_en) = written_at(tr, EN, None);
    let (i_start, t_start) = written_at(tr, LPFSMEN, Some(LPFSMEN_START));
    assert!(
        i_pll < i_ctrl && i_ctrl < i_en && i_en < i_start,
        "{i_pll} {i_ctrl} {i_en} {i_start}"
    );
    assert!(
        t_ctrl - t_pll >= Duration::from_millis(2),
        "{:?}",
        t_ctrl - t_pll
    );
    assert!(
        t_start - t_en >= Duration::from_millis(2),
        "{:?}",
        t_start - t_en
    );
    // the 4 ms of waits are configuration time of the cycle (energy: flash_load_mw)
    assert!(
        o.timings.config_load >= Duration::from_millis(4),
        "{:?}",
        o.timings
    );
    assert_eq!(dev.stats().bring_up_violations, 0);
}

/// A driver whose map's bring-up is changed by `edit` against the emulated sensor of the
/// shipped map: its cycle fails, and the sensor says why.
fn broken_bring_up(edit: impl FnOnce(&mut DriverConfig)) -> (ErrorKind, Vec<String>) {
    let clock = Arc::new(VirtualClock::new());
    let dev = EmulatedDevice::new(fast(), clock.clone(), 9).unwrap();
    let mut cfg = DriverConfig::emulated_default();
    edit(&mut cfg);
    let mut d = SensorDriver::new(dev, cfg, clock).unwrap();
    // the flash holds the image (its write would outlast any wait before the start)
    d.bring_up().unwrap();
    d.flash_write().unwrap();
    let two = req(SensorMode::Depth(Algorithm::TwoPhase), 300.0);
    let e = d.cycle(&two).unwrap_err();
    let why = d.transport().bring_up_violations().to_vec();
    assert!(d.transport().stats().bring_up_violations >= 1);
    (e.kind(), why)
}

/// An edit of the driver's configuration.
type Edit = fn(&mut DriverConfig);

/// What the sensor refuses, and the edit of the driver's map that makes the driver do it.
const BROKEN: [(&str, Edit); 4] = [
    ("before the PLL settled", |c| {
        c.map.bring_up.as_mut().unwrap().pll_settle_us = 0;
    }),
    ("EN (0xb400) before CTRL", |c| {
        let b = c.map.bring_up.as_mut().unwrap();
        (b.ctrl, b.en) = (b.en, b.ctrl);
    }),
    ("before the imager settled", |c| {
        c.map.bring_up.as_mut().unwrap().enable_settle_us = 0;
    }),
    ("imager not enabled", |c| c.map.bring_up = None),
];

#[test]
fn a_bring_up_out_of_order_or_too_fast_is_refused_by_the_sensor() {
    for (want, edit) in BROKEN {
        let (kind, why) = broken_bring_up(edit);
        assert_eq!(kind, ErrorKind::Timeout, "{want}");
        assert!(why.iter().any(|w| w.contains(want)), "{want}: {why:?}");
    }
}

#[test]
fn a_reset_pulse_too_short_is_refused_by_the_sensor() {
    // a driver that knows no bring-up and does not hold reset low: its first cycle fails
    // (imager not enabled) and leaves the sensor in reset; the next releases it at once
    let clock = Arc::new(VirtualClock::new());
    let dev = EmulatedDevice::new(fast(), clock.clone(), 3).unwrap();
    let mut cfg = DriverConfig::emulated_default();
    cfg.map.bring_up = None;
    cfg.timing.reset_low_us = 0;
    let mut d = SensorDriver::new(dev, cfg, clock).unwrap();
    let two = req(SensorMode::Depth(Algorithm::TwoPhase), 300.0);
    d.cycle(&two).unwrap_err();
    d.cycle(&two).unwrap_err();
    let why = d.transport().bring_up_violations();
    assert!(
        why.iter()
            .any(|w| w.contains("reset released after 0 µs low")),
        "{why:?}"
    );
}
