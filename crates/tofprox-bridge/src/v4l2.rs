//! Layer 1b: a V4L2 capture device, for single-board computers whose kernel driver delivers
//! the raw phase images itself (the IRS1125 driver of the Raspberry Pi kernel: every image of
//! a sequence stacked in one Y12 buffer; the MLX7502x drivers posted to linux-media).
//!
//! Three parts, as for USB:
//! - [`V4l2Device`], the seam **at the ioctl level**: one method per ioctl the capture needs
//!   (QUERYCAP, G_FMT/S_FMT, QUERYCTRL/G_CTRL/S_CTRL, REQBUFS, QBUF/DQBUF on mmap'd
//!   buffers, STREAMON/STREAMOFF), failing with the driver's errno.
//! - [`sys::V4l2Fd`] (Linux): the real device, thin `libc` ioctls (no `v4l`/`v4l2r` crate:
//!   both generate their bindings with bindgen at build time, i.e. libclang on every build
//!   host, for the nine ioctls used here).
//! - `fake::FakeV4l2` (cargo feature `v4l2-fake`, tests only): formats it accepts, controls
//!   with ranges, a buffer queue filled with stacked phase images of a scene, errno on demand.
//!
//! [`camera::V4l2Camera`] runs one capture per cycle over any of them.

pub mod camera;
#[cfg(feature = "v4l2-fake")]
pub mod fake;
#[cfg(target_os = "linux")]
pub mod sys;

use std::time::Duration;

use crate::error::{BridgeError, ErrorKind};
use crate::pixels::PixelPacking;

/// `V4L2_CAP_VIDEO_CAPTURE`.
pub const CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
/// `V4L2_CAP_STREAMING`.
pub const CAP_STREAMING: u32 = 0x0400_0000;
/// `V4L2_CAP_DEVICE_CAPS`: `device_caps` is valid.
pub const CAP_DEVICE_CAPS: u32 = 0x8000_0000;
/// `V4L2_CTRL_FLAG_NEXT_CTRL`: QUERYCTRL returns the next control after the id.
pub const CTRL_FLAG_NEXT_CTRL: u32 = 0x8000_0000;
/// `V4L2_CTRL_FLAG_DISABLED`.
pub const CTRL_FLAG_DISABLED: u32 = 0x0001;
/// `V4L2_BUF_FLAG_ERROR`: the buffer was dequeued but its data is corrupt.
pub const BUF_FLAG_ERROR: u32 = 0x0040;

/// `v4l2_fourcc(a, b, c, d)`.
pub const fn fourcc(code: &[u8; 4]) -> u32 {
    (code[0] as u32) | (code[1] as u32) << 8 | (code[2] as u32) << 16 | (code[3] as u32) << 24
}

/// The raw grey formats a ToF driver delivers, with their packing (`pixels.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum PixelFormat {
    /// `V4L2_PIX_FMT_Y12` (`'Y12 '`): 12 bits in the low bits of a little-endian 16-bit word
    /// (what the Raspberry Pi's unicam writes for the IRS1125's `MEDIA_BUS_FMT_Y12_1X12`).
    #[serde(rename = "Y12")]
    Y12,
    /// `V4L2_PIX_FMT_Y12P` (`'Y12P'`): MIPI CSI-2 RAW12 packing, two pixels in three bytes.
    #[serde(rename = "Y12P")]
    Y12P,
    /// `V4L2_PIX_FMT_Y16` (`'Y16 '`): one 16-bit word per pixel, codes in the low `adc_bits`.
    #[serde(rename = "Y16")]
    Y16,
}

impl PixelFormat {
    /// The fourcc.
    pub fn fourcc(self) -> u32 {
        match self {
            PixelFormat::Y12 => fourcc(b"Y12 "),
            PixelFormat::Y12P => fourcc(b"Y12P"),
            PixelFormat::Y16 => fourcc(b"Y16 "),
        }
    }

    /// How a line's pixels are packed.
    pub fn packing(self) -> PixelPacking {
        match self {
            PixelFormat::Y12P => PixelPacking::Raw12,
            PixelFormat::Y12 | PixelFormat::Y16 => PixelPacking::Raw16,
        }
    }

