//! The forward model: scene → electrons per tap A/B → differential voltage → ADC codes.

use ndarray::{Array3, ArrayView2};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::ModelConfig;
use crate::effects;
use crate::effects::adc::Adc;
use crate::effects::correlation::Correlation;
use crate::effects::cover_window_crosstalk::on_glass_return_rel;
use crate::effects::fixed_pattern::FixedPatterns;
use crate::effects::multipath::multipath_phase_offset_rad;
use crate::effects::pixel::PixelParams;
use crate::effects::tap_gain_mismatch::tap_gain_leak_e;
use crate::effects::user::{UserResponse, capture_response};
use crate::effects::vcsel_droop::{DutyCycle, droop_factor};
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
    /// Read, kTC, dark-shot and averaged-quantisation variance (LSB², before ÷ averaged).
    var_const_lsb2: f64,
    /// tap_gain_mismatch: D = (1 + ε/2) N_A − (1 − ε/2) N_B (0 when off).
    tap_eps: f64,
    /// The user effects' response to the capture's conditions (`effects::user`).
    user: UserResponse,
}

/// The scene as seen by the pixels: a flat wall or depth/reflectivity maps
/// whose window starts at `origin`.
struct SceneView<'a> {
    maps: Option<(ArrayView2<'a, f64>, ArrayView2<'a, f64>)>,
    origin: [usize; 2],
    wall_d: f64,
    wall_r: f64,
}

impl SceneView<'_> {
    /// (distance m, reflectivity) seen by window pixel (r, c), before the lens.
    fn at(&self, r: usize, c: usize) -> Result<(f64, f64), ModelError> {
        let Some((dm, rm)) = &self.maps else {
            return Ok((self.wall_d, self.wall_r));
        };
        let idx = (r + self.origin[0], c + self.origin[1]);
        match (dm.get(idx), rm.get(idx)) {
            (Some(&d), Some(&rf)) => Ok((d, rf)),
            _ => Err(ModelError::invalid("scene: depth map index out of range")),
        }
    }
}

/// Pass 1's per-pixel results, row-major over the window.
struct PixelTerms {
    sig: Vec<f64>,
    phase: Vec<f64>,
    var_a: Vec<f64>,
    var_b: Vec<f64>,
    amb_e: Vec<f64>,
    xt_e: Vec<f64>,
    xt_phi: Vec<f64>,
}

/// One pixel of pass 1: signal and ambient electrons, phase, noise variance
/// coefficients (LSB²) and the window return (electrons, phase) when on.
struct PixelTerm {
    s: f64,
    phi: f64,
    amb: f64,
    var_a: f64,
    var_b: f64,
    crosstalk: Option<(f64, f64)>,
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

    /// The capture's constants; `on_glass_rel` is the return of a surface pressed on the cover
    /// window relative to the clean window's crosstalk (0 when there is none).
    fn consts(&self, req: &CaptureRequest, user: UserResponse, on_glass_rel: f64) -> CaptureConsts {
        let m = &self.model;
        let t = req.exposure_us;
        let px = PixelParams::new(m, t, req.temperature_c);
        let illum = req.illumination;
        let lsb_per_e = m.get(ids::sensor::LSB_PER_KE) * 1e-3;
        let var_const_lsb2 = self.constant_var_lsb2(&px, lsb_per_e, req);
        CaptureConsts {
            thetas: req.phases_deg.iter().map(|d| d.to_radians()).collect(),
            droop: (0..req.phases_deg.len())
                .map(|k| droop_factor(m, k, DutyCycle::of_capture(t, &req.conditions)))
                .collect(),
            // a user effect on the gain scales the signal charge (effects::user)
            signal_e: if illum {
                m.get(ids::sensor::SIGNAL_E_PER_US) * t * px.drift_gain * user.gain_factor
            } else {
                0.0
            },
            ambient_e: if m.is_enabled(effects::ambient_light::ID) {
                m.get(effects::ambient_light::E_PER_US_PER_KLUX) * req.ambient_klux * t
            } else {
                0.0
            },
            contrast: if m.is_enabled(effects::demodulation_contrast::ID) {
                m.get(effects::demodulation_contrast::CONTRAST)
            } else {
                1.0
            },
            falloff_n: m
                .is_enabled(effects::signal_falloff::ID)
                .then(|| m.get(effects::signal_falloff::EXPONENT)),
            multipath: m.is_enabled(effects::multipath::ID).then(|| {
                (
                    m.get(effects::multipath::RELATIVE_AMPLITUDE),
                    multipath_phase_offset_rad(
                        self.geometry.phase_rad_per_m(),
                        m.get(effects::multipath::EXTRA_PATH_M),
                    ),
                )
            }),
            crosstalk: (illum && m.is_enabled(effects::cover_window_crosstalk::ID)).then(|| {
                use crate::effects::cover_window_crosstalk as xt;
                (
                    // a surface on the glass returns by the window's path (its contact law)
                    m.get(xt::E_PER_US)
                        * (1.0 + m.get(xt::SMUDGE_REL) + on_glass_rel)
                        * t
                        * px.drift_gain,
                    // eq. 2.6 inverted at the window: 4π f d_w / c
                    self.geometry.phase_rad_per_m() * m.get(xt::WINDOW_DISTANCE_MM) * 1e-3,
                    m.get(xt::GRADIENT_REL),
                )
            }),
            var_const_lsb2,
            user,
            tap_eps: if m.is_enabled(effects::tap_gain_mismatch::ID) {
                m.get(effects::tap_gain_mismatch::MISMATCH_REL)
            } else {
                0.0
            },
            px,
            lsb_per_e,
            // eq. 2.6 inverted: φ = 4π f d / c
            tof_rad_per_m: self.geometry.phase_rad_per_m(),
            averaged: f64::from(req.averaged.max(1)),
        }
    }

