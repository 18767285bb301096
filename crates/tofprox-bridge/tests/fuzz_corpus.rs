//! The fuzz corpora (fuzz/corpus/<target>/, kept in git) as regression tests: every kept
//! input goes through the same target body as under libFuzzer (fuzz/src/lib.rs), so an input
//! that once crashed a reader and was added to a corpus keeps failing here if the fix
//! regresses — on stable Rust, in every `cargo test`.

#[path = "../../../fuzz/src/lib.rs"]
mod bodies;

use std::path::Path;

fn replay(target: &str, body: fn(&[u8])) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../fuzz/corpus")
        .join(target);
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let p = e.unwrap().path();
        let bytes = std::fs::read(&p).unwrap();
        let r = std::panic::catch_unwind(|| body(&bytes));
        assert!(r.is_ok(), "{target}: {} panicked", p.display());
        n += 1;
    }
    assert!(n >= 2, "{target}: the corpus holds {n} inputs");
}

#[test]
fn usbcap_corpus() {
    replay("usbcap", bodies::usbcap);
}

#[test]
fn pixels_corpus() {
    replay("pixels", bodies::pixels);
}

#[test]
fn device_decode_corpus() {
    replay("device_decode", bodies::device_decode);
}

#[test]
fn reassembly_corpus() {
    replay("reassembly", bodies::reassembly);
}

#[test]
fn recording_header_corpus() {
    replay("recording_header", bodies::recording_header);
}

#[test]
fn npy_corpus() {
    replay("npy", bodies::npy);
}
