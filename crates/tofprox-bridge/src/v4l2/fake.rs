//! A fake V4L2 ToF device at the ioctl level (cargo feature `v4l2-fake`; tests only): the
//! formats it accepts, integer controls with ranges, a buffer queue filled with the stacked
//! phase images of a [`FakeScene`], and errno on demand through a [`FakeHandle`] shared with
//! the test (a failing ioctl, a device that vanishes mid-stream and comes back).
//!
//! It behaves as the V4L2 core does where a client can get it wrong: S_FMT and REQBUFS while
//! streaming are `EBUSY`, DQBUF before STREAMON or with nothing queued is `EINVAL`, a control
//! outside its range is `ERANGE`, STREAMOFF hands every queued buffer back.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use ndarray::Array3;

use super::{
    CAP_DEVICE_CAPS, CAP_STREAMING, CAP_VIDEO_CAPTURE, CTRL_FLAG_NEXT_CTRL, Capability,
    ControlInfo, Dequeued, Errno, PixFormat, PixelFormat, V4l2Device,
};
use crate::clock::Clock;
use crate::pixels::{BufferLayout, encode_buffer};

/// What a scene is asked for one sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneRequest {
    /// Raw images in the sequence.
    pub images: usize,
    /// Lines per image.
    pub rows: usize,
    /// Pixels per line.
    pub cols: usize,
    /// Values of every control at the trigger, by name.
    pub controls: HashMap<String, i32>,
    /// The sequence number of the frame.
    pub sequence: u32,
}

/// Makes the stacked phase images of one sequence as `(images, rows, cols)` codes.
pub trait FakeScene: Send {
    /// The codes of one sequence.
    fn images(&mut self, req: &SceneRequest) -> Array3<u16>;
}

/// The ioctls faults can be injected into.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Ioctl {
    /// VIDIOC_S_FMT.
    SFmt,
    /// VIDIOC_S_CTRL.
    SCtrl,
    /// VIDIOC_REQBUFS.
    Reqbufs,
    /// VIDIOC_QBUF.
    Qbuf,
    /// VIDIOC_DQBUF.
    Dqbuf,
    /// VIDIOC_STREAMON.
    Streamon,
}

#[derive(Debug, Default)]
struct Faults {
    once: HashMap<Ioctl, Errno>,
    gone: bool,
    vanish_after_frames: Option<u32>,
    frames: u32,
    streamons: u32,
    streamoffs: u32,
}

/// The test's side of a fake: faults to inject and what the device saw. Clones share state.
#[derive(Debug, Clone, Default)]
pub struct FakeHandle(Arc<Mutex<Faults>>);

impl FakeHandle {
    fn lock(&self) -> MutexGuard<'_, Faults> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
    /// The next `ioctl` fails once with `errno`.
    pub fn fail_next(&self, ioctl: Ioctl, errno: Errno) {
        self.lock().once.insert(ioctl, errno);
    }
    /// The device vanishes after delivering `frames` more frames: every later ioctl is
    /// `ENODEV` and opening it `ENOENT`, until [`FakeHandle::replug`].
    pub fn vanish_after(&self, frames: u32) {
        let mut f = self.lock();
        f.vanish_after_frames = Some(f.frames + frames);
    }
    /// The device is back (a new open succeeds).
    pub fn replug(&self) {
        let mut f = self.lock();
        f.gone = false;
        f.vanish_after_frames = None;
    }
    /// Whether the device is gone.
    pub fn is_gone(&self) -> bool {
        self.lock().gone
    }
    /// Frames delivered so far.
    pub fn frames(&self) -> u32 {
        self.lock().frames
    }
    /// STREAMON and STREAMOFF calls so far.
    pub fn stream_calls(&self) -> (u32, u32) {
        let f = self.lock();
        (f.streamons, f.streamoffs)
    }
    /// Take an injected fault of `ioctl`, or `ENODEV` when gone.
    fn check(&self, ioctl: Ioctl) -> Result<(), Errno> {
        let mut f = self.lock();
        if f.gone {
            return Err(Errno::ENODEV);
        }
        f.once.remove(&ioctl).map_or(Ok(()), Err)
    }
}

/// One integer control of the fake.
#[derive(Debug, Clone)]
pub struct FakeControl {
    /// Its description (id, name, range).
    pub info: ControlInfo,
    /// Its value.
    pub value: i32,
}

