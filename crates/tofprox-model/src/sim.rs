//! The forward model: scene → electrons per tap A/B → differential voltage → ADC codes.

use ndarray::{Array3, ArrayView2};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::ModelConfig;
use crate::effects::adc::Adc;
use crate::effects::fixed_pattern::FixedPatterns;
use crate::effects::optical::{Correlation, droop_factor, multipath_phase_offset_rad};
use crate::effects::pixel::{PixelParams, tap_gain_leak_e};
use crate::error::ModelError;
use crate::geometry::{CaptureRequest, SensorGeometry};
use crate::ids;
use crate::scene::Scene;
use tofprox_core::camera::{Plane, RayGrid};

/// A sensor instance: model + geometry + the fixed patterns drawn from one seed.
#[derive(Debug, Clone)]
pub struct Simulator {
    model: ModelConfig,
    geometry: SensorGeometry,
    seed: u64,
    patterns: FixedPatterns,
    adc: Adc,
    correlation: Correlation,
    /// The window's unit rays through the model's `[camera]` (None: no lens geometry).
    rays: Option<RayGrid>,
}

/// Per-capture constants.
struct CaptureConsts {
    thetas: Vec<f64>,
    droop: Vec<f64>,
    signal_e: f64,
    ambient_e: f64,
    contrast: f64,
    falloff_n: Option<f64>,
    multipath: Option<(f64, f64)>,
    /// cover_window_crosstalk: (electrons of the window return before the column
    /// profile, its time-of-flight phase 4π f d_w / c, gradient across the columns).
    crosstalk: Option<(f64, f64, f64)>,
    px: PixelParams,
    lsb_per_e: f64,
    tof_rad_per_m: f64,
    averaged: f64,
}

impl Simulator {
    /// Build a sensor: validates the geometry and draws FPN, PRNU, FPPN and the DNL
    /// table from `seed` (as functions of full-array position: windows see the same pixels).
    pub fn new(
        model: &ModelConfig,
        geometry: SensorGeometry,
        seed: u64,
    ) -> Result<Self, ModelError> {
        geometry.validate()?;
        let rays = model
            .camera()
            .map(|k| {
                k.rays(
                    geometry.roi_origin[0],
                    geometry.roi_origin[1],
                    geometry.rows,
                    geometry.cols,
                )
            })
            .transpose()
            .map_err(|e| ModelError::invalid(format!("camera: {e}")))?;
        Ok(Self {
            rays,
            model: model.clone(),
            geometry,
            seed,
            patterns: FixedPatterns::draw(model, &geometry, seed),
            adc: Adc::new(model, geometry.adc_bits, seed),
            correlation: Correlation::from_model(model),
        })
    }

    /// The model this sensor was built from.
    pub fn model(&self) -> &ModelConfig {
        &self.model
    }
    /// The simulated geometry.
    pub fn geometry(&self) -> &SensorGeometry {
        &self.geometry
    }
    /// The seed of the fixed patterns.
    pub fn seed(&self) -> u64 {
        self.seed
    }
    /// The correlation function in use.
    pub fn correlation(&self) -> &Correlation {
        &self.correlation
    }
    /// The fixed per-pixel patterns (offset in LSB at the ADC input, gain, phase delay).
    pub fn patterns(&self) -> &FixedPatterns {
        &self.patterns
    }
    /// The ADC model.
    pub fn adc(&self) -> &Adc {
        &self.adc
    }
    /// The window's unit rays through the model's `[camera]`, `None` without a lens.
    pub fn rays(&self) -> Option<&RayGrid> {
        self.rays.as_ref()
    }

    /// Simulate one capture: (K, rows, cols) codes, the mean of `req.averaged`
    /// acquisitions (noise σ/√n), integer codes when `quantization` is on and averaged = 1.
    pub fn capture(
        &self,
        scene: &Scene,
        req: &CaptureRequest,
        rng: &mut impl Rng,
    ) -> Result<Array3<f64>, ModelError> {
        self.run(scene, req, Some(rng))
    }