    /// The noise variance that does not depend on the signal (LSB², before
    /// ÷ averaged): kTC and dark shot noise of both taps, read noise, and the
    /// quantisation 1/12 LSB² of each averaged acquisition.
    fn constant_var_lsb2(&self, px: &PixelParams, lsb_per_e: f64, req: &CaptureRequest) -> f64 {
        let extra_q_var = if self.adc.quantizes() && req.averaged > 1 {
            1.0 / 12.0
        } else {
            0.0
        };
        (2.0 * px.ktc_var_e2 + if px.dark_shot { 2.0 * px.dark_e } else { 0.0 })
            * (lsb_per_e * lsb_per_e)
            + px.read_var_lsb2
            + extra_q_var
    }

    fn run<R: Rng>(
        &self,
        scene: &Scene,
        req: &CaptureRequest,
        mut rng: Option<&mut R>,
    ) -> Result<Array3<f64>, ModelError> {
        req.validate()?;
        scene.validate()?;
        let view = self.scene_view(scene)?;
        let user = capture_response(
            self.model.user_effects(),
            &req.conditions,
            &req.quantities(),
        )?;
        let on_glass_rel = scene
            .on_window_reflectivity()
            .map_or(0.0, on_glass_return_rel);
        let cc = self.consts(req, user, on_glass_rel);
        let terms = self.pixel_pass(&view, &cc)?;
        let (rows, cols) = (self.geometry.rows, self.geometry.cols);
        let mut out = Array3::<f64>::zeros((cc.thetas.len(), rows, cols));
        let plane = rows * cols;
        let Some(buf) = out.as_slice_mut() else {
            return Err(ModelError::invalid("internal: output array not contiguous"));
        };
        let quantize_each = self.adc.quantizes() && req.averaged == 1 && rng.is_some();
        for k in 0..cc.thetas.len() {
            let Some(out_k) = buf.get_mut(k * plane..(k + 1) * plane) else {
                return Err(ModelError::invalid("internal: output plane out of range"));
            };
            self.image_pass(&cc, &terms, k, out_k, rng.as_deref_mut());
            // ADC in its own pass: short independent iterations pipeline well
            self.digitize(out_k, quantize_each);
        }
        Ok(out)
    }

