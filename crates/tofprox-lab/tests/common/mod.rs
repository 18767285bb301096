//! Checks shared by the lab's integration tests.
#![allow(dead_code)] // each test binary uses a subset of the helpers
use tofprox_lab::Diagnosis;
use tofprox_lab::diagnose::{AddOutcome, Rms, Verdict};

/// The lab's promise (docs/lab.md): after `add`, the depth error falls to within 1.3× of the same
/// recording without the hidden effect (`control`), and the fit improves.
#[track_caller]
pub fn assert_add_reaches_control(out: &AddOutcome, control: &Rms) {
    eprintln!(
        "   before {:?}\n   after  {:?}\n   control {:?}",
        out.before.rms, out.after.rms, control
    );
    assert!(out.after.rms.depth_2phase_mm <= 1.3 * control.depth_2phase_mm);
    assert!(out.after.rms.depth_4phase_mm <= 1.3 * control.depth_4phase_mm);
    assert!(out.after.fit.chi2_per_dof < out.before.fit.chi2_per_dof);
}

/// Write `ds` as a recording; `extra(i, repeat)` adds keys to capture i's conditions.
pub fn write_recording(
    ds: &tofprox_lab::Dataset,
    dir: &std::path::Path,
    extra: impl Fn(usize, usize) -> Vec<(&'static str, f64)>,
) {
    let mut w = tofprox_format::RecordingWriter::create(dir, ds.sensor, None).unwrap();
    let mut repeat = 0;
    for (i, c) in ds.captures.iter().enumerate() {
        let mut conditions = std::collections::BTreeMap::new();
        if let Some(d) = c.distance_m {
            conditions.insert("distance_m".to_string(), d);
        }
        conditions.insert("ambient_klux".to_string(), c.ambient_klux);
        conditions.insert("temperature_c".to_string(), c.temperature_c.unwrap_or(25.0));
        // repeats follow one another
        let same = i > 0 && {
            let p = &ds.captures[i - 1];
            p.distance_m == c.distance_m
                && p.exposure_us == c.exposure_us
                && p.illumination == c.illumination
        };
        repeat = if same { repeat + 1 } else { 0 };
        for (k, v) in extra(i, repeat) {
            conditions.insert(k.to_string(), v);
        }
        let spec = tofprox_format::CaptureSpec {
            phases_deg: c.phases_deg.clone(),
            exposure_us: c.exposure_us,
            illumination: c.illumination,
            averaged: c.averaged,
            timestamp_ns: None,
            conditions,
        };
        w.append(spec, &tofprox_format::RawFrames::F64(c.frames.clone()))
            .unwrap();
    }
    w.finish().unwrap();
}

/// The diagnosis' one sentence of evidence (`Diagnosis::evidence`, docs/lab-json.md) quotes its
/// own numbers for its verdict: the condition the residual follows and its structure z, the
/// best candidate's share of the excess (or size) and its z after, χ²/dof, the remaining size
/// against the tolerance, and where the noise came from.
#[track_caller]
pub fn assert_evidence_quotes(d: &Diagnosis) {
    let ev = d.evidence();
    eprintln!("   evidence: {ev}");
    let mut want = vec![format!("the noise is {}", d.noise.describe())];
    let follows = |st: &tofprox_lab::structure::ConditionScore| {
        format!(
            "The residual follows {} (structure z = {:.1}",
            st.condition, st.z
        )
    };
    let share = |c: &tofprox_lab::diagnose::CandidateScore| {
        if c.explained_excess.is_finite() {
            format!("explains {:.0} % of the excess", 100.0 * c.explained_excess)
        } else {
            format!("removes {:.2} mm", c.explained.mm)
        }
    };
    match d.verdict {
        Verdict::MissingEffect => {
            want.push(follows(&d.structure_remaining[0]));
            let c = &d.candidates[0];
            want.push(format!("{} {}", c.effect, share(c)));
            want.push(format!("leaving z = {:.1}", d.candidates[0].z_after));
        }
        Verdict::Unexplained => {
            want.push(follows(&d.structure_remaining[0]));
            let c = &d.candidates[0];
            want.push(format!(
                "no catalogue effect accounts for it: the best of {}, {}, {}",
                d.candidates.len(),
                c.effect,
                share(c)
            ));
        }
        Verdict::NothingMissing | Verdict::NoiseNotMeasured => {
            want.push(format!("{:.2} mm depth-equivalent", d.size.mm));
            want.push(format!("{:.2} mm", d.tolerance_mm));
            let st = &d.structure_remaining[0];
            want.push(format!(
                "strongest structure z = {:.1} against {}",
                st.z, st.condition
            ));
        }
        Verdict::Ambiguous => {
            want.push(format!("vary {}", d.separate_by.as_deref().unwrap()));
        }
    }
    for w in want {
        assert!(ev.contains(&w), "evidence {ev:?} lacks {w:?}");
    }
}

/// The model file `explain` writes (`--out`): `base` with every added effect as
/// fitted in the final model; and the spec that holds it at its values
/// (`compare --hold-effects`), with the notes of holding it.
pub fn written_and_held(
    ex: &tofprox_lab::diagnose::Explanation,
    prep: &tofprox_lab::fit::Prepared,
    base: &tofprox_model::ModelConfig,
) -> (tofprox_lab::fit::LabSpec, Vec<String>) {
    let fin = ex.final_model().unwrap();
    let mut m = base.clone();
    for e in &ex.added {
        let (_, params) = tofprox_lab::diagnose::effect_params(prep, fin, e).unwrap();
        let notes = tofprox_lab::signatures::write_effect(&mut m, e, &params, fin, prep).unwrap();
        eprintln!("wrote {e}: {notes:?}");
    }
    let text =
        tofprox_lab::model_file::update_model_text(&base.to_toml_string(), &m, &ex.added).unwrap();
    let written = tofprox_model::ModelConfig::from_toml_str(&text).unwrap();
    tofprox_lab::adapter::spec_holding_model(&written, prep)
}
