//! The effect registry: every physical effect of the model as a documented unit
//! with its id, its physics, the thesis reference, its residual signature, its
//! parameters (units, typical value, physical range), what it acts on, which
//! capture conditions drive it and whether it cancels in the 4-phase algorithm.
//!
//! Ids and parameter names are spelled once, in [`crate::ids`]; the laws live in
//! [`crate::effects`]. This table is the one list the simulator's configuration,
//! the config validation, `tofprox model effects`, the docs and the lab
//! (`tofprox_lab`: which effects it fits, their drivers, 2- vs 4-phase) read.

use serde::Serialize;

use crate::ids::{self, ParamId};

/// What an effect changes in the signal chain (2.2–3.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ActsOn {
    /// The signal electrons of a return (their number, or a second return).
    Signal,
    /// The shape of the correlation C(φ − θ).
    Correlation,
    /// The signal phasor's gain and phase: the lab applies it to amplitude and
    /// phase rather than adding codes.
    Phasor,
    /// Electrons common to both taps (background, dark current).
    TapCharge,
    /// The differential charge of the two taps directly.
    Differential,
    /// A code offset of the read-out.
    Offset,
    /// The ADC's transfer function.
    Adc,
    /// Noise only: the expected codes do not change.
    Noise,
}

/// A capture condition (or a quantity of a sample) an effect varies with; the
/// lab advises on a condition one effect varies with and another does not.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Driver {
    /// The signal amplitude (reflectivity, distance, exposure).
    Amplitude,
    /// `exposure_us`.
    ExposureUs,
    /// `ambient_klux`.
    AmbientKlux,
    /// `temperature_c`.
    TemperatureC,
    /// The raw image's index in the acquisition.
    ImageIndex,
    /// The phase φ − θ of a raw image.
    Phase,
    /// `distance_m`.
    DistanceM,
    /// The output code of the ADC.
    AdcCode,
}

impl ActsOn {
    /// The name as in `tofprox model effects` and its JSON.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Signal => "signal",
            Self::Correlation => "correlation",
            Self::Phasor => "phasor",
            Self::TapCharge => "tap_charge",
            Self::Differential => "differential",
            Self::Offset => "offset",
            Self::Adc => "adc",
            Self::Noise => "noise",
        }
    }
}

impl Driver {
    /// The name as a recording's condition key or the lab's quantity.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Amplitude => "amplitude",
            Self::ExposureUs => "exposure_us",
            Self::AmbientKlux => "ambient_klux",
            Self::TemperatureC => "temperature_c",
            Self::ImageIndex => "image_index",
            Self::Phase => "phase",
            Self::DistanceM => "distance_m",
            Self::AdcCode => "adc_code",
        }
    }
}

/// One parameter of an effect.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ParamInfo {
    /// Key in the model file (`[effects.<id>] <name> = value`).
    pub name: &'static str,
    /// Physical unit ("" for dimensionless).
    pub unit: &'static str,
    /// Typical value (thesis value where the thesis gives one).
    pub typical: f64,
    /// Smallest physically meaningful value (inclusive).
    pub min: f64,
    /// Largest physically meaningful value (inclusive).
    pub max: f64,
    /// One-line meaning.
    pub doc: &'static str,
}

/// One effect of the catalogue.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct EffectInfo {
    /// Stable id, used as `[effects.<id>]` in model files.
    pub id: &'static str,
    /// Short title.
    pub title: &'static str,
    /// One paragraph of physics with the equation used.
    pub explanation: &'static str,
    /// Where the thesis treats it.
    pub thesis_ref: &'static str,
    /// What the effect looks like in a residual (measured − model).
    pub signature: &'static str,
    /// Parameters with units, typical values and ranges.
    pub params: &'static [ParamInfo],
    /// Enabled in `config/model/baseline.toml` (what a usual calibration covers).
    pub in_baseline: bool,
    /// What it changes in the signal chain.
    pub acts_on: ActsOn,
    /// The conditions its residual varies with.
    pub drivers: &'static [Driver],
    /// Its residual is common to the raw images and cancels in the 4-phase
    /// algorithm (0° − 180°), not in 2-phase (5.1.2.3, eq. 3.4).
    pub cancels_in_four_phase: bool,
}

impl EffectInfo {
    /// Parameter description by name.
    pub fn param(&self, name: &str) -> Option<&'static ParamInfo> {
        self.params.iter().find(|p| p.name == name)
    }
}

const fn p(
    id: ParamId,
    unit: &'static str,
    typical: f64,
    min: f64,
    max: f64,
    doc: &'static str,
) -> ParamInfo {
    ParamInfo {
        name: id.name(),
        unit,
        typical,
        min,
        max,
        doc,
    }
}

/// Section name of the always-on sensor constants (`[sensor]` in a model file).
pub const SENSOR_SECTION: &str = ids::sensor::SECTION;

