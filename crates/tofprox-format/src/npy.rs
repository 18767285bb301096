//! A small, strict `.npy` reader and writer (NumPy format versions 1.0, 2.0 and
//! 3.0) for the three element types tofprox stores: little-endian `uint16`,
//! `float32` and `float64`, C order, any number of dimensions.
//!
//! Why our own: its errors say exactly what is wrong (truncated by how many
//! bytes, which dtype was found, Fortran order, big endian) and it never
//! allocates more than the file's real size, so random bytes cannot make it
//! panic or exhaust memory.

use std::io::Read;
use std::path::Path;

use ndarray::{ArrayD, IxDyn};

use crate::error::{ErrorKind, FormatError};
use crate::limits;

const MAGIC: &[u8; 6] = b"\x93NUMPY";
/// Headers larger than this are refused (NumPy itself writes < 200 bytes).
const MAX_HEADER_LEN: usize = 64 * 1024;

/// Element type of a `.npy` array.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    /// `<u2`: raw ADC codes.
    U16,
    /// `<f4`: averaged codes, calibration tables.
    F32,
    /// `<f8`: averaged codes.
    F64,
}

impl Dtype {
    /// The NumPy `descr` string.
    pub fn descr(self) -> &'static str {
        match self {
            Dtype::U16 => "<u2",
            Dtype::F32 => "<f4",
            Dtype::F64 => "<f8",
        }
    }
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::U16 => 2,
            Dtype::F32 => 4,
            Dtype::F64 => 8,
        }
    }
    /// The NumPy name (`uint16`, …), for messages.
    pub fn name(self) -> &'static str {
        match self {
            Dtype::U16 => "uint16",
            Dtype::F32 => "float32",
            Dtype::F64 => "float64",
        }
    }
    fn from_descr(descr: &str) -> Result<Dtype, FormatError> {
        match descr {
            "<u2" => Ok(Dtype::U16),
            "<f4" => Ok(Dtype::F32),
            "<f8" => Ok(Dtype::F64),
            d if d.starts_with('>') => Err(npy_err(format!(
                "dtype '{d}' is big endian; tofprox reads little-endian '<u2', '<f4' or '<f8' only"
            ))),
            d => Err(npy_err(format!(
                "unsupported dtype '{d}': expected '<u2' (uint16 raw codes), '<f4' (float32) or '<f8' (float64)"
            ))),
        }
    }
}

/// What the header of a `.npy` file says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NpyHeader {
    /// Element type.
    pub dtype: Dtype,
    /// Shape, C order.
    pub shape: Vec<usize>,
    /// Byte offset of the first data byte.
    pub data_offset: usize,
}

impl NpyHeader {
    /// Number of elements (None on overflow).
    pub fn len(&self) -> Option<usize> {
        self.shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))
    }
    /// Whether the array has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == Some(0)
    }
    /// Number of data bytes the header announces (None on overflow).
    pub fn data_len(&self) -> Option<usize> {
        self.len()?.checked_mul(self.dtype.size())
    }
}

/// An array read from a `.npy` file.
#[derive(Debug, Clone, PartialEq)]
pub enum NpyArray {
    /// `<u2`
    U16(ArrayD<u16>),
    /// `<f4`
    F32(ArrayD<f32>),
    /// `<f8`
    F64(ArrayD<f64>),
}

fn npy_err(msg: impl Into<String>) -> FormatError {
    FormatError::new(ErrorKind::Npy, msg)
}

