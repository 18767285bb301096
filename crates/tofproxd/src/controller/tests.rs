//! The controller's unit tests: one cycle at a time against the scripted source.

use super::capture::check_cycle;
use super::*;
use crate::source::{ScriptedSource, Step};

fn cfg() -> Config {
    let mut c = Config::default();
    c.ambient.probe_every = 1000;
    c
}

fn ctl(steps: Vec<Step>) -> Controller<ScriptedSource> {
    Controller::new(
        cfg(),
        ScriptedSource::new(24, 32, steps),
        ModeCalibrations::default(),
    )
    .unwrap()
}

#[test]
fn cycles_with_real_world_float_shifts_are_accepted_other_shifts_refused() {
    let mut src = ScriptedSource::new(24, 32, vec![Step::target(800.0)]);
    let req = CycleRequest {
        mode: Mode::FourPhase,
        exposure_us: 100.0,
        row_window: None,
        modulation_hz: None,
        single_image: None,
    };
    let mut c = src.cycle(&req).unwrap();
    assert_eq!(check_cycle(&c).unwrap(), Mode::FourPhase);
    // shifts as f32 radians (π/2 → 90.0000025°) and a −0° wrapped to 359.99…°
    c.phases_deg = [0.0f32, 90.0, 180.0, 270.0]
        .iter()
        .map(|d| f64::from(d.to_radians()).to_degrees())
        .collect();
    c.phases_deg[0] = 360.0 - 1e-9;
    assert!(c.phases_deg.iter().any(|p| (p - p.round()).abs() > 1e-6));
    assert_eq!(check_cycle(&c).unwrap(), Mode::FourPhase);
    // a sensor shifting its illumination: [0, 270, 180, 90] canonical
    c.phases_deg = vec![0.0, 270.0, 180.0, 90.0];
    assert_eq!(check_cycle(&c).unwrap(), Mode::FourPhase);
    // a 1° offset is another shift (a wrong depth, not a float rounding)
    c.phases_deg = vec![0.0, 91.0, 180.0, 270.0];
    assert!(check_cycle(&c).is_err());
}

#[test]
fn near_at_once_far_after_debounce() {
    let mut c = ctl(vec![
        Step::target(800.0),
        Step::target(50.0),
        Step::target(800.0),
        Step::target(800.0),
        Step::target(800.0),
    ]);
    let o = c.step(false);
    assert!(o.valid && !o.near, "{o:?}");
    assert!(
        o.distance_mm.is_some_and(|d| d.abs_diff(800) < 30),
        "{:?}",
        o.distance_mm
    );
    assert!(c.step(false).near, "near at once");
    assert!(c.step(false).near, "debounce 1");
    assert!(c.step(false).near, "debounce 2");
    assert!(!c.step(false).near, "far after 3");
}

/// Every update carries a CLOCK_BOOTTIME stamp taken between the cycle's call and its
/// return (the capture's frames are in), read against `/proc/uptime` (an independent view
/// of the same clock), never going backwards — failed cycles and the stop included.
#[test]
fn every_update_carries_the_capture_time_on_boottime() {
    let uptime_ns = || -> u64 {
        let s = std::fs::read_to_string("/proc/uptime").expect("/proc/uptime");
        let secs: f64 = s.split_whitespace().next().unwrap().parse().unwrap();
        (secs * 1e9) as u64
    };
    let mut c = ctl(vec![
        Step::target(800.0),
        Step::target(50.0),
        Step::Fail(SourceErrorKind::Timeout),
        Step::target(800.0),
    ]);
    let mut last = 0;
    for _ in 0..4 {
        let before = uptime_ns();
        let t = c.step(false).update.timestamp_ns.expect("stamped");
        let after = uptime_ns();
        // /proc/uptime has 10 ms resolution
        assert!(
            t + 20_000_000 >= before && t <= after + 20_000_000,
            "{before} ≤ {t} ≤ {after}"
        );
        assert!(t >= last, "monotone: {last} then {t}");
        last = t;
    }
    let t = c.stop().timestamp_ns.expect("the stop is stamped");
    assert!(t >= last);
}

