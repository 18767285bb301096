//! Near/far state machine: thresholds, hysteresis, far debounce, saturation → near, nothing → far.

use ndarray::ShapeBuilder;
use tofprox_core::pipeline::{DepthFrame, FLAG_INVALID, FLAG_LOW_AMPLITUDE, FLAG_SATURATED};
use tofprox_core::proximity::{NearFarConfig, NearFarDetector, Roi};

const ROWS: usize = 8;
const COLS: usize = 8;

/// Every pixel valid at `mm`.
fn wall(mm: u16) -> DepthFrame {
    let mut f = DepthFrame::zeros(ROWS, COLS);
    f.depth_mm.fill(mm);
    f.depth_m.fill(mm as f32 / 1000.0);
    f
}

/// Every pixel invalid with `flags`.
fn invalid(flags: u8) -> DepthFrame {
    let mut f = DepthFrame::zeros(ROWS, COLS);
    f.flags.fill(flags | FLAG_INVALID);
    f
}

fn detector(debounce: u32) -> NearFarDetector {
    NearFarDetector::new(NearFarConfig {
        near_mm: 200,
        far_mm: 300,
        roi: Roi::default(),
        far_debounce: debounce,
        min_valid_fraction: 0.2,
    })
    .unwrap()
}

#[test]
fn thresholds_and_changed_only_on_transitions() {
    let mut d = detector(1);
    let r = d.update(&wall(1000));
    assert!(!r.near && !r.changed);
    assert_eq!(r.distance_mm, Some(1000));
    assert_eq!(r.valid_fraction, 1.0);
    let r = d.update(&wall(200)); // at near_mm: near
    assert!(r.near && r.changed);
    let r = d.update(&wall(150));
    assert!(r.near && !r.changed);
    let r = d.update(&wall(300)); // at far_mm: far (debounce 1)
    assert!(!r.near && r.changed);
}

#[test]
fn hysteresis_between_thresholds_keeps_state() {
    let mut d = detector(1);
    assert!(
        !d.update(&wall(250)).near,
        "between thresholds from far stays far"
    );
    assert!(d.update(&wall(199)).near);
    let r = d.update(&wall(250));
    assert!(
        r.near && !r.changed,
        "between thresholds from near stays near"
    );
    let r = d.update(&wall(299));
    assert!(r.near);
    assert!(!d.update(&wall(301)).near);
}

#[test]
fn debounce_only_towards_far() {
    let mut d = detector(3);
    assert!(d.update(&wall(100)).near, "far → near is immediate");
    assert!(d.update(&wall(800)).near);
    assert!(d.update(&wall(800)).near);
    // An in-between reading resets the count.
    assert!(d.update(&wall(250)).near);
    assert!(d.update(&wall(800)).near);
    assert!(d.update(&wall(800)).near);
    let r = d.update(&wall(800));
    assert!(
        !r.near && r.changed,
        "third consecutive far reading switches"
    );
    // A single near reading in between also resets.
    let mut d = detector(2);
    d.update(&wall(100));
    d.update(&wall(800));
    assert!(d.update(&wall(100)).near);
    assert!(d.update(&wall(800)).near);
    assert!(!d.update(&wall(800)).near);
}

#[test]
fn saturation_counts_as_near_and_nothing_counts_as_far() {
    let mut d = detector(1);
    let r = d.update(&invalid(FLAG_SATURATED));
    assert!(
        r.near && r.changed,
        "fully saturated ROI: something is too close"
    );
    assert_eq!(r.distance_mm, None);
    assert_eq!(r.valid_fraction, 0.0);
    let r = d.update(&invalid(FLAG_LOW_AMPLITUDE));
    assert!(!r.near && r.changed, "no valid target counts as far");
    assert_eq!(r.distance_mm, None);
    // Partly saturated (≥ 25 %) with the rest of the ROI far: still near.
    let mut f = wall(1500);
    for r in 2..6 {
        for c in 2..4 {
            f.flags[(r, c)] = FLAG_SATURATED | FLAG_INVALID;
            f.depth_mm[(r, c)] = 0;
        }
    }
    assert!(d.update(&f).near);
}