/// Format a shape as NumPy does: `(4, 16, 16)`.
pub fn shape_str(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Parse the header at the start of `bytes` (which may hold more than the header).
pub fn parse_header(bytes: &[u8]) -> Result<NpyHeader, FormatError> {
    if bytes.len() < 10 {
        return Err(npy_err(format!(
            "not a .npy file: {} bytes, shorter than the 10-byte preamble",
            bytes.len()
        )));
    }
    if &bytes[..6] != MAGIC {
        return Err(npy_err(
            "not a .npy file: missing the \\x93NUMPY magic string",
        ));
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            let Some(b) = bytes.get(8..12) else {
                return Err(npy_err("truncated .npy preamble"));
            };
            (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize, 12)
        }
        _ => {
            return Err(npy_err(format!(
                "unsupported .npy format version {major}.{minor} (1.0, 2.0 and 3.0 are read)"
            )));
        }
    };
    if header_len > MAX_HEADER_LEN {
        return Err(npy_err(format!(
            "header length {header_len} bytes is implausible (limit {MAX_HEADER_LEN})"
        )));
    }
    let end = start + header_len;
    let Some(raw) = bytes.get(start..end) else {
        return Err(npy_err(format!(
            "truncated: the header announces {header_len} bytes but the file ends after {}",
            bytes.len().saturating_sub(start)
        )));
    };
    let text = std::str::from_utf8(raw).map_err(|_| npy_err("header is not valid text"))?;
    let dict = parse_dict(text)?;
    let mut descr = None;
    let mut fortran = None;
    let mut shape = None;
    for (k, v) in dict {
        match (k.as_str(), v) {
            ("descr", PyValue::Str(s)) => descr = Some(s),
            ("fortran_order", PyValue::Bool(b)) => fortran = Some(b),
            ("shape", PyValue::Tuple(t)) => shape = Some(t),
            ("descr" | "fortran_order" | "shape", _) => {
                return Err(npy_err(format!("header key '{k}' has the wrong type")));
            }
            (other, _) => {
                return Err(npy_err(format!("unexpected header key '{other}'")));
            }
        }
    }
    let descr = descr.ok_or_else(|| npy_err("header lacks 'descr'"))?;
    let fortran = fortran.ok_or_else(|| npy_err("header lacks 'fortran_order'"))?;
    let shape = shape.ok_or_else(|| npy_err("header lacks 'shape'"))?;
    if fortran {
        return Err(npy_err(
            "array is stored in Fortran order; write it in C order (numpy.ascontiguousarray)",
        ));
    }
    let dtype = Dtype::from_descr(&descr)?;
    let header = NpyHeader {
        dtype,
        shape,
        data_offset: end,
    };
    if header.data_len().is_none() {
        return Err(npy_err(format!(
            "shape {} is too large",
            shape_str(&header.shape)
        )));
    }
    Ok(header)
}

/// Read only the header of a `.npy` file and check the file size matches it.
/// Only a regular file of at most [`limits::MAX_NPY_BYTES`] is opened, and
/// with `inside` only one that resolves inside that directory.
pub fn read_header(path: &Path, inside: Option<&Path>) -> Result<NpyHeader, FormatError> {
    let (mut f, meta) = limits::open_regular(path, limits::MAX_NPY_BYTES, inside)?;
    let file_len = meta.len();
    // the preamble (≤ 12 bytes) says how long the header is; read just that much
    let mut buf = Vec::with_capacity(128);
    (&mut f)
        .take(12)
        .read_to_end(&mut buf)
        .map_err(|e| FormatError::io(path, "cannot read", e))?;
    let header_len = match buf.get(6) {
        Some(1) if buf.len() >= 10 => usize::from(u16::from_le_bytes([buf[8], buf[9]])),
        Some(2 | 3) if buf.len() >= 12 => {
            u32::from_le_bytes([buf[8], buf[9], buf[10], buf[11]]) as usize
        }
        _ => 0, // parse_header reports what is wrong
    };
    (&mut f)
        .take(header_len.min(MAX_HEADER_LEN + 1) as u64)
        .read_to_end(&mut buf)
        .map_err(|e| FormatError::io(path, "cannot read", e))?;
    let header = parse_header(&buf).map_err(|e| e.at(path))?;
    check_size(&header, file_len).map_err(|e| e.at(path))?;
    Ok(header)
}

fn check_size(header: &NpyHeader, file_len: u64) -> Result<(), FormatError> {
    let want = header.data_len().unwrap_or(usize::MAX) as u64;
    let have = file_len.saturating_sub(header.data_offset as u64);
    if have < want {
        return Err(npy_err(format!(
            "truncated: shape {} of {} needs {want} data bytes, the file has {have}",
            shape_str(&header.shape),
            header.dtype.name()
        )));
    }
    if have > want {
        return Err(npy_err(format!(
            "{} unexpected bytes after the data of shape {} {}",
            have - want,
            shape_str(&header.shape),
            header.dtype.name()
        )));
    }
    Ok(())
}