#[test]
fn failures_never_publish_near_and_recover() {
    let mut c = ctl(vec![
        Step::target(800.0),
        Step::Fail(SourceErrorKind::Timeout),
        Step::Garbage,
        Step::Fail(SourceErrorKind::Disconnected),
        Step::target(800.0),
    ]);
    assert!(!c.step(false).near);
    let o = c.step(false);
    assert_eq!(o.update.state, Some(State::Error));
    assert!(
        o.update
            .last_error
            .as_deref()
            .is_some_and(|e| e.contains("timeout"))
    );
    assert_eq!(o.update.near, None, "a failed cycle does not touch Near");
    let o = c.step(false);
    assert!(!o.valid && o.update.near.is_none(), "{o:?}");
    assert!(!o.near, "garbage (all-zero) frame must not read as near");
    let o = c.step(false);
    assert_eq!(o.update.state, Some(State::Unavailable));
    let o = c.step(false);
    assert_eq!(o.update.state, Some(State::Running));
    assert_eq!(
        o.update.last_error.as_deref(),
        Some(""),
        "error cleared on recovery"
    );
}

#[test]
fn partial_readout_requests_a_window_around_the_roi() {
    let mut c = ctl(vec![Step::target(800.0)]);
    c.step(false);
    let w = c.source().requests[0].row_window.expect("window requested");
    // central half of 24 rows = rows 6..18, margin 2 → 4..20
    assert_eq!((w.row0, w.rows), (4, 16));
    let mut c = Controller::new(
        cfg(),
        ScriptedSource::new(24, 32, vec![Step::target(800.0)]).without_row_window(),
        ModeCalibrations::default(),
    )
    .unwrap();
    assert!(c.step(false).valid);
    assert_eq!(c.source().requests[0].row_window, None);
}

#[test]
fn adaptive_rate_fast_when_approaching_slow_when_still() {
    let mut steps = vec![
        Step::target(900.0),
        Step::target(700.0),
        Step::target(500.0),
    ];
    steps.extend(std::iter::repeat_n(Step::target(900.0), 14));
    let mut c = ctl(steps);
    c.step(false);
    assert_eq!(c.rate_hz(), 2.0);
    c.step(false);
    assert_eq!(c.rate_hz(), 10.0, "approaching 200 mm in 0.5 s");
    c.step(false);
    for _ in 0..13 {
        c.step(false);
    }
    assert_eq!(c.rate_hz(), 1.0, "far and still → slow");
}

#[test]
fn background_light_switches_to_4phase_and_back() {
    let mut cfg = cfg();
    cfg.ambient.probe_every = 3;
    cfg.ambient.low_readings = 2;
    let bright = Step::Target {
        distance_mm: 800.0,
        amplitude_lsb: 300.0,
        background_lsb: 200.0,
    };
    let mut steps = vec![bright.clone(); 6];
    steps.extend(vec![Step::target(800.0); 4]);
    let mut c = Controller::new(
        cfg,
        ScriptedSource::new(24, 32, steps),
        ModeCalibrations::default(),
    )
    .unwrap();
    c.step(false);
    c.step(false);
    assert_eq!(c.mode(), Mode::TwoPhase);
    let o = c.step(false);
    assert_eq!(o.captured_mode, Some(Mode::FourPhase), "probe");
    assert_eq!(c.mode(), Mode::FourPhase, "ambient {:?}", c.ambient_lsb);
    for _ in 0..3 {
        c.step(false);
        assert_eq!(c.mode(), Mode::FourPhase);
    }
    c.step(false);
    assert_eq!(c.mode(), Mode::FourPhase, "hysteresis: 1 low reading");
    c.step(false);
    assert_eq!(c.mode(), Mode::TwoPhase, "2 low readings → back");
    c.step(false);
    assert_eq!(
        c.source().requests.last().map(|r| r.mode),
        Some(Mode::TwoPhase)
    );
}

#[test]
fn auto_exposure_bounded() {
    let weak = Step::Target {
        distance_mm: 800.0,
        amplitude_lsb: 2.0,
        background_lsb: 0.0,
    };
    let mut c = ctl(vec![weak; 20]);
    for _ in 0..20 {
        c.step(false);
    }
    // the decision's need: a 2 % target at far_mm (150 mm) returns min_amplitude_lsb (8)
    // with the nominal K 0.09 LSB·m²/µs after 8 · 0.15² / (0.09 · 0.02) = 100 µs
    let need_us = 8.0 * 0.15 * 0.15 / (0.09 * 0.02);
    assert!(
        (c.exposure_us() - need_us).abs() < 1e-6,
        "lengthened up to the decision's need, not the eye-safe max: {}",
        c.exposure_us()
    );
    c.exposure.set_decision_us(None);
    for _ in 0..20 {
        c.step(false);
    }
    assert_eq!(c.exposure_us(), 500.0, "without it: up to the eye-safe max");
    let hot = Step::Target {
        distance_mm: 800.0,
        amplitude_lsb: 4000.0,
        background_lsb: 0.0,
    };
    c.source_mut().push(vec![hot; 20]);
    for _ in 0..20 {
        c.step(false);
    }
    // amplitude scales with exposure: 4000 LSB × t/100 µs fits the 12-bit range below ~51 µs
    let t = c.exposure_us();
    assert!(
        (20.0..51.0).contains(&t),
        "shortened until unsaturated, never below min: {t}"
    );
}

