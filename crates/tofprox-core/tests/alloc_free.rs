//! The steady state of `Pipeline::process` (and `NearFarDetector::update`) is allocation-free:
//! a counting global allocator sees zero allocations across repeated calls after the first.

use ndarray::{Array1, Array2, Array3, ShapeBuilder};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use tofprox_core::Algorithm;
use tofprox_core::calib::{FppnMap, OffsetCalibration, WigglingLut};
use tofprox_core::pipeline::{Calibration, Pipeline, PipelineConfig};
use tofprox_core::proximity::{NearFarConfig, NearFarDetector};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

#[allow(unsafe_code)] // a counting allocator is the one way to observe allocations
// SAFETY: forwards to the system allocator; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.load(Ordering::SeqCst)
}

#[test]
fn process_is_allocation_free_after_the_first_call() {
    let (rows, cols) = (172, 224);
    for algorithm in Algorithm::ALL {
        let calibration = Calibration {
            crosstalk: None,
            offset: Some(OffsetCalibration {
                dark_lsb: Array2::from_elem((rows, cols), 2040.0),
            }),
            wiggling: Some(WigglingLut {
                algorithm,
                correction_rad: Array1::from_shape_fn(360, |i| 0.3 + 0.02 * (i as f32 * 0.1).sin()),
            }),
            fppn: Some(FppnMap {
                phase_offset_rad: Array2::from_elem((rows, cols), 0.01),
            }),
        };
        let config = PipelineConfig {
            algorithm,
            ..PipelineConfig::default()
        };
        let mut pipeline = Pipeline::new(rows, cols, config, calibration).unwrap();
        let mut detector = NearFarDetector::new(NearFarConfig::default()).unwrap();
        let raw_u16 = Array3::from_shape_fn((4, rows, cols), |(k, r, c)| {
            (2048 + 300 * ((k + r + c) % 3)) as u16
        });
        let raw_f64 = raw_u16.mapv(|v| v as f64);
        let mut raw_fortran = Array3::<f32>::zeros((4, rows, cols).f());
        raw_fortran.assign(&raw_u16.mapv(|v| v as f32));

        // First calls (may size internal scratch buffers).
        pipeline.process(raw_u16.view()).unwrap();
        let frame = pipeline.process(raw_u16.view()).unwrap();
        detector.update(frame);

        let before = allocations();
        for _ in 0..20 {
            let frame = pipeline.process(raw_u16.view()).unwrap();
            detector.update(frame);
            pipeline.process(raw_f64.view()).unwrap();
            pipeline.process(raw_fortran.view()).unwrap(); // staging path
        }
        let after = allocations();
        assert_eq!(
            after - before,
            0,
            "{algorithm}: {} allocations in the steady state",
            after - before
        );
        // The work was real: the frame has valid depth.
        assert!(pipeline.frame().valid_fraction() > 0.5);
    }
}
