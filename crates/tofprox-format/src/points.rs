//! Point-cloud files: a frame's camera-frame points (metres; `X` right, `Y` down, `Z` along the
//! optical axis — OpenCV's frame, [`tofprox_core::camera`]) as NumPy `.npy` or PLY.
//!
//! - `.npy`: `float32 (rows·cols, 3)`, C order, one row per pixel in row-major pixel order
//!   (pixel `(r, c)` is row `r·cols + c`, so the cloud stays organised like the depth image);
//!   invalid pixels are `NaN, NaN, NaN`.
//! - `.ply`: PLY 1.0 `binary_little_endian`, one `vertex` element with `float x, y, z`; invalid
//!   pixels are left out (viewers do not expect NaN vertices).

use std::path::Path;

use ndarray::{Array2, ArrayView2, ArrayView3};

use crate::error::{ErrorKind, FormatError};

/// The file format of a point cloud, chosen by the file's extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointCloudFormat {
    /// NumPy `.npy`, `float32 (rows·cols, 3)`, NaN where invalid.
    Npy,
    /// PLY, binary little-endian, valid points only.
    Ply,
}

impl PointCloudFormat {
    /// The format of `path` by its extension (`.npy` or `.ply`, any case).
    pub fn from_path(path: &Path) -> Result<Self, FormatError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("npy") => Ok(PointCloudFormat::Npy),
            Some("ply") => Ok(PointCloudFormat::Ply),
            _ => Err(FormatError::new(
                ErrorKind::Unsupported,
                "a point cloud is written as .npy or .ply (chosen by the extension)",
            )
            .at(path)),
        }
    }

    /// The file extension (without the dot).
    pub fn extension(&self) -> &'static str {
        match self {
            PointCloudFormat::Npy => "npy",
            PointCloudFormat::Ply => "ply",
        }
    }
}

/// Encode the points `(rows, cols, 3)` of the pixels where `valid` is true (same `(rows, cols)`)
/// in `format` (see the module docs for what each format does with invalid pixels). Errors when
/// the shapes do not match.
pub fn encode_points(
    points: ArrayView3<f32>,
    valid: ArrayView2<bool>,
    format: PointCloudFormat,
) -> Result<Vec<u8>, FormatError> {
    let (rows, cols, three) = points.dim();
    if three != 3 || valid.dim() != (rows, cols) {
        return Err(FormatError::new(
            ErrorKind::Invalid,
            format!(
                "points of shape {:?} with a validity mask of {:?}: expected (rows, cols, 3) and (rows, cols)",
                points.dim(),
                valid.dim()
            ),
        ));
    }
    Ok(match format {
        PointCloudFormat::Npy => {
            let mut out = Array2::<f32>::from_elem((rows * cols, 3), f32::NAN);
            for ((r, c), &ok) in valid.indexed_iter() {
                if ok {
                    for i in 0..3 {
                        out[(r * cols + c, i)] = points[(r, c, i)];
                    }
                }
            }
            crate::npy::encode_f32(&out)
        }
        PointCloudFormat::Ply => {
            let n = valid.iter().filter(|v| **v).count();
            let header = format!(
                "ply\nformat binary_little_endian 1.0\ncomment tofprox point cloud: metres, camera frame (X right, Y down, Z along the optical axis)\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
            );
            let mut out = Vec::with_capacity(header.len() + 12 * n);
            out.extend_from_slice(header.as_bytes());
            for ((r, c), &ok) in valid.indexed_iter() {
                if ok {
                    for i in 0..3 {
                        out.extend_from_slice(&points[(r, c, i)].to_le_bytes());
                    }
                }
            }
            out
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array3};

    fn cloud() -> (Array3<f32>, Array2<bool>) {
        let pts = Array3::from_shape_fn((2, 3, 3), |(r, c, i)| (r * 100 + c * 10 + i) as f32);
        let mut valid = Array2::from_elem((2, 3), true);
        valid[(0, 1)] = false;
        (pts, valid)
    }

    #[test]
    fn npy_is_organised_with_nan_for_invalid_pixels() {
        let (pts, valid) = cloud();
        let bytes = encode_points(pts.view(), valid.view(), PointCloudFormat::Npy).unwrap();
        let a = crate::npy::decode(&bytes).unwrap();
        let crate::npy::NpyArray::F32(a) = a else {
            panic!("float32 expected")
        };
        assert_eq!(a.shape(), &[6, 3]);
        let a = a.into_dimensionality::<ndarray::Ix2>().unwrap();
        assert!(a.row(1).iter().all(|v| v.is_nan()));
        assert_eq!(a.row(5).to_vec(), vec![120.0, 121.0, 122.0]);
        assert_eq!(a.row(0).to_vec(), vec![0.0, 1.0, 2.0]);
    }

    #[test]
    fn ply_holds_the_valid_points_little_endian() {
        let (pts, valid) = cloud();
        let bytes = encode_points(pts.view(), valid.view(), PointCloudFormat::Ply).unwrap();
        let end = b"end_header\n";
        let at = bytes
            .windows(end.len())
            .position(|w| w == end)
            .expect("header end")
            + end.len();
        let header = std::str::from_utf8(&bytes[..at]).unwrap();
        assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
        assert!(header.contains("element vertex 5\n"), "{header}");
        let body: Vec<f32> = bytes[at..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(body.len(), 15);
        assert_eq!(&body[..6], &[0.0, 1.0, 2.0, 20.0, 21.0, 22.0]);
        assert_eq!(&body[12..], &[120.0, 121.0, 122.0]);
    }

    #[test]
    fn format_by_extension_and_shape_errors() {
        assert_eq!(
            PointCloudFormat::from_path(Path::new("a/b.PLY")).unwrap(),
            PointCloudFormat::Ply
        );
        assert_eq!(
            PointCloudFormat::from_path(Path::new("b.npy")).unwrap(),
            PointCloudFormat::Npy
        );
        let e = PointCloudFormat::from_path(Path::new("cloud.xyz")).unwrap_err();
        assert!(e.to_string().contains("cloud.xyz"), "{e}");
        let (pts, _) = cloud();
        let wrong = Array2::from_elem((3, 2), true);
        assert!(encode_points(pts.view(), wrong.view(), PointCloudFormat::Npy).is_err());
    }
}
