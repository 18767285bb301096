//! Stage timings of compare + diagnose on the benchmark's recording
//! (`cargo run --release -p tofprox-lab --example profile_diagnose`), or on a
//! full-array sweep (`… --example profile_diagnose -- full`: 224×172 pixels,
//! 101 captures; peak memory with `/usr/bin/time -v`), or on a recording
//! directory with a model file as `tofprox lab diagnose` reads them
//! (`… --example profile_diagnose -- REC MODEL`).
use std::path::Path;
use std::time::Instant;

use tofprox_lab::diagnose::{compare, diagnose};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::synth::{SynthSpec, generate};

/// The recording and the lab spec: the benchmark's (or the full-array
/// sweep's) synthetic one, or a recording directory and a model file.
fn input(args: &[String]) -> Result<(Prepared, LabSpec), tofprox_lab::LabError> {
    if let [rec, model] = args {
        let (prep, m) = tofprox_lab::workflow::load(Path::new(rec), Path::new(model))?;
        return Ok((prep, tofprox_lab::adapter::spec_from_model(&m)));
    }
    let spec = if args.first().is_some_and(|a| a == "full") {
        SynthSpec::full_array_sweep()
    } else {
        SynthSpec::diagnose_benchmark()
    };
    let lab = LabSpec {
        harmonic_order: 3,
        ..LabSpec::default()
    };
    Ok((Prepared::new(&generate(&spec))?, lab))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let t0 = Instant::now();
    let (prep, lab) = match input(&args) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e}");
            return;
        }
    };
    eprintln!(
        "{:>8.2} s  recording ready ({} captures, {} samples)",
        t0.elapsed().as_secs_f64(),
        prep.caps.len(),
        prep.meas.len()
    );
    let t0 = Instant::now();
    let cb =
        |stage: &str, f: f64| eprintln!("{:>8.2} s  {stage} {f:.2}", t0.elapsed().as_secs_f64());
    let cmp = match compare(&prep, &lab, &cb) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            return;
        }
    };
    eprintln!("{:>8.2} s  compare done", t0.elapsed().as_secs_f64());
    match diagnose(&prep, &cmp, &cb) {
        Ok(d) => {
            eprintln!(
                "{:>8.2} s  diagnose done: {:?} {:?}",
                t0.elapsed().as_secs_f64(),
                d.verdict,
                d.effect
            );
            let refitted: Vec<&str> = d
                .candidates
                .iter()
                .filter(|c| c.rms_after.is_some())
                .map(|c| c.effect.as_str())
                .collect();
            eprintln!("refitted with the whole model: {refitted:?}");
            eprint!("{}", tofprox_lab::report::diagnosis_text(&d));
        }
        Err(e) => eprintln!("error: {e}"),
    }
}
