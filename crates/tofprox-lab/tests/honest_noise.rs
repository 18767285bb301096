//! Honest noise (issue 20, docs/lab.md "Noise"): repeats are found by the
//! physical conditions only — bookkeeping keys such as `repeat` or
//! `timestamp_s` (docs/recording-format.md) never split them —, and a
//! recording without signal (random codes, constant frames, every code on a
//! rail) is never `nothing_missing`; a sparse one without repeats is
//! `noise_not_measured`.
use std::path::Path;

use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tofprox_format::{RawFrames, Recording, RecordingWriter};

mod common;
use common::write_recording as write;
use tofprox_lab::adapter::{load_recording, spec_from_model};
use tofprox_lab::diagnose::{Verdict, compare, diagnose};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::noise::NoiseSource;
use tofprox_lab::synth::{Hidden, SynthSpec, generate};
use tofprox_lab::{Comparison, Diagnosis, LabError};
use tofprox_model::ModelConfig;

fn lab_spec() -> LabSpec {
    LabSpec {
        harmonic_order: 3,
        ..LabSpec::default()
    }
}

fn compared(dir: &Path, spec: &LabSpec) -> (Prepared, Comparison) {
    let ds = load_recording(dir).unwrap();
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, spec, &|_, _| {}).unwrap();
    (prep, cmp)
}

#[test]
fn bookkeeping_keys_never_split_repeats() {
    let ds = generate(&SynthSpec {
        seed: 31,
        hidden: vec![Hidden::Droop { eps: 0.006 }],
        ..SynthSpec::default()
    });
    let tmp = tempfile::tempdir().unwrap();
    let (plain, kept, physical) = (
        tmp.path().join("plain"),
        tmp.path().join("bookkeeping"),
        tmp.path().join("physical"),
    );
    write(&ds, &plain, |_, _| Vec::new());
    // what `tofprox sim sweep --repeats 2` writes, and more bookkeeping
    write(&ds, &kept, |i, rep| {
        vec![
            ("repeat", rep as f64),
            ("capture_index", i as f64),
            ("timestamp_s", 0.25 * i as f64),
        ]
    });
    // a physical condition that differs between the repeats: no repeats left
    write(&ds, &physical, |i, _| {
        vec![("supply_voltage_v", 3.3 + 1e-3 * i as f64)]
    });
    let (_, c_plain) = compared(&plain, &lab_spec());
    let (prep, c_kept) = compared(&kept, &lab_spec());
    let (_, c_phys) = compared(&physical, &lab_spec());
    // 2 exposures × 24 distances swept twice, and the darks per exposure
    let NoiseSource::Repeats { groups } = c_kept.model.noise.source else {
        panic!(
            "bookkeeping keys split the repeats: {:?}",
            c_kept.model.noise
        );
    };
    assert!(groups >= 48, "{groups} groups of repeats");
    assert_eq!(c_plain.model.noise.source, c_kept.model.noise.source);
    assert!(
        (c_plain.fit.chi2_per_dof - c_kept.fit.chi2_per_dof).abs() < 1e-9,
        "{} vs {}",
        c_plain.fit.chi2_per_dof,
        c_kept.fit.chi2_per_dof
    );
    assert!(prep.extra_keys.is_empty(), "{:?}", prep.extra_keys);
    assert_eq!(c_phys.model.noise.source, NoiseSource::NotMeasured);
    // with the noise measured the droop is not absorbed into it
    assert!(c_kept.fit.chi2_per_dof > 1.5, "{}", c_kept.fit.chi2_per_dof);
    let d = diagnose(&prep, &c_kept, &|_, _| {}).unwrap();
    assert_eq!(d.verdict, Verdict::MissingEffect, "{}", d.reason);
    assert_eq!(d.effect.as_deref(), Some("vcsel_droop"));
    reported_values_are_honest(&d);
}

/// No share above 100 % and no negative z after reaches a report.
fn reported_values_are_honest(d: &Diagnosis) {
    for c in &d.candidates {
        assert!(
            !(c.explained_excess > 1.0 || c.cv_gain > 1.0 || c.z_after < 0.0),
            "{}: explained {} cv {} z after {}",
            c.effect,
            c.explained_excess,
            c.cv_gain,
            c.z_after
        );
    }
}