    /// One single acquisition as integer codes (the request's `averaged` is ignored).
    pub fn capture_u16(
        &self,
        scene: &Scene,
        req: &CaptureRequest,
        rng: &mut impl Rng,
    ) -> Result<Array3<u16>, ModelError> {
        let single = CaptureRequest {
            averaged: 1,
            ..req.clone()
        };
        let codes = self.run(scene, &single, Some(rng))?;
        let max = self.adc.max_code();
        Ok(codes.mapv(|v| v.round().clamp(0.0, max) as u16))
    }

    /// Noise-free mean codes (quantisation as its mean): what the lab fits with.
    pub fn expected(&self, scene: &Scene, req: &CaptureRequest) -> Result<Array3<f64>, ModelError> {
        self.run::<rand::rngs::SmallRng>(scene, req, None)
    }

    fn consts(&self, req: &CaptureRequest) -> CaptureConsts {
        let m = &self.model;
        let t = req.exposure_us;
        let px = PixelParams::new(m, t, req.temperature_c);
        let illum = req.illumination;
        CaptureConsts {
            thetas: req.phases_deg.iter().map(|d| d.to_radians()).collect(),
            droop: (0..req.phases_deg.len())
                .map(|k| droop_factor(m, k, t))
                .collect(),
            signal_e: if illum {
                m.get(ids::sensor::SIGNAL_E_PER_US) * t * px.drift_gain
            } else {
                0.0
            },
            ambient_e: if m.is_enabled(ids::ambient_light::ID) {
                m.get(ids::ambient_light::E_PER_US_PER_KLUX) * req.ambient_klux * t
            } else {
                0.0
            },
            contrast: if m.is_enabled(ids::demodulation_contrast::ID) {
                m.get(ids::demodulation_contrast::CONTRAST)
            } else {
                1.0
            },
            falloff_n: m
                .is_enabled(ids::signal_falloff::ID)
                .then(|| m.get(ids::signal_falloff::EXPONENT)),
            multipath: m.is_enabled(ids::multipath::ID).then(|| {
                (
                    m.get(ids::multipath::RELATIVE_AMPLITUDE),
                    multipath_phase_offset_rad(
                        self.geometry.phase_rad_per_m(),
                        m.get(ids::multipath::EXTRA_PATH_M),
                    ),
                )
            }),
            crosstalk: (illum && m.is_enabled(ids::cover_window_crosstalk::ID)).then(|| {
                use ids::cover_window_crosstalk as xt;
                (
                    m.get(xt::E_PER_US) * (1.0 + m.get(xt::SMUDGE_REL)) * t * px.drift_gain,
                    // eq. 2.6 inverted at the window: 4π f d_w / c
                    self.geometry.phase_rad_per_m() * m.get(xt::WINDOW_DISTANCE_MM) * 1e-3,
                    m.get(xt::GRADIENT_REL),
                )
            }),
            px,
            lsb_per_e: m.get(ids::sensor::LSB_PER_KE) * 1e-3,
            // eq. 2.6 inverted: φ = 4π f d / c
            tof_rad_per_m: self.geometry.phase_rad_per_m(),
            averaged: f64::from(req.averaged.max(1)),
        }
    }

