//! The noise sources: no law on the expected codes, only variances the simulator
//! sums per sample (2.3.2), so the three share one module:
//!
//! - `shot_noise`: Photon shot noise (thesis 2.3.2.2 eq. 2.16, 2.3.2.6)
//! - `read_noise`: Read-out noise (thesis 2.3.2.4, 2.3.2.6)
//! - `ktc_noise`: Reset (kTC) noise (thesis 2.3.2.1 eq. 2.14-2.15)

use crate::entry::{ActsOn, EffectInfo, param as p};

/// The typed ids of `ktc_noise`.
pub mod ktc_noise {
    crate::ids::effect_ids!(ktc_noise {
        C_INT_FF = "c_int_ff",
    });
}

/// The typed ids of `read_noise`.
pub mod read_noise {
    crate::ids::effect_ids!(read_noise {
        SIGMA_LSB = "sigma_lsb",
    });
}

/// The typed ids of `shot_noise`.
pub mod shot_noise {
    crate::ids::effect_ids!(shot_noise {
        EXCESS_NOISE_FACTOR = "excess_noise_factor",
    });
}

/// The catalogue entry of `shot_noise`.
pub static SHOT_NOISE: EffectInfo = EffectInfo {
    id: shot_noise::ID.as_str(),
    title: "Photon shot noise",
    explanation: "Photo-electrons arrive Poisson-distributed: σ² = N per tap (eq. 2.16) including the background-light electrons; the taps are independent so the differential variance is N_A + N_B (times an excess noise factor F). Scaled by 1/averaged for averaged captures. Together with read noise this gives the photon transfer curve var = g² F (N_A + N_B) + σ_read² (2.3.2.6).",
    thesis_ref: "2.3.2.2 eq. 2.16, 2.3.2.6",
    signature: "variance linear in the collected electrons (photon transfer curve)",
    params: &[p(
        shot_noise::EXCESS_NOISE_FACTOR,
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
};

effect!(ShotNoise, SHOT_NOISE, shot_noise::ID, chain = 220);

/// The catalogue entry of `read_noise`.
pub static READ_NOISE: EffectInfo = EffectInfo {
    id: read_noise::ID.as_str(),
    title: "Read-out noise",
    explanation: "Thermal noise of source follower, column amplifier and ADC (eq. 2.18) referred to the output: Gaussian σ_read in LSB, independent of light; the floor of the photon transfer curve.",
    thesis_ref: "2.3.2.4, 2.3.2.6",
    signature: "constant noise floor in dark frames",
    params: &[p(
        read_noise::SIGMA_LSB,
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
};

effect!(ReadNoise, READ_NOISE, read_noise::ID, chain = 230);

/// The catalogue entry of `ktc_noise`.
pub static KTC_NOISE: EffectInfo = EffectInfo {
    id: ktc_noise::ID.as_str(),
    title: "Reset (kTC) noise",
    explanation: "Resetting the integration capacitance leaves an uncertain charge σ = √(k T C_int)/e per tap (eq. 2.14-2.15), T the capture's temperature; both taps independent.",
    thesis_ref: "2.3.2.1 eq. 2.14-2.15",
    signature: "constant noise floor growing slowly with temperature",
    params: &[p(
        ktc_noise::C_INT_FF,
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
};

effect!(KtcNoise, KTC_NOISE, ktc_noise::ID, chain = 240);