/// Decode a whole `.npy` file held in memory.
pub fn decode(bytes: &[u8]) -> Result<NpyArray, FormatError> {
    let header = parse_header(bytes)?;
    check_size(&header, bytes.len() as u64)?;
    let data = bytes.get(header.data_offset..).unwrap_or(&[]);
    let shape = IxDyn(&header.shape);
    let err = |e: ndarray::ShapeError| npy_err(format!("shape error: {e}"));
    Ok(match header.dtype {
        Dtype::U16 => NpyArray::U16(ArrayD::from_shape_vec(shape, decode_le(data)).map_err(err)?),
        Dtype::F32 => NpyArray::F32(ArrayD::from_shape_vec(shape, decode_le(data)).map_err(err)?),
        Dtype::F64 => NpyArray::F64(ArrayD::from_shape_vec(shape, decode_le(data)).map_err(err)?),
    })
}

/// Read a whole `.npy` file; nothing larger than the file is allocated.
/// The file is opened as by [`read_header`].
pub fn read(path: &Path, inside: Option<&Path>) -> Result<NpyArray, FormatError> {
    // allocates the file's real size (bounded); decode checks it against the header
    let bytes = limits::read_bounded(path, limits::MAX_NPY_BYTES, inside)?;
    decode(&bytes).map_err(|e| e.at(path))
}

/// Encode an array as a version 1.0 `.npy` file (version 2.0 if the header
/// would not fit), C order, little endian.
pub fn encode(shape: &[usize], dtype: Dtype, data_le: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut dict = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}",
        dtype.descr(),
        shape_str(shape)
    );
    let v1 = dict.len() + 1 + 10 <= u16::MAX as usize;
    let pre = if v1 { 10 } else { 12 };
    // pad with spaces so that the data starts on a 64-byte boundary, end in '\n'
    let total = (pre + dict.len() + 1).div_ceil(64) * 64;
    while pre + dict.len() + 1 < total {
        dict.push(' ');
    }
    dict.push('\n');
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(MAGIC);
    if v1 {
        out.extend_from_slice(&[1, 0]);
        out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&[2, 0]);
        out.extend_from_slice(&(dict.len() as u32).to_le_bytes());
    }
    out.extend_from_slice(dict.as_bytes());
    data_le(&mut out);
    out
}

/// An element type `.npy` files hold, little endian.
trait LeElem: Copy {
    const DTYPE: Dtype;
    /// Append the little-endian bytes.
    fn put_le(self, out: &mut Vec<u8>);
    /// Read from exactly `DTYPE.size()` bytes.
    fn from_le(b: &[u8]) -> Self;
}

macro_rules! le_elem {
    ($t:ty, $dtype:expr) => {
        impl LeElem for $t {
            const DTYPE: Dtype = $dtype;
            fn put_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn from_le(b: &[u8]) -> Self {
                let mut a = [0u8; std::mem::size_of::<$t>()];
                a.copy_from_slice(b);
                <$t>::from_le_bytes(a)
            }
        }
    };
}
le_elem!(u16, Dtype::U16);
le_elem!(f32, Dtype::F32);
le_elem!(f64, Dtype::F64);

/// The data bytes as elements (`data` holds whole elements: `check_size` ran).
fn decode_le<T: LeElem>(data: &[u8]) -> Vec<T> {
    data.chunks_exact(T::DTYPE.size()).map(T::from_le).collect()
}

/// Encode an array of any element type in C order.
fn encode_le<T, S, D>(a: &ndarray::ArrayBase<S, D>) -> Vec<u8>
where
    T: LeElem,
    S: ndarray::Data<Elem = T>,
    D: ndarray::Dimension,
{
    encode(a.shape(), T::DTYPE, |out| {
        out.reserve(a.len() * T::DTYPE.size());
        for &v in a.iter() {
            v.put_le(out);
        }
    })
}

/// Encode a `u16` array (any dimension) in C order.
pub fn encode_u16<S, D>(a: &ndarray::ArrayBase<S, D>) -> Vec<u8>
where
    S: ndarray::Data<Elem = u16>,
    D: ndarray::Dimension,
{
    encode_le(a)
}

/// Encode an `f32` array (any dimension) in C order.
pub fn encode_f32<S, D>(a: &ndarray::ArrayBase<S, D>) -> Vec<u8>
where
    S: ndarray::Data<Elem = f32>,
    D: ndarray::Dimension,
{
    encode_le(a)
}