    /// The scene as a per-pixel accessor: constant, window-shaped or full-array-shaped map.
    fn scene_view<'a>(&self, scene: &'a Scene) -> Result<SceneView<'a>, ModelError> {
        let g = &self.geometry;
        let (rows, cols) = (g.rows, g.cols);
        Ok(match scene {
            Scene::FlatWall {
                distance_m,
                reflectivity,
            } => SceneView {
                maps: None,
                origin: [0, 0],
                wall_d: *distance_m,
                wall_r: *reflectivity,
            },
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
                SceneView {
                    maps: Some((distance_m.view(), reflectivity.view())),
                    origin,
                    wall_d: 1.0,
                    wall_r: 1.0,
                }
            }
            // out of focus on the glass: no image, its light comes by the window's path
            Scene::OnWindow { .. } => SceneView {
                maps: None,
                origin: [0, 0],
                wall_d: 1.0,
                wall_r: 0.0,
            },
        })
    }

    /// Pass 1, per pixel: signal electrons, phase, and the noise variance
    /// coefficients var = a · droop_k + b (LSB², already ÷ averaged).
    fn pixel_pass(&self, view: &SceneView, cc: &CaptureConsts) -> Result<PixelTerms, ModelError> {
        let (rows, cols) = (self.geometry.rows, self.geometry.cols);
        let plane = rows * cols;
        let mut t = PixelTerms {
            sig: vec![0.0f64; plane],
            phase: vec![0.0f64; plane],
            var_a: vec![0.0f64; plane],
            var_b: vec![0.0f64; plane],
            amb_e: vec![0.0f64; plane],
            // cover_window_crosstalk per pixel: electrons and phase (empty when off)
            xt_e: Vec::new(),
            xt_phi: Vec::new(),
        };
        if cc.crosstalk.is_some() {
            (t.xt_e, t.xt_phi) = (vec![0.0f64; plane], vec![0.0f64; plane]);
        }
        for r in 0..rows {
            for c in 0..cols {
                let i = r * cols + c;
                let p = self.pixel(view, cc, r, c, i)?;
                if let (Some(a), Some(b), Some(sg), Some(ph), Some(am)) = (
                    t.var_a.get_mut(i),
                    t.var_b.get_mut(i),
                    t.sig.get_mut(i),
                    t.phase.get_mut(i),
                    t.amb_e.get_mut(i),
                ) {
                    (*a, *b, *sg, *ph, *am) = (p.var_a, p.var_b, p.s, p.phi, p.amb);
                }
                if let (Some((xe, xphi)), Some(x), Some(xp)) =
                    (p.crosstalk, t.xt_e.get_mut(i), t.xt_phi.get_mut(i))
                {
                    (*x, *xp) = (xe, xphi);
                }
            }
        }
        Ok(t)
    }

    /// One pixel of pass 1: its distance through the lens, its electrons, phase
    /// and noise variance coefficients.
    fn pixel(
        &self,
        view: &SceneView,
        cc: &CaptureConsts,
        r: usize,
        c: usize,
        i: usize,
    ) -> Result<PixelTerm, ModelError> {
        let px = &cc.px;
        let (d, refl) = view.at(r, c)?;
        let (d, lens_gain) = self.through_lens(view, d, r, c);
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
        // (+ the user effects' phase, effects::user)
        let phi = cc.tof_rad_per_m * d
            + delay
            + px.drift_rad
            + px.amplitude_phase_rad(s * cc.contrast)
            + cc.user.phase_rad;
        // the window return: w(c) g_p N_xt at 4π f d_w / c + the pixel's delay
        let col_span = (self.geometry.full_cols.max(2) - 1) as f64;
        let crosstalk = cc.crosstalk.map(|(n_xt, phi_w, grad)| {
            let u = (c + self.geometry.roi_origin[1]) as f64 / col_span - 0.5;
            (
                n_xt * (1.0 + grad * u).max(0.0) * gain,
                phi_w + delay + px.drift_rad,
            )
        });
        let xe = crosstalk.map_or(0.0, |(x, _)| x);
        let g2 = cc.lsb_per_e * cc.lsb_per_e;
        let mp_rel = cc.multipath.map_or(0.0, |(a, _)| a);
        Ok(PixelTerm {
            // shot noise of both taps: F (N_A + N_B) = F ((N (1 + a_mp) + N_xt) droop + 2 N_amb) (eq. 2.16)
            var_a: px.shot_f * (s * (1.0 + mp_rel) + xe) * g2 / cc.averaged,
            var_b: (px.shot_f * 2.0 * amb * g2 + cc.var_const_lsb2) / cc.averaged,
            s,
            phi,
            amb,
            crosstalk,
        })
    }

    /// Through the lens (thesis 5.1.3): a flat wall at perpendicular distance d is
    /// seen along the pixel's ray, d / cos θ; the image irradiance falls with cos⁴ θ
    /// (natural vignetting) and the wall is lit at incidence θ (Lambert, cos θ).
    /// Returns (distance along the ray, irradiance gain).
    fn through_lens(&self, view: &SceneView, d: f64, r: usize, c: usize) -> (f64, f64) {
        match self.rays.as_ref().and_then(|g| g.dir(r, c)) {
            Some(dir) => {
                let cos4 = dir[2].powi(4);
                match view.maps {
                    None => (
                        Plane::fronto_parallel(d).ray_length_m(dir).unwrap_or(d),
                        cos4 * dir[2],
                    ),
                    Some(_) => (d, cos4),
                }
            }
            None => (d, 1.0),
        }
    }

    /// Pass 2 for raw image `k` (acquisition order), contiguous over pixels:
    /// the ADC-input voltage in LSB, with noise when `rng` is given.
    fn image_pass<R: Rng>(
        &self,
        cc: &CaptureConsts,
        t: &PixelTerms,
        k: usize,
        out_k: &mut [f64],
        mut rng: Option<&mut R>,
    ) {
        let theta = cc.thetas.get(k).copied().unwrap_or(0.0);
        let dr = cc.droop.get(k).copied().unwrap_or(1.0);
        let pixels = out_k
            .iter_mut()
            .zip(&t.sig)
            .zip(&t.phase)
            .zip(&t.var_a)
            .zip(&t.var_b)
            .zip(&t.amb_e)
            .zip(&self.patterns.offset_lsb);
        for (i, ((((((o, &s), &phi), &va), &vb), &amb), &offset)) in pixels.enumerate() {
            let xt = t.xt_e.get(i).copied().zip(t.xt_phi.get(i).copied());
            let diff =
                self.differential_e(cc, s * dr, phi, theta, amb, xt.map(|(x, xp)| (x * dr, xp)));
            // the user effects' offset at the ADC input (effects::user)
            let mut u = diff * cc.lsb_per_e + offset + cc.user.offset_lsb;
            if let Some(rng) = rng.as_deref_mut() {
                let var = va * dr + vb;
                if var > 0.0 {
                    let z: f64 = rng.sample(StandardNormal);
                    u += var.sqrt() * z;
                }
            }
            *o = u;
        }
    }

    /// The differential charge D of one pixel in one raw image (electrons):
    /// signal `sk` (droop applied) at phase `phi`, ambient `amb`, the window
    /// return `xt` (electrons with droop, phase), correlated at step `theta`.
    fn differential_e(
        &self,
        cc: &CaptureConsts,
        sk: f64,
        phi: f64,
        theta: f64,
        amb: f64,
        xt: Option<(f64, f64)>,
    ) -> f64 {
        let corr = &self.correlation;
        let px = &cc.px;
        let (mp_rel, mp_dphi) = cc.multipath.unwrap_or((0.0, 0.0));
        // correlation of each return: N_A,B = N/2 (1 ± K C(φ − θ)) (2.2.2)
        let mut corr_e = sk * corr.eval(phi - theta);
        if mp_rel > 0.0 {
            corr_e += mp_rel * sk * corr.eval(phi + mp_dphi - theta);
        }
        let mut xk = 0.0;
        if let Some((x, xp)) = xt {
            xk = x;
            corr_e += xk * corr.eval(xp - theta);
        }
        let mut diff = cc.contrast * corr_e;
        let total = sk * (1.0 + mp_rel) + xk;
        if px.sbi.is_some() {
            let na = 0.5 * (total + diff) + amb + px.dark_e;
            let nb = 0.5 * (total - diff) + amb + px.dark_e;
            diff += px.sbi_error_e(na, nb);
        }
        if cc.tap_eps != 0.0 {
            // ε/2 · (N_A + N_B): a share of the total charge leaks into D
            diff += tap_gain_leak_e(cc.tap_eps, total + 2.0 * (amb + px.dark_e));
        }
        diff
    }

    /// The ADC of one raw image: quantised codes (`quantize_each`) or the mean code.
    fn digitize(&self, out_k: &mut [f64], quantize_each: bool) {
        let adc = &self.adc;
        if quantize_each {
            for o in out_k.iter_mut() {
                *o = adc.quantize(adc.transfer(*o));
            }
        } else {
            for o in out_k.iter_mut() {
                *o = adc.mean_code(adc.transfer(*o));
            }
        }
    }
}