#[test]
fn calibration_keyed_to_mode() {
    let lut = tofprox_core::calib::WigglingLut {
        algorithm: Algorithm::FourPhase,
        correction_rad: ndarray::Array1::zeros(16),
    };
    let calib = ModeCalibrations {
        two_phase: Calibration {
            wiggling: Some(lut),
            ..Calibration::default()
        },
        ..ModeCalibrations::default()
    };
    let err = Controller::new(cfg(), ScriptedSource::new(4, 4, vec![]), calib)
        .err()
        .unwrap();
    assert!(err.to_string().contains("refused"), "{err}");
}

#[test]
fn roi_outside_the_sensor_is_refused_naming_the_key() {
    for roi in [
        [20, 0, 10, 10],
        [0, 30, 4, 4],
        [0, 0, 0, 4],
        [usize::MAX, 0, 2, 2],
    ] {
        let mut c = cfg();
        c.proximity.roi = Some(roi);
        let err = Controller::new(
            c,
            ScriptedSource::new(24, 32, vec![]),
            ModeCalibrations::default(),
        )
        .err()
        .unwrap_or_else(|| panic!("{roi:?} accepted"));
        let msg = err.to_string();
        assert!(
            msg.contains("proximity.roi") && msg.contains("24x32"),
            "{msg}"
        );
    }
    let mut c = cfg();
    c.proximity.roi = Some([14, 22, 10, 10]);
    assert!(
        Controller::new(
            c,
            ScriptedSource::new(24, 32, vec![]),
            ModeCalibrations::default()
        )
        .is_ok(),
        "touching the last row and column is inside"
    );
}

#[test]
fn stop_powers_off() {
    let mut c = ctl(vec![Step::target(50.0)]);
    assert!(c.step(false).near);
    let u = c.stop();
    assert_eq!(u.state, Some(State::Off));
    assert_eq!(u.near, Some(false));
    assert_eq!(c.source().power_offs, 1);
}

/// The rails path (every code on a rail) is paced and accounted by the same rule as a
/// processed cycle: no sleep when a recording is replayed as fast as possible, the rest
/// of the period otherwise, and the cycle enters the energy meter either way.
#[test]
fn rails_cycles_follow_the_replay_pacing_and_are_accounted() {
    let mut replay = cfg();
    replay.backend = crate::config::Backend::Replay;
    replay.replay.realtime = false;
    let mut c = Controller::new(
        replay,
        ScriptedSource::new(24, 32, vec![Step::Garbage, Step::target(800.0)]),
        ModeCalibrations::default(),
    )
    .unwrap();
    let rails = c.step(false);
    assert!(!rails.valid && rails.error.is_none(), "{rails:?}");
    assert_eq!(
        rails.sleep,
        Duration::ZERO,
        "unpaced replay: no sleep after a rails frame"
    );
    let ok = c.step(false);
    assert!(ok.valid);
    assert_eq!(ok.sleep, Duration::ZERO);
    assert_eq!(c.energy().cycles(), 2, "both cycles accounted");

    let mut c = ctl(vec![Step::Garbage]);
    let rails = c.step(false);
    let period = Duration::from_secs_f64(1.0 / c.rate_hz());
    assert!(
        rails.sleep > Duration::ZERO && rails.sleep < period,
        "paced: the rest of the period, {:?}",
        rails.sleep
    );
    assert!(rails.update.power_mw.is_some_and(|p| p > 0.0));
}

