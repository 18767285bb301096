//! The sensor engineer's view of a comparison (issue 37, item 8): per capture, unpadded, the
//! model's predicted codes, the measured and predicted depth and a table of how well each
//! capture fits; how much of the depth error is systematic; and `add` with chosen parameters
//! held. Checked on the lab's own synthetic recordings (`tofprox_lab::synth`, whose physics is
//! written independently of the lab's), against formulations written here another way: the
//! depth by a single-bin DFT of the raw images (not eq. 2.2/2.3's atan2 of differences), the
//! residual as measured − predicted code (not the residual table's own subtraction), the
//! depth noise by the scatter of repeated captures (not the propagated noise model).
use std::f64::consts::TAU;
use std::path::Path;

use tofprox_lab::arrays::per_capture;
use tofprox_lab::depth_error::depth_split;
use tofprox_lab::hold::HoldRequest;
use tofprox_lab::synth::{Hidden, SynthSpec, generate};
use tofprox_lab::workflow::add_holding;
use tofprox_lab::{ErrorKind, LabSpec, Prepared, compare};
use tofprox_model::ModelConfig;

fn prepared(spec: &SynthSpec) -> Prepared {
    Prepared::new(&generate(spec)).unwrap()
}

/// The baseline model file without the dark current (the synthetic truth has none).
fn model_file() -> ModelConfig {
    let mut m = ModelConfig::baseline();
    m.set_enabled("dark_current", false).unwrap();
    m
}

/// Phase (rad, [0, 2π)) of raw images `u` at `phases_deg` by a single-bin DFT,
/// arg Σ u_k·e^{iθ_k} — for 0/90/180/270° the same angle as eq. 2.3, written another way.
fn dft_phase(u: &[f64], phases_deg: &[f64]) -> f64 {
    let (mut re, mut im) = (0.0, 0.0);
    for (v, p) in u.iter().zip(phases_deg) {
        let t = p.to_radians();
        re += v * t.cos();
        im += v * t.sin();
    }
    im.atan2(re).rem_euclid(TAU)
}

#[test]
fn per_capture_arrays_and_table_split_the_comparison() {
    let ds = generate(&SynthSpec {
        hidden: vec![Hidden::Droop { eps: 0.01 }],
        ..SynthSpec::default()
    });
    let prep = Prepared::new(&ds).unwrap();
    let cmp = compare(&prep, &LabSpec::default(), &|_, _| {}).unwrap();
    let (arrays, table) = per_capture(&prep, &cmp).unwrap();
    assert_eq!(
        (arrays.len(), table.len()),
        (ds.captures.len(), ds.captures.len())
    );
    // unpadded: each capture its own number of raw images (4 for the darks and the sweep,
    // 24 for the correlation capture)
    for (c, (a, cap)) in arrays.iter().zip(&ds.captures).enumerate() {
        assert_eq!(
            a.predicted_codes.dim(),
            (cap.phases_deg.len(), 8, 8),
            "capture {c}"
        );
        assert_eq!(a.measured_depth_mm.dim(), (8, 8));
        assert_eq!(table[c].raw_images, cap.phases_deg.len());
    }
    assert!(arrays.iter().any(|a| a.predicted_codes.dim().0 == 24));
    // measured − predicted code is the residual table's residual, sample by sample
    for s in &cmp.recs {
        let (c, k, p) = (s.cap as usize, usize::from(s.k), s.pix as usize);
        let meas = prep.meas[prep.idx(c, k, p)];
        let pred = f64::from(arrays[c].predicted_codes[[k, p / 8, p % 8]]);
        assert!(
            (meas - pred - f64::from(s.r)).abs() < 2e-3 * meas.abs().max(1.0),
            "capture {c} image {k} pixel {p}: {meas} − {pred} vs {}",
            s.r
        );
    }
    // the table adds up to the comparison's totals
    let share: f64 = table.iter().map(|r| r.chi2_share).sum();
    assert!((share - 1.0).abs() < 1e-9, "Σ χ² share {share}");
    let n: usize = table.iter().map(|r| r.samples).sum();
    assert_eq!(n, cmp.n);
    let ss: f64 = table
        .iter()
        .filter(|r| r.samples > 0)
        .map(|r| r.samples as f64 * r.rms_residual_lsb.powi(2))
        .sum();
    let raw = (ss / n as f64).sqrt();
    assert!(
        (raw - cmp.rms.raw_lsb).abs() < 1e-9 * cmp.rms.raw_lsb,
        "{raw} vs {:?}",
        cmp.rms
    );
    let chi2: f64 = table.iter().map(|r| r.chi2).sum();
    assert!((chi2 - cmp.chi2).abs() < 1e-6 * cmp.chi2);
    // the depth: darks have none; the sweep's by the DFT of the measured codes less the
    // fitted offset, and its rms against the predicted depth recomputed here
    let mm_per_rad = prep.mm_per_rad();
    let range_mm = mm_per_rad * TAU;
    let mut checked = 0;
    for (c, (row, a)) in table.iter().zip(&arrays).enumerate() {
        let cap = &ds.captures[c];
        assert_eq!(row.exposure_us, cap.exposure_us);
        if !cap.illumination {
            assert_eq!(row.algorithm, None);
            assert!(a.measured_depth_mm.iter().all(|v| v.is_nan()));
            assert!(row.depth_rms_mm.is_nan());
            continue;
        }
        assert_eq!(row.algorithm, Some(tofprox_core::Algorithm::FourPhase));
        assert_eq!(row.conditions.get("distance_m"), cap.distance_m.as_ref());
        if cap.phases_deg.len() != 4 {
            continue;
        }
        let (mut s, mut m) = (0.0, 0usize);
        for p in 0..64 {
            let o = prep.mid + cmp.model.offset[p];
            let u: Vec<f64> = (0..4).map(|k| prep.meas[prep.idx(c, k, p)] - o).collect();
            let want = dft_phase(&u, &cap.phases_deg) * mm_per_rad;
            let got = f64::from(a.measured_depth_mm[[p / 8, p % 8]]);
            if got.is_nan() {
                continue;
            }
            // either side of the wrap is the same depth
            let d = (got - want).abs();
            assert!(
                d.min(range_mm - d) < 0.05,
                "capture {c} pixel {p}: {got} vs {want} mm"
            );
            let e = f64::from(a.predicted_depth_mm[[p / 8, p % 8]]) - got;
            let e = e - range_mm * (e / range_mm).round();
            s += e * e;
            m += 1;
        }
        if m == 0 {
            continue; // every pixel saturated (the nearest distances)
        }
        checked += 1;
        let rms = (s / m as f64).sqrt();
        assert!(
            (rms - row.depth_rms_mm).abs() < 1e-3 * rms.max(0.1),
            "capture {c}: {rms} vs {}",
            row.depth_rms_mm
        );
    }
    assert!(checked > 50, "{checked} captures with depth");
}

