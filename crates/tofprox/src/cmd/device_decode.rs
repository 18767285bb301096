//! `tofprox device decode`: a capture of a camera's USB stream (usbmon pcap/pcapng or text)
//! plus the mode it was taken in → a version 1 recording. Thin over
//! `tofprox_bridge::{usbcap, decode}`; the recording is written by `tofprox-format`.
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use tofprox_bridge::decode::{Decoded, StreamSpec, decode_stream};
use tofprox_bridge::pixels::{BufferLayout, PixelPacking};
use tofprox_bridge::usbcap::{MAX_CAPTURE_BYTES, read_capture};
use tofprox_core::{Algorithm, SensorGeometry};
use tofprox_format::{CaptureSpec, RawFrames};

#[derive(clap::Args, Debug)]
pub struct DecodeArgs {
    /// The capture: a pcap/pcapng from `tcpdump -i usbmonN -s 0 -w f.pcap` or Wireshark, or
    /// usbmon text (`/sys/kernel/debug/usb/usbmon/Nu`; only payloads of ≤ 32 bytes survive it).
    capture: PathBuf,
    /// The mode the camera ran: 2phase or 4phase (sets the phases and images per capture).
    #[arg(long)]
    mode: Algorithm,
    /// Rows of one raw image.
    #[arg(long)]
    rows: usize,
    /// Columns of one raw image.
    #[arg(long)]
    cols: usize,
    /// Pixel packing: raw16 (16-bit little-endian words, code in the low bits) or raw12
    /// (MIPI CSI-2: two pixels in three bytes).
    #[arg(long, default_value = "raw16")]
    packing: PixelPacking,
    /// Each frame stacks all raw images of one capture (as REAL3 V4L2 drivers deliver them).
    #[arg(long)]
    stacked: bool,
    /// Bytes from one line's start to the next, when lines are padded.
    #[arg(long)]
    stride_bytes: Option<usize>,
    /// Frames start with the emulated CX3's status line (image index, CRC).
    #[arg(long)]
    status_line: bool,
    /// ADC resolution, bits.
    #[arg(long, default_value_t = 12)]
    adc_bits: u8,
    /// Modulation frequency the camera ran at, Hz.
    #[arg(long)]
    modulation_hz: f64,
    /// Exposure per raw image, µs.
    #[arg(long)]
    exposure_us: f64,
    /// The stream's endpoint `BUS:DEVICE:ENDPOINT` (e.g. 2:5:0x83); default: the bulk-IN
    /// endpoint that carried the most bytes.
    #[arg(long, value_parser = parse_endpoint)]
    endpoint: Option<(u16, u8, u8)>,
    /// Output recording directory (must not hold a recording yet, unless --force).
    #[arg(long)]
    out: PathBuf,
    /// Replace the recording already in `--out`.
    #[arg(long)]
    force: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
}

fn parse_endpoint(s: &str) -> Result<(u16, u8, u8), String> {
    let bad = || format!("{s:?} is not BUS:DEVICE:ENDPOINT (e.g. 2:5:0x83)");
    let p: Vec<&str> = s.split(':').collect();
    let [bus, dev, ep] = p.as_slice() else {
        return Err(bad());
    };
    let ep = match ep.strip_prefix("0x") {
        Some(h) => u8::from_str_radix(h, 16).map_err(|_| bad())?,
        None => ep.parse::<u8>().map_err(|_| bad())?,
    };
    Ok((
        bus.parse().map_err(|_| bad())?,
        dev.parse().map_err(|_| bad())?,
        ep | 0x80,
    ))
}

pub fn decode(a: DecodeArgs) -> anyhow::Result<ExitCode> {
    // the geometry first: nothing is read or sized from an impossible one
    let sensor = SensorGeometry::full(a.rows, a.cols, a.adc_bits, a.modulation_hz);
    sensor.validate()?;
    // the bounded reader: regular files only (a FIFO or device is refused, never waited on)
    let bytes = tofprox_format::limits::read_bounded(&a.capture, MAX_CAPTURE_BYTES, None)
        .with_context(|| format!("reading {}", a.capture.display()))?;
    let transfers =
        read_capture(&bytes).with_context(|| format!("reading {}", a.capture.display()))?;
    let per = a.mode.raw_images();
    let spec = StreamSpec {
        layout: BufferLayout {
            packing: a.packing,
            cols: a.cols,
            rows: a.rows,
            images: if a.stacked { per } else { 1 },
            stride_bytes: a.stride_bytes,
            adc_bits: a.adc_bits,
        },
        status_line: a.status_line,
        images_per_capture: per,
        endpoint: a.endpoint,
    };
    let d = decode_stream(&transfers, &spec)
        .with_context(|| format!("decoding {}", a.capture.display()))?;
    write(&a, sensor, &d)?;
    summary(&a, &d);
    Ok(ExitCode::SUCCESS)
}

fn write(a: &DecodeArgs, sensor: SensorGeometry, d: &Decoded) -> anyhow::Result<()> {
    let (bus, dev, ep) = d.endpoint;
    let description = format!(
        "decoded by tofprox device decode from {} (bus {bus} device {dev} endpoint {ep:#04x}), {} mode",
        a.capture.display(),
        a.mode
    );
    let mut w = super::new_recording(&a.out, sensor, Some(description), a.force)?;
    for c in &d.captures {
        let spec = CaptureSpec {
            phases_deg: a.mode.phases_deg().to_vec(),
            exposure_us: a.exposure_us,
            illumination: true,
            averaged: 1,
            timestamp_ns: Some(c.time_ns),
            conditions: BTreeMap::new(),
        };
        w.append(spec, &RawFrames::U16(c.frames.clone()))
            .map_err(|e| super::output_error(&a.out, e))?;
    }
    w.finish().map_err(|e| super::output_error(&a.out, e))
}

fn summary(a: &DecodeArgs, d: &Decoded) {
    let s = d.reassembly;
    if a.json {
        let v = serde_json::json!({
            "captures": d.captures.len(),
            "endpoint": [d.endpoint.0, d.endpoint.1, d.endpoint.2],
            "reassembly": s,
            "tail_images": d.tail_images,
            "out": a.out.display().to_string(),
        });
        println!("{v}");
    } else {
        println!(
            "{} capture(s) to {} ({} frames reassembled, {} dropped, {} raw image(s) at the end left over)",
            d.captures.len(),
            a.out.display(),
            s.frames_ok,
            s.frames_dropped,
            d.tail_images
        );
    }
}
