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
}
