//! Speed of the forward model.
//!
//! `cargo bench -p tofprox-model --bench capture`

use rand::SeedableRng;
use rand::rngs::SmallRng;
use tofprox_model::{CaptureRequest, ModelConfig, Scene, SensorGeometry, Simulator};

fn main() {
    divan::main();
}

/// One full-array (224×172) 4-phase capture, every effect enabled, averaged = 1.
#[divan::bench]
fn full_array_4phase_all_effects(bencher: divan::Bencher) {
    let sim =
        Simulator::new(&ModelConfig::full(), SensorGeometry::irs1645(), 7).expect("simulator");
    let mut req = CaptureRequest::four_phase(1000.0);
    req.ambient_klux = 10.0;
    req.temperature_c = 35.0;
    let scene = Scene::wall(0.6, 0.8);
    let mut rng = SmallRng::seed_from_u64(1);
    bencher.bench_local(|| sim.capture(&scene, &req, &mut rng).expect("capture"));
}

/// The noise-free mean of the same capture (what the lab evaluates in its fits).
#[divan::bench]
fn full_array_4phase_expected(bencher: divan::Bencher) {
    let sim =
        Simulator::new(&ModelConfig::full(), SensorGeometry::irs1645(), 7).expect("simulator");
    let req = CaptureRequest::four_phase(1000.0);
    let scene = Scene::wall(0.6, 0.8);
    bencher.bench_local(|| sim.expected(&scene, &req).expect("expected"));
}

/// Building a sensor (drawing every fixed pattern and the DNL table).
#[divan::bench]
fn simulator_new_full_array() -> Simulator {
    Simulator::new(&ModelConfig::full(), SensorGeometry::irs1645(), 7).expect("simulator")
}

/// A sweep of 32 full-array 4-phase captures over rayon pools of 1 and 2 threads
/// (scaling with cores; one seed per capture index keeps it deterministic).
#[divan::bench(args = [1, 2], sample_count = 10)]
fn sweep_32_captures(bencher: divan::Bencher, threads: usize) {
    use rayon::prelude::*;
    let sim =
        Simulator::new(&ModelConfig::full(), SensorGeometry::irs1645(), 7).expect("simulator");
    let req = CaptureRequest::four_phase(1000.0);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    bencher.bench_local(|| {
        pool.install(|| {
            (0..32u64)
                .into_par_iter()
                .map(|i| {
                    let mut rng = SmallRng::seed_from_u64(i);
                    let scene = Scene::wall(0.2 + 0.05 * i as f64, 0.8);
                    sim.capture(&scene, &req, &mut rng).expect("capture").sum()
                })
                .sum::<f64>()
        })
    });
}
