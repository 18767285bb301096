//! The shipped config files parse, validate, and mean what they say.

use std::path::PathBuf;

use tofprox_bridge::emulated::{EmulatedConfig, FaultKind, FrameSource};
use tofprox_bridge::{DeviceConfigFile, DriverConfig, ErrorKind, ProtocolConfig};

fn config_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

#[test]
fn emulated_default_file_equals_built_in_defaults() {
    let c = EmulatedConfig::load(&config_dir().join("emulated/default.toml")).unwrap();
    let d = EmulatedConfig::default();
    assert_eq!(c.protocol, d.protocol);
    assert_eq!(c.timing, d.timing);
    assert_eq!(c.faults, d.faults);
    assert_eq!(c.flash_size_bytes, d.flash_size_bytes);
    assert_eq!(c.sensor_map().unwrap(), d.sensor_map().unwrap());
}

#[test]
fn fault_and_hand_files() {
    let c = EmulatedConfig::load(&config_dir().join("emulated/faults.toml")).unwrap();
    assert_eq!(c.frame_source, FrameSource::Ideal);
    for k in FaultKind::ALL {
        assert!(c.faults.spec(k).probability > 0.0, "{k:?}");
        assert_eq!(c.faults.spec(k).at_cycles.len(), 1, "{k:?}");
    }
    let h = EmulatedConfig::load(&config_dir().join("emulated/hand.toml")).unwrap();
    assert_eq!(h.scene.kind, tofprox_model::ScriptKind::Hand);
}

#[test]
fn device_file_equals_defaults() {
    let (f, d) = DeviceConfigFile::load(&config_dir().join("sensor/device.toml")).unwrap();
    assert_eq!(f.usb, tofprox_bridge::UsbSelector::default());
    assert_eq!(d, DriverConfig::emulated_default());
    assert_eq!(d.protocol, ProtocolConfig::default());
}

#[test]
fn bad_files_name_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.toml");
    std::fs::write(&p, "[faults.unplug]\nprobabilty = 0.1\n").unwrap();
    let e = EmulatedConfig::load(&p).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Config);
    assert!(format!("{:?}", e).contains("probabilty"), "{e:?}");
    std::fs::write(&p, "[faults.unplug]\nprobability = 2.0\n").unwrap();
    let e = EmulatedConfig::load(&p).unwrap_err();
    assert!(e.to_string().contains("faults.unplug.probability"), "{e}");
    std::fs::write(&p, "[timing]\nstartup_us = -1.0\n").unwrap();
    assert!(
        EmulatedConfig::load(&p)
            .unwrap_err()
            .to_string()
            .contains("timing.startup_us")
    );
    std::fs::write(&p, "[driver.timing]\npoll_interval_us = 0\n").unwrap();
    assert!(
        DeviceConfigFile::load(&p)
            .unwrap_err()
            .to_string()
            .contains("poll_interval_us")
    );
}

#[test]
fn cover_window_files_are_the_phone_model_clean_and_smudged() {
    let clean = EmulatedConfig::load(&config_dir().join("emulated/window-clean.toml")).unwrap();
    let smudged = EmulatedConfig::load(&config_dir().join("emulated/window-smudged.toml")).unwrap();
    let (c, s) = (clean.cover_window.unwrap(), smudged.cover_window.unwrap());
    assert_eq!(c.smudge_rel, 0.0);
    assert_eq!(s.smudge_rel, 1.0, "the smudge doubles the crosstalk");
    assert_eq!(
        tofprox_model::CoverWindow {
            smudge_rel: 0.0,
            ..s
        },
        c,
        "same window otherwise"
    );
    assert!(clean.model.unwrap().ends_with("model/phone.toml"));
    // an out-of-range window is refused naming the parameter
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("w.toml");
    std::fs::write(&p, "[cover_window]\nsmudge_rel = -1.0\n").unwrap();
    let e = EmulatedConfig::load(&p).unwrap_err();
    assert!(format!("{e:?}").contains("smudge_rel"), "{e:?}");
}

/// docs/bridge.md "Public facts and our inventions": where the public record names a register,
/// the shipped emulated map uses it — LPFSMEN (0x9000) starts the sequence with 5 and stops it
/// with 1, the sensor answers at the REAL3 address 0x3D — and no invented register sits on it.
#[test]
fn shipped_map_follows_the_public_facts() {
    let m = EmulatedConfig::default().sensor_map().unwrap();
    const LPFSMEN: u16 = 0x9000;
    assert_eq!(m.sequences.start_measurement, vec![[LPFSMEN, 5]]);
    assert_eq!(m.sequences.stop_measurement, vec![[LPFSMEN, 1]]);
    assert_eq!(m.sensor.i2c_address, 0x3D);
    let invented = [
        m.raw.exposure_base,
        m.raw.phase_base,
        m.raw.illumination_base,
        m.raw.count_register,
        m.flash.load_register,
    ];
    for base in invented {
        assert!(
            !(base..base + m.raw.max_count).contains(&LPFSMEN),
            "{base:#06x}"
        );
    }
    assert!(m.sequences.flash_image.iter().all(|[r, _]| *r != LPFSMEN));

    // the imager bring-up: reset pulsed ~2 µs; PLL registers, wait 2 ms, CTRL (0xB401) then
    // EN (0xB400), wait 2 ms — addresses and waits public, the values written ours
    const EN: u16 = 0xB400;
    const CTRL: u16 = 0xB401;
    let b = m.bring_up.as_ref().expect("the shipped map has [bring_up]");
    assert_eq!((b.ctrl[0], b.en[0]), (CTRL, EN));
    assert_eq!((b.pll_settle_us, b.enable_settle_us), (2000, 2000));
    assert_eq!(b.reset_low_us, 2);
    let pulse_us = DriverConfig::emulated_default().timing.reset_low_us;
    assert!(
        (2..=10).contains(&pulse_us),
        "reset pulse {pulse_us} µs, ~2 µs public"
    );
    let (_, dev) = DeviceConfigFile::load(&config_dir().join("sensor/device.toml")).unwrap();
    assert_eq!(dev.timing.reset_low_us, 2, "config/sensor/device.toml");
    for seq in [&m.sequences.minimum, &m.sequences.flash_image] {
        assert!(seq.iter().all(|[r, _]| *r != EN && *r != CTRL));
    }
    // the driver refuses a reset pulse shorter than the sensor's
    let mut short = DriverConfig::emulated_default();
    short.timing.reset_low_us = 1;
    let e = short.validate().unwrap_err();
    assert!(e.to_string().contains("timing.reset_low_us"), "{e}");
    // a map naming one register for both is refused
    let bad = tofprox_bridge::regmap::EMULATED_MAP_TOML
        .replace("en = [0xB400, 0x0001]", "en = [0xB401, 0x0001]");
    let e = tofprox_bridge::SensorMap::from_toml_str(&bad, "x").unwrap_err();
    assert!(e.to_string().contains("bring_up"), "{e}");
}
