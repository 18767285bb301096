//! The real V4L2 device: a file descriptor and the ioctls of `linux/videodev2.h`, through
//! `libc` (the structures below are the kernel's UAPI layouts, their sizes asserted against
//! the sizes encoded in the ioctl numbers on 64-bit Linux).
//!
//! The ioctl numbers use the generic Linux encoding (`_IOC`: dir in bits 30–31, size in
//! 16–29, type in 8–15, number in 0–7) of arm, arm64, x86 and riscv — the single-board
//! computers this is for; other encodings (powerpc, mips) are not supported.
//!
//! `unsafe` is allowed in this module only: ioctl, mmap/munmap, poll and open on raw
//! descriptors, each block with its SAFETY argument.
#![allow(unsafe_code)]

use std::ffi::CString;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::ffi::OsStrExt;
use std::path::Path;
use std::time::Duration;

use super::{CAP_DEVICE_CAPS, Capability, ControlInfo, Dequeued, Errno, PixFormat, V4l2Device};

const BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
const MEMORY_MMAP: u32 = 1;
const FIELD_NONE: u32 = 1;

const fn ioc(dir: u32, nr: u32, size: usize) -> libc::c_ulong {
    ((dir << 30) | ((size as u32) << 16) | ((b'V' as u32) << 8) | nr) as libc::c_ulong
}
const fn ior<T>(nr: u32) -> libc::c_ulong {
    ioc(2, nr, size_of::<T>())
}
const fn iow<T>(nr: u32) -> libc::c_ulong {
    ioc(1, nr, size_of::<T>())
}
const fn iowr<T>(nr: u32) -> libc::c_ulong {
    ioc(3, nr, size_of::<T>())
}

/// `struct v4l2_capability`.
#[repr(C)]
#[derive(Default)]
struct RawCapability {
    driver: [u8; 16],
    card: [u8; 32],
    bus_info: [u8; 32],
    version: u32,
    capabilities: u32,
    device_caps: u32,
    reserved: [u32; 3],
}

/// `struct v4l2_pix_format`.
#[repr(C)]
#[derive(Clone, Copy, Default)]
struct RawPixFormat {
    width: u32,
    height: u32,
    pixelformat: u32,
    field: u32,
    bytesperline: u32,
    sizeimage: u32,
    colorspace: u32,
    priv_: u32,
    flags: u32,
    ycbcr_enc: u32,
    quantization: u32,
    xfer_func: u32,
}

/// The union of `struct v4l2_format` (200 bytes, pointer-aligned: it holds `v4l2_window`).
#[repr(C)]
union RawFormatUnion {
    pix: RawPixFormat,
    raw: [u8; 200],
    _align: *mut libc::c_void,
}

/// `struct v4l2_format`.
#[repr(C)]
struct RawFormat {
    type_: u32,
    fmt: RawFormatUnion,
}

/// `struct v4l2_queryctrl`.
#[repr(C)]
#[derive(Default)]
struct RawQueryCtrl {
    id: u32,
    type_: u32,
    name: [u8; 32],
    minimum: i32,
    maximum: i32,
    step: i32,
    default_value: i32,
    flags: u32,
    reserved: [u32; 2],
}

/// `struct v4l2_control`.
#[repr(C)]
#[derive(Default)]
struct RawControl {
    id: u32,
    value: i32,
}

/// `struct v4l2_requestbuffers`.
#[repr(C)]
#[derive(Default)]
struct RawRequestBuffers {
    count: u32,
    type_: u32,
    memory: u32,
    capabilities: u32,
    flags: u8,
    reserved: [u8; 3],
}

/// `struct v4l2_timecode`.
#[repr(C)]
#[derive(Clone, Copy, Default)]
struct RawTimecode {
    type_: u32,
    flags: u32,
    frames: u8,
    seconds: u8,
    minutes: u8,
    hours: u8,
    userbits: [u8; 4],
}