    fn run<R: Rng>(
        &self,
        scene: &Scene,
        req: &CaptureRequest,
        mut rng: Option<&mut R>,
    ) -> Result<Array3<f64>, ModelError> {
        req.validate()?;
        scene.validate()?;
        let g = &self.geometry;
        let (rows, cols) = (g.rows, g.cols);
        // Scene accessor: constant, window-shaped or full-array-shaped map.
        let (dmap, rmap, origin): (Option<ArrayView2<f64>>, Option<ArrayView2<f64>>, [usize; 2]) =
            match scene {
                Scene::FlatWall { .. } => (None, None, [0, 0]),
                Scene::DepthMap {
                    distance_m,
                    reflectivity,
                } => {
                    let dim = distance_m.dim();
                    let origin = if dim == (rows, cols) {
                        [0, 0]
                    } else if dim == (g.full_rows, g.full_cols) {
                        g.roi_origin
                    } else {
                        return Err(ModelError::invalid(format!(
                            "scene: depth map {}x{} matches neither the window {}x{} nor the full array {}x{}",
                            dim.0, dim.1, rows, cols, g.full_rows, g.full_cols
                        )));
                    };
                    (Some(distance_m.view()), Some(reflectivity.view()), origin)
                }
            };
        let (wall_d, wall_r) = match scene {
            Scene::FlatWall {
                distance_m,
                reflectivity,
            } => (*distance_m, *reflectivity),
            Scene::DepthMap { .. } => (1.0, 1.0),
        };

        let cc = self.consts(req);
        let origin_col = g.roi_origin[1];
        let k_images = cc.thetas.len();
        let mut out = Array3::<f64>::zeros((k_images, rows, cols));
        let plane = rows * cols;
        let Some(buf) = out.as_slice_mut() else {
            return Err(ModelError::invalid("internal: output array not contiguous"));
        };
        let adc = &self.adc;
        let quantize_each = adc.quantizes() && req.averaged == 1;
        let extra_q_var = if adc.quantizes() && req.averaged > 1 {
            1.0 / 12.0
        } else {
            0.0
        };
        let corr = &self.correlation;
        let px = &cc.px;
        let k_con = cc.contrast;

        // Pass 1, per pixel: signal electrons, phase, and the noise variance
        // coefficients var = a · droop_k + b (LSB², already ÷ averaged).
        let g2 = cc.lsb_per_e * cc.lsb_per_e;
        let mp_rel = cc.multipath.map_or(0.0, |(a, _)| a);
        let mp_dphi = cc.multipath.map_or(0.0, |(_, d)| d);
        let var_const = (2.0 * px.ktc_var_e2 + if px.dark_shot { 2.0 * px.dark_e } else { 0.0 })
            * g2
            + px.read_var_lsb2
            + extra_q_var;
        let mut sig = vec![0.0f64; plane];
        let mut phase = vec![0.0f64; plane];
        let mut var_a = vec![0.0f64; plane];
        let mut var_b = vec![0.0f64; plane];
        let mut amb_e = vec![0.0f64; plane];
        // cover_window_crosstalk per pixel: electrons and phase (empty when off)
        let xt_on = cc.crosstalk.is_some();
        let (mut xt_e, mut xt_phi) = if xt_on {
            (vec![0.0f64; plane], vec![0.0f64; plane])
        } else {
            (Vec::new(), Vec::new())
        };
        let col_span = (g.full_cols.max(2) - 1) as f64;
        for r in 0..rows {
            for c in 0..cols {
                let i = r * cols + c;
                let (d, refl) = match (&dmap, &rmap) {
                    (Some(dm), Some(rm)) => {
                        let idx = (r + origin[0], c + origin[1]);
                        match (dm.get(idx), rm.get(idx)) {
                            (Some(&d), Some(&rf)) => (d, rf),
                            _ => {
                                return Err(ModelError::invalid(
                                    "scene: depth map index out of range",
                                ));
                            }
                        }
                    }
                    _ => (wall_d, wall_r),
                };
                // Through the lens (thesis 5.1.3): a flat wall at perpendicular distance d is
                // seen along the pixel's ray, d / cos θ; the image irradiance falls with cos⁴ θ
                // (natural vignetting) and the wall is lit at incidence θ (Lambert, cos θ).
                let (d, lens_gain) = match self.rays.as_ref().and_then(|g| g.dir(r, c)) {
                    Some(dir) => {
                        let cos4 = dir[2].powi(4);
                        match dmap {
                            None => (
                                Plane::fronto_parallel(d).ray_length_m(dir).unwrap_or(d),
                                cos4 * dir[2],
                            ),
                            Some(_) => (d, cos4),
                        }
                    }
                    None => (d, 1.0),
                };
                let gain = self.patterns.gain.get(i).copied().unwrap_or(1.0) * lens_gain;
                let delay = self.patterns.delay_rad.get(i).copied().unwrap_or(0.0);
                // signal_falloff: N ∝ ρ (1 m / d)^n; prnu multiplies all optical electrons
                let falloff = match cc.falloff_n {
                    Some(2.0) => 1.0 / (d * d),
                    Some(n) => d.powf(-n),
                    None => 1.0,
                };
                let s = cc.signal_e * refl * falloff * gain;
                let amb = cc.ambient_e * gain;
                // eq. 2.6 inverted + FPPN/global delay + drift + amplitude-dependent error
                let phi =
                    cc.tof_rad_per_m * d + delay + px.drift_rad + px.amplitude_phase_rad(s * k_con);
                if let (Some(a), Some(b), Some(sg), Some(ph), Some(am)) = (
                    var_a.get_mut(i),
                    var_b.get_mut(i),
                    sig.get_mut(i),
                    phase.get_mut(i),
                    amb_e.get_mut(i),
                ) {
                    // the window return: w(c) g_p N_xt at 4π f d_w / c + the pixel's delay
                    let mut xe = 0.0;
                    if let (Some((n_xt, phi_w, grad)), Some(x), Some(xp)) =
                        (cc.crosstalk, xt_e.get_mut(i), xt_phi.get_mut(i))
                    {
                        let u = (c + origin_col) as f64 / col_span - 0.5;
                        xe = n_xt * (1.0 + grad * u).max(0.0) * gain;
                        *x = xe;
                        *xp = phi_w + delay + px.drift_rad;
                    }
                    // shot noise of both taps: F (N_A + N_B) = F ((N (1 + a_mp) + N_xt) droop + 2 N_amb) (eq. 2.16)
                    *a = px.shot_f * (s * (1.0 + mp_rel) + xe) * g2 / cc.averaged;
                    *b = (px.shot_f * 2.0 * amb * g2 + var_const) / cc.averaged;
                    *sg = s;
                    *ph = phi;
                    *am = amb;
                }
            }
        }

        // Pass 2, per raw image (acquisition order), contiguous over pixels.
        let dark = px.dark_e;
        let sbi_on = px.sbi.is_some();
        // tap_gain_mismatch: D = (1 + ε/2) N_A − (1 − ε/2) N_B
        let tap_eps = if self.model.is_enabled(ids::tap_gain_mismatch::ID) {
            self.model.get(ids::tap_gain_mismatch::MISMATCH_REL)
        } else {
            0.0
        };
        let noisy = rng.is_some();
        for k in 0..k_images {
            let theta = cc.thetas.get(k).copied().unwrap_or(0.0);
            let dr = cc.droop.get(k).copied().unwrap_or(1.0);
            let Some(out_k) = buf.get_mut(k * plane..(k + 1) * plane) else {
                return Err(ModelError::invalid("internal: output plane out of range"));
            };
            let pixels = out_k
                .iter_mut()
                .zip(&sig)
                .zip(&phase)
                .zip(&var_a)
                .zip(&var_b)
                .zip(&amb_e)
                .zip(&self.patterns.offset_lsb);
            for (i, ((((((o, &s), &phi), &va), &vb), &amb), &offset)) in pixels.enumerate() {
                let sk = s * dr;
                // correlation of each return: N_A,B = N/2 (1 ± K C(φ − θ)) (2.2.2)
                let mut corr_e = sk * corr.eval(phi - theta);
                if mp_rel > 0.0 {
                    corr_e += mp_rel * sk * corr.eval(phi + mp_dphi - theta);
                }
                let mut xk = 0.0;
                if xt_on && let (Some(&x), Some(&xp)) = (xt_e.get(i), xt_phi.get(i)) {
                    xk = x * dr;
                    corr_e += xk * corr.eval(xp - theta);
                }
                let mut diff = k_con * corr_e;
                let total = sk * (1.0 + mp_rel) + xk;
                if sbi_on {
                    let na = 0.5 * (total + diff) + amb + dark;
                    let nb = 0.5 * (total - diff) + amb + dark;
                    diff += px.sbi_error_e(na, nb);
                }
                if tap_eps != 0.0 {
                    // ε/2 · (N_A + N_B): a share of the total charge leaks into D
                    diff += tap_gain_leak_e(tap_eps, total + 2.0 * (amb + dark));
                }
                let mut u = diff * cc.lsb_per_e + offset;
                if let Some(rng) = rng.as_deref_mut() {
                    let var = va * dr + vb;
                    if var > 0.0 {
                        let z: f64 = rng.sample(StandardNormal);
                        u += var.sqrt() * z;
                    }
                }
                *o = u;
            }
            // ADC in its own pass: short independent iterations pipeline well
            if quantize_each && noisy {
                for o in out_k.iter_mut() {
                    *o = adc.quantize(adc.transfer(*o));
                }
            } else {
                for o in out_k.iter_mut() {
                    *o = adc.mean_code(adc.transfer(*o));
                }
            }
        }
        Ok(out)
    }
}