/// Encode an `f64` array (any dimension) in C order.
pub fn encode_f64<S, D>(a: &ndarray::ArrayBase<S, D>) -> Vec<u8>
where
    S: ndarray::Data<Elem = f64>,
    D: ndarray::Dimension,
{
    encode_le(a)
}

// ---- a tiny parser for the Python dict literal of the header ----

#[derive(Debug, Clone, PartialEq)]
enum PyValue {
    Str(String),
    Bool(bool),
    Tuple(Vec<usize>),
}

struct Cursor<'a> {
    s: &'a [u8],
    i: usize,
}

impl Cursor<'_> {
    fn ws(&mut self) {
        while self.i < self.s.len() && (self.s[self.i] as char).is_ascii_whitespace() {
            self.i += 1;
        }
    }
    fn peek(&mut self) -> Option<u8> {
        self.ws();
        self.s.get(self.i).copied()
    }
    fn eat(&mut self, c: u8) -> Result<(), FormatError> {
        if self.peek() == Some(c) {
            self.i += 1;
            Ok(())
        } else {
            Err(npy_err(format!(
                "malformed header: expected '{}' at byte {}",
                c as char, self.i
            )))
        }
    }
    fn string(&mut self) -> Result<String, FormatError> {
        let q = self
            .peek()
            .ok_or_else(|| npy_err("malformed header: unexpected end"))?;
        if q != b'\'' && q != b'"' {
            return Err(npy_err(format!(
                "malformed header: expected a quoted string at byte {}",
                self.i
            )));
        }
        self.i += 1;
        let start = self.i;
        while self.i < self.s.len() && self.s[self.i] != q {
            self.i += 1;
        }
        if self.i >= self.s.len() {
            return Err(npy_err("malformed header: unterminated string"));
        }
        let out = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
        self.i += 1;
        Ok(out)
    }
    fn word(&mut self) -> &[u8] {
        self.ws();
        let start = self.i;
        while self.i < self.s.len() && (self.s[self.i] as char).is_ascii_alphanumeric() {
            self.i += 1;
        }
        &self.s[start..self.i]
    }
    fn value(&mut self) -> Result<PyValue, FormatError> {
        match self.peek() {
            Some(b'\'' | b'"') => Ok(PyValue::Str(self.string()?)),
            Some(b'(') => {
                self.i += 1;
                let mut dims = Vec::new();
                loop {
                    if self.peek() == Some(b')') {
                        self.i += 1;
                        break;
                    }
                    let w = self.word();
                    let w = std::str::from_utf8(w).unwrap_or("");
                    let w = w.strip_suffix('L').unwrap_or(w);
                    let d: usize = w.parse().map_err(|_| {
                        npy_err(format!(
                            "malformed header: shape dimension '{w}' is not a non-negative integer"
                        ))
                    })?;
                    dims.push(d);
                    match self.peek() {
                        Some(b',') => self.i += 1,
                        Some(b')') => {}
                        _ => return Err(npy_err("malformed header: bad shape tuple")),
                    }
                    if dims.len() > 32 {
                        return Err(npy_err("malformed header: more than 32 dimensions"));
                    }
                }
                Ok(PyValue::Tuple(dims))
            }
            _ => match self.word() {
                b"True" => Ok(PyValue::Bool(true)),
                b"False" => Ok(PyValue::Bool(false)),
                _ => Err(npy_err(format!(
                    "malformed header: unexpected value at byte {}",
                    self.i
                ))),
            },
        }
    }
}