/// `struct v4l2_buffer` (single-planar; `m` holds the mmap offset, pointer-sized).
#[repr(C)]
struct RawBuffer {
    index: u32,
    type_: u32,
    bytesused: u32,
    flags: u32,
    field: u32,
    timestamp: libc::timeval,
    timecode: RawTimecode,
    sequence: u32,
    memory: u32,
    m: libc::c_ulong,
    length: u32,
    reserved2: u32,
    request_fd: i32,
}

#[cfg(target_pointer_width = "64")]
const _: () = {
    // the sizes `linux/videodev2.h` gives on LP64 (they are part of the ioctl numbers)
    assert!(size_of::<RawCapability>() == 104);
    assert!(size_of::<RawFormat>() == 208);
    assert!(size_of::<RawQueryCtrl>() == 68);
    assert!(size_of::<RawControl>() == 8);
    assert!(size_of::<RawRequestBuffers>() == 20);
    assert!(size_of::<RawBuffer>() == 88);
};

const VIDIOC_QUERYCAP: libc::c_ulong = ior::<RawCapability>(0);
const VIDIOC_G_FMT: libc::c_ulong = iowr::<RawFormat>(4);
const VIDIOC_S_FMT: libc::c_ulong = iowr::<RawFormat>(5);
const VIDIOC_REQBUFS: libc::c_ulong = iowr::<RawRequestBuffers>(8);
const VIDIOC_QUERYBUF: libc::c_ulong = iowr::<RawBuffer>(9);
const VIDIOC_QBUF: libc::c_ulong = iowr::<RawBuffer>(15);
const VIDIOC_DQBUF: libc::c_ulong = iowr::<RawBuffer>(17);
const VIDIOC_STREAMON: libc::c_ulong = iow::<libc::c_int>(18);
const VIDIOC_STREAMOFF: libc::c_ulong = iow::<libc::c_int>(19);
const VIDIOC_G_CTRL: libc::c_ulong = iowr::<RawControl>(27);
const VIDIOC_S_CTRL: libc::c_ulong = iowr::<RawControl>(28);
const VIDIOC_QUERYCTRL: libc::c_ulong = iowr::<RawQueryCtrl>(36);

fn last_errno() -> Errno {
    Errno(
        std::io::Error::last_os_error()
            .raw_os_error()
            .unwrap_or(libc::EIO),
    )
}

fn text(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// One mmap'd buffer, unmapped on drop.
struct Mapping {
    ptr: *mut libc::c_void,
    len: usize,
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: `ptr`/`len` are exactly what a successful mmap returned and nothing
        // borrows the mapping any more (its slices borrow `V4l2Fd`, which owns it).
        unsafe { libc::munmap(self.ptr, self.len) };
    }
}

/// An open V4L2 device node.
pub struct V4l2Fd {
    fd: OwnedFd,
    maps: Vec<Mapping>,
}

// SAFETY: the mappings are plain memory owned by this value; the raw pointers are only
// dereferenced through `&self`/`&mut self`, so moving the value to another thread is sound.
unsafe impl Send for V4l2Fd {}

impl V4l2Fd {
    /// Open the node read-write, non-blocking (DQBUF waits in `poll`, bounded).
    pub fn open(path: &Path) -> Result<Self, Errno> {
        let c = CString::new(path.as_os_str().as_bytes()).map_err(|_| Errno::EINVAL)?;
        // SAFETY: `c` is a valid NUL-terminated path; open has no other preconditions.
        let fd = unsafe {
            libc::open(
                c.as_ptr(),
                libc::O_RDWR | libc::O_NONBLOCK | libc::O_CLOEXEC,
            )
        };
        if fd < 0 {
            return Err(last_errno());
        }
        // SAFETY: `fd` was just returned by open and is owned by nobody else.
        let fd = unsafe { OwnedFd::from_raw_fd(fd) };
        Ok(Self {
            fd,
            maps: Vec::new(),
        })
    }

    /// One ioctl with `arg` as its in/out structure, retried on EINTR.
    fn ioctl<T>(&self, request: libc::c_ulong, arg: &mut T) -> Result<(), Errno> {
        loop {
            // SAFETY: `request` encodes `size_of::<T>()` and `T` is the kernel's structure
            // for it (sizes asserted above); `arg` is a valid exclusive reference for the call.
            let r = unsafe { libc::ioctl(self.fd.as_raw_fd(), request as _, arg as *mut T) };
            if r >= 0 {
                return Ok(());
            }
            let e = last_errno();
            if e.0 != libc::EINTR {
                return Err(e);
            }
        }
    }