/// Always-present sensor constants (not effects; `[sensor]` in a model file).
pub static SENSOR_PARAMS: &[ParamInfo] = &[
    p(
        ids::sensor::SIGNAL_E_PER_US,
        "e-/us",
        40.0,
        1e-3,
        1e6,
        "photo-electrons per µs of exposure (both taps) from a reflectivity-1 target at 1 m at nominal optical power",
    ),
    p(
        ids::sensor::LSB_PER_KE,
        "LSB/ke-",
        3.0,
        1e-3,
        1e4,
        "conversion gain of the differential read-out: ADC codes per 1000 electrons of tap difference",
    ),
];

/// Harmonic parameters `h2_rel … h9_rel`, `h2_phase_deg … h9_phase_deg`.
/// Typical values: the odd harmonics of the measured-like VCSEL/pulse correlation
/// ([`crate::effects::optical::measured_like_waveforms`], about ±6 mm wiggling at
/// 80 MHz), plus small even harmonics of a slightly asymmetric duty cycle.
static HARMONIC_PARAMS: &[ParamInfo] = &[
    p(
        ids::HARMONIC_REL[0],
        "",
        0.008,
        0.0,
        0.5,
        "2nd harmonic amplitude relative to the fundamental (duty-cycle asymmetry)",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[0],
        "deg",
        0.0,
        -180.0,
        180.0,
        "2nd harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[1],
        "",
        0.023,
        0.0,
        0.5,
        "3rd harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[1],
        "deg",
        28.0,
        -180.0,
        180.0,
        "3rd harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[2],
        "",
        0.002,
        0.0,
        0.5,
        "4th harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[2],
        "deg",
        0.0,
        -180.0,
        180.0,
        "4th harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[3],
        "",
        0.0032,
        0.0,
        0.5,
        "5th harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[3],
        "deg",
        54.0,
        -180.0,
        180.0,
        "5th harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[4],
        "",
        0.0005,
        0.0,
        0.5,
        "6th harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[4],
        "deg",
        0.0,
        -180.0,
        180.0,
        "6th harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[5],
        "",
        0.0009,
        0.0,
        0.5,
        "7th harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[5],
        "deg",
        79.0,
        -180.0,
        180.0,
        "7th harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[6],
        "",
        0.0002,
        0.0,
        0.5,
        "8th harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[6],
        "deg",
        0.0,
        -180.0,
        180.0,
        "8th harmonic phase",
    ),
    p(
        ids::HARMONIC_REL[7],
        "",
        0.0003,
        0.0,
        0.5,
        "9th harmonic amplitude relative to the fundamental",
    ),
    p(
        ids::HARMONIC_PHASE_DEG[7],
        "deg",
        103.0,
        -180.0,
        180.0,
        "9th harmonic phase",
    ),
];

/// Optional string keys of `waveform_harmonics` (file paths, relative to the model file).
pub static WAVEFORM_FILE_KEYS: &[&str] = &["illumination_file", "modulation_file"];

