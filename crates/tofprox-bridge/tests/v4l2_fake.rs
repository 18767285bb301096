//! The V4L2 camera over the fake device (ioctl level): the stacked buffer becomes the exact
//! codes that made it, the exposure goes through the control, the stream is off between
//! cycles, and the failures a real driver gives (wrong format, EBUSY, a device vanishing
//! mid-stream) are clear errors naming the device, never frames.

use std::sync::Arc;
use std::time::Duration;

use ndarray::Array3;
use tofprox_bridge::v4l2::camera::{V4l2Camera, V4l2Settings};
use tofprox_bridge::v4l2::fake::{
    FakeControl, FakeDevice, FakeScene, FakeSpec, Ioctl, SceneRequest,
};
use tofprox_bridge::v4l2::{Errno, PixelFormat};
use tofprox_bridge::{Clock, ErrorKind, VirtualClock};

/// Codes that differ per image, row and column, with the exposure control's value in them,
/// so a misplaced image, line or nibble shows.
struct Pattern;

fn pattern(k: usize, r: usize, c: usize, exposure: i32) -> u16 {
    ((k * 1031 + r * 67 + c * 13 + exposure as usize) % 4096) as u16
}

impl FakeScene for Pattern {
    fn images(&mut self, req: &SceneRequest) -> Array3<u16> {
        let e = req.controls.get("Exposure").copied().unwrap_or(0);
        Array3::from_shape_fn((req.images, req.rows, req.cols), |(k, r, c)| {
            pattern(k, r, c, e)
        })
    }
}

fn fake(format: PixelFormat, clock: Arc<dyn Clock>) -> FakeDevice {
    fake_of(format, 4, clock)
}

fn fake_of(format: PixelFormat, images: u32, clock: Arc<dyn Clock>) -> FakeDevice {
    let spec = FakeSpec {
        format,
        cols: 10,
        rows: 6,
        images,
        pad_bytes: 4,
        adc_bits: 12,
        controls: vec![
            FakeControl::integer(0x0098_0911, "Exposure", 10..=2000, 10),
            FakeControl::integer(0x009a_0901, "Modulation Frequency", 10..=100, 10),
        ],
        frame_time: Duration::from_millis(30),
    };
    FakeDevice::new(spec, Box::new(Pattern), clock)
}

fn settings(format: PixelFormat) -> V4l2Settings {
    V4l2Settings {
        device: "/dev/video7".into(),
        pixel_format: format,
        width: 10,
        rows: 6,
        images: 4,
        exposure_controls: vec!["exposure".into()], // names compare case-insensitively
        ..V4l2Settings::default()
    }
}

#[test]
fn stacked_buffers_decode_to_the_codes_that_made_them() {
    for format in [PixelFormat::Y12, PixelFormat::Y12P] {
        let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
        let dev = fake(format, clock.clone());
        let handle = dev.handle();
        let mut cam = V4l2Camera::open(dev.open().unwrap(), settings(format), clock).unwrap();
        for (cycle, exposure_us) in [(1, 250.0), (2, 5000.0)] {
            let cap = cam.capture(exposure_us, None).unwrap();
            // the control's range is 10..=2000 µs: 5000 is clamped, and reported as applied
            let applied = exposure_us.min(2000.0);
            assert_eq!(cap.exposure_us, applied);
            let want =
                Array3::from_shape_fn((4, 6, 10), |(k, r, c)| pattern(k, r, c, applied as i32));
            assert_eq!(cap.frames, want, "{format:?}");
            assert_eq!(cap.phases_deg, vec![0.0, 90.0, 180.0, 270.0]);
            assert_eq!(cap.modulation_hz, 80e6);
            assert_eq!(cap.timings.to_frame, Duration::from_millis(30));
            // one stream per cycle: on, one frame, off
            assert_eq!(handle.stream_calls(), (cycle, cycle));
        }
        cam.close().unwrap();
    }
}

