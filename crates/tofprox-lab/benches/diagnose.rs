//! `diagnose` on a 900-capture 16×16 recording (issue: ≤ 5 s on 2 cores).
use tofprox_lab::diagnose::{compare, diagnose};
use tofprox_lab::fit::{LabSpec, Prepared};
use tofprox_lab::synth::{Hidden, SynthSpec, generate};

fn main() {
    divan::main();
}

fn recording() -> Prepared {
    // 2 darks per exposure, 1 correlation capture, 3 exposures × 149 distances
    // × 2 repeats = 894 sweep captures → 901 captures.
    let spec = SynthSpec {
        rows: 16,
        cols: 16,
        distances_m: (0..149).map(|i| 0.15 + i as f64 * (1.65 / 148.0)).collect(),
        exposures_us: vec![250.0, 500.0, 1000.0],
        hidden: vec![Hidden::Droop { eps: 0.01 }],
        ..SynthSpec::default()
    };
    let ds = generate(&spec);
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