#[test]
fn low_percentile_sees_partial_object_and_ignores_outliers() {
    // Default ROI: central 4×4 of the 8×8 frame (rows/cols 2..6).
    let mut d = detector(1);
    let mut f = wall(1500);
    // A hand covering a quarter of the ROI at 150 mm.
    for r in 2..4 {
        for c in 2..4 {
            f.depth_mm[(r, c)] = 150;
        }
    }
    let r = d.update(&f);
    assert!(r.near);
    assert_eq!(r.distance_mm, Some(150));
    // A single flying pixel at 50 mm on a far wall does not trigger near.
    let mut d = detector(1);
    let mut f = wall(1500);
    f.depth_mm[(3, 3)] = 50;
    let r = d.update(&f);
    assert!(!r.near);
    assert_eq!(r.distance_mm, Some(1500));
    // Pixels outside the ROI are ignored.
    let mut f = wall(1500);
    f.depth_mm.row_mut(0).fill(100);
    assert!(!d.update(&f).near);
}

#[test]
fn config_validation_roi_clipping_and_reset() {
    let bad = NearFarConfig {
        near_mm: 400,
        far_mm: 300,
        ..NearFarConfig::default()
    };
    assert!(NearFarDetector::new(bad).is_err());
    let bad = NearFarConfig {
        min_valid_fraction: 1.5,
        ..NearFarConfig::default()
    };
    assert!(NearFarDetector::new(bad).is_err());
    let bad = NearFarConfig {
        far_mm: 70_000,
        ..NearFarConfig::default()
    };
    assert!(NearFarDetector::new(bad).is_err());
    assert!(detector(1).with_percentile(1.5).is_err());
    // A ROI partly outside the frame is clipped; entirely outside → no target → far, no panic.
    let mut d = NearFarDetector::new(NearFarConfig {
        roi: Roi {
            row0: 6,
            col0: 6,
            rows: 10,
            cols: 10,
        },
        ..NearFarConfig::default()
    })
    .unwrap();
    let mut f = wall(1500);
    f.depth_mm[(7, 7)] = 100;
    f.depth_mm[(6, 7)] = 100;
    assert!(d.update(&f).near);
    d.reset();
    assert!(!d.is_near());
    let mut d = NearFarDetector::new(NearFarConfig {
        roi: Roi {
            row0: 50,
            col0: 50,
            rows: 4,
            cols: 4,
        },
        ..NearFarConfig::default()
    })
    .unwrap();
    let r = d.update(&wall(100));
    assert!(!r.near && r.distance_mm.is_none());
    assert_eq!(
        Roi::centered(172, 224, 0.5),
        Roi {
            row0: 43,
            col0: 56,
            rows: 86,
            cols: 112
        }
    );
}

#[test]
fn malformed_frame_does_not_panic() {
    let mut f = wall(100);
    f.flags = ndarray::Array2::zeros((3, 20)); // inconsistent with depth (8×8)
    let mut d = detector(1);
    let r = d.update(&f);
    assert!(r.valid_fraction <= 1.0);
    let empty = DepthFrame::zeros(0, 0);
    let r = d.update(&empty);
    assert_eq!(r.distance_mm, None);
}

#[test]
fn nothing_in_range_is_a_far_reading_broken_data_is_none() {
    use tofprox_core::pipeline::{FLAG_IMPLAUSIBLE, FLAG_NON_FINITE};
    let mut d = detector(1);
    for flags in [FLAG_LOW_AMPLITUDE, FLAG_IMPLAUSIBLE] {
        let r = d.update(&invalid(flags));
        assert!(
            r.no_target && !r.near && r.distance_mm.is_none(),
            "{flags}: {r:?}"
        );
    }
    let r = d.update(&invalid(FLAG_NON_FINITE));
    assert!(
        !r.no_target && !r.near,
        "non-finite data is no reading: {r:?}"
    );
    let r = d.update(&invalid(FLAG_SATURATED));
    assert!(
        r.near && !r.no_target,
        "saturation is near, not nothing: {r:?}"
    );
    let r = d.update(&wall(1000));
    assert!(!r.no_target && r.distance_mm == Some(1000));
}

