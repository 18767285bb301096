//! A captured USB video stream → raw phase captures (pure, no I/O): `tofprox device decode`.
//!
//! Transfers of one bulk-IN endpoint ([`crate::usbcap`]) → UVC payloads reassembled into frames
//! ([`crate::uvc::Reassembler`]: FID toggles, EOF closes) → pixel codes ([`crate::pixels`]) →
//! captures of `images_per_capture` consecutive raw images.
//!
//! Which raw image of a sequence a frame holds must be known, never guessed: a buffer that
//! stacks the whole sequence carries it by position; a frame with our status line carries its
//! `raw_index`. A stream of single images without either is grouped from its first frame and
//! refused as soon as a frame was lost (the phases after the gap are unknown).

use ndarray::{Array3, Axis, concatenate};

use crate::frame::StatusLine;
use crate::pixels::{BufferLayout, PixelError, decode_buffer};
use crate::usbcap::{BulkIn, busiest_endpoint};
use crate::uvc::{FrameSpec, Push, Reassembler, ReassemblyStats};

/// How the stream was taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamSpec {
    /// One frame's pixel buffer (its stacked images included).
    pub layout: BufferLayout,
    /// Each frame starts with the emulated CX3's status line (one line of RAW16 words).
    pub status_line: bool,
    /// Raw images per capture (the mode's: 2 for 2-phase, 4 for 4-phase).
    pub images_per_capture: usize,
    /// The endpoint `(bus, device, endpoint)`; `None`: the one that carried the most bytes.
    pub endpoint: Option<(u16, u8, u8)>,
}

/// One capture: its raw images and the time of the transfer that completed its first frame.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedCapture {
    /// Capture time, ns since the capture file's epoch.
    pub time_ns: u64,
    /// `(images_per_capture, rows, cols)` codes.
    pub frames: Array3<u16>,
}

/// The decoded stream.
#[derive(Debug, Clone)]
pub struct Decoded {
    /// The endpoint decoded.
    pub endpoint: (u16, u8, u8),
    /// Complete captures, in order.
    pub captures: Vec<DecodedCapture>,
    /// What the reassembler saw and dropped.
    pub reassembly: ReassemblyStats,
    /// Raw images at the end that did not complete a capture (dropped).
    pub tail_images: usize,
}

/// Why a stream cannot be decoded.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// No bulk-IN transfer in the capture (or none of the asked endpoint).
    #[error("no completed bulk-IN transfer{0}")]
    NoStream(String),
    /// A frame's pixels are not what the layout says.
    #[error("frame {frame}: {source}")]
    Pixels {
        /// Index of the reassembled frame.
        frame: usize,
        /// The pixel error.
        #[source]
        source: PixelError,
    },
    /// A status line is missing, malformed or out of sequence.
    #[error("frame {frame}: {reason}")]
    StatusLine {
        /// Index of the reassembled frame.
        frame: usize,
        /// What is wrong.
        reason: String,
    },
    /// Frames were lost in a stream that carries no image index.
    #[error(
        "{0} frame(s) lost in a stream of single images without an image index: the phase of \
         the images after a gap is unknown (capture stacked buffers, or with the status line)"
    )]
    LostWithoutIndex(u64),
    /// Nothing complete.
    #[error("no complete capture: {frames} frame(s) decoded, {per} raw images per capture")]
    NoCapture {
        /// Frames decoded.
        frames: usize,
        /// Images per capture.
        per: usize,
    },
    /// An impossible spec.
    #[error("{0}")]
    Spec(&'static str),
}

