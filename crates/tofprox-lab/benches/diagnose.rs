//! `compare` + `diagnose` on a 901-capture 16×16 recording (issue 11: ≤ 2 s on
//! 2 cores; figures, machine and load in the README's performance table).
use tofprox_lab::diagnose::{compare, diagnose};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::synth::{SynthSpec, generate};

fn main() {
    divan::main();
}

fn recording() -> Prepared {
    let ds = generate(&SynthSpec::diagnose_benchmark());
    assert!(ds.captures.len() >= 900);
    Prepared::new(&ds).expect("valid synthetic recording")
}

#[divan::bench(sample_count = 3, sample_size = 1)]
fn diagnose_900_captures(bencher: divan::Bencher) {
    let prep = recording();
    let spec = LabSpec {
        harmonic_order: 3,
        ..LabSpec::default()
    };
    bencher.bench_local(|| {
        let cmp = compare(&prep, &spec, &|_, _| {}).expect("compare");
        diagnose(&prep, &cmp, &|_, _| {}).expect("diagnose")
    });
}
