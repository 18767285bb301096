//! Recording and calibration metadata of simulated captures, as the end-to-end tests write
//! them.

/// The recording metadata of a simulated capture: its phases, exposure, illumination and
/// averaging, and as conditions the ground-truth `distance_m` (with the simulated wall's
/// `reflectivity` 0.9) when given, the ambient light and the temperature.
pub fn capture_spec(
    req: &tofprox_model::CaptureRequest,
    distance_m: Option<f64>,
) -> tofprox_format::CaptureSpec {
    let mut conditions = std::collections::BTreeMap::new();
    if let Some(d) = distance_m {
        conditions.insert("distance_m".to_string(), d);
        conditions.insert("reflectivity".to_string(), 0.9);
    }
    conditions.insert("ambient_klux".to_string(), req.ambient_klux);
    conditions.insert("temperature_c".to_string(), req.temperature_c);
    tofprox_format::CaptureSpec {
        phases_deg: req.phases_deg.clone(),
        exposure_us: req.exposure_us,
        illumination: req.illumination,
        averaged: req.averaged,
        timestamp_ns: None,
        conditions,
    }
}

/// A calibration part's provenance naming only the recording.
pub fn part_source(recording: &str) -> tofprox_format::PartSource {
    tofprox_format::PartSource {
        recording: recording.into(),
        ..Default::default()
    }
}