/// Decode the transfers of a capture file into raw captures.
pub fn decode_stream(transfers: &[BulkIn], spec: &StreamSpec) -> Result<Decoded, DecodeError> {
    let l = &spec.layout;
    let buffer_bytes = l
        .validate()
        .map_err(|source| DecodeError::Pixels { frame: 0, source })?;
    if spec.images_per_capture == 0 || (l.images > 1 && l.images != spec.images_per_capture) {
        return Err(DecodeError::Spec(
            "a stacked buffer must hold exactly the images of one capture",
        ));
    }
    if spec.status_line && l.packing != crate::pixels::PixelPacking::Raw16 {
        return Err(DecodeError::Spec(
            "the status line exists only with RAW16 frames",
        ));
    }
    let endpoint = match spec.endpoint {
        Some(e) => e,
        None => busiest_endpoint(transfers).ok_or_else(|| DecodeError::NoStream(String::new()))?,
    };
    let head = if spec.status_line { l.cols * 2 } else { 0 };
    let mut r = Reassembler::new(FrameSpec {
        frame_bytes: head + buffer_bytes,
        pad_align: 1,
    });
    let mut images = Vec::new(); // (time, raw index if known, image)
    let mut n_frames = 0usize;
    let ours = transfers
        .iter()
        .filter(|t| (t.bus, t.device, t.endpoint) == endpoint);
    for t in ours {
        if let Push::Frame(f) = r.push(&t.data) {
            let (status, codes) = frame_codes(f, head, spec, n_frames)?;
            for (k, img) in codes.axis_iter(Axis(0)).enumerate() {
                let index = status.map(|s| usize::from(s.raw_index) + k);
                images.push((t.time_ns, index, img.insert_axis(Axis(0)).to_owned()));
            }
            n_frames += 1;
        }
    }
    if r.stats().payloads == 0 {
        return Err(DecodeError::NoStream(format!(" on endpoint {endpoint:?}")));
    }
    let stats = r.stats();
    let unindexed = !spec.status_line && l.images == 1 && spec.images_per_capture > 1;
    if unindexed && stats.frames_dropped > 0 {
        return Err(DecodeError::LostWithoutIndex(stats.frames_dropped));
    }
    let (captures, tail_images) = group(images, spec.images_per_capture);
    if captures.is_empty() {
        let per = spec.images_per_capture;
        return Err(DecodeError::NoCapture {
            frames: n_frames,
            per,
        });
    }
    Ok(Decoded {
        endpoint,
        captures,
        reassembly: stats,
        tail_images,
    })
}

/// One reassembled frame → its status line (if any) and `(images, rows, cols)` codes.
fn frame_codes(
    f: &[u8],
    head: usize,
    spec: &StreamSpec,
    frame: usize,
) -> Result<(Option<StatusLine>, Array3<u16>), DecodeError> {
    let (line, pixels) = f.split_at(head);
    let status = if spec.status_line {
        let s = StatusLine::decode(line).ok_or_else(|| DecodeError::StatusLine {
            frame,
            reason: "malformed status line".into(),
        })?;
        if crc32fast::hash(pixels) != s.crc32 {
            let reason = "pixel CRC differs from the status line's".into();
            return Err(DecodeError::StatusLine { frame, reason });
        }
        Some(s)
    } else {
        None
    };
    let codes = decode_buffer(pixels, &spec.layout)
        .map_err(|source| DecodeError::Pixels { frame, source })?;
    Ok((status, codes))
}

type Image = (u64, Option<usize>, Array3<u16>);