    fn map_buffer(&self, index: u32) -> Result<Mapping, Errno> {
        let mut b = raw_buffer(index);
        self.ioctl(VIDIOC_QUERYBUF, &mut b)?;
        let len = b.length as usize;
        // SAFETY: a shared read mapping of the offset and length the driver gave for this
        // buffer; the kernel validates both.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ,
                libc::MAP_SHARED,
                self.fd.as_raw_fd(),
                b.m as libc::off_t,
            )
        };
        if ptr == libc::MAP_FAILED {
            return Err(last_errno());
        }
        Ok(Mapping { ptr, len })
    }
}

fn raw_buffer(index: u32) -> RawBuffer {
    RawBuffer {
        index,
        type_: BUF_TYPE_VIDEO_CAPTURE,
        bytesused: 0,
        flags: 0,
        field: 0,
        timestamp: libc::timeval {
            tv_sec: 0,
            tv_usec: 0,
        },
        timecode: RawTimecode::default(),
        sequence: 0,
        memory: MEMORY_MMAP,
        m: 0,
        length: 0,
        reserved2: 0,
        request_fd: 0,
    }
}

fn raw_format(pix: RawPixFormat) -> RawFormat {
    let mut f = RawFormat {
        type_: BUF_TYPE_VIDEO_CAPTURE,
        fmt: RawFormatUnion { raw: [0; 200] },
    };
    f.fmt.pix = pix;
    f
}

fn pix_of(f: &RawFormat) -> PixFormat {
    // SAFETY: the union is initialised (zeroed, then `pix` written by us or the kernel);
    // every bit pattern is a valid `RawPixFormat` (plain u32 fields).
    let p = unsafe { f.fmt.pix };
    PixFormat {
        width: p.width,
        height: p.height,
        pixelformat: p.pixelformat,
        bytesperline: p.bytesperline,
        sizeimage: p.sizeimage,
    }
}

impl V4l2Device for V4l2Fd {
    fn querycap(&mut self) -> Result<Capability, Errno> {
        let mut c = RawCapability::default();
        self.ioctl(VIDIOC_QUERYCAP, &mut c)?;
        let caps = if c.capabilities & CAP_DEVICE_CAPS != 0 {
            c.device_caps
        } else {
            c.capabilities
        };
        Ok(Capability {
            driver: text(&c.driver),
            card: text(&c.card),
            bus_info: text(&c.bus_info),
            device_caps: caps,
        })
    }

    fn g_fmt(&mut self) -> Result<PixFormat, Errno> {
        let mut f = raw_format(RawPixFormat::default());
        self.ioctl(VIDIOC_G_FMT, &mut f)?;
        Ok(pix_of(&f))
    }

    fn s_fmt(&mut self, want: &PixFormat) -> Result<PixFormat, Errno> {
        let mut f = raw_format(RawPixFormat {
            width: want.width,
            height: want.height,
            pixelformat: want.pixelformat,
            field: FIELD_NONE,
            bytesperline: want.bytesperline,
            ..RawPixFormat::default()
        });
        self.ioctl(VIDIOC_S_FMT, &mut f)?;
        Ok(pix_of(&f))
    }

    fn queryctrl(&mut self, id: u32) -> Result<ControlInfo, Errno> {
        let mut q = RawQueryCtrl {
            id,
            ..RawQueryCtrl::default()
        };
        self.ioctl(VIDIOC_QUERYCTRL, &mut q)?;
        Ok(ControlInfo {
            id: q.id,
            name: text(&q.name),
            minimum: q.minimum,
            maximum: q.maximum,
            step: q.step,
            flags: q.flags,
        })
    }

    fn g_ctrl(&mut self, id: u32) -> Result<i32, Errno> {
        let mut c = RawControl { id, value: 0 };
        self.ioctl(VIDIOC_G_CTRL, &mut c)?;
        Ok(c.value)
    }