#[test]
fn the_noise_floor_is_the_scatter_of_repeats_and_a_missing_effect_is_systematic() {
    // a correct model (no hidden effect, a sinusoidal truth): the depth error is noise
    let clean = SynthSpec {
        harmonics: Vec::new(),
        ..SynthSpec::default()
    };
    let prep = prepared(&clean);
    let cmp = compare(&prep, &LabSpec::default(), &|_, _| {}).unwrap();
    let split = depth_split(&prep, &cmp);
    // the scatter of repeats, written here: half the mean squared difference of the
    // two repeats' depth errors per pixel (capture order: repeats follow one another)
    let (arrays, table) = per_capture(&prep, &cmp).unwrap();
    let (mut s, mut n) = (0.0, 0usize);
    let range_mm = prep.mm_per_rad() * TAU;
    let mut c = 1;
    while c < table.len() {
        let (a, b) = (&table[c - 1], &table[c]);
        let repeat = a.raw_images == 4
            && a.algorithm.is_some()
            && a.conditions == b.conditions
            && a.exposure_us == b.exposure_us;
        if !repeat {
            c += 1;
            continue;
        }
        for (x, y) in arrays[c - 1]
            .measured_depth_mm
            .iter()
            .zip(&arrays[c].measured_depth_mm)
        {
            if x.is_finite() && y.is_finite() {
                let d = f64::from(x - y);
                let d = d - range_mm * (d / range_mm).round();
                s += 0.5 * d * d;
                n += 1;
            }
        }
        c += 2;
    }
    assert!(n > 1000, "{n} pixel pairs");
    let scatter_mm = (s / n as f64).sqrt();
    let f = split.four_phase;
    eprintln!("clean: {split:?}; repeats' scatter {scatter_mm:.3} mm (4-phase)");
    assert!(
        (f.noise_mm / scatter_mm - 1.0).abs() < 0.1,
        "{f:?} vs {scatter_mm}"
    );
    assert!(f.systematic_share < 0.2, "{f:?}");
    // a droop the model lacks: most of the depth error is systematic, less after adding it
    let droopy = prepared(&SynthSpec {
        harmonics: Vec::new(),
        hidden: vec![Hidden::Droop { eps: 0.03 }],
        ..SynthSpec::default()
    });
    let mut m = model_file();
    m.set_param("waveform_harmonics", "h3_rel", 0.0).unwrap();
    let (res, _, held) = add_holding(
        &droopy,
        &mut m,
        "vcsel_droop",
        Path::new("rec"),
        &[],
        &|_, _| {},
    )
    .unwrap();
    assert!(held.is_empty());
    let (before, after) = (
        depth_split(&droopy, &res.before),
        depth_split(&droopy, &res.after),
    );
    eprintln!("droop: before {before:?}\n       after {after:?}");
    assert!(before.two_phase.systematic_share > 0.5, "{before:?}");
    assert!(after.two_phase.systematic_mm < 0.5 * before.two_phase.systematic_mm);
    // the noise floor is the sensor's, not the model's: about the same before and after
    assert!((after.two_phase.noise_mm / before.two_phase.noise_mm - 1.0).abs() < 0.1);
}