/// The catalogue, in signal-chain order.
pub static CATALOGUE: &[EffectInfo] = &[
    EffectInfo {
        id: ids::signal_falloff::ID.as_str(),
        title: "Reflected signal vs distance",
        explanation: "The optical power reaching a pixel from a diffuse target falls with the square of the distance: N_sig = signal_e_per_us · t_exp · ρ · (1 m / d)^n with n = 2 for a Lambertian wall. Disabled, the collected signal is that of 1 m at every distance (the constant-electron sweeps of fig. 3.9).",
        thesis_ref: "2.2.1, 3.3.3 (fig. 3.7: signal loss with distance)",
        signature: "amplitude ∝ d^-n; depth residuals of offset-like effects grow with distance",
        params: &[p(
            ids::signal_falloff::EXPONENT,
            "",
            2.0,
            1.0,
            3.0,
            "distance exponent n of the falloff (2 = inverse square)",
        )],
        in_baseline: true,
        acts_on: ActsOn::Signal,
        drivers: &[Driver::DistanceM],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::demodulation_contrast::ID.as_str(),
        title: "Demodulation contrast",
        explanation: "Only a share K of the photo-generated charge is separated by the modulation gates; the rest adds equally to both taps: N_A,B = N/2 · (1 ± K·C(φ−θ)). K is eq. 2.10/2.11's demodulation contrast. Disabled, K = 1.",
        thesis_ref: "2.2.2.2, eq. 2.10-2.11",
        signature: "amplitude scales by K at constant intensity; no phase change",
        params: &[p(
            ids::demodulation_contrast::CONTRAST,
            "",
            0.8,
            0.05,
            1.0,
            "demodulation contrast K",
        )],
        in_baseline: true,
        acts_on: ActsOn::Signal,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::waveform_harmonics::ID.as_str(),
        title: "Non-sinusoidal correlation (wiggling)",
        explanation: "Illumination and modulation are rectangular-like, so the correlation is C(x) = cos x + Σ_{n=2..9} r_n cos(n x + ψ_n) (normalised to |C| ≤ 1) instead of cos x. 4-phase sampling aliases odd harmonics 3, 5 onto the fundamental and produces the circular 'wiggling' depth error with 4 periods per 2π; even harmonics (duty-cycle asymmetry) cancel in 4-phase but not in 2-phase. Alternatively C is computed from measured illumination and modulation waveforms (one period each, CSV or NPY) by circular cross-correlation C(τ) = ⟨s(t) · (2 r(t+τ) − 1)⟩.",
        thesis_ref: "2.3.1.1, 3.2.2, 3.3.6, 5.1.2.1 (fig. 3.10, 3.11, 5.1)",
        signature: "depth error periodic in phase (period π/2 for 4-phase, plus π for 2-phase), independent of exposure and amplitude",
        params: HARMONIC_PARAMS,
        in_baseline: true,
        acts_on: ActsOn::Correlation,
        drivers: &[Driver::Phase, Driver::DistanceM],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::multipath::ID.as_str(),
        title: "Multipath return",
        explanation: "A second, weaker return travels a longer path (e.g. via the floor or a side wall) and mixes into the pixel: N_2 = a · N_sig at phase φ₂ = 4π f (d + Δ/2) / c. The measured phasor is the sum of both, so the depth is pulled towards the longer path by an amount oscillating with distance.",
        thesis_ref: "not treated in the thesis (extension; standard iToF error)",
        signature: "depth error oscillating with distance with period c/(2f) scaled by path difference; same in 2- and 4-phase",
        params: &[
            p(
                ids::multipath::RELATIVE_AMPLITUDE,
                "",
                0.08,
                0.0,
                1.0,
                "amplitude of the second return relative to the direct one",
            ),
            p(
                ids::multipath::EXTRA_PATH_M,
                "m",
                0.4,
                0.0,
                20.0,
                "additional round-trip path length of the second return",
            ),
        ],
        in_baseline: false,
        acts_on: ActsOn::Signal,
        drivers: &[Driver::DistanceM],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::cover_window_crosstalk::ID.as_str(),
        title: "Cover-window crosstalk",
        explanation: "The cover window (phone glass) in front of emitter and lens reflects part of the illumination straight back into the pixels, before it reaches the scene. It is a return at the window's distance d_w (a few mm) that does not depend on the scene: N_xt = e_per_us · (1 + smudge_rel) · t_exp · w(c) · g_p · droop_k · drift_gain electrons (both taps, ∝ exposure and illumination power), w(c) = max(0, 1 + gradient_rel · (c/(cols_full − 1) − ½)) the profile across the columns (the emitter sits beside the array), at phase φ_xt = 4π f d_w / c + φ_delay,p (the electrical delay of every return). Its taps follow N_A,B = N_xt/2 · (1 ± K C(φ_xt − θ_k)); its electrons add shot noise and tap charge (SBI) like any light. The measured phasor is the sum of scene and window returns, so a weak far target is pulled towards zero distance; a smudge (grease scatters more light back) multiplies it by 1 + smudge_rel.",
        thesis_ref: "not treated in the thesis (extension: phone proximity sensors sit behind a cover glass, 2.4.2); an extra return adds its phasor (2.2.1, eq. 2.2/2.3); the stray-light correction step of fig. 3.1 (3.1)",
        signature: "a constant complex offset per pixel ∝ exposure, at ≈ zero distance, present with nothing in range; depth of weak (far, dark) targets pulled short, bright near targets unaffected; same in 2- and 4-phase",
        params: &[
            p(
                ids::cover_window_crosstalk::E_PER_US,
                "e-/us",
                20.0,
                0.0,
                1e5,
                "crosstalk electrons per µs of exposure (both taps) of the clean window at nominal optical power (20 ≈ the return of a white target at 1.4 m)",
            ),
            p(
                ids::cover_window_crosstalk::SMUDGE_REL,
                "",
                0.0,
                0.0,
                50.0,
                "extra crosstalk of a smudged window relative to the clean one (1 = doubled)",
            ),
            p(
                ids::cover_window_crosstalk::WINDOW_DISTANCE_MM,
                "mm",
                3.0,
                0.0,
                50.0,
                "distance d_w of the cover window's reflecting surface from the sensor",
            ),
            p(
                ids::cover_window_crosstalk::GRADIENT_REL,
                "",
                0.5,
                -2.0,
                2.0,
                "relative change of the crosstalk from the first to the last column of the full array",
            ),
        ],
        in_baseline: false,
        acts_on: ActsOn::Signal,
        drivers: &[Driver::ExposureUs],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::vcsel_droop::ID.as_str(),
        title: "VCSEL power droop over successive raw images",
        explanation: "The VCSEL heats while it emits; its optical power falls over successive raw images of one acquisition: P_k = P · (1 − D · (1 − exp(−(k + k₀) · s / τ))) for raw image k in acquisition order, with heating per image s = 1 ms · (t_exp / 1 ms)^β (β = 1: heating by on-time, s = t_exp; β = 0: by image count) and k₀ images of heating before the first one (k₀ = 1: the first image is already drooped). Unequal amplitudes of the images used together distort the phasor; 4-phase loses its 0/180 symmetry. Second form: a monotone shape of the VCSEL's on-time before image k, t_on = k·t_exp, given by `shape_on_time_us` (knots, µs) and `shape_loss_rel` (the loss L < 1, P_k = P·(1 − L(t_on))), linear between the knots and flat outside them; it replaces the parametric law.",
        thesis_ref: "3.3.7.2, 5.1.2.1 ('varying emission power during exposure of several raw images')",
        signature: "raw residual grows with raw-image index and with exposure; depth error with period 2π in phase",
        params: &[
            p(
                ids::vcsel_droop::DROOP_REL,
                "",
                0.03,
                0.0,
                0.5,
                "asymptotic relative power loss D",
            ),
            p(
                ids::vcsel_droop::TAU_US,
                "us",
                3000.0,
                1.0,
                1e7,
                "thermal time constant τ of the droop (in accumulated exposure)",
            ),
            p(
                ids::vcsel_droop::EXPOSURE_POWER,
                "1",
                1.0,
                0.0,
                2.0,
                "β: heating per raw image ∝ exposure^β (1: on-time, 0: image count)",
            ),
            p(
                ids::vcsel_droop::FIRST_IMAGE_INDEX,
                "1",
                0.0,
                0.0,
                8.0,
                "k₀: raw images of heating before the first (1: the first image already drooped)",
            ),
        ],
        in_baseline: false,
        acts_on: ActsOn::Signal,
        drivers: &[Driver::ImageIndex],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::prnu::ID.as_str(),
        title: "Photo-response non-uniformity incl. vignetting",
        explanation: "Each pixel converts light with its own gain g_p ~ N(1, σ) (fill factor, micro-lens, QE variation) and the lens and illumination profile fall off towards the corners: g_p · (1 − v · r²) with r the distance from the optical centre normalised to the corner. Multiplies signal and background electrons of both taps; never changes the phase.",
        thesis_ref: "2.3.1.3 (PRNU)",
        signature: "per-pixel amplitude ratio fixed over all captures, radial falloff; no depth effect",
        params: &[
            p(
                ids::prnu::SIGMA_REL,
                "",
                0.01,
                0.0,
                0.3,
                "per-pixel gain standard deviation",
            ),
            p(
                ids::prnu::VIGNETTING_REL,
                "",
                0.25,
                0.0,
                0.9,
                "relative response loss at the array corner (quadratic in radius)",
            ),
        ],
        in_baseline: true,
        acts_on: ActsOn::Signal,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::fppn::ID.as_str(),
        title: "Fixed-pattern phase noise and global delay",
        explanation: "The modulation signal reaches each pixel with its own delay: a global delay τ_g of driver and cabling, a delay growing along the distributed RC line of the column, τ(x) = τ_c · x (2 − x) (Elmore delay of a distributed line driven at x = 0, x = row/(rows − 1)), and a per-pixel random part. The phase offset is φ_delay = 2π f τ, added to φ_tof.",
        thesis_ref: "2.3.1.4",
        signature: "constant depth offset per pixel, growing down the columns; independent of distance",
        params: &[
            p(
                ids::fppn::GLOBAL_DELAY_NS,
                "ns",
                1.5,
                -20.0,
                20.0,
                "global delay of driver and cabling",
            ),
            p(
                ids::fppn::COLUMN_DELAY_PS,
                "ps",
                120.0,
                0.0,
                5000.0,
                "extra delay at the far end of the column RC line",
            ),
            p(
                ids::fppn::PIXEL_SIGMA_PS,
                "ps",
                15.0,
                0.0,
                1000.0,
                "per-pixel random delay standard deviation",
            ),
        ],
        in_baseline: true,
        acts_on: ActsOn::Phasor,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::amplitude_phase_error::ID.as_str(),
        title: "Amplitude-dependent phase error",
        explanation: "Non-linearity of pixel and read-out makes the phase depend on the signal amplitude (dark vs bright surfaces, fig. 2.9): Δφ = φ_max · (1 − x/(1 + xⁿ)^(1/n)), x = A/A_ref, A the differential amplitude in electrons. n = 1 is the hyperbolic law φ_max·A_ref/(A_ref + A); larger n saturate more sharply (n ≈ 2 is close to a tanh). Second form, where no member of the family fits: a monotone shape Δφ(A) given by `shape_amplitude_e` (knots, e⁻) and `shape_phase_rad` (values), linear between the knots and flat outside them; it replaces the parametric law.",
        thesis_ref: "2.3.1.2 (fig. 2.9)",
        signature: "depth error depending on amplitude (reflectivity, distance, exposure), not on phase",
        params: &[
            p(
                ids::amplitude_phase_error::MAX_RAD,
                "rad",
                0.03,
                -0.5,
                0.5,
                "phase error φ_max in the limit of zero amplitude",
            ),
            p(
                ids::amplitude_phase_error::REFERENCE_E,
                "e-",
                3000.0,
                1.0,
                1e10,
                "amplitude A_ref at which half of φ_max remains",
            ),
            p(
                ids::amplitude_phase_error::SHAPE,
                "1",
                1.0,
                0.25,
                10.0,
                "sharpness n of the saturation (1: hyperbolic)",
            ),
        ],
        in_baseline: false,
        acts_on: ActsOn::Phasor,
        drivers: &[Driver::Amplitude, Driver::ExposureUs],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::temperature_drift::ID.as_str(),
        title: "Temperature drift of phase and gain",
        explanation: "Driver and VCSEL delays and the responsivity change with temperature: Δφ = k_φ·ΔT + k_φ2·ΔT², gain ×(1 + k_g·ΔT + k_g2·ΔT²), ΔT = T − T_ref. The second-order terms describe a drift that bends (delays and responsivity that change faster when hot); 0 gives the linear law. T is the capture's temperature_c. Second form: monotone shapes of T itself given by `shape_temperature_c` (knots, °C) with `shape_phase_rad` (Δφ) and `shape_gain_rel` (G), linear between the knots and flat outside them; they replace the polynomial (and its reference_c).",
        thesis_ref: "3.1 (temperature compensation step of fig. 3.1)",
        signature: "depth offset and amplitude change with temperature_c (linear, or bending with the second-order terms)",
        params: &[
            p(
                ids::temperature_drift::PHASE_MRAD_PER_K,
                "mrad/K",
                1.5,
                -100.0,
                100.0,
                "phase drift k_φ",
            ),
            p(
                ids::temperature_drift::GAIN_REL_PER_K,
                "1/K",
                -0.002,
                -0.05,
                0.05,
                "relative signal drift k_g",
            ),
            p(
                ids::temperature_drift::PHASE_MRAD_PER_K2,
                "mrad/K^2",
                0.0,
                -5.0,
                5.0,
                "second-order phase drift k_φ2",
            ),
            p(
                ids::temperature_drift::GAIN_REL_PER_K2,
                "1/K^2",
                0.0,
                -0.002,
                0.002,
                "second-order relative signal drift k_g2",
            ),
            p(
                ids::temperature_drift::REFERENCE_C,
                "degC",
                25.0,
                -40.0,
                125.0,
                "temperature T_ref without drift",
            ),
        ],
        in_baseline: false,
        acts_on: ActsOn::Phasor,
        drivers: &[Driver::TemperatureC],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::ambient_light::ID.as_str(),
        title: "Uncorrelated background light",
        explanation: "Background light (sunlight, lamps) is not modulated: it adds N_amb = k · E · t_exp electrons equally to both taps (E in klux, after the optical filter). It carries no phase but adds shot noise and drives the taps towards the SBI threshold.",
        thesis_ref: "2.2.2.1, 5.1.2.3",
        signature: "noise grows with ambient_klux; with SBI mismatch a 2-phase-only depth error",
        params: &[p(
            ids::ambient_light::E_PER_US_PER_KLUX,
            "e-/us/klux",
            3.0,
            0.0,
            1e4,
            "electrons per µs per tap per klux",
        )],
        in_baseline: true,
        acts_on: ActsOn::TapCharge,
        drivers: &[Driver::AmbientKlux],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::dark_current::ID.as_str(),
        title: "Dark current and its shot noise",
        explanation: "Thermally generated electrons add N_dark = i_d · t_exp to both taps, doubling every ΔT_2 kelvin: i_d(T) = i_d,25 · 2^((T − 25 °C)/ΔT_2). Their Poisson noise σ² = N_dark per tap (eq. 2.17) is part of this effect.",
        thesis_ref: "2.3.2.3, eq. 2.17",
        signature: "noise floor growing with exposure and temperature; common mode only",
        params: &[
            p(
                ids::dark_current::E_PER_US,
                "e-/us",
                0.05,
                0.0,
                1e4,
                "dark electrons per µs per tap at 25 °C",
            ),
            p(
                ids::dark_current::DOUBLING_C,
                "K",
                7.0,
                1.0,
                30.0,
                "temperature increase that doubles the dark current",
            ),
        ],
        in_baseline: true,
        acts_on: ActsOn::TapCharge,
        drivers: &[Driver::ExposureUs],
        cancels_in_four_phase: true,
    },
    EffectInfo {
        id: ids::sbi_asymmetry::ID.as_str(),
        title: "SBI circuit with mismatch",
        explanation: "The suppression-of-background-illumination circuit (fig. 2.7) monitors both taps; once the fuller tap passes the threshold Q_th (at t_on = Q_th / r_max) it injects a common current into both taps: the smaller photo-current (clamp_share s = 0, the thesis' circuit: it subtracts the common part) or, towards s = 1, the larger one (a clamp that holds the fuller tap at Q_th); r_inj = (1 − s)·r_min + s·r_max, never removing more charge than the emptier tap holds (N_inj ≤ N_min). Mismatch m between the two injection transistors leaves a differential error ΔN = −m · r_inj · (t_exp − t_on). The error depends on |C(φ−θ)| and is identical in the 0°/180° (90°/270°) images, so 4-phase cancels it and 2-phase does not (fig. 5.6-5.8). Second form, a clamp with a knee of any shape: the charge removed from each tap as a monotone shape of the fuller tap's charge, `shape_tap_charge_e` (knots, e⁻) and `shape_removed_e` (values, e⁻, 0 at the first knot where the circuit starts, non-decreasing), linear between the knots, never more than the emptier tap holds; it replaces threshold_e and clamp_share (the mismatch m stays).",
        thesis_ref: "2.2.2.1, 5.1.2.3 (fig. 5.6-5.8)",
        signature: "2-phase-only depth error rising with ambient_klux and exposure above a threshold; 4-phase unaffected",
        params: &[
            p(
                ids::sbi_asymmetry::THRESHOLD_E,
                "e-",
                60000.0,
                100.0,
                1e8,
                "tap charge Q_th at which the SBI starts to inject",
            ),
            p(
                ids::sbi_asymmetry::MISMATCH_REL,
                "",
                0.03,
                -0.3,
                0.3,
                "relative mismatch m of the injected currents between tap A and B",
            ),
            p(
                ids::sbi_asymmetry::CLAMP_SHARE,
                "",
                0.0,
                0.0,
                1.0,
                "s: 0 injects the smaller tap current (subtracts), 1 the larger (clamps the fuller tap at Q_th)",
            ),
        ],
        in_baseline: false,
        acts_on: ActsOn::Differential,
        drivers: &[Driver::AmbientKlux, Driver::ExposureUs, Driver::Amplitude],
        cancels_in_four_phase: true,
    },
    EffectInfo {
        id: ids::tap_gain_mismatch::ID.as_str(),
        title: "Tap gain mismatch (A/B)",
        explanation: "The two taps of a pixel convert charge with slightly different gains (storage capacitance, source follower): D = (1 + ε/2)·N_A − (1 − ε/2)·N_B = (N_A − N_B) + ε/2·(N_A + N_B). A share of the total charge (signal, background light, dark current) leaks into the differential code, the same in every raw image: 4-phase cancels it (0° − 180°), 2-phase does not (it moves the phasor's origin like an offset that grows with the signal, cf. eq. 3.4).",
        thesis_ref: "2.2.2 (two-tap pixel, eq. 2.1), 3.3.3 eq. 3.4",
        signature: "common-mode code ∝ total charge (signal and ambient), equal in all raw images; 2-phase depth error, 4-phase unaffected",
        params: &[p(
            ids::tap_gain_mismatch::MISMATCH_REL,
            "1",
            0.002,
            -0.1,
            0.1,
            "relative gain difference ε = g_A/g_B − 1",
        )],
        in_baseline: false,
        acts_on: ActsOn::Differential,
        drivers: &[Driver::Amplitude, Driver::AmbientKlux],
        cancels_in_four_phase: true,
    },
    EffectInfo {
        id: ids::fpn_offset::ID.as_str(),
        title: "Fixed-pattern offset (FPN) of the read-out",
        explanation: "Every pixel's differential code carries a fixed offset from its read-out path (fig. 3.12): 16 ADCs with even/odd ping-pong channels (column c maps to ADC channel by the 32-column mirrored pattern of 3.3.7.1: col 0 → ADC0 odd, col 15 → ADC0 even, col 31 ≡ col 0), the column source follower/amplifier, a term growing along the column line, and the pixel's reset transistor. offset = ch(c) + col(c) + line · row/(rows−1) + pix(r, c); overall σ ≈ 34 LSB (fig. 3.13). It is what a dark frame measures and what the offset calibration subtracts.",
        thesis_ref: "2.3.1.3, 3.3.3, 3.3.7.1 (fig. 3.12-3.16)",
        signature: "constant per-pixel code offset, present in dark frames; column stripes; 2-phase depth error growing with distance",
        params: &[
            p(
                ids::fpn_offset::ADC_CHANNEL_SIGMA_LSB,
                "LSB",
                8.0,
                0.0,
                500.0,
                "offset standard deviation between ADC channels",
            ),
            p(
                ids::fpn_offset::COLUMN_SIGMA_LSB,
                "LSB",
                15.0,
                0.0,
                500.0,
                "offset standard deviation between column amplifiers",
            ),
            p(
                ids::fpn_offset::PIXEL_SIGMA_LSB,
                "LSB",
                29.0,
                0.0,
                500.0,
                "per-pixel offset standard deviation",
            ),
            p(
                ids::fpn_offset::COLUMN_LINE_LSB,
                "LSB",
                4.0,
                -500.0,
                500.0,
                "offset change from the top to the bottom of a column line",
            ),
            p(
                ids::fpn_offset::MEAN_LSB,
                "LSB",
                0.0,
                -1000.0,
                1000.0,
                "mean offset over the array",
            ),
        ],
        in_baseline: true,
        acts_on: ActsOn::Offset,
        drivers: &[],
        cancels_in_four_phase: true,
    },
    EffectInfo {
        id: ids::adc_gain::ID.as_str(),
        title: "ADC gain error",
        explanation: "The converter slope deviates from ideal by a gain error in % of full-scale range: k_gain = 2^N / (FSR · (1 + e_gain)) (eq. 3.2). A common factor on all raw images never changes the phase (eq. 3.3) but scales amplitude and moves saturation.",
        thesis_ref: "3.2.1 eq. 3.2, 3.3.2 eq. 3.3, table 3.2",
        signature: "amplitude ratio, earlier saturation; no depth effect",
        params: &[p(
            ids::adc_gain::GAIN_ERROR_PCT_FSR,
            "%FSR",
            -4.713,
            -30.0,
            30.0,
            "gain error e_gain (table 3.2: min -6.096, typ -4.713, max -2.176)",
        )],
        in_baseline: true,
        acts_on: ActsOn::Adc,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::adc_offset::ID.as_str(),
        title: "ADC offset error",
        explanation: "A constant added to the transfer function: code = mid + k·u + o (3.2.1). Equal in all raw images, it adds a 45° phasor in 2-phase (eq. 3.4, fig. 3.7) and cancels in 4-phase; it is part of what dark frames measure.",
        thesis_ref: "3.2.1, 3.3.3 eq. 3.4, fig. 3.7, table 3.2",
        signature: "constant code offset; 2-phase depth error growing with distance (45° phasor)",
        params: &[p(
            ids::adc_offset::OFFSET_LSB,
            "LSB",
            -10.84,
            -500.0,
            500.0,
            "offset error o (table 3.2: min -13.94, typ -10.84, max 12.19)",
        )],
        in_baseline: true,
        acts_on: ActsOn::Offset,
        drivers: &[],
        cancels_in_four_phase: true,
    },
    EffectInfo {
        id: ids::adc_inl::ID.as_str(),
        title: "ADC integral non-linearity",
        explanation: "The differential converter's INL has opposite sign on the two half-ranges (fig. 3.4): INL(u) = I · sin(2π u / 2^N) for u the input in LSB around mid, zero at mid and at the rails, extremes ±I at half of each half-range. It distorts large phase-image voltages and gives a wiggling-like error with extremes at 22.5°/67.5° and zeros at multiples of 45° (fig. 3.8).",
        thesis_ref: "3.2.1, 3.3.1, 3.3.4 (fig. 3.4, 3.8), table 3.2",
        signature: "raw residual odd in (code − mid) with period 2^N; depth error with period π/2 growing with amplitude",
        params: &[p(
            ids::adc_inl::INL_LSB,
            "LSB",
            -1.744,
            -500.0,
            500.0,
            "INL extreme I (table 3.2: min -2.392, typ -1.744, max 1.875)",
        )],
        in_baseline: false,
        acts_on: ActsOn::Adc,
        drivers: &[Driver::AdcCode, Driver::ExposureUs],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::adc_dnl::ID.as_str(),
        title: "ADC differential non-linearity",
        explanation: "Code transition levels deviate randomly from their ideal positions, T_k = k − ½ + ε_k with ε_k Gaussian (σ = DNL/(3√2), clipped to ±DNL/2) from a fixed per-sensor table, so step widths 1 + ε_{k+1} − ε_k lie within 1 ± DNL LSB (a transition below its predecessor is a missing code).",
        thesis_ref: "3.2.1, 3.3.1, 3.3.5 (fig. 3.9), table 3.2",
        signature: "raw residual jumping from code to code, fixed per code; depth error well below 1 cm",
        params: &[p(
            ids::adc_dnl::DNL_LSB,
            "LSB",
            1.906,
            0.0,
            4.0,
            "maximum DNL (table 3.2: min 1.594, typ 1.906, max 2.438)",
        )],
        in_baseline: false,
        acts_on: ActsOn::Adc,
        drivers: &[Driver::AdcCode],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::quantization::ID.as_str(),
        title: "Quantisation to integer codes",
        explanation: "The ADC outputs integer codes: uniform error in [−½, ½] LSB with σ = 1/√12 LSB (2.3.2.5). Averaged captures (averaged = n) return the mean of n quantised acquisitions, modelled as the continuous transfer plus noise of variance (σ² + 1/12)/n. Codes saturate at 0 and 2^N − 1 (the saturation flag of 3.2.1) whether or not this effect is on.",
        thesis_ref: "2.3.2.5, eq. 2.20-2.21, 3.2.1",
        signature: "integer codes; 1/12 LSB² noise floor",
        params: &[],
        in_baseline: true,
        acts_on: ActsOn::Adc,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::shot_noise::ID.as_str(),
        title: "Photon shot noise",
        explanation: "Photo-electrons arrive Poisson-distributed: σ² = N per tap (eq. 2.16) including the background-light electrons; the taps are independent so the differential variance is N_A + N_B (times an excess noise factor F). Scaled by 1/averaged for averaged captures. Together with read noise this gives the photon transfer curve var = g² F (N_A + N_B) + σ_read² (2.3.2.6).",
        thesis_ref: "2.3.2.2 eq. 2.16, 2.3.2.6",
        signature: "variance linear in the collected electrons (photon transfer curve)",
        params: &[p(
            ids::shot_noise::EXCESS_NOISE_FACTOR,
            "",
            1.0,
            1.0,
            5.0,
            "excess noise factor F (1 = pure Poisson)",
        )],
        in_baseline: true,
        acts_on: ActsOn::Noise,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::read_noise::ID.as_str(),
        title: "Read-out noise",
        explanation: "Thermal noise of source follower, column amplifier and ADC (eq. 2.18) referred to the output: Gaussian σ_read in LSB, independent of light; the floor of the photon transfer curve.",
        thesis_ref: "2.3.2.4, 2.3.2.6",
        signature: "constant noise floor in dark frames",
        params: &[p(
            ids::read_noise::SIGMA_LSB,
            "LSB",
            1.2,
            0.0,
            100.0,
            "read noise standard deviation",
        )],
        in_baseline: true,
        acts_on: ActsOn::Noise,
        drivers: &[],
        cancels_in_four_phase: false,
    },
    EffectInfo {
        id: ids::ktc_noise::ID.as_str(),
        title: "Reset (kTC) noise",
        explanation: "Resetting the integration capacitance leaves an uncertain charge σ = √(k T C_int)/e per tap (eq. 2.14-2.15), T the capture's temperature; both taps independent.",
        thesis_ref: "2.3.2.1 eq. 2.14-2.15",
        signature: "constant noise floor growing slowly with temperature",
        params: &[p(
            ids::ktc_noise::C_INT_FF,
            "fF",
            20.0,
            0.01,
            10000.0,
            "integration capacitance C_int per tap",
        )],
        in_baseline: true,
        acts_on: ActsOn::Noise,
        drivers: &[],
        cancels_in_four_phase: false,
    },
];