impl FakeControl {
    /// An enabled integer control of step 1 in `range`, at `value`.
    pub fn integer(id: u32, name: &str, range: std::ops::RangeInclusive<i32>, value: i32) -> Self {
        let info = ControlInfo {
            id,
            name: name.into(),
            minimum: *range.start(),
            maximum: *range.end(),
            step: 1,
            flags: 0,
        };
        Self { info, value }
    }
}

/// How the fake device is made: the driver's one format and its controls.
pub struct FakeSpec {
    /// The format it delivers (S_FMT answers with this whatever is asked).
    pub format: PixelFormat,
    /// Pixels per line.
    pub cols: u32,
    /// Lines of one image.
    pub rows: u32,
    /// Images stacked per buffer.
    pub images: u32,
    /// Line padding bytes the driver adds (its stride).
    pub pad_bytes: u32,
    /// ADC bits of the codes.
    pub adc_bits: u8,
    /// Integer controls.
    pub controls: Vec<FakeControl>,
    /// Time one sequence takes from trigger to buffer (slept on `clock`).
    pub frame_time: Duration,
}

/// The fake device (one open file descriptor).
pub struct FakeV4l2 {
    spec: Arc<FakeSpecShared>,
    handle: FakeHandle,
    buffers: Vec<Vec<u8>>,
    queued: VecDeque<u32>,
    streaming: bool,
    controls: Vec<FakeControl>,
}

struct FakeSpecShared {
    spec: FakeSpec,
    scene: Mutex<Box<dyn FakeScene>>,
    clock: Arc<dyn Clock>,
}

/// Opens new file descriptors of one fake device (the state of its faults survives them).
#[derive(Clone)]
pub struct FakeDevice {
    shared: Arc<FakeSpecShared>,
    handle: FakeHandle,
}

impl FakeDevice {
    /// A fake of `spec` whose frames come from `scene`, taking time on `clock`.
    pub fn new(spec: FakeSpec, scene: Box<dyn FakeScene>, clock: Arc<dyn Clock>) -> Self {
        let shared = FakeSpecShared {
            spec,
            scene: Mutex::new(scene),
            clock,
        };
        Self {
            shared: Arc::new(shared),
            handle: FakeHandle::default(),
        }
    }
    /// The test's handle.
    pub fn handle(&self) -> FakeHandle {
        self.handle.clone()
    }
    /// open(2): `ENOENT` while the device is gone.
    pub fn open(&self) -> Result<FakeV4l2, Errno> {
        if self.handle.is_gone() {
            return Err(Errno::ENOENT);
        }
        Ok(FakeV4l2 {
            controls: self.shared.spec.controls.clone(),
            spec: self.shared.clone(),
            handle: self.handle.clone(),
            buffers: Vec::new(),
            queued: VecDeque::new(),
            streaming: false,
        })
    }
}

impl FakeV4l2 {
    fn format(&self) -> PixFormat {
        let s = &self.spec.spec;
        let line = s.format.packing().line_bytes(s.cols as usize) as u32;
        let bytesperline = line + s.pad_bytes;
        PixFormat {
            width: s.cols,
            height: s.rows * s.images,
            pixelformat: s.format.fourcc(),
            bytesperline,
            sizeimage: bytesperline * s.rows * s.images,
        }
    }

    fn layout(&self) -> BufferLayout {
        let s = &self.spec.spec;
        BufferLayout {
            packing: s.format.packing(),
            cols: s.cols as usize,
            rows: s.rows as usize,
            images: s.images as usize,
            stride_bytes: Some(self.format().bytesperline as usize),
            adc_bits: s.adc_bits,
        }
    }

    /// Fill buffer `index` with the next sequence of the scene.
    fn fill(&mut self, index: u32, sequence: u32) -> Result<u32, Errno> {
        let s = &self.spec.spec;
        let req = SceneRequest {
            images: s.images as usize,
            rows: s.rows as usize,
            cols: s.cols as usize,
            controls: self
                .controls
                .iter()
                .map(|c| (c.info.name.clone(), c.value))
                .collect(),
            sequence,
        };
        let codes = self
            .spec
            .scene
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .images(&req);
        let bytes = encode_buffer(&codes, &self.layout()).map_err(|_| Errno::EIO)?;
        let buf = self.buffers.get_mut(index as usize).ok_or(Errno::EINVAL)?;
        let n = bytes.len().min(buf.len());
        buf[..n].copy_from_slice(&bytes[..n]);
        Ok(n as u32)
    }
}