#[test]
fn a_held_parameter_keeps_its_value_while_the_others_are_fitted() {
    // a droop linear in the raw image (A_k = A·(1 − ε·k)): the law's time constant and loss
    // trade against each other, so τ can be held anywhere in the linear regime and the
    // rate D/τ is fitted
    let prep = prepared(&SynthSpec {
        hidden: vec![Hidden::Droop { eps: 0.01 }],
        ..SynthSpec::default()
    });
    let file = model_file();
    let mut m = file.clone();
    let hold = [HoldRequest::parse("tau_us=20000").unwrap()];
    let (res, _, held) = add_holding(
        &prep,
        &mut m,
        "vcsel_droop",
        Path::new("rec"),
        &hold,
        &|_, _| {},
    )
    .unwrap();
    eprintln!(
        "params {:?} ± {:?}; held {held:?}",
        res.params, res.standard_errors
    );
    assert_eq!(held.get("tau_us"), Some(&20000.0));
    let tau = m.param("vcsel_droop", "tau_us").unwrap();
    assert!((tau - 20000.0).abs() < 1e-6, "tau_us written {tau}");
    assert!((res.params["ln_tau"] - 20f64.ln()).abs() < 1e-12);
    assert!(
        res.standard_errors["ln_tau"].is_nan(),
        "a held parameter has no error"
    );
    // the others moved from the file's values, and fit the droop down to about the noise
    let d = m.param("vcsel_droop", "droop_rel").unwrap();
    assert_ne!(d, file.param("vcsel_droop", "droop_rel").unwrap());
    assert!(d > 0.0 && res.standard_errors["droop_rate"].is_finite());
    eprintln!(
        "χ²/dof {:.3} → {:.3}",
        res.before.fit.chi2_per_dof, res.after.fit.chi2_per_dof
    );
    assert!(res.after.fit.chi2_per_dof < 0.5 * res.before.fit.chi2_per_dof);
    assert!(res.after.fit.chi2_per_dof < 1.1, "{:?}", res.after.fit);
    // held at the file's value when no value is given
    let mut m2 = file.clone();
    let (_, _, held) = add_holding(
        &prep,
        &mut m2,
        "vcsel_droop",
        Path::new("rec"),
        &[HoldRequest::parse("exposure_power").unwrap()],
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(held.get("exposure_power"), Some(&1.0));
    assert_eq!(m2.param("vcsel_droop", "exposure_power"), Some(1.0));
}

#[test]
fn holds_the_lab_cannot_keep_are_refused_with_what_to_do() {
    let prep = prepared(&SynthSpec {
        distances_m: vec![0.3, 0.6, 0.9],
        ..SynthSpec::default()
    });
    let refused = |effect: &str, hold: &str| {
        let mut m = model_file();
        let h = [HoldRequest::parse(hold).unwrap()];
        let e = add_holding(&prep, &mut m, effect, Path::new("rec"), &h, &|_, _| {})
            .err()
            .expect("refused");
        assert_eq!(e.kind(), ErrorKind::InvalidModel, "{e}");
        e.to_string()
    };
    // D = rate·τ: holding the loss alone would hold τ too
    let e = refused("vcsel_droop", "droop_rel=0.02");
    assert!(
        e.contains("holds tau_us too") && e.contains("hold them together"),
        "{e}"
    );
    let e = refused("vcsel_droop", "tau_usec=100");
    assert!(e.contains("did you mean `tau_us`"), "{e}");
    let e = refused("waveform_harmonics", "h3_rel");
    assert!(e.contains("signature"), "{e}");
    assert!(HoldRequest::parse("tau_us=fast").is_err());
}