/// Saturation is evidence (issue 21): a cheek on the window saturating every code at the
/// shortest exposure is near for as long as it lasts — far beyond `loop.near_hold_ms` —
/// after one 4-phase confirmation at `exposure.min_us`; an all-zero frame is no data and a
/// held Near is released within the bound.
#[test]
fn a_saturating_cheek_is_near_while_it_lasts_zeros_are_no_data() {
    let cheek = Step::Target {
        distance_mm: 10.0,
        amplitude_lsb: 1e6,
        background_lsb: 0.0,
    };
    let mut steps = vec![Step::target(800.0)];
    steps.extend(std::iter::repeat_n(cheek, 40));
    steps.extend(std::iter::repeat_n(Step::Garbage, 30));
    let mut c = ctl(steps);
    assert!(!c.step(false).near);
    let first = c.step(false);
    assert!(!first.valid && !first.near, "confirm first: {first:?}");
    let confirmed = c.step(false);
    let req = c.source().requests[2];
    assert_eq!(req.mode, Mode::FourPhase, "the confirmation is 4-phase");
    assert_eq!(
        req.exposure_us, c.cfg.exposure.min_us,
        "at the shortest exposure"
    );
    assert!(confirmed.valid && confirmed.near, "{confirmed:?}");
    let hold = Duration::from_millis(c.cfg.loop_.near_hold_ms);
    let mut held = Duration::ZERO;
    for _ in 0..38 {
        let o = c.step(false);
        assert!(o.valid && o.near, "{o:?}");
        assert_eq!(
            o.update.distance_mm,
            Some(0),
            "near from saturation: unknown"
        );
        held += o.sleep;
    }
    assert!(held > 2 * hold, "near for {held:?}, beyond the hold bound");
    assert_eq!(c.exposure_us(), c.cfg.exposure.min_us);
    // all-zero frames: no data; Near held at most near_hold_ms since the last reading
    let mut since = Duration::ZERO;
    let mut released = false;
    for _ in 0..30 {
        let o = c.step(false);
        assert!(!o.valid, "{o:?}");
        since += o.sleep;
        if !o.near {
            released = true;
            break;
        }
        assert!(since < hold + o.sleep, "held {since:?}");
    }
    assert!(released, "Near released after the hold bound");
}

/// A bright target just beyond the unambiguous range (2.498 m at the scripted 60 MHz)
/// wraps to 50 mm with the amplitude of a 1000× retroreflector (`K·G·t/d²`, K = 0.09
/// LSB·m²/µs nominal, 100 µs): the second frequency puts it at 2.55 m, Far is published;
/// a hand at 50 mm is confirmed and Near published. The extra capture is accounted.
#[test]
fn a_dim_near_candidate_is_confirmed_at_the_second_frequency() {
    let du = tofprox_core::phasor::unambiguous_range_m(60e6);
    let retro = Step::Target {
        distance_mm: (du + 0.05) * 1e3,
        amplitude_lsb: 0.09 * 1000.0 * 100.0 / (du + 0.05).powi(2),
        background_lsb: 0.0,
    };
    let mut c = ctl(vec![retro.clone(), retro, Step::target(50.0)]);
    for _ in 0..2 {
        let o = c.step(false);
        assert!(o.valid && !o.near, "aliased retroreflector is far: {o:?}");
    }
    let asked: Vec<_> = c
        .source()
        .requests
        .iter()
        .map(|r| r.modulation_hz)
        .collect();
    assert_eq!(asked, [None, Some(70e6), None, Some(70e6)]);
    let o = c.step(false);
    assert!(o.near, "a hand at 50 mm is confirmed: {o:?}");
    assert_eq!(c.source().requests.len(), 6);
    assert!(c.step(false).near);
    assert_eq!(
        c.source().requests.len(),
        7,
        "no confirmation while a confirmed near lasts"
    );
    assert_eq!(
        c.energy().cycles(),
        4,
        "one reading per step, both captures in it"
    );

    // off: the amplitude test decides alone, the retroreflector reads near
    let mut off = cfg();
    off.proximity.second_modulation_hz = 0.0;
    let retro = Step::Target {
        distance_mm: (du + 0.05) * 1e3,
        amplitude_lsb: 0.09 * 1000.0 * 100.0 / (du + 0.05).powi(2),
        background_lsb: 0.0,
    };
    let mut c = Controller::new(
        off,
        ScriptedSource::new(24, 32, vec![retro]),
        ModeCalibrations::default(),
    )
    .unwrap();
    assert!(c.step(false).near, "one frequency cannot tell");
}

#[test]
fn depth_message_only_when_wanted() {
    let mut c = ctl(vec![Step::target(800.0)]);
    assert!(c.step(false).depth.is_none());
    let d = c.step(true).depth.expect("depth");
    assert_eq!(
        d.depth_le.len(),
        usize::from(d.width) * usize::from(d.height) * 2
    );
}