    /// The format of a fourcc, if it is one of ours.
    pub fn from_fourcc(code: u32) -> Option<Self> {
        [PixelFormat::Y12, PixelFormat::Y12P, PixelFormat::Y16]
            .into_iter()
            .find(|f| f.fourcc() == code)
    }
}

/// A fourcc as its four characters (for messages).
pub fn fourcc_str(code: u32) -> String {
    code.to_le_bytes()
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
        .collect::<String>()
        .trim_end_matches('.')
        .to_string()
}

/// What VIDIOC_QUERYCAP answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Capability {
    /// Driver name (`unicam`, `vivid`, …).
    pub driver: String,
    /// Card name.
    pub card: String,
    /// Bus information.
    pub bus_info: String,
    /// Capabilities of this device node (`device_caps` where valid, else `capabilities`).
    pub device_caps: u32,
}

/// The single-planar pixel format (`struct v4l2_pix_format`, the fields used).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixFormat {
    /// Pixels per line.
    pub width: u32,
    /// Lines per buffer (all stacked images).
    pub height: u32,
    /// Fourcc.
    pub pixelformat: u32,
    /// Bytes from one line to the next (the driver fills it in).
    pub bytesperline: u32,
    /// Bytes of a buffer (the driver fills it in).
    pub sizeimage: u32,
}

/// What VIDIOC_QUERYCTRL answers (`struct v4l2_queryctrl`, the fields used).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControlInfo {
    /// Control id.
    pub id: u32,
    /// Name as the driver spells it (`"Exposure"`, …).
    pub name: String,
    /// Smallest value.
    pub minimum: i32,
    /// Largest value.
    pub maximum: i32,
    /// Step between values.
    pub step: i32,
    /// Flags (`CTRL_FLAG_DISABLED`, …).
    pub flags: u32,
}

/// A buffer VIDIOC_DQBUF handed back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dequeued {
    /// Buffer index.
    pub index: u32,
    /// Bytes of data in it.
    pub bytesused: u32,
    /// Buffer flags (`BUF_FLAG_ERROR`).
    pub flags: u32,
    /// The driver's frame counter.
    pub sequence: u32,
}

/// An ioctl's failure: the errno the driver returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Errno(pub i32);

impl Errno {
    /// `ENOENT`.
    pub const ENOENT: Errno = Errno(libc::ENOENT);
    /// `ENODEV`: the device is gone.
    pub const ENODEV: Errno = Errno(libc::ENODEV);
    /// `EBUSY`: another process streams, or buffers are allocated.
    pub const EBUSY: Errno = Errno(libc::EBUSY);
    /// `EINVAL`: a request the driver does not take.
    pub const EINVAL: Errno = Errno(libc::EINVAL);
    /// `ERANGE`: a control value outside its range.
    pub const ERANGE: Errno = Errno(libc::ERANGE);
    /// `EIO`: the transfer failed.
    pub const EIO: Errno = Errno(libc::EIO);
    /// `EAGAIN`: no buffer ready in time.
    pub const EAGAIN: Errno = Errno(libc::EAGAIN);

    /// The bridge's kind for this errno.
    pub fn kind(self) -> ErrorKind {
        match self.0 {
            libc::ENODEV | libc::ENXIO | libc::ENOENT => ErrorKind::Disconnected,
            libc::EBUSY | libc::EACCES | libc::EPERM => ErrorKind::Access,
            libc::EINVAL | libc::ERANGE | libc::ENOTTY => ErrorKind::Config,
            libc::EAGAIN | libc::ETIMEDOUT => ErrorKind::Timeout,
            libc::EPIPE => ErrorKind::Protocol,
            _ => ErrorKind::Io,
        }
    }

    /// A bridge error for `ioctl` on `device`, keeping the errno as the source.
    pub fn on(self, device: &str, ioctl: &str) -> BridgeError {
        let io = std::io::Error::from_raw_os_error(self.0);
        BridgeError::with_source(self.kind(), format!("{device}: {ioctl}"), io)
    }
}

