//! Ideal raw frames: every pixel sees one return whose correlation (thesis eq. 2.1) with
//! the sensor's shifted demodulation is a pure sinusoid, `mid + A·cos(φ − θ_k)` at the image's
//! phase shift θ_k. Written here, not through the model or the pipeline, so the tests of
//! either compare against a formula of their own.

use ndarray::Array3;

/// `(phases, rows, cols)` codes of a return of amplitude `amplitude_lsb` at phase `phi_rad`
/// over the level `mid_lsb`, one image per shift of `phases_deg`, the same in every pixel.
pub fn ideal_codes(
    phi_rad: f64,
    amplitude_lsb: f64,
    mid_lsb: f64,
    (rows, cols): (usize, usize),
    phases_deg: &[f64],
) -> Array3<f64> {
    Array3::from_shape_fn((phases_deg.len(), rows, cols), |(k, _, _)| {
        mid_lsb + amplitude_lsb * (phi_rad - phases_deg[k].to_radians()).cos()
    })
}

/// Codes as the ADC delivers them: rounded towards zero and clipped to `0..=max_code`.
pub fn clipped_u16(codes: &Array3<f64>, max_code: f64) -> Array3<u16> {
    codes.mapv(|v| v.clamp(0.0, max_code) as u16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_shifts_of_one_return_hold_its_phase_and_amplitude() {
        let phases = [0.0, 90.0, 180.0, 270.0];
        let c = ideal_codes(0.6, 500.0, 2048.0, (2, 3), &phases);
        assert_eq!(c.dim(), (4, 2, 3));
        let p = |k: usize| c[(k, 1, 2)];
        // I = c0 − c180 = 2A cos φ, Q = c90 − c270 = 2A sin φ
        let (i, q) = (p(0) - p(2), p(1) - p(3));
        assert!((q.atan2(i) - 0.6).abs() < 1e-12);
        assert!((i.hypot(q) - 1000.0).abs() < 1e-9);
        assert!(((p(0) + p(2)) / 2.0 - 2048.0).abs() < 1e-9);
    }

    #[test]
    fn clipping_keeps_the_adc_range() {
        let c = ideal_codes(0.0, 1e5, 2048.0, (1, 1), &[0.0, 90.0, 180.0]);
        let u = clipped_u16(&c, 4095.0);
        assert_eq!(u.iter().copied().collect::<Vec<_>>(), vec![4095, 2048, 0]);
    }
}
