//! Stage timings of compare + diagnose on the benchmark's recording
//! (`cargo run --release -p tofprox-lab --example profile_diagnose`).
use std::time::Instant;

use tofprox_lab::diagnose::{compare, diagnose};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::synth::{SynthSpec, generate};

fn main() {
    let ds = generate(&SynthSpec::diagnose_benchmark());
    let prep = match Prepared::new(&ds) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e}");
            return;
        }
    };
    let lab = LabSpec {
        harmonic_order: 3,
        ..LabSpec::default()
    };
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
    eprintln!(
        "{:>8.2} s  compare done ({} captures)",
        t0.elapsed().as_secs_f64(),
        ds.captures.len()
    );
    match diagnose(&prep, &cmp, &cb) {
        Ok(d) => eprintln!(
            "{:>8.2} s  diagnose done: {:?} {:?}",
            t0.elapsed().as_secs_f64(),
            d.verdict,
            d.effect
        ),
        Err(e) => eprintln!("error: {e}"),
    }
}
