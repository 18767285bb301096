//! Implementations of the effect families. Each module documents the effects it
//! implements by catalogue id; [`crate::catalogue`](mod@crate::catalogue) holds their descriptions.
//!
//! - [`optical`]: `signal_falloff`, `demodulation_contrast`, `waveform_harmonics`,
//!   `multipath`, `vcsel_droop`, `ambient_light`
//! - [`fixed_pattern`]: `prnu`, `fpn_offset`, `fppn` (per-pixel patterns drawn once)
//! - [`pixel`]: `sbi_asymmetry`, `amplitude_phase_error`, `temperature_drift`,
//!   `dark_current`, `shot_noise`, `ktc_noise`, `read_noise`
//! - [`shape`]: the monotone shape form of `amplitude_phase_error`,
//!   `temperature_drift`, `sbi_asymmetry` and `vcsel_droop` (knots of the
//!   driver, values of the effect)
//! - [`adc`]: `adc_gain`, `adc_offset`, `adc_inl`, `adc_dnl`, `quantization`

pub mod adc;
pub mod fixed_pattern;
pub mod optical;
pub mod pixel;
pub mod shape;
