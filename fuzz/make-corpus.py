#!/usr/bin/env python3
"""Write the seed corpora of the fuzz targets into fuzz/corpus/<target>/ (kept in git).

Each seed is built byte by byte from the public formats (libpcap/pcapng, the kernel's
usbmon_packet and usbmon text, MIPI RAW12, UVC payload headers, NumPy .npy, our
recording.toml), not with the code under test. libFuzzer grows the corpus from these; the
regression test (crates/tofprox-bridge/tests/fuzz_corpus.rs) replays every file kept here.
Rerun after changing a format: python3 fuzz/make-corpus.py
"""
import os
import shutil
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def usbmon(event, xfer, ep, status, data, length, t):
    h = bytearray(64)
    h[8], h[9], h[10], h[11] = ord(event), xfer, ep, 7
    h[12:14] = struct.pack("<H", 3)
    h[16:24] = struct.pack("<Q", t // 1_000_000)
    h[24:28] = struct.pack("<I", t % 1_000_000)
    h[28:32] = struct.pack("<i", status)
    h[32:36] = struct.pack("<I", length)
    h[36:40] = struct.pack("<I", len(data))
    return bytes(h) + bytes(data)


def uvc_payloads(frame, fid, chunk=16):
    parts = [frame[i:i + chunk] for i in range(0, len(frame), chunk)] or [b""]
    out = []
    for i, c in enumerate(parts):
        bits = 0x80 | fid | (0x02 if i + 1 == len(parts) else 0)
        out.append(bytes([2, bits]) + bytes(c))
    return out


def raw16_frame(rows, cols, seed):
    return b"".join(struct.pack("<H", (seed * 977 + i * 5) % 4096) for i in range(rows * cols))


def packets(rows=2, cols=4, frames=4):
    pk = []
    for f in range(frames):
        for p in uvc_payloads(raw16_frame(rows, cols, f), f % 2):
            pk.append(usbmon("C", 3, 0x82, 0, p, len(p), 5_000_000 + 1000 * len(pk)))
    pk.insert(1, usbmon("S", 3, 0x82, -115, b"", 512, 5_000_500))
    pk.append(usbmon("C", 2, 0x80, 0, b"\x01", 1, 6_000_000))
    return pk


def pcap(pk, link=220):
    f = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, link)
    for i, p in enumerate(pk):
        f += struct.pack("<IIII", 100 + i, 0, len(p), len(p)) + p
    return f


def pcapng(pk):
    def block(kind, body):
        n = 12 + (len(body) + 3) // 4 * 4
        return struct.pack("<II", kind, n) + body + b"\0" * (n - 12 - len(body)) + struct.pack("<I", n)
    f = block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1))
    f += block(1, struct.pack("<HHI", 220, 0, 0))
    for i, p in enumerate(pk):
        f += block(6, struct.pack("<IIIII", 0, 0, i, len(p), len(p)) + p)
    return f


def text():
    return (
        b"ffff9a0b 3575914555 S Bi:3:007:2 -115 512 <\n"
        b"ffff9a0b 3575914560 C Bi:3:007:2 0 6 = 0c8d0102 0304\n"
        b"ffff9a0c 3575914570 C Bo:3:007:2 0 4 >\n"
        b"ffff9a0d 3575914580 C Bi:007:2 0 2 = 8c01\n"
    )


def layout_head(packing_raw16, cols, rows, images, stride, adc_bits):
    p = (1 if packing_raw16 else 0) | (2 if stride is not None else 0)
    s = struct.pack("<I", stride or 0)[:3]
    return bytes([p]) + struct.pack("<HH", cols, rows) + bytes([images]) + s + bytes([adc_bits])


def raw12(codes):
    out = bytearray()
    for a, b in zip(codes[0::2], codes[1::2]):
        out += bytes([a >> 4, b >> 4, ((b & 15) << 4) | (a & 15)])
    return bytes(out)


