//! The socket publisher end to end, with no D-Bus at all: the daemon binary on the emulated
//! device with the demo's scripted hand (`config/tofproxd-emulated.toml`), `publisher =
//! "socket"`, and every D-Bus address pointing nowhere — a bus connection attempted would fail
//! the start. A plain socket client must see the hand's near and far (docs/daemon.md, "The
//! socket publisher").

use std::io::{BufRead, BufReader};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use serde_json::Value;

/// The daemon process, killed on drop.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The demo's configuration with the socket publisher on `sock`, written into `dir`.
fn socket_config(dir: &Path, sock: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = std::fs::read_to_string(root.join("config/tofproxd-emulated.toml"))
        .expect("config/tofproxd-emulated.toml");
    let mut cfg: toml::Table = toml::from_str(&text).expect("demo config is TOML");
    cfg.insert("publisher".into(), "socket".into());
    let mut socket = toml::Table::new();
    socket.insert("path".into(), sock.display().to_string().into());
    cfg.insert("socket".into(), socket.into());
    // the calibration path is relative to the demo config's directory
    let calib = root
        .join("calib/emulated")
        .canonicalize()
        .expect("calib/emulated");
    cfg["processing"]
        .as_table_mut()
        .expect("[processing]")
        .insert("calibration".into(), calib.display().to_string().into());
    let path = dir.join("tofproxd.toml");
    std::fs::write(&path, toml::to_string(&cfg).expect("toml")).expect("write config");
    path
}

fn spawn(config: &Path, dir: &Path) -> Daemon {
    let nowhere = format!("unix:path={}", dir.join("no-bus-here").display());
    let child = Command::new(env!("CARGO_BIN_EXE_tofproxd"))
        .arg("--config")
        .arg(config)
        .env("DBUS_SYSTEM_BUS_ADDRESS", &nowhere)
        .env("DBUS_SESSION_BUS_ADDRESS", &nowhere)
        .env_remove("DBUS_STARTER_ADDRESS")
        .env_remove("NOTIFY_SOCKET")
        .spawn()
        .expect("spawn tofproxd");
    Daemon(child)
}

/// Connect once the daemon has made the socket (it must not exit meanwhile).
fn connect(daemon: &mut Daemon, sock: &Path) -> BufReader<UnixStream> {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if let Some(status) = daemon.0.try_wait().expect("try_wait") {
            panic!("tofproxd exited before serving the socket: {status}");
        }
        if let Ok(s) = UnixStream::connect(sock) {
            s.set_read_timeout(Some(Duration::from_secs(20)))
                .expect("timeout");
            return BufReader::new(s);
        }
        assert!(Instant::now() < deadline, "no socket at {}", sock.display());
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn next_line(r: &mut BufReader<UnixStream>) -> Value {
    let mut line = String::new();
    let n = r.read_line(&mut line).expect("a line within 20 s");
    assert!(n > 0, "the daemon closed the connection");
    assert!(line.ends_with('\n'), "one object per line: {line:?}");
    let v: Value = serde_json::from_str(&line).expect("each line is one JSON object");
    assert_eq!(v["version"], 1, "schema version: {line}");
    v
}

#[test]
fn socket_client_sees_the_hands_near_and_far_without_dbus() {
    let dir = tempfile::tempdir().expect("tempdir");
    let sock = dir.path().join("proximity.sock");
    let config = socket_config(dir.path(), &sock);
    let mut daemon = spawn(&config, dir.path());
    let t0_ns = tofproxd::boottime::boottime_ns();
    let mut client = connect(&mut daemon, &sock);

    // on connect: the status before our claim — the sensor held in reset
    let hello = next_line(&mut client);
    assert_eq!(hello["type"], "status");
    assert_eq!(hello["state"], "off", "{hello}");
    assert_eq!(hello["near"], false);
    assert!(hello["distance_mm"].is_null(), "{hello}");

    // our connection is the claim: readings flow; follow the hand to near and back to far
    let (near_mm, far_mm) = (150, 200);
    let mut readings: Vec<(u64, bool, Option<u64>)> = Vec::new();
    let mut near_lines: Vec<(u64, bool, Option<u64>)> = Vec::new();
    let mut last_ts = 0u64;
    let deadline = Instant::now() + Duration::from_secs(60);
    // (the second Near change's own reading line follows it)
    while near_lines.len() < 2 || readings.last().map(|r| r.0) < near_lines.get(1).map(|n| n.0) {
        assert!(
            Instant::now() < deadline,
            "no near and far within 60 s: near lines {near_lines:?}, {} readings",
            readings.len()
        );
        let v = next_line(&mut client);
        let kind = v["type"].as_str().expect("type").to_string();
        if kind == "status" {
            continue;
        }
        let ts = v["timestamp_ns"].as_u64().expect("timestamp_ns");
        let near = v["near"].as_bool().expect("near");
        let d = v["distance_mm"].as_u64();
        assert!(ts >= last_ts, "timestamps monotone: {ts} after {last_ts}");
        last_ts = ts;
        match kind.as_str() {
            "reading" => readings.push((ts, near, d)),
            "near" => near_lines.push((ts, near, d)),
            other => panic!("unknown line type {other}"),
        }
    }
    eprintln!(
        "near changes (timestamp_ns, near, distance_mm): {near_lines:?}; {} readings",
        readings.len()
    );
    let now_ns = tofproxd::boottime::boottime_ns();
    assert!(
        t0_ns < near_lines[0].0 && last_ts <= now_ns,
        "CLOCK_BOOTTIME stamps"
    );

    // near first (the hand within near_mm), then far (at least far_mm, or nothing in range)
    let (near_ts, near, near_d) = near_lines[0];
    assert!(near, "the first Near change is to near: {near_lines:?}");
    let near_d = near_d.expect("a near reading has a distance");
    assert!(
        near_d <= near_mm,
        "near at {near_d} mm (threshold {near_mm} mm)"
    );
    let (far_ts, far, far_d) = near_lines[1];
    assert!(!far, "then far: {near_lines:?}");
    assert!(far_d.is_none_or(|d| d >= far_mm), "far at {far_d:?} mm");
    assert!(far_ts > near_ts);
    // each Near change comes with its reading, of the same capture
    for (ts, n, d) in &near_lines {
        assert!(
            readings.contains(&(*ts, *n, *d)),
            "the reading of the Near change at {ts} ns: {near_lines:?} {readings:?}"
        );
    }
    // the hand came close: 5 cm in the script, read within a few cm
    let closest = readings
        .iter()
        .filter_map(|r| r.2)
        .min()
        .expect("distances");
    eprintln!("closest reading: {closest} mm");
    assert!(
        (20..=100).contains(&closest),
        "closest reading {closest} mm"
    );
    // and before it came near, the readings were far
    assert!(
        readings
            .iter()
            .take_while(|r| r.0 < near_ts)
            .any(|r| r.2.is_some_and(|d| d > far_mm)),
        "far readings before the hand approached: {readings:?}"
    );
    // reading times strictly increase (one capture each)
    assert!(readings.windows(2).all(|w| w[0].0 < w[1].0));

    // disconnecting releases the claim: a new client soon finds the sensor back in reset
    drop(client);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        std::thread::sleep(Duration::from_millis(500));
        let mut probe = connect(&mut daemon, &sock);
        let hello = next_line(&mut probe);
        if hello["state"] == "off" {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "still {} 10 s after the only client left",
            hello["state"]
        );
    }
    assert!(
        daemon.0.try_wait().expect("try_wait").is_none(),
        "still running"
    );
}