/// A copy of `examples/recording` (each capture `copies` times) with its
/// frames replaced by `frames(capture, shape)`.
fn example_copy(
    dir: &Path,
    copies: usize,
    mut frames: impl FnMut((usize, usize, usize)) -> Array3<f64>,
) {
    let ex = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/recording");
    let rec = Recording::open(&ex).unwrap();
    let mut w = RecordingWriter::create(dir, *rec.sensor(), None).unwrap();
    for (i, meta) in rec.captures().iter().enumerate() {
        let shape = rec.load(i).unwrap().to_f64().dim();
        for _ in 0..copies {
            w.append(meta.spec(), &RawFrames::F64(frames(shape)))
                .unwrap();
        }
    }
    w.finish().unwrap();
}

fn diagnosed(dir: &Path) -> Result<Diagnosis, LabError> {
    let ds = load_recording(dir)?;
    let prep = Prepared::new(&ds)?;
    let cmp = compare(
        &prep,
        &spec_from_model(&ModelConfig::baseline()),
        &|_, _| {},
    )?;
    diagnose(&prep, &cmp, &|_, _| {})
}

/// Without signal: `unexplained` with the reason, never `nothing_missing`.
fn assert_no_signal(what: &str, d: Result<Diagnosis, LabError>) {
    let d = d.unwrap_or_else(|e| panic!("{what}: {e}"));
    eprintln!("{what}: {:?}: {}", d.verdict, d.reason);
    assert_eq!(d.verdict, Verdict::Unexplained, "{what}: {}", d.reason);
    assert!(d.reason.contains("no signal"), "{what}: {}", d.reason);
    // what the refusal rests on: the codes' variation the model follows
    assert!(
        d.reason.contains("variation over each capture"),
        "{what}: {}",
        d.reason
    );
    assert!(d.effect.is_none() && d.candidates.is_empty());
}

#[test]
fn random_and_constant_frames_are_never_nothing_missing() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(20);
    for copies in [1, 2] {
        // uniform random 12-bit codes, every repeat drawn anew
        let random = tmp.path().join(format!("random{copies}"));
        example_copy(&random, copies, |s| {
            Array3::from_shape_simple_fn(s, || f64::from(rng.random_range(0u16..4096)))
        });
        assert_no_signal(&format!("random codes ×{copies}"), diagnosed(&random));
        // every code the same
        let constant = tmp.path().join(format!("constant{copies}"));
        example_copy(&constant, copies, |s| Array3::from_elem(s, 1800.0));
        assert_no_signal(&format!("constant frames ×{copies}"), diagnosed(&constant));
    }
}

#[test]
fn without_measured_noise_a_noise_like_residual_is_not_nothing_missing() {
    // the control of the synthetic generator (nothing hidden), one capture per
    // condition: the residual looks like noise, but nothing measured the noise
    let ds = generate(&SynthSpec {
        seed: 11,
        repeats: 1,
        ..SynthSpec::default()
    });
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, &lab_spec(), &|_, _| {}).unwrap();
    assert_eq!(cmp.model.noise.source, NoiseSource::NotMeasured);
    let d = diagnose(&prep, &cmp, &|_, _| {}).unwrap();
    assert_eq!(d.verdict, Verdict::NoiseNotMeasured, "{}", d.reason);
    assert!(d.reason.contains("not measured"), "{}", d.reason);
    common::assert_evidence_quotes(&d);
    reported_values_are_honest(&d);
}

