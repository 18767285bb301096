//! The statistics engine on the lab's own synthetic truth (independent of
//! tofprox-model): each hidden effect is named, the control says nothing
//! missing, an out-of-catalogue effect is unexplained.
mod common;

use tofprox_lab::diagnose::{Verdict, add_effect, compare, diagnose};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::synth::{Hidden, SynthSpec, generate};

fn spec() -> LabSpec {
    LabSpec {
        harmonic_order: 3,
        ..LabSpec::default()
    }
}

fn run(s: SynthSpec) -> tofprox_lab::Diagnosis {
    let ds = generate(&s);
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, &spec(), &|_, _| {}).unwrap();
    let d = diagnose(&prep, &cmp, &|_, _| {}).unwrap();
    eprintln!(
        "{:?}: verdict {:?} {:?} z {:.1} chi2/dof {:.3} strongest {:?} ({})",
        s.hidden, d.verdict, d.effect, d.fit.z, d.fit.chi2_per_dof, d.strongest_condition, d.reason
    );
    for c in &d.candidates {
        eprintln!(
            "   {:24} expl {:6.3} cv {:6.3} z_after {:8.1} dBIC {:10.1} struct_after {:?}",
            c.effect, c.explained_excess, c.cv_gain, c.z_after, c.delta_bic, c.structure_after
        );
    }
    common::assert_evidence_quotes(&d);
    d
}

#[test]
fn control_says_nothing_missing() {
    let d = run(SynthSpec {
        seed: 11,
        ..SynthSpec::default()
    });
    assert_eq!(d.verdict, Verdict::NothingMissing);
}

#[test]
fn names_vcsel_droop() {
    let d = run(SynthSpec {
        seed: 12,
        hidden: vec![Hidden::Droop { eps: 0.006 }],
        ..SynthSpec::default()
    });
    assert_eq!(d.verdict, Verdict::MissingEffect);
    assert_eq!(d.effect.as_deref(), Some("vcsel_droop"));
}

#[test]
fn names_amplitude_phase_error() {
    let d = run(SynthSpec {
        seed: 13,
        hidden: vec![Hidden::AmpPhase { k: 0.02 }],
        ..SynthSpec::default()
    });
    assert_eq!(d.effect.as_deref(), Some("amplitude_phase_error"));
}

#[test]
fn names_temperature_drift() {
    let d = run(SynthSpec {
        seed: 14,
        temperatures_c: vec![15.0, 25.0, 45.0],
        distances_m: (0..12).map(|i| 0.2 + i as f64 * 0.13).collect(),
        hidden: vec![Hidden::TempDrift { k: 0.002 }],
        ..SynthSpec::default()
    });
    assert_eq!(d.effect.as_deref(), Some("temperature_drift"));
}

#[test]
fn names_extra_harmonic() {
    let d = run(SynthSpec {
        seed: 15,
        hidden: vec![Hidden::Harmonic {
            h: 5,
            re: 0.02,
            im: -0.01,
        }],
        ..SynthSpec::default()
    });
    assert_eq!(d.effect.as_deref(), Some("waveform_harmonics"));
}

#[test]
fn names_adc_inl() {
    let d = run(SynthSpec {
        seed: 16,
        hidden: vec![Hidden::Inl { s: -6.0 }],
        ..SynthSpec::default()
    });
    assert_eq!(d.effect.as_deref(), Some("adc_inl"));
}

#[test]
fn names_sbi_asymmetry() {
    let d = run(SynthSpec {
        seed: 17,
        ambients_klux: vec![0.0, 40.0, 80.0],
        distances_m: (0..12).map(|i| 0.2 + i as f64 * 0.13).collect(),
        hidden: vec![Hidden::Sbi { m: 0.8, q0: 30.0 }],
        ..SynthSpec::default()
    });
    assert_eq!(d.effect.as_deref(), Some("sbi_asymmetry"));
}

#[test]
fn out_of_catalogue_is_unexplained() {
    let d = run(SynthSpec {
        seed: 18,
        hidden: vec![Hidden::RowExposureOffset { lsb_per_ms: 3.0 }],
        ..SynthSpec::default()
    });
    assert_eq!(d.verdict, Verdict::Unexplained);
    assert_eq!(d.strongest_condition.as_deref(), Some("exposure_us"));
}

#[test]
fn add_makes_the_error_fall() {
    let s = SynthSpec {
        seed: 19,
        hidden: vec![Hidden::Droop { eps: 0.006 }],
        ..SynthSpec::default()
    };
    let ds = generate(&s);
    let prep = Prepared::new(&ds).unwrap();
    let out = add_effect(&prep, &spec(), "vcsel_droop", &|_, _| {}).unwrap();
    let ctl = generate(&SynthSpec {
        hidden: vec![],
        ..s
    });
    let cprep = Prepared::new(&ctl).unwrap();
    let c = compare(&cprep, &spec(), &|_, _| {}).unwrap();
    common::assert_add_reaches_control(&out, &c.rms);
}

#[test]
fn without_repeats_and_darks_the_lab_still_gives_a_verdict() {
    // no repeated captures (noise from residuals) and no dark captures
    // (offsets from the 4-phase means): a clear hidden effect is still named
    let mut ds = generate(&SynthSpec {
        seed: 20,
        repeats: 1,
        hidden: vec![Hidden::Harmonic {
            h: 5,
            re: 0.03,
            im: 0.0,
        }],
        ..SynthSpec::default()
    });
    ds.captures.retain(|c| c.illumination);
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, &spec(), &|_, _| {}).unwrap();
    assert!(!cmp.model.noise.source.measured());
    let d = diagnose(&prep, &cmp, &|_, _| {}).unwrap();
    assert_eq!(
        d.effect.as_deref(),
        Some("waveform_harmonics"),
        "{}",
        d.reason
    );
}

#[test]
fn a_recording_without_ground_truth_is_an_error_not_a_panic() {
    let mut ds = generate(&SynthSpec {
        seed: 21,
        ..SynthSpec::default()
    });
    for c in &mut ds.captures {
        c.distance_m = None;
    }
    assert!(Prepared::new(&ds).is_err());
    let mut ds = generate(&SynthSpec {
        seed: 22,
        ..SynthSpec::default()
    });
    ds.captures[3].frames[[0, 0, 0]] = f64::NAN;
    assert!(Prepared::new(&ds).is_err());
}
