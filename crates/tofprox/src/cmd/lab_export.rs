//! `tofprox lab compare|diagnose|explain --export DIR`: the lab's results as files a sensor
//! engineer opens in numpy or a spreadsheet (docs/lab-json.md, "Exported files") — built over
//! the lab's public result types ([`Comparison`], [`Diagnosis`], [`Explanation`]) only.
//!
//! - `residual_lsb.npy` float32 `(captures, K, rows, cols)`: measured − model per raw code (LSB);
//!   NaN where a code is not in the fit (saturated, a capture left out, a raw image the capture
//!   does not have). `residual_z.npy`: the same over its noise σ (unit variance under noise).
//! - per-pixel maps float64 `(rows, cols)`: `pixel_chi2.npy` (χ² per sample), `offset_lsb.npy`,
//!   `gain_lsb.npy` (amplitude per unit of the signal law), `phase_rad.npy`.
//! - `captures.csv` (one row per capture: its conditions and mean depth errors),
//!   `structure.csv` (one row per condition), and with a diagnosis `candidates.csv`.
//! - `explain`: each step's files under `step_1/`, `step_2/`, … (without the residual arrays:
//!   `explain` keeps no residual table of its steps).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use ndarray::{Array2, Array4};
use tofprox_lab::diagnose::{Diagnosis, Explanation};
use tofprox_lab::structure::ConditionScore;
use tofprox_lab::{Comparison, Prepared};

/// The files of one comparison (and its diagnosis), as (name, bytes).
fn comparison_files(
    prep: &Prepared,
    cmp: &Comparison,
    d: Option<&Diagnosis>,
) -> Vec<(String, Vec<u8>)> {
    let map = |v: &[f64]| {
        let a = Array2::from_shape_fn((prep.rows, prep.cols), |(r, c)| {
            v.get(r * prep.cols + c).copied().unwrap_or(f64::NAN)
        });
        tofprox_format::npy::encode_f64(&a)
    };
    let mut files = Vec::new();
    // (`explain` keeps no residual table of its steps: their maps and tables only)
    if !cmp.recs.is_empty() {
        let (res, z) = residual_arrays(prep, cmp);
        files.push((
            "residual_lsb.npy".into(),
            tofprox_format::npy::encode_f32(&res),
        ));
        files.push(("residual_z.npy".into(), tofprox_format::npy::encode_f32(&z)));
    }
    files.extend([
        ("pixel_chi2.npy".into(), map(&cmp.pixel_chi2)),
        ("offset_lsb.npy".into(), map(&cmp.model.offset)),
        ("gain_lsb.npy".into(), map(&cmp.model.gain)),
        ("phase_rad.npy".into(), map(&cmp.model.phase)),
        ("captures.csv".into(), captures_csv(cmp).into_bytes()),
        (
            "structure.csv".into(),
            structure_csv(&cmp.structure).into_bytes(),
        ),
    ]);
    if let Some(d) = d {
        files.push(("candidates.csv".into(), candidates_csv(d).into_bytes()));
    }
    files
}

/// The residual table as dense arrays `(captures, K, rows, cols)`: r (LSB) and r·√w.
fn residual_arrays(prep: &Prepared, cmp: &Comparison) -> (Array4<f32>, Array4<f32>) {
    let k_max = prep
        .caps
        .iter()
        .map(|c| c.theta_rad.len())
        .max()
        .unwrap_or(0);
    let shape = (prep.caps.len(), k_max, prep.rows, prep.cols);
    let mut res = Array4::from_elem(shape, f32::NAN);
    let mut z = Array4::from_elem(shape, f32::NAN);
    for s in &cmp.recs {
        let (row, col) = (s.pix as usize / prep.cols, s.pix as usize % prep.cols);
        let at = [s.cap as usize, usize::from(s.k), row, col];
        if let (Some(r), Some(zz)) = (res.get_mut(at), z.get_mut(at)) {
            *r = s.r;
            *zz = s.r * s.w.sqrt();
        }
    }
    (res, z)
}

/// A CSV field of a number: shortest round-trip form, `nan` for NaN (numpy and Python read it).
fn num(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else {
        format!("{v}")
    }
}

/// A CSV text field (quoted when it holds a comma, quote or line break).
fn text(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn captures_csv(cmp: &Comparison) -> String {
    let mut s = String::from(
        "capture,distance_m,exposure_us,ambient_klux,temperature_c,depth_error_2phase_mm,\
         depth_error_4phase_mm,measured_amplitude_lsb,model_amplitude_lsb\n",
    );
    for c in &cmp.depth {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{}",
            c.capture,
            num(c.distance_m),
            num(c.exposure_us),
            num(c.ambient_klux),
            c.temperature_c.map_or(String::new(), num),
            num(c.depth_2phase_mm),
            num(c.depth_4phase_mm),
            num(c.measured_amplitude_lsb),
            num(c.model_amplitude_lsb)
        );
    }
    s
}

fn structure_csv(st: &[ConditionScore]) -> String {
    let mut s = String::from("condition,z,dof,direction,size_mm,size_lsb\n");
    for c in st {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{}",
            text(&c.condition),
            num(c.z),
            c.dof,
            text(c.direction),
            num(c.size_mm),
            num(c.size_lsb)
        );
    }
    s
}

fn candidates_csv(d: &Diagnosis) -> String {
    let mut s = String::from(
        "effect,delta_bic,explained_excess,cv_gain,explained_mm,explained_lsb,z_after\n",
    );
    for c in &d.candidates {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{}",
            text(&c.effect),
            num(c.delta_bic),
            num(c.explained_excess),
            num(c.cv_gain),
            num(c.explained.mm),
            num(c.explained.lsb),
            num(c.z_after)
        );
    }
    s
}

/// The files of `explain`: each step's comparison and diagnosis under `step_<n>/`.
fn explanation_files(prep: &Prepared, ex: &Explanation) -> Vec<(String, Vec<u8>)> {
    let mut files = Vec::new();
    for (i, st) in ex.steps.iter().enumerate() {
        for (name, bytes) in comparison_files(prep, &st.comparison, Some(&st.diagnosis)) {
            files.push((format!("step_{}/{name}", i + 1), bytes));
        }
    }
    files
}

/// What `--export` writes: a comparison, with its diagnosis, or a whole explanation.
pub enum Export<'a> {
    /// `compare` (`None`) or `diagnose` (`Some`).
    Comparison(&'a Comparison, Option<&'a Diagnosis>),
    /// `explain`.
    Explanation(&'a Explanation),
}

/// Write the export to `dir` (made when missing). No file is replaced without `force`: every
/// name is checked before the first is written.
pub fn write(dir: &Path, prep: &Prepared, what: Export<'_>, force: bool) -> anyhow::Result<()> {
    let files = match what {
        Export::Comparison(cmp, d) => comparison_files(prep, cmp, d),
        Export::Explanation(ex) => explanation_files(prep, ex),
    };
    let paths: Vec<PathBuf> = files.iter().map(|(n, _)| dir.join(n)).collect();
    if !force && let Some(p) = paths.iter().find(|p| p.exists()) {
        anyhow::bail!(
            "{} exists: pass --force to replace the files of --export {}, or choose another directory",
            p.display(),
            dir.display()
        );
    }
    for (p, (_, bytes)) in paths.iter().zip(&files) {
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        tofprox_format::write_atomic(p, bytes)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    eprintln!("{} files exported to {}", files.len(), dir.display());
    Ok(())
}