/// A V4L2 capture device at the ioctl level. Every call blocks; errors are the driver's errno.
/// Buffers are `V4L2_MEMORY_MMAP`, single-planar `V4L2_BUF_TYPE_VIDEO_CAPTURE`.
pub trait V4l2Device: Send {
    /// VIDIOC_QUERYCAP.
    fn querycap(&mut self) -> Result<Capability, Errno>;
    /// VIDIOC_G_FMT.
    fn g_fmt(&mut self) -> Result<PixFormat, Errno>;
    /// VIDIOC_S_FMT: the driver may adjust the format; the adjusted one is returned.
    fn s_fmt(&mut self, format: &PixFormat) -> Result<PixFormat, Errno>;
    /// VIDIOC_QUERYCTRL of `id` (or the control after it with `CTRL_FLAG_NEXT_CTRL`).
    fn queryctrl(&mut self, id: u32) -> Result<ControlInfo, Errno>;
    /// VIDIOC_G_CTRL.
    fn g_ctrl(&mut self, id: u32) -> Result<i32, Errno>;
    /// VIDIOC_S_CTRL: returns the value the driver applied.
    fn s_ctrl(&mut self, id: u32, value: i32) -> Result<i32, Errno>;
    /// VIDIOC_REQBUFS of `count` mmap buffers (0 frees them); the real device maps each
    /// (VIDIOC_QUERYBUF + mmap). Returns the number granted.
    fn reqbufs(&mut self, count: u32) -> Result<u32, Errno>;
    /// VIDIOC_QBUF of buffer `index`.
    fn qbuf(&mut self, index: u32) -> Result<(), Errno>;
    /// Wait up to `timeout` for a filled buffer (poll), then VIDIOC_DQBUF (`EAGAIN`: none).
    fn dqbuf(&mut self, timeout: Duration) -> Result<Dequeued, Errno>;
    /// The mapped memory of buffer `index`.
    fn buffer(&self, index: u32) -> Result<&[u8], Errno>;
    /// VIDIOC_STREAMON.
    fn streamon(&mut self) -> Result<(), Errno>;
    /// VIDIOC_STREAMOFF (also returns every queued buffer to the application).
    fn streamoff(&mut self) -> Result<(), Errno>;
}

/// The control named `name` (case-insensitive), enumerating with `CTRL_FLAG_NEXT_CTRL`.
pub fn find_control(dev: &mut dyn V4l2Device, name: &str) -> Result<Option<ControlInfo>, Errno> {
    let mut id = 0u32;
    loop {
        match dev.queryctrl(id | CTRL_FLAG_NEXT_CTRL) {
            Ok(c) if c.name.eq_ignore_ascii_case(name) => return Ok(Some(c)),
            Ok(c) if c.id <= id => return Ok(None), // a driver that does not advance
            Ok(c) => id = c.id,
            Err(Errno::EINVAL) => return Ok(None), // past the last control
            Err(e) => return Err(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourccs_are_the_kernels() {
        // videodev2.h: V4L2_PIX_FMT_Y12 = v4l2_fourcc('Y','1','2',' ') = 0x20323159
        assert_eq!(PixelFormat::Y12.fourcc(), 0x2032_3159);
        assert_eq!(PixelFormat::Y12P.fourcc(), 0x5032_3159);
        assert_eq!(PixelFormat::Y16.fourcc(), 0x2036_3159);
        assert_eq!(fourcc_str(PixelFormat::Y12.fourcc()), "Y12");
        assert_eq!(
            PixelFormat::from_fourcc(0x5032_3159),
            Some(PixelFormat::Y12P)
        );
        assert_eq!(PixelFormat::from_fourcc(fourcc(b"YUYV")), None);
    }

    #[test]
    fn errnos_map_to_the_bridges_kinds() {
        assert_eq!(Errno::ENODEV.kind(), ErrorKind::Disconnected);
        assert_eq!(Errno::EBUSY.kind(), ErrorKind::Access);
        assert_eq!(Errno::EINVAL.kind(), ErrorKind::Config);
        assert_eq!(Errno::EAGAIN.kind(), ErrorKind::Timeout);
        let e = Errno::ENODEV.on("/dev/video0", "VIDIOC_DQBUF");
        let msg = format!(
            "{e}: {}",
            std::error::Error::source(&e).expect("errno kept")
        );
        assert!(msg.starts_with("/dev/video0: VIDIOC_DQBUF: "), "{msg}");
    }
}
