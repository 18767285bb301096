//! Measured waveforms (thesis 5.1.2.1): one period of the illumination and of the modulation
//! gate, read from CSV or `.npy` files and checked. Below both `config` (which reads the files a
//! model names) and `effects::correlation` (which builds the correlation from them), so neither
//! imports the other for it.

use std::f64::consts::TAU;
use std::path::Path;

use crate::error::{ErrorKind, ModelError};

/// Complex Fourier coefficients c_n = (1/M) Σ x_k e^{−i n 2π k/M}, n = 0..=nmax.
pub(crate) fn fourier(x: &[f64], nmax: usize) -> Vec<(f64, f64)> {
    let m = x.len().max(1) as f64;
    (0..=nmax)
        .map(|n| {
            let (mut re, mut im) = (0.0, 0.0);
            for (k, v) in x.iter().enumerate() {
                let a = TAU * (n * k) as f64 / m;
                re += v * a.cos();
                im -= v * a.sin();
            }
            (re / m, im / m)
        })
        .collect()
}

/// Check a measured waveform pair.
pub fn validate_waveforms(illumination: &[f64], modulation: &[f64]) -> Result<(), ModelError> {
    for (name, w) in [("illumination", illumination), ("modulation", modulation)] {
        if w.len() < 16 || w.len() > 1_000_000 {
            return Err(ModelError::new(
                ErrorKind::OutOfRange,
                format!(
                    "{name} waveform has {} samples, allowed [16, 1000000] (one period)",
                    w.len()
                ),
            ));
        }
        if let Some(v) = w.iter().find(|v| !v.is_finite()) {
            return Err(ModelError::new(
                ErrorKind::OutOfRange,
                format!("{name} waveform contains {v}"),
            ));
        }
    }
    if illumination.iter().any(|&v| v < 0.0) || illumination.iter().all(|&v| v == 0.0) {
        return Err(ModelError::new(
            ErrorKind::OutOfRange,
            "illumination waveform must be optical power ≥ 0 and not all zero",
        ));
    }
    if modulation.iter().any(|&v| !(0.0..=1.0).contains(&v)) {
        return Err(ModelError::new(
            ErrorKind::OutOfRange,
            "modulation waveform must lie in [0, 1] (1 = charge to tap A, 0 = tap B)",
        ));
    }
    let s = fourier(illumination, 1);
    let m = fourier(modulation, 1);
    if s[1].0.hypot(s[1].1) < 1e-9 || m[1].0.hypot(m[1].1) < 1e-9 {
        return Err(ModelError::new(
            ErrorKind::OutOfRange,
            "waveform has no component at the modulation frequency",
        ));
    }
    Ok(())
}

/// The values of a 1-D float64/float32 `.npy` file, read by the workspace's one `.npy`
/// reader (`tofprox_format::npy`); anything else is described.
fn waveform_of_npy(bytes: &[u8]) -> Result<Vec<f64>, String> {
    use tofprox_format::npy::{self, NpyArray};
    let array = npy::decode(bytes).map_err(|e| e.to_string())?;
    let shape = match &array {
        NpyArray::F64(a) if a.ndim() == 1 => return Ok(a.iter().copied().collect()),
        NpyArray::F32(a) if a.ndim() == 1 => return Ok(a.iter().map(|&v| f64::from(v)).collect()),
        NpyArray::U16(a) => {
            return Err(format!(
                "uint16 array {}: a waveform is float64/float32",
                npy::shape_str(a.shape())
            ));
        }
        NpyArray::F32(a) => a.shape().to_vec(),
        NpyArray::F64(a) => a.shape().to_vec(),
    };
    Err(format!(
        "array of shape {}: a waveform is 1-D",
        npy::shape_str(&shape)
    ))
}

/// Load one period of a waveform from CSV (one value per line, or the last column
/// of comma/whitespace separated rows; `#` comments and a header line allowed) or NPY (1-D float).
pub fn load_waveform(path: &Path) -> Result<Vec<f64>, ModelError> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    use tofprox_format::limits::{MAX_NPY_BYTES, MAX_TOML_BYTES, read_bounded, read_text_bounded};
    if is_npy {
        let bytes = read_bounded(path, MAX_NPY_BYTES, None)?;
        return waveform_of_npy(&bytes).map_err(|msg| {
            ModelError::new(ErrorKind::Parse, format!("{}: {msg}", path.display()))
        });
    }
    let text = read_text_bounded(path, MAX_TOML_BYTES)?;
    let mut out = Vec::new();
    for (lineno, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let last = line
            .split([',', ';', ' ', '\t'])
            .rfind(|s| !s.is_empty())
            .unwrap_or("");
        match last.parse::<f64>() {
            Ok(v) => out.push(v),
            Err(_) if out.is_empty() => continue, // header line
            Err(_) => {
                return Err(ModelError::new(
                    ErrorKind::Parse,
                    format!(
                        "{}:{}: `{last}` is not a number",
                        path.display(),
                        lineno + 1
                    ),
                ));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waveform_files_csv_and_npy() {
        let dir = std::env::temp_dir().join(format!("tofprox-model-wave-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let csv = dir.join("w.csv");
        std::fs::write(&csv, "# period\nt,value\n0,1.0\n1,2.5\n2,0.5\n").unwrap();
        assert_eq!(load_waveform(&csv).unwrap(), vec![1.0, 2.5, 0.5]);
        std::fs::write(&csv, "t,value\n0,1.0\n1,abc\n").unwrap();
        let e = load_waveform(&csv).unwrap_err();
        assert!(e.to_string().contains(":3:"), "{e}");
        let npy = dir.join("w.npy");
        // written byte by byte as NumPy does (not by the reader's own encoder)
        let npy_bytes = |descr: &str, shape: &str, data: &[u8]| {
            let dict =
                format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
            let mut h = dict.into_bytes();
            while (10 + h.len() + 1) % 64 != 0 {
                h.push(b' ');
            }
            h.push(b'\n');
            let mut b = b"\x93NUMPY\x01\x00".to_vec();
            b.extend_from_slice(&(h.len() as u16).to_le_bytes());
            b.extend_from_slice(&h);
            b.extend_from_slice(data);
            b
        };
        let f32s: Vec<u8> = [0.25f32, 0.5]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        std::fs::write(&npy, npy_bytes("<f4", "(2,)", &f32s)).unwrap();
        assert_eq!(load_waveform(&npy).unwrap(), vec![0.25, 0.5]);
        let f64s: Vec<u8> = [0.1f64, 0.7, 0.2]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        std::fs::write(&npy, npy_bytes("<f8", "(3,)", &f64s)).unwrap();
        assert_eq!(load_waveform(&npy).unwrap(), vec![0.1, 0.7, 0.2]);
        std::fs::write(&npy, npy_bytes("<f4", "(1, 2)", &f32s)).unwrap();
        let e = load_waveform(&npy).unwrap_err();
        assert!(
            e.to_string().contains("shape (1, 2): a waveform is 1-D"),
            "{e}"
        );
        std::fs::write(&npy, npy_bytes("<u2", "(2,)", &[1, 0, 2, 0])).unwrap();
        let e = load_waveform(&npy).unwrap_err();
        assert!(e.to_string().contains("uint16 array (2,)"), "{e}");
        assert!(load_waveform(&dir.join("missing.csv")).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