/// Look up an effect by id.
pub fn effect(id: &str) -> Option<&'static EffectInfo> {
    CATALOGUE.iter().find(|e| e.id == id)
}

/// The parameter's description (units, typical value, range); `None` for a
/// constant of no entry (none: ids::tests).
pub fn param_info(p: ParamId) -> Option<&'static ParamInfo> {
    if p.section() == SENSOR_SECTION {
        SENSOR_PARAMS.iter().find(|i| i.name == p.name())
    } else {
        effect(p.section())?.param(p.name())
    }
}

/// The parameter's typical value. Every [`ParamId`] names a registry parameter
/// (checked by the tests of [`crate::ids`]), so this never misses; were it to,
/// the value is NaN, as in [`crate::ModelConfig::get`].
pub fn typical(p: ParamId) -> f64 {
    param_info(p).map_or(f64::NAN, |i| i.typical)
}

/// The catalogue of effects.
pub fn catalogue() -> &'static [EffectInfo] {
    CATALOGUE
}

/// The candidate a misspelled name most likely meant ("did you mean"): the closest by
/// Jaro–Winkler similarity, if it is close enough (≥ 0.8; `vcsel_drop` → `vcsel_droop`).
pub fn closest<'a>(given: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    candidates
        .into_iter()
        .map(|c| (strsim::jaro_winkler(given, c), c))
        .filter(|(score, _)| *score >= 0.8)
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, c)| c)
}

#[cfg(test)]
mod closest_tests {
    use super::*;

    #[test]
    fn misspelled_effects_find_their_id_and_strangers_find_none() {
        let ids = || CATALOGUE.iter().map(|e| e.id);
        assert_eq!(
            closest("vcsel_drop", ids()),
            Some(ids::vcsel_droop::ID.as_str())
        );
        assert_eq!(closest("adcinl", ids()), Some(ids::adc_inl::ID.as_str()));
        assert_eq!(
            closest("quantisation", ids()),
            Some(ids::quantization::ID.as_str())
        );
        assert_eq!(closest("banana", ids()), None);
    }
}