/// Consecutive images → captures of `per`; with known indices a capture is exactly the images
/// `0..per` in order (anything else is skipped up to the next index 0).
fn group(images: Vec<Image>, per: usize) -> (Vec<DecodedCapture>, usize) {
    let mut out = Vec::new();
    let mut run: Vec<Image> = Vec::with_capacity(per);
    for img in images {
        let expected = run.len();
        match img.1 {
            Some(i) if i != expected => {
                run.clear();
                if i == 0 {
                    run.push(img);
                }
            }
            _ => run.push(img),
        }
        if run.len() == per {
            let views: Vec<_> = run.iter().map(|(_, _, a)| a.view()).collect();
            if let Ok(frames) = concatenate(Axis(0), &views) {
                out.push(DecodedCapture {
                    time_ns: run[0].0,
                    frames,
                });
            }
            run.clear();
        }
    }
    (out, run.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pixels::{PixelPacking, encode_buffer};
    use crate::uvc::split_frame;

    fn layout(packing: PixelPacking, images: usize) -> BufferLayout {
        BufferLayout {
            packing,
            cols: 12,
            rows: 3,
            images,
            stride_bytes: None,
            adc_bits: 12,
        }
    }

    fn codes(seed: usize, images: usize) -> Array3<u16> {
        Array3::from_shape_fn((images, 3, 12), |(k, r, c)| {
            ((seed * 977 + k * 131 + r * 17 + c * 5) % 4096) as u16
        })
    }

    /// Frames → UVC payloads (FID toggling, EOF on the last) → bulk-IN transfers, with a
    /// control transfer of another endpoint in between.
    fn stream(frames: &[Vec<u8>], max_payload: usize) -> Vec<BulkIn> {
        let mut out = Vec::new();
        for (i, f) in frames.iter().enumerate() {
            for p in split_frame(f, i % 2 == 1, i as u32, max_payload) {
                out.push(BulkIn {
                    time_ns: 1000 * out.len() as u64,
                    bus: 1,
                    device: 4,
                    endpoint: 0x83,
                    data: p,
                });
            }
            out.push(BulkIn {
                time_ns: 0,
                bus: 1,
                device: 4,
                endpoint: 0x81,
                data: vec![0; 4],
            });
        }
        out
    }

    /// `n` known buffers of `images` stacked images each, encoded without a status line, and
    /// the spec that decodes them (one capture per buffer).
    fn unindexed(
        packing: PixelPacking,
        images: usize,
        n: usize,
        endpoint: Option<(u16, u8, u8)>,
    ) -> (Vec<Array3<u16>>, Vec<Vec<u8>>, StreamSpec) {
        let l = layout(packing, images);
        let truth: Vec<_> = (0..n).map(|s| codes(s, images)).collect();
        let frames = truth
            .iter()
            .map(|c| encode_buffer(c, &l).unwrap())
            .collect();
        let spec = StreamSpec {
            layout: l,
            status_line: false,
            images_per_capture: images,
            endpoint,
        };
        (truth, frames, spec)
    }

    /// Issue 35 N5: the layout is checked before the reassembler sizes its buffer from it.
    #[test]
    fn a_huge_layout_is_refused_before_reassembly() {
        let (_, frames, mut spec) = unindexed(PixelPacking::Raw16, 1, 1, None);
        let s = stream(&frames, 40);
        spec.layout.cols = 4_611_686_018_427_387_904;
        assert!(matches!(
            decode_stream(&s, &spec),
            Err(DecodeError::Pixels {
                source: PixelError::Layout(_),
                ..
            })
        ));
        spec.layout.cols = 12;
        spec.layout.stride_bytes = Some(usize::MAX);
        assert!(matches!(
            decode_stream(&s, &spec),
            Err(DecodeError::Pixels {
                source: PixelError::Layout(_),
                ..
            })
        ));
    }

    #[test]
    fn stacked_raw12_buffers_become_captures() {
        let (truth, frames, spec) = unindexed(PixelPacking::Raw12, 4, 3, None);
        let d = decode_stream(&stream(&frames, 40), &spec).unwrap();
        assert_eq!(d.endpoint, (1, 4, 0x83));
        assert_eq!(d.captures.len(), 3);
        for (c, t) in d.captures.iter().zip(&truth) {
            assert_eq!(&c.frames, t);
        }
        assert_eq!((d.tail_images, d.reassembly.frames_dropped), (0, 0));
    }

    #[test]
    fn single_images_group_and_a_lost_frame_is_refused() {
        let (truth, frames, mut spec) = unindexed(PixelPacking::Raw16, 1, 5, Some((1, 4, 0x83)));
        spec.images_per_capture = 2;
        let d = decode_stream(&stream(&frames, 20), &spec).unwrap();
        assert_eq!((d.captures.len(), d.tail_images), (2, 1));
        assert_eq!(
            d.captures[1].frames.index_axis(Axis(0), 1),
            truth[3].index_axis(Axis(0), 0)
        );
        // lose one payload in the middle of frame 2: its frame is torn, the phases after unknown
        let mut s = stream(&frames, 20);
        let victim = s
            .iter()
            .position(|t| t.data.first() == Some(&12) && t.time_ns > 8000);
        s.remove(victim.unwrap());
        assert!(matches!(
            decode_stream(&s, &spec),
            Err(DecodeError::LostWithoutIndex(n)) if n >= 1
        ));
    }

    #[test]
    fn status_lines_align_captures_on_their_raw_index() {
        let l = layout(PixelPacking::Raw16, 1);
        // the capture starts in the middle of a sequence: raw images 1, then 0, 1, 0, 1
        let idx = [1u16, 0, 1, 0, 1];
        let truth: Vec<_> = (0..5).map(|s| codes(s, 1)).collect();
        let frames: Vec<_> = truth
            .iter()
            .zip(idx)
            .map(|(c, raw_index)| {
                let status = StatusLine {
                    frame_counter: 0,
                    raw_index,
                    row0: 0,
                    rows: 3,
                    exposure_reg: 0,
                    phase_reg: 0,
                    illumination: true,
                    crc32: 0,
                };
                crate::frame::encode_frame(c.as_slice().unwrap(), 12, Some(status))
            })
            .collect();
        let spec = StreamSpec {
            layout: l,
            status_line: true,
            images_per_capture: 2,
            endpoint: None,
        };
        let d = decode_stream(&stream(&frames, 24), &spec).unwrap();
        assert_eq!(d.captures.len(), 2);
        assert_eq!(
            d.captures[0].frames.index_axis(Axis(0), 0),
            truth[1].index_axis(Axis(0), 0)
        );
        assert_eq!(
            d.captures[1].frames.index_axis(Axis(0), 1),
            truth[4].index_axis(Axis(0), 0)
        );
    }
}
