//! The simulator honours a model file's user effects (`effects::user`): a phase
//! response reads as the depth change c·Δφ/(4πf) (eq. 2.6), a gain response
//! scales the correlation amplitude, an offset response shifts every code, each
//! at the capture's own value of the condition; a bad expression is refused when
//! the file is read.
use std::collections::BTreeMap;

use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};

const F_HZ: f64 = 80e6;

fn geometry() -> SensorGeometry {
    SensorGeometry {
        rows: 2,
        cols: 2,
        roi_origin: [80, 110],
        full_rows: 172,
        full_cols: 224,
        adc_bits: 12,
        modulation_hz: F_HZ,
    }
}

fn model(user: &str) -> ModelConfig {
    let text = format!("{}\n{user}", ModelConfig::ideal().to_toml_string());
    ModelConfig::from_toml_str(&text).unwrap()
}

/// Pixel 0's (I, Q) = (c0 − c180, c90 − c270) and mean code of a 4-phase capture.
fn iq(sim: &Simulator, d_m: f64, conditions: &[(&str, f64)]) -> (f64, f64, f64) {
    let req = CaptureRequest {
        conditions: conditions
            .iter()
            .map(|(k, v)| (k.to_string(), *v))
            .collect::<BTreeMap<_, _>>(),
        ..CaptureRequest::four_phase(500.0)
    };
    let f = sim.expected(&Scene::wall(d_m, 1.0), &req).unwrap();
    let c = |k: usize| f[[k, 0, 0]];
    (c(0) - c(2), c(1) - c(3), (c(0) + c(1) + c(2) + c(3)) / 4.0)
}

const SHAPE: &str = "[[user_effects]]\nname = \"bias_r\"\ncondition = \"vcsel_bias_ma\"\nacts_on = \"ACTS\"\nknots_x = [10.0, 30.0]\nknots_y = [0.0, VALUE]\n";

fn with(acts: &str, value: f64) -> Simulator {
    let m = model(
        &SHAPE
            .replace("ACTS", acts)
            .replace("VALUE", &format!("{value:?}")),
    );
    Simulator::new(&m, geometry(), 1).unwrap()
}

#[test]
fn a_phase_response_reads_as_its_depth() {
    let sim = with("phase", 0.08);
    // at 20 mA the shape gives 0.04 rad: the depth change c·Δφ/(4πf)
    let dd_m = 0.04 * 299_792_458.0 / (4.0 * std::f64::consts::PI * F_HZ);
    let shifted = iq(&sim, 1.0, &[("vcsel_bias_ma", 20.0)]);
    let moved = iq(&sim, 1.0 + dd_m, &[]);
    let at_ref = iq(&sim, 1.0, &[("vcsel_bias_ma", 10.0)]);
    let none = iq(&sim, 1.0, &[]);
    let ang = |p: (f64, f64, f64)| p.1.atan2(p.0);
    assert!(
        (ang(shifted) - ang(moved)).abs() < 2e-3,
        "{shifted:?} vs {moved:?}"
    );
    assert!((ang(at_ref) - ang(none)).abs() < 1e-9);
    assert!((ang(shifted) - ang(none)).abs() > 0.03);
}

#[test]
fn a_gain_and_an_offset_response_scale_and_shift_the_codes() {
    let none = iq(&with("gain", 0.1), 1.0, &[]);
    let g = iq(&with("gain", 0.1), 1.0, &[("vcsel_bias_ma", 30.0)]);
    let amp = |p: (f64, f64, f64)| p.0.hypot(p.1);
    assert!((amp(g) / amp(none) - 1.1).abs() < 2e-3, "{g:?} vs {none:?}");
    let o0 = iq(&with("offset", 12.0), 1.0, &[]);
    let o = iq(&with("offset", 12.0), 1.0, &[("vcsel_bias_ma", 20.0)]);
    assert!((o.2 - o0.2 - 6.0).abs() < 0.05, "{o:?} vs {o0:?}");
    assert!((amp(o) - amp(o0)).abs() < 0.05);
}

#[test]
fn an_expression_is_evaluated_per_capture_and_checked_at_load() {
    let m = model(
        "[[user_effects]]\nname = \"supply_gain\"\ncondition = \"supply_v\"\nacts_on = \"gain\"\n\
         expression = \"k * (supply_v - 3.3) + 0.0 * exposure_us\"\nparams = [{ name = \"k\", value = 0.5, min = -2.0, max = 2.0 }]\n",
    );
    let sim = Simulator::new(&m, geometry(), 1).unwrap();
    let amp = |p: (f64, f64, f64)| p.0.hypot(p.1);
    let base = amp(iq(&sim, 1.0, &[("supply_v", 3.3)]));
    let up = amp(iq(&sim, 1.0, &[("supply_v", 3.5)]));
    assert!((up / base - 1.1).abs() < 2e-3, "{up} / {base}");
    // the file round-trips, user effect and all
    let back = ModelConfig::from_toml_str(&m.to_toml_string()).unwrap();
    assert_eq!(back.user_effects(), m.user_effects());
    let bad = ModelConfig::from_toml_str(
        "[[user_effects]]\nname = \"x\"\ncondition = \"supply_v\"\nacts_on = \"gain\"\nexpression = \"k * supply_volts\"\nparams = [{ name = \"k\", value = 0.5, min = -2.0, max = 2.0 }]\n",
    )
    .unwrap_err()
    .to_string();
    assert!(bad.contains("unknown variable `supply_volts`"), "{bad}");
    assert!(
        bad.contains("supply_v, exposure_us, temperature_c, ambient_klux, k"),
        "{bad}"
    );
}