    fn s_ctrl(&mut self, id: u32, value: i32) -> Result<i32, Errno> {
        let mut c = RawControl { id, value };
        self.ioctl(VIDIOC_S_CTRL, &mut c)?;
        Ok(c.value)
    }

    fn reqbufs(&mut self, count: u32) -> Result<u32, Errno> {
        self.maps.clear();
        let mut r = RawRequestBuffers {
            count,
            type_: BUF_TYPE_VIDEO_CAPTURE,
            memory: MEMORY_MMAP,
            ..RawRequestBuffers::default()
        };
        self.ioctl(VIDIOC_REQBUFS, &mut r)?;
        self.maps = (0..r.count)
            .map(|i| self.map_buffer(i))
            .collect::<Result<_, _>>()?;
        Ok(r.count)
    }

    fn qbuf(&mut self, index: u32) -> Result<(), Errno> {
        self.ioctl(VIDIOC_QBUF, &mut raw_buffer(index))
    }

    fn dqbuf(&mut self, timeout: Duration) -> Result<Dequeued, Errno> {
        let mut p = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let ms = libc::c_int::try_from(timeout.as_millis()).unwrap_or(libc::c_int::MAX);
        // SAFETY: one valid pollfd for the duration of the call.
        let n = unsafe { libc::poll(&mut p, 1, ms) };
        if n < 0 {
            return Err(last_errno());
        }
        if p.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0
            && p.revents & libc::POLLIN == 0
        {
            return Err(Errno::ENODEV);
        }
        let mut b = raw_buffer(0);
        self.ioctl(VIDIOC_DQBUF, &mut b)?; // EAGAIN when poll timed out
        Ok(Dequeued {
            index: b.index,
            bytesused: b.bytesused,
            flags: b.flags,
            sequence: b.sequence,
        })
    }

    fn buffer(&self, index: u32) -> Result<&[u8], Errno> {
        let m = self.maps.get(index as usize).ok_or(Errno::EINVAL)?;
        // SAFETY: a live PROT_READ mapping of `len` bytes owned by `self`; the returned slice
        // borrows `self`, so the mapping outlives it (dropped only by `reqbufs` / drop, which
        // need `&mut self` / ownership).
        Ok(unsafe { std::slice::from_raw_parts(m.ptr.cast::<u8>(), m.len) })
    }

    fn streamon(&mut self) -> Result<(), Errno> {
        let mut t = BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        self.ioctl(VIDIOC_STREAMON, &mut t)
    }

    fn streamoff(&mut self) -> Result<(), Errno> {
        let mut t = BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        self.ioctl(VIDIOC_STREAMOFF, &mut t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ioctl_numbers_are_the_kernels() {
        // linux/videodev2.h on LP64, as `printf("%#lx", VIDIOC_…)` prints them
        #[cfg(target_pointer_width = "64")]
        {
            assert_eq!(VIDIOC_QUERYCAP, 0x8068_5600);
            assert_eq!(VIDIOC_S_FMT, 0xc0d0_5605);
            assert_eq!(VIDIOC_REQBUFS, 0xc014_5608);
            assert_eq!(VIDIOC_QBUF, 0xc058_560f);
            assert_eq!(VIDIOC_DQBUF, 0xc058_5611);
            assert_eq!(VIDIOC_STREAMON, 0x4004_5612);
            assert_eq!(VIDIOC_S_CTRL, 0xc008_561c);
            assert_eq!(VIDIOC_QUERYCTRL, 0xc044_5624);
        }
    }

    #[test]
    fn a_missing_node_is_enoent_and_a_non_v4l2_file_is_enotty() {
        let Err(e) = V4l2Fd::open(Path::new("/dev/nonexistent-video-node")) else {
            panic!("opened a missing node");
        };
        assert_eq!(e, Errno::ENOENT);
        let mut dev = V4l2Fd::open(Path::new("/dev/null")).expect("open /dev/null");
        assert_eq!(dev.querycap().unwrap_err(), Errno(libc::ENOTTY));
    }
}