#[test]
fn memory_order_and_roi_position_do_not_change_the_reading() {
    // A 20×30 frame with a depth gradient, saturated, low-amplitude and invalid pixels; the same
    // frame in column-major order (read through ndarray's iterators, not the row slices) must
    // give the same readings, for the auto ROI and for an off-centre one clipped by the frame.
    let (rows, cols) = (20, 30);
    let mut f = DepthFrame::zeros(rows, cols);
    for r in 0..rows {
        for c in 0..cols {
            f.depth_mm[(r, c)] = (100 + 13 * r + 7 * c) as u16;
            match (r * cols + c) % 11 {
                0 => f.flags[(r, c)] = FLAG_SATURATED | FLAG_INVALID,
                1 => f.flags[(r, c)] = FLAG_LOW_AMPLITUDE | FLAG_INVALID,
                _ => {}
            }
        }
    }
    let mut g = DepthFrame::zeros(rows, cols);
    g.depth_mm = ndarray::Array2::zeros((rows, cols).f());
    g.depth_mm.assign(&f.depth_mm);
    g.flags = ndarray::Array2::zeros((rows, cols).f());
    g.flags.assign(&f.flags);
    assert!(g.flags.as_slice().is_none());
    for roi in [
        Roi::default(),
        Roi {
            row0: 13,
            col0: 21,
            rows: 50,
            cols: 50,
        },
    ] {
        for percentile in [0.0, 0.1, 0.5, 1.0] {
            let cfg = NearFarConfig {
                near_mm: 200,
                far_mm: 300,
                roi,
                far_debounce: 1,
                min_valid_fraction: 0.2,
            };
            let mut a = NearFarDetector::new(cfg)
                .unwrap()
                .with_percentile(percentile)
                .unwrap();
            let mut b = a.clone();
            let (ra, rb) = (a.update(&f), b.update(&g));
            assert_eq!(ra, rb, "{roi:?} {percentile}");
            // The nearest-rank percentile of the valid depths inside the ROI, by a sort.
            let roi = roi.resolve(rows, cols);
            let mut valid: Vec<u16> = (roi.row0..roi.row0 + roi.rows)
                .flat_map(|r| (roi.col0..roi.col0 + roi.cols).map(move |c| (r, c)))
                .filter(|&p| f.flags[p] == 0)
                .map(|p| f.depth_mm[p])
                .collect();
            valid.sort_unstable();
            let rank = ((percentile * valid.len() as f32).ceil() as usize).clamp(1, valid.len());
            assert_eq!(ra.distance_mm, Some(u32::from(valid[rank - 1])));
        }
    }
}

/// `statistic_below_far` says, without a state change, whether the next update's statistic
/// lies below `far_mm`: one flying pixel does not, a quarter of the ROI at 250 mm does, too few
/// valid pixels do not.
#[test]
fn statistic_below_far_predicts_the_update_without_changing_state() {
    let d = detector(1);
    let mut f = wall(1500);
    f.depth_mm[(3, 3)] = 50;
    assert!(!d.statistic_below_far(&f));
    for r in 2..4 {
        for c in 2..4 {
            f.depth_mm[(r, c)] = 250;
        }
    }
    assert!(d.statistic_below_far(&f));
    assert!(!d.is_near(), "no state change");
    let mut u = d.clone();
    assert_eq!(u.update(&f).distance_mm, Some(250));
    // 3 of the 16 ROI pixels valid (< 20 %): no statistic
    let mut g = invalid(FLAG_LOW_AMPLITUDE);
    for c in 2..5 {
        g.flags[(2, c)] = 0;
        g.depth_mm[(2, c)] = 60;
    }
    assert!(!d.statistic_below_far(&g));
    assert_eq!(u.update(&g).distance_mm, None);
}