impl V4l2Device for FakeV4l2 {
    fn querycap(&mut self) -> Result<Capability, Errno> {
        if self.handle.is_gone() {
            return Err(Errno::ENODEV);
        }
        Ok(Capability {
            driver: "fake-tof".into(),
            card: "fake IRS1125-class ToF".into(),
            bus_info: "platform:fake".into(),
            device_caps: CAP_VIDEO_CAPTURE | CAP_STREAMING | CAP_DEVICE_CAPS,
        })
    }

    fn g_fmt(&mut self) -> Result<PixFormat, Errno> {
        Ok(self.format())
    }

    fn s_fmt(&mut self, _want: &PixFormat) -> Result<PixFormat, Errno> {
        self.handle.check(Ioctl::SFmt)?;
        if self.streaming || !self.buffers.is_empty() {
            return Err(Errno::EBUSY);
        }
        Ok(self.format()) // one format only, as the IRS1125 driver
    }

    fn queryctrl(&mut self, id: u32) -> Result<ControlInfo, Errno> {
        let found = if id & CTRL_FLAG_NEXT_CTRL != 0 {
            let after = id & !CTRL_FLAG_NEXT_CTRL;
            self.controls
                .iter()
                .filter(|c| c.info.id > after)
                .min_by_key(|c| c.info.id)
        } else {
            self.controls.iter().find(|c| c.info.id == id)
        };
        found.map(|c| c.info.clone()).ok_or(Errno::EINVAL)
    }

    fn g_ctrl(&mut self, id: u32) -> Result<i32, Errno> {
        let c = self.controls.iter().find(|c| c.info.id == id);
        c.map(|c| c.value).ok_or(Errno::EINVAL)
    }

    fn s_ctrl(&mut self, id: u32, value: i32) -> Result<i32, Errno> {
        self.handle.check(Ioctl::SCtrl)?;
        let c = self.controls.iter_mut().find(|c| c.info.id == id);
        let c = c.ok_or(Errno::EINVAL)?;
        if !(c.info.minimum..=c.info.maximum).contains(&value) {
            return Err(Errno::ERANGE);
        }
        let step = c.info.step.max(1);
        c.value = c.info.minimum + (value - c.info.minimum) / step * step;
        Ok(c.value)
    }

    fn reqbufs(&mut self, count: u32) -> Result<u32, Errno> {
        self.handle.check(Ioctl::Reqbufs)?;
        if self.streaming {
            return Err(Errno::EBUSY);
        }
        let size = self.format().sizeimage as usize;
        self.buffers = vec![vec![0; size]; count.min(8) as usize];
        self.queued.clear();
        Ok(self.buffers.len() as u32)
    }

    fn qbuf(&mut self, index: u32) -> Result<(), Errno> {
        self.handle.check(Ioctl::Qbuf)?;
        if index as usize >= self.buffers.len() || self.queued.contains(&index) {
            return Err(Errno::EINVAL);
        }
        self.queued.push_back(index);
        Ok(())
    }

    fn dqbuf(&mut self, _timeout: Duration) -> Result<Dequeued, Errno> {
        self.handle.check(Ioctl::Dqbuf)?;
        if !self.streaming {
            return Err(Errno::EINVAL);
        }
        let index = self.queued.pop_front().ok_or(Errno::EINVAL)?;
        self.spec.clock.sleep(self.spec.spec.frame_time);
        let sequence = {
            let mut f = self.handle.lock();
            if f.vanish_after_frames.is_some_and(|n| f.frames >= n) {
                f.gone = true;
                return Err(Errno::ENODEV);
            }
            f.frames += 1;
            f.frames - 1
        };
        let bytesused = self.fill(index, sequence)?;
        Ok(Dequeued {
            index,
            bytesused,
            flags: 0,
            sequence,
        })
    }

    fn buffer(&self, index: u32) -> Result<&[u8], Errno> {
        self.buffers
            .get(index as usize)
            .map(Vec::as_slice)
            .ok_or(Errno::EINVAL)
    }

    fn streamon(&mut self) -> Result<(), Errno> {
        self.handle.check(Ioctl::Streamon)?;
        if self.buffers.is_empty() {
            return Err(Errno::EINVAL);
        }
        self.streaming = true;
        self.handle.lock().streamons += 1;
        Ok(())
    }

    fn streamoff(&mut self) -> Result<(), Errno> {
        if self.handle.is_gone() {
            return Err(Errno::ENODEV);
        }
        self.streaming = false;
        self.queued.clear();
        self.handle.lock().streamoffs += 1;
        Ok(())
    }
}