#[test]
fn repeated_raw_images_measure_the_noise() {
    // the control with each pair of repeats as one capture of 8 raw images
    // (0°, 90°, 180°, 270° twice): the noise comes from the repeated shifts
    let mut ds = generate(&SynthSpec {
        seed: 12,
        ..SynthSpec::default()
    });
    let mut merged = Vec::new();
    let mut caps = std::mem::take(&mut ds.captures).into_iter();
    while let Some(mut a) = caps.next() {
        if a.phases_deg.len() == 4 {
            let b = caps.next().unwrap();
            assert_eq!((a.distance_m, a.exposure_us), (b.distance_m, b.exposure_us));
            a.phases_deg.extend(b.phases_deg);
            a.frames = ndarray::concatenate(ndarray::Axis(0), &[a.frames.view(), b.frames.view()])
                .unwrap();
        }
        merged.push(a);
    }
    ds.captures = merged;
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, &lab_spec(), &|_, _| {}).unwrap();
    let NoiseSource::RawImages { captures } = cmp.model.noise.source else {
        panic!("{:?}", cmp.model.noise);
    };
    // 48 sweep captures, a few saturated everywhere at the near end
    assert!(captures >= 40, "{captures}");
    let d = diagnose(&prep, &cmp, &|_, _| {}).unwrap();
    assert_eq!(d.verdict, Verdict::NothingMissing, "{}", d.reason);
}

/// Every code on a rail of the ADC (each pixel at 0 or 4095, some of each):
/// nothing to fit, and the error says why — it names the rails and the share
/// of the codes at each — instead of "no valid samples to fit" alone.
#[test]
fn an_all_rail_recording_names_the_rails() {
    let tmp = tempfile::tempdir().unwrap();
    let rails = tmp.path().join("rails");
    let mut i = 0usize;
    example_copy(&rails, 1, |s| {
        Array3::from_shape_simple_fn(s, || {
            i += 1;
            if i.is_multiple_of(3) { 0.0 } else { 4095.0 }
        })
    });
    let err = diagnosed(&rails).expect_err("an all-rail recording is refused");
    let msg = err.to_string();
    eprintln!("{msg}");
    assert_eq!(err.kind(), tofprox_lab::ErrorKind::InvalidData);
    assert!(msg.contains("rail"), "{msg}");
    // the two rails of the 12-bit ADC, with the share of the codes at each
    let share = |after: &str| -> f64 {
        let tail = &msg[msg.find(after).unwrap_or_else(|| panic!("{after}: {msg}"))..];
        let pct = tail.find(" %").unwrap();
        let start = tail[..pct].rfind(' ').unwrap();
        tail[start + 1..pct].parse().unwrap()
    };
    assert!(msg.contains("4095 LSB") && msg.contains("(0 to"), "{msg}");
    let (low, high) = (share("illuminated captures"), share("LSB), "));
    assert!((low - 100.0 / 3.0).abs() < 1.0, "low rail {low} %: {msg}");
    assert!(
        (high - 200.0 / 3.0).abs() < 1.0,
        "high rail {high} %: {msg}"
    );
}

/// A sparse recording: 11 captures of 16×16 pixels — a dark, a correlation
/// capture and 9 distances at one exposure, no repeats (what `sim sweep
/// --distances 0.3:1.1:0.1 --exposures 500` writes) — of a sensor with
/// nothing hidden: nothing measured the noise, so the verdict is
/// `noise_not_measured`, not `unexplained` from a noise taken from the
/// residuals (whose χ² was n, not n − p: χ²/dof 1.05, z 4.4 on `sim sweep`'s
/// recording, from the per-pixel parameters alone).
#[test]
fn a_sparse_recording_without_repeats_is_noise_not_measured() {
    let ds = generate(&SynthSpec {
        rows: 16,
        cols: 16,
        seed: 13,
        repeats: 1,
        distances_m: (0..9).map(|i| 0.3 + 0.1 * f64::from(i)).collect(),
        exposures_us: vec![500.0],
        ..SynthSpec::default()
    });
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, &lab_spec(), &|_, _| {}).unwrap();
    assert_eq!(cmp.model.noise.source, NoiseSource::NotMeasured);
    let d = diagnose(&prep, &cmp, &|_, _| {}).unwrap();
    eprintln!(
        "{} captures: {:?}: {}",
        ds.captures.len(),
        d.verdict,
        d.reason
    );
    assert_eq!(d.verdict, Verdict::NoiseNotMeasured, "{}", d.reason);
    assert!(d.reason.contains("not measured"), "{}", d.reason);
    reported_values_are_honest(&d);
}
