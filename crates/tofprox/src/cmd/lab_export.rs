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
use tofprox_lab::arrays::ComparisonArrays;
use tofprox_lab::diagnose::{Diagnosis, Explanation};
use tofprox_lab::structure::ConditionScore;
use tofprox_lab::{Comparison, Prepared};

/// The files of one comparison (and its diagnosis), as (name, bytes).
fn comparison_files(
    prep: &Prepared,
    cmp: &Comparison,
    d: Option<&Diagnosis>,
) -> Vec<(String, Vec<u8>)> {
    use tofprox_format::npy::{encode_f32, encode_f64};
    let a = ComparisonArrays::of(prep, cmp);
    let mut files = Vec::new();
    // (`explain` keeps no residual table of its steps: their maps and tables only)
    if let (Some(res), Some(z)) = (&a.residual_lsb, &a.residual_z) {
        files.push(("residual_lsb.npy".into(), encode_f32(res)));
        files.push(("residual_z.npy".into(), encode_f32(z)));
    }
    files.extend([
        ("pixel_chi2.npy".into(), encode_f64(&a.pixel_chi2)),
        ("offset_lsb.npy".into(), encode_f64(&a.offset_lsb)),
        ("gain_lsb.npy".into(), encode_f64(&a.gain_lsb)),
        ("phase_rad.npy".into(), encode_f64(&a.phase_rad)),
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