#[test]
fn a_sequence_starting_with_a_grey_image_gives_its_phase_images() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let dev = fake_of(PixelFormat::Y16, 5, clock.clone());
    let mut s = settings(PixelFormat::Y16);
    (s.images, s.first_phase_image) = (5, 1);
    let mut cam = V4l2Camera::open(dev.open().unwrap(), s, clock).unwrap();
    let cap = cam.capture(300.0, None).unwrap();
    let want = Array3::from_shape_fn((4, 6, 10), |(k, r, c)| pattern(k + 1, r, c, 300));
    assert_eq!(cap.frames, want);
}

#[test]
fn a_format_the_driver_does_not_give_is_refused_naming_both() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let dev = fake(PixelFormat::Y12P, clock.clone());
    let Err(e) = V4l2Camera::open(dev.open().unwrap(), settings(PixelFormat::Y12), clock) else {
        panic!("opened with the wrong format");
    };
    assert_eq!(e.kind(), ErrorKind::Config);
    let msg = e.to_string();
    assert!(msg.contains("/dev/video7: asked Y12 10x24"), "{msg}");
    assert!(msg.contains("the driver gives Y12P 10x24"), "{msg}");
}

#[test]
fn a_missing_control_is_refused_naming_the_key() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let dev = fake(PixelFormat::Y12, clock.clone());
    let mut s = settings(PixelFormat::Y12);
    s.exposure_controls = vec!["Integration Time".into()];
    let Err(e) = V4l2Camera::open(dev.open().unwrap(), s, clock) else {
        panic!("opened without the control");
    };
    let msg = e.to_string();
    assert!(
        msg.contains("v4l2.exposure_controls = \"Integration Time\""),
        "{msg}"
    );
}

#[test]
fn a_second_frequency_needs_the_modulation_control() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let dev = fake(PixelFormat::Y12, clock.clone());
    let mut cam = V4l2Camera::open(
        dev.open().unwrap(),
        settings(PixelFormat::Y12),
        clock.clone(),
    )
    .unwrap();
    let e = cam.capture(100.0, Some(70e6)).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Config);
    assert!(e.to_string().contains("no v4l2.modulation_control"), "{e}");

    let mut s = settings(PixelFormat::Y12);
    s.modulation_control = "Modulation Frequency".into();
    let mut cam = V4l2Camera::open(dev.open().unwrap(), s, clock).unwrap();
    assert_eq!(cam.capture(100.0, Some(70e6)).unwrap().modulation_hz, 70e6);
    assert_eq!(cam.capture(100.0, None).unwrap().modulation_hz, 80e6);
}

#[test]
fn busy_and_vanishing_devices_are_errors_naming_the_device() {
    let clock: Arc<dyn Clock> = Arc::new(VirtualClock::new());
    let dev = fake(PixelFormat::Y12, clock.clone());
    let handle = dev.handle();
    let mut cam = V4l2Camera::open(
        dev.open().unwrap(),
        settings(PixelFormat::Y12),
        clock.clone(),
    )
    .unwrap();
    handle.fail_next(Ioctl::Streamon, Errno::EBUSY);
    let e = cam.capture(100.0, None).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Access);
    assert!(
        e.to_string().starts_with("/dev/video7: VIDIOC_STREAMON"),
        "{e}"
    );
    // the failed cycle still stopped the stream: the next one runs
    cam.capture(100.0, None).unwrap();

    handle.vanish_after(1);
    cam.capture(100.0, None).unwrap();
    let e = cam.capture(100.0, None).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected);
    assert!(
        e.to_string().starts_with("/dev/video7: VIDIOC_DQBUF"),
        "{e}"
    );
    assert_eq!(
        dev.open().err(),
        Some(Errno::ENOENT),
        "gone until replugged"
    );
    handle.replug();
    let mut cam = V4l2Camera::open(dev.open().unwrap(), settings(PixelFormat::Y12), clock).unwrap();
    cam.capture(100.0, None).unwrap();
}