def npy(dtype, shape, payload):
    header = "{'descr': '%s', 'fortran_order': False, 'shape': (%s), }" % (
        dtype, "".join(f"{n}, " for n in shape).rstrip(" ") if len(shape) != 1 else f"{shape[0]},")
    pad = 64 - (10 + len(header) + 1) % 64
    header = header + " " * pad + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + payload


V3 = '''format = "tofprox-recording"
version = 3
kind = "raw"

[sensor]
rows = 2
cols = 4
roi_origin = [0, 0]
full_rows = 2
full_cols = 4
adc_bits = 12
modulation_hz = 80e6

[[capture]]
frames = "frames/000000.npy"
phases_deg = [0.0, 90.0]
exposure_us = 500.0
illumination = true
averaged = 1

[capture.second_frequency]
frames = "frames/000001.npy"
modulation_hz = 60e6
phases_deg = [0.0, 90.0]
'''

DEPTH = '''format = "tofprox-recording"
version = 3
kind = "depth"

[depth]
rows = 4
cols = 6

[[capture]]
depth_mm = "frames/000000_depth_mm.npy"
timestamp_ns = 1000000000
'''


def main():
    corpus = os.path.join(HERE, "corpus")
    shutil.rmtree(corpus, ignore_errors=True)
    seeds = {
        "usbcap": {
            "pcap": pcap(packets()),
            "pcap189": pcap([p[:48] + p[64:] for p in packets()], link=189),
            "pcapng": pcapng(packets()),
            "text": text(),
            "text-non-ascii": b"ffff 1 C Bi:3:007:2 0 2 = a\xc3\xa9b\n",
        },
        "pixels": {
            "raw16": layout_head(True, 4, 2, 1, None, 12) + raw16_frame(2, 4, 1),
            "raw12-stride": layout_head(False, 4, 2, 2, 8, 12)
            + b"".join(raw12([0xABC, 0x123, 0xFFF, 0]) + b"\0\0" for _ in range(4)),
            "huge-cols": layout_head(True, 65535, 65535, 255, None, 12) + b"\0" * 16,
            "huge-stride": layout_head(True, 4, 2, 1, 0xFFFFFF, 16) + b"\0" * 16,
        },
        "device_decode": {
            "pcap-2phase": layout_head(True, 4, 2, 1, None, 12) + b"\x00" + pcap(packets()),
            "pcap-stacked": layout_head(True, 4, 1, 2, None, 12) + b"\x00" + pcap(packets()),
            "text": layout_head(True, 1, 1, 1, None, 12) + b"\x00" + text(),
            "huge": layout_head(True, 65535, 65535, 4, 0xFFFFFF, 12) + b"\x02" + pcapng(packets()),
        },
        "reassembly": {
            "raw": bytes([0, 6, 1, 3, 14]) + b"".join(uvc_payloads(raw16_frame(3, 16, 0), 0)),
            "structured": bytes([1, 6, 1, 3, 40]) + bytes(range(0, 60)),
        },
        "recording_header": {
            "v1-example": open(os.path.join(REPO, "examples/recording/recording.toml"), "rb").read(),
            "v3-second-frequency": V3.encode(),
            "v3-depth": DEPTH.encode(),
        },
        "npy": {
            "u16": npy("<u2", (2, 2, 4), struct.pack("<16H", *range(16))),
            "f32": npy("<f4", (1, 2, 2), struct.pack("<4f", 1.5, float("nan"), -0.0, 2047.5)),
            "f64": npy("<f8", (3,), struct.pack("<3d", 1.0, 2.0, 3.0)),
            "example-wiggling": open(os.path.join(REPO, "calib/emulated/wiggling_2phase.npy"), "rb").read(),
        },
    }
    for target, files in seeds.items():
        d = os.path.join(corpus, target)
        os.makedirs(d)
        for name, data in files.items():
            with open(os.path.join(d, name), "wb") as f:
                f.write(data)
    print(f"wrote {sum(len(v) for v in seeds.values())} seeds into {corpus}")


if __name__ == "__main__":
    main()
