//! The fixture seam: what puts a target in front of the module and hands the station the
//! module's [`SensorDriver`]. On the line an operator (or a motorised stage) moves the
//! target ([`OperatorFixture`]); in tests and demos the emulated device renders the target
//! as its scene ([`EmulatedFixture`], feature `emulated`).

use std::collections::BTreeMap;
use std::sync::Arc;

use tofprox_bridge::{Clock, SensorDriver, UsbTransport};

use crate::{StationError, Target};

/// What the fixture is asked to present.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Placement<'a> {
    /// The calibration wall.
    Wall(&'a Target),
    /// The check target.
    Check(&'a Target),
    /// Nothing in range (the absorber).
    Absorber(&'a Target),
}

impl Placement<'_> {
    /// The target presented.
    pub fn target(&self) -> &Target {
        match self {
            Placement::Wall(t) | Placement::Check(t) | Placement::Absorber(t) => t,
        }
    }

    /// The operator's instruction for this placement.
    pub fn instruction(&self) -> String {
        let t = self.target();
        let what = match self {
            Placement::Wall(_) => "the flat calibration wall",
            Placement::Check(_) => "the check target",
            Placement::Absorber(_) => "the absorber (nothing else in range)",
        };
        format!(
            "place {what} ({:.2} × {:.2} m, reflectivity {}) at {} m, perpendicular to the optical axis",
            t.size_m[0], t.size_m[1], t.reflectivity, t.distance_m
        )
    }
}

/// Puts targets in front of the module and owns its driver.
pub trait Fixture {
    /// The module's USB transport.
    type Transport: UsbTransport;
    /// Present `placement` and return the module's driver, ready to capture.
    fn present(
        &mut self,
        placement: Placement<'_>,
    ) -> Result<&mut SensorDriver<Self::Transport>, StationError>;
    /// Conditions the fixture knows of every capture (`ambient_klux`, `temperature_c`),
    /// written into the recordings beside the target's.
    fn conditions(&self) -> BTreeMap<String, f64>;
    /// The clock the device runs on (device time of the report).
    fn clock(&self) -> Arc<dyn Clock>;
    /// One line naming the module (the driver's transport).
    fn describe(&self) -> String;
}

/// A fixture an operator (or a stage controller) moves: `prompt` is told each placement and
/// returns when it is done.
pub struct OperatorFixture<T: UsbTransport, P: FnMut(&str) -> Result<(), StationError>> {
    driver: SensorDriver<T>,
    clock: Arc<dyn Clock>,
    prompt: P,
    conditions: BTreeMap<String, f64>,
    last: Option<String>,
}

impl<T: UsbTransport, P: FnMut(&str) -> Result<(), StationError>> OperatorFixture<T, P> {
    /// A fixture around `driver`; `conditions` are the station's (ambient, temperature).
    pub fn new(
        driver: SensorDriver<T>,
        clock: Arc<dyn Clock>,
        conditions: BTreeMap<String, f64>,
        prompt: P,
    ) -> Self {
        OperatorFixture {
            driver,
            clock,
            prompt,
            conditions,
            last: None,
        }
    }
}

impl<T: UsbTransport, P: FnMut(&str) -> Result<(), StationError>> Fixture
    for OperatorFixture<T, P>
{
    type Transport = T;

    fn present(&mut self, placement: Placement<'_>) -> Result<&mut SensorDriver<T>, StationError> {
        let ask = placement.instruction();
        if self.last.as_deref() != Some(ask.as_str()) {
            (self.prompt)(&ask)?;
            self.last = Some(ask);
        }
        Ok(&mut self.driver)
    }

    fn conditions(&self) -> BTreeMap<String, f64> {
        self.conditions.clone()
    }

    fn clock(&self) -> Arc<dyn Clock> {
        self.clock.clone()
    }

    fn describe(&self) -> String {
        self.driver.transport().describe()
    }
}

#[cfg(feature = "emulated")]
pub use emulated::EmulatedFixture;

#[cfg(feature = "emulated")]
mod emulated {
    use super::*;
    use tofprox_bridge::{EmulatedConfig, EmulatedDevice};

    /// The emulated module: each placement becomes the emulated device's scene (a flat wall at
    /// the target's distance and reflectivity), the module's fixed patterns drawn from the same
    /// seed every time, so it stays one sensor.
    pub struct EmulatedFixture {
        base: EmulatedConfig,
        seed: u64,
        clock: Arc<dyn Clock>,
        driver: Option<SensorDriver<EmulatedDevice>>,
        presented: Option<(f64, f64)>,
    }

    impl EmulatedFixture {
        /// The emulated module of `base` (model, cover window, faults; its scene is replaced
        /// by each placement) with fixed patterns and noise from `seed`, on `clock`.
        pub fn new(base: EmulatedConfig, seed: u64, clock: Arc<dyn Clock>) -> Self {
            EmulatedFixture {
                base,
                seed,
                clock,
                driver: None,
                presented: None,
            }
        }
    }

    impl Fixture for EmulatedFixture {
        type Transport = EmulatedDevice;

        fn present(
            &mut self,
            placement: Placement<'_>,
        ) -> Result<&mut SensorDriver<EmulatedDevice>, StationError> {
            let t = placement.target();
            let scene = (t.distance_m, t.reflectivity);
            if self.presented != Some(scene) || self.driver.is_none() {
                let mut cfg = self.base.clone();
                cfg.scene = tofprox_model::SceneScript {
                    kind: tofprox_model::ScriptKind::Wall,
                    wall_distance_m: t.distance_m,
                    wall_reflectivity: t.reflectivity,
                    ..cfg.scene
                };
                let d = SensorDriver::emulated(cfg, self.clock.clone(), self.seed).map_err(
                    |source| StationError::Device {
                        step: "emulated fixture".into(),
                        source,
                    },
                )?;
                self.driver = Some(d);
                self.presented = Some(scene);
            }
            self.driver.as_mut().ok_or_else(unreachable_driver)
        }

        fn conditions(&self) -> BTreeMap<String, f64> {
            BTreeMap::from([
                ("ambient_klux".to_string(), self.base.ambient_klux),
                ("temperature_c".to_string(), self.base.temperature_c),
            ])
        }

        fn clock(&self) -> Arc<dyn Clock> {
            self.clock.clone()
        }

        fn describe(&self) -> String {
            format!("emulated module, seed {}", self.seed)
        }
    }

    fn unreachable_driver() -> StationError {
        StationError::Device {
            step: "emulated fixture".into(),
            source: tofprox_bridge::BridgeError::config("no emulated device"),
        }
    }
}
