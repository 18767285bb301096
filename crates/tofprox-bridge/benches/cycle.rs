//! Speed of one driver cycle against the emulated device (virtual clock: no
//! sleeps), with frame synthesis measured separately.
//!
//! `cargo bench -p tofprox-bridge --bench cycle`
//!
//! Before divan's wall-clock table, `main` prints the **CPU time** per cycle
//! of this thread (from `/proc/thread-self/schedstat`, ns resolution), which
//! is the figure the 2 ms target is about.

use std::sync::Arc;
use std::time::Duration;

use tofprox_bridge::emulated::synth::{FrameSynth, IdealSynth, ModelSynth, RawParams};
use tofprox_bridge::emulated::{EmulatedConfig, FrameSource};
use tofprox_bridge::uvc::{FrameSpec, Push, Reassembler, split_frame};
use tofprox_bridge::{
    Algorithm, BridgeError, CycleRequest, DriverConfig, EmulatedDevice, RowWindow, SensorDriver,
    SensorGeometry, SensorMap, SensorMode, VirtualClock,
};
use tofprox_model::{ModelConfig, SceneScript};

fn geom() -> SensorGeometry {
    SensorGeometry::irs1645()
}

/// The two illuminated raw images of a 2-phase cycle at 300 µs.
fn raws_2phase() -> [RawParams; 2] {
    [0.0, 90.0].map(|p| RawParams {
        exposure_us: 300.0,
        phase_deg: p,
        illuminated: true,
    })
}

/// The tofprox-model frame source with the baseline model and the hand script.
fn model_synth() -> ModelSynth {
    ModelSynth::new(
        ModelConfig::baseline(),
        geom(),
        SceneScript::hand(),
        1,
        0.0,
        25.0,
    )
    .unwrap()
}

/// The partial read-out window measured next to the full frame.
const WINDOW_40_ROWS: RowWindow = RowWindow::rows_only(66, 40);

/// Pre-rendered frames: isolates the driver stack from synthesis.
struct Replay(Vec<Vec<u16>>);

impl FrameSynth for Replay {
    fn superframe(
        &mut self,
        _t_s: f64,
        raws: &[RawParams],
        (row0, rows): (usize, usize),
        _modulation_hz: f64,
        out: &mut Vec<Vec<u16>>,
    ) -> Result<(), BridgeError> {
        out.resize_with(raws.len(), Vec::new);
        for (k, o) in out.iter_mut().enumerate() {
            let src = &self.0[k % self.0.len()];
            o.clear();
            o.extend_from_slice(&src[row0 * 224..(row0 + rows) * 224]);
        }
        Ok(())
    }
}

fn replay_driver() -> SensorDriver<EmulatedDevice> {
    let mut frames = Vec::new();
    let raws = raws_2phase();
    IdealSynth::new(geom(), SceneScript::wall(1.0), 1)
        .superframe(0.0, &raws, (0, 172), 80e6, &mut frames)
        .unwrap();
    let clock = Arc::new(VirtualClock::new());
    let cfg = EmulatedConfig {
        frame_source: FrameSource::Ideal,
        ..EmulatedConfig::default()
    };
    let dev = EmulatedDevice::with_synth(
        cfg,
        SensorMap::emulated(),
        clock.clone(),
        1,
        Box::new(Replay(frames)),
    )
    .unwrap();
    let mut d = SensorDriver::new(dev, DriverConfig::emulated_default(), clock).unwrap();
    d.cycle(&req(None)).unwrap(); // first cycle writes the flash; measure steady state
    d
}

fn req(row_window: Option<RowWindow>) -> CycleRequest {
    CycleRequest {
        mode: SensorMode::Depth(Algorithm::TwoPhase),
        exposure_us: 300.0,
        row_window,
        modulation_hz: None,
        single_image: None,
    }
}

fn thread_cpu() -> Option<Duration> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = s.split_whitespace().next()?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

fn cpu_per_call(n: u32, mut f: impl FnMut()) -> Option<Duration> {
    let t0 = thread_cpu()?;
    for _ in 0..n {
        f();
    }
    Some((thread_cpu()? - t0) / n)
}

fn report_cpu() {
    let mut d = replay_driver();
    let full = cpu_per_call(300, || drop(d.cycle(&req(None)).unwrap()));
    let win = cpu_per_call(300, || drop(d.cycle(&req(Some(WINDOW_40_ROWS))).unwrap()));
    let raws = raws_2phase();
    let mut model = model_synth();
    let mut out = Vec::new();
    let mut t = 0.0;
    let synth = cpu_per_call(30, || {
        t += 0.25;
        model
            .superframe(t, &raws, (0, 172), 80e6, &mut out)
            .unwrap();
    });
    let mut ideal = IdealSynth::new(geom(), SceneScript::hand(), 1);
    let ideal_t = cpu_per_call(100, || {
        t += 0.25;
        ideal
            .superframe(t, &raws, (0, 172), 80e6, &mut out)
            .unwrap();
    });
    let show = |o: Option<Duration>| {
        o.map_or("n/a (no /proc/thread-self/schedstat)".to_string(), |d| {
            format!("{d:?}")
        })
    };
    println!("CPU time per call (this thread):");
    println!(
        "  driver stack + emulated transfers, 2-phase 172x224 cycle: {}",
        show(full)
    );
    println!(
        "  same, 40-row window:                                       {}",
        show(win)
    );
    println!(
        "  frame synthesis, tofprox-model baseline, 2 raw images:     {}",
        show(synth)
    );
    println!(
        "  frame synthesis, ideal source, 2 raw images:               {}",
        show(ideal_t)
    );
}

fn main() {
    report_cpu();
    divan::main();
}

#[divan::bench]
fn cycle_2phase_full_frame(bencher: divan::Bencher) {
    let mut d = replay_driver();
    bencher.bench_local(|| d.cycle(&req(None)).unwrap());
}

#[divan::bench]
fn cycle_2phase_40_rows(bencher: divan::Bencher) {
    let mut d = replay_driver();
    bencher.bench_local(|| d.cycle(&req(Some(WINDOW_40_ROWS))).unwrap());
}

#[divan::bench]
fn reassemble_one_full_frame(bencher: divan::Bencher) {
    let frame: Vec<u8> = (0..173 * 224 * 2).map(|i| (i % 251) as u8).collect();
    let sets = [
        split_frame(&frame, true, 0, 16384),
        split_frame(&frame, false, 0, 16384),
    ];
    let mut r = Reassembler::new(FrameSpec {
        frame_bytes: frame.len(),
        pad_align: 16,
    });
    let mut i = 0usize;
    bencher.bench_local(|| {
        i += 1;
        let mut n = 0;
        for p in &sets[i % 2] {
            if let Push::Frame(f) = r.push(p) {
                n = f.len();
            }
        }
        assert_eq!(n, frame.len());
        n
    });
}

#[divan::bench(sample_count = 20)]
fn synth_model_2phase(bencher: divan::Bencher) {
    let raws = raws_2phase();
    let mut model = model_synth();
    let mut out = Vec::new();
    bencher.bench_local(|| {
        model
            .superframe(2.0, &raws, (0, 172), 80e6, &mut out)
            .unwrap()
    });
}
