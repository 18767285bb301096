//! tofprox physical sensor model: scene to raw ADC codes with an effect catalogue.
//!
//! A forward model of an indirect time-of-flight PMD sensor (IRS1645 class) after
//! the thesis (chapters 2.2-2.3, 3.2-3.3, 5.1): per pixel and raw image, the
//! electrons collected by taps A and B (signal with falloff, demodulation contrast
//! and a non-sinusoidal correlation, ambient light, dark current, SBI), noise,
//! the differential voltage with fixed-pattern offset, and a 12-bit differential
//! ADC with gain, offset, INL, DNL, quantisation and saturation.
//!
//! Every physical effect is a separately switchable unit of the [`catalogue`](mod@catalogue);
//! a model file (`config/model/*.toml`) enables effects and sets their parameters.
//!
//! Conventions (those of `tofprox_core`, crate documentation): `code_k = mid + offset + A · C(φ − θ_k)`,
//! `φ = 4π f d / c + φ_delay`, mid = 2^(bits−1).
//!
//! ```
//! use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};
//! let sim = Simulator::new(&ModelConfig::ideal(), SensorGeometry::irs1645().window(80, 100, 4, 4).unwrap(), 1).unwrap();
//! let codes = sim.expected(&Scene::wall(0.5, 1.0), &CaptureRequest::four_phase(500.0)).unwrap();
//! assert_eq!(codes.dim(), (4, 4, 4));
//! ```

pub mod catalogue;
pub mod config;
pub mod effects;
pub mod entry;
pub mod error;
pub mod figures;
pub mod geometry;
pub mod ids;
pub mod preset;
pub mod scene;
pub mod sim;
pub mod summary;
pub mod sweep;
pub mod waveform;

pub use catalogue::{EffectInfo, ParamInfo, catalogue};
pub use config::{EffectSettings, MeasuredWaveforms, ModelConfig};
pub use error::{ErrorKind, ModelError};
pub use geometry::{CaptureRequest, SensorGeometry};
pub use scene::{
    CoverWindow, Expect, Motion, ObjectPose, PhoneScene, Scene, SceneScript, ScriptKind,
    phone_scenes,
};
pub use sim::Simulator;
pub use summary::{EffectState, ModelSummary};
pub use sweep::{PlannedCapture, SweepPlan};