fn parse_dict(text: &str) -> Result<Vec<(String, PyValue)>, FormatError> {
    let mut c = Cursor {
        s: text.as_bytes(),
        i: 0,
    };
    c.eat(b'{')?;
    let mut out: Vec<(String, PyValue)> = Vec::new();
    loop {
        if c.peek() == Some(b'}') {
            c.i += 1;
            break;
        }
        let k = c.string()?;
        c.eat(b':')?;
        let v = c.value()?;
        if out.iter().any(|(kk, _)| *kk == k) {
            return Err(npy_err(format!("malformed header: duplicate key '{k}'")));
        }
        out.push((k, v));
        match c.peek() {
            Some(b',') => c.i += 1,
            Some(b'}') => {}
            _ => return Err(npy_err("malformed header: expected ',' or '}'")),
        }
    }
    if c.peek().is_some() {
        return Err(npy_err("malformed header: text after the closing '}'"));
    }
    Ok(out)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use ndarray::{Array3, array};
    use proptest::prelude::*;

    /// Replace the first occurrence of `from` (same length as `to`).
    pub(crate) fn replace_bytes(b: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
        let mut out = b.to_vec();
        let i = b.windows(from.len()).position(|w| w == from).unwrap();
        out[i..i + from.len()].copy_from_slice(to);
        out
    }

    #[test]
    fn roundtrip_all_dtypes() {
        let a = Array3::from_shape_fn((3, 2, 5), |(k, r, c)| (k * 100 + r * 10 + c) as u16);
        let NpyArray::U16(b) = decode(&encode_u16(&a)).unwrap() else {
            panic!("wrong dtype")
        };
        assert_eq!(b.shape(), &[3, 2, 5]);
        assert_eq!(
            b.iter().copied().collect::<Vec<_>>(),
            a.iter().copied().collect::<Vec<_>>()
        );

        let f = array![[1.5f32, -2.0], [f32::MAX, 0.25]];
        let NpyArray::F32(g) = decode(&encode_f32(&f)).unwrap() else {
            panic!("wrong dtype")
        };
        assert_eq!(g.into_dimensionality::<ndarray::Ix2>().unwrap(), f);

        let d = ndarray::Array1::from(vec![1.0f64, 2.5, -7.0]);
        let bytes = encode_f64(&d);
        assert_eq!(
            parse_header(&bytes).unwrap().data_offset % 64,
            0,
            "data starts on a 64-byte boundary"
        );
        let NpyArray::F64(e) = decode(&bytes).unwrap() else {
            panic!("wrong dtype")
        };
        assert_eq!(e.into_dimensionality::<ndarray::Ix1>().unwrap(), d);
    }

    #[test]
    fn reads_numpy_written_header() {
        // Exactly what numpy 1.26 writes for np.zeros((2,3), '<u2').
        let mut b =
            b"\x93NUMPY\x01\x00v\x00{'descr': '<u2', 'fortran_order': False, 'shape': (2, 3), }"
                .to_vec();
        while b.len() < 127 {
            b.push(b' ');
        }
        b.push(b'\n');
        b.extend_from_slice(&[0u8; 12]);
        let h = parse_header(&b).unwrap();
        assert_eq!(h.shape, vec![2, 3]);
        assert_eq!(h.dtype, Dtype::U16);
        assert_eq!(h.data_offset, 128);
        assert!(matches!(decode(&b).unwrap(), NpyArray::U16(_)));
    }

    #[test]
    fn clear_errors() {
        let a = Array3::<u16>::zeros((2, 4, 4));
        let good = encode_u16(&a);
        let e = decode(&good[..good.len() - 3]).unwrap_err();
        assert!(e.message().contains("truncated"), "{e}");
        assert!(e.message().contains("64 data bytes"), "{e}");
        let mut extra = good.clone();
        extra.push(0);
        assert!(
            decode(&extra)
                .unwrap_err()
                .message()
                .contains("unexpected bytes")
        );
        let e = decode(&replace_bytes(&good, b"<u2", b"<i2")).unwrap_err();
        assert!(e.message().contains("unsupported dtype '<i2'"), "{e}");
        let e = decode(&replace_bytes(&good, b"<u2", b">u2")).unwrap_err();
        assert!(e.message().contains("big endian"), "{e}");
        let e = decode(&replace_bytes(&good, b"False", b"True ")).unwrap_err();
        assert!(e.message().contains("Fortran"), "{e}");
        assert!(
            decode(b"hello world")
                .unwrap_err()
                .message()
                .contains("magic")
        );
        assert!(
            decode(b"\x93NUM")
                .unwrap_err()
                .message()
                .contains("not a .npy")
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = decode(&bytes);
        }

        #[test]
        fn mutated_valid_file_never_panics(pos in 0usize..200, val in any::<u8>(), cut in 0usize..200) {
            let a = Array3::from_shape_fn((2, 3, 4), |(k, r, c)| (k + r + c) as f32);
            let mut b = encode_f32(&a);
            let n = b.len();
            b[pos % n] = val;
            b.truncate(n - cut.min(n));
            let _ = decode(&b);
        }
    }
}
