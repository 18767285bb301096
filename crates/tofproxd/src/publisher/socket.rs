//! The socket publisher (`publisher = "socket"`, `[socket]`): JSON Lines ([`super::jsonl`]) on
//! a Unix stream socket, for clients without D-Bus — a shell script (`socat - UNIX:…`), an
//! Android sensors sub-HAL, a test. The daemon then connects to no bus at all.
//!
//! - A connected client is a proximity claim (the loop runs while one is connected);
//!   disconnecting releases it. What a client writes is read and ignored.
//! - On connect a client gets a `status` line, then a `near` line per Near change and a
//!   `reading` line per valid reading.
//! - Slow clients never stall the loop: each client has a queue of `socket.queue_lines`
//!   lines; a client whose queue is full is disconnected at once (its claim released, logged),
//!   never sent a gap — a client that sees the connection close knows it missed lines, and
//!   reconnects to a fresh `status` line.
//! - At most `socket.max_clients` clients at once; a further one is closed at once.
//! - The socket file is made with `socket.mode` (default `0o660`: the daemon's user and
//!   group); a stale socket file (no one listening) is replaced, anything else at the path is
//!   refused. It is removed when the publisher ends.

use std::collections::BTreeMap;
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::jsonl::{Line, LineKind, lines_for};
use super::{PublishError, Publisher, StatusChange};
use crate::config::SocketConfig;
use crate::hub::{Claim, Hub};

/// Why the socket could not be served.
#[derive(Debug, thiserror::Error)]
pub enum SocketError {
    /// Something other than a socket is at the path.
    #[error("socket.path {path}: exists and is not a socket; not removing it")]
    NotASocket {
        /// The path.
        path: PathBuf,
    },
    /// Another process listens on the path.
    #[error(
        "socket.path {path}: another process is listening on it (is another tofproxd running?)"
    )]
    InUse {
        /// The path.
        path: PathBuf,
    },
    /// Binding, removing the stale file or setting the mode failed.
    #[error("socket.path {path}: {what}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The step.
        what: &'static str,
        /// The system's error.
        source: std::io::Error,
    },
}

/// A connected client: its queue and its task.
struct Client {
    tx: mpsc::Sender<Arc<str>>,
    task: JoinHandle<()>,
}

/// The clients by id, shared between the accept task, the client tasks and the publisher.
#[derive(Clone, Default)]
struct Clients(Arc<Mutex<BTreeMap<u64, Client>>>);

impl Clients {
    fn lock(&self) -> MutexGuard<'_, BTreeMap<u64, Client>> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The claim name of client `id` (cannot collide with a D-Bus unique name, `:1.N`).
fn claim_name(id: u64) -> String {
    format!("socket#{id}")
}

/// Forget client `id` and release its claim (idempotent).
fn drop_client(clients: &Clients, hub: &Hub, id: u64) {
    if let Some(c) = clients.lock().remove(&id) {
        c.task.abort();
    }
    if hub.client_gone(&claim_name(id)) {
        tracing::info!("socket client {id} disconnected: its proximity claim is released");
    }
}

/// Serves the socket; publishing writes to every client's queue.
pub struct SocketPublisher {
    clients: Clients,
    hub: Arc<Hub>,
    accept: JoinHandle<()>,
    path: PathBuf,
}

impl SocketPublisher {
    /// Bind `cfg.path` (replacing a stale socket), set its mode and start accepting clients.
    /// Must be called inside the tokio runtime.
    pub fn bind(cfg: &SocketConfig, hub: Arc<Hub>) -> Result<Self, SocketError> {
        let path = cfg.path.clone();
        let io = |what| {
            let path = path.clone();
            move |source| SocketError::Io { path, what, source }
        };
        remove_stale(&path)?;
        let listener = UnixListener::bind(&path).map_err(io("bind"))?;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(cfg.mode))
            .map_err(io("setting its mode"))?;
        let clients = Clients::default();
        let accept = tokio::spawn(accept_clients(
            listener,
            clients.clone(),
            hub.clone(),
            cfg.max_clients,
            cfg.queue_lines,
        ));
        tracing::info!("socket publisher on {}", path.display());
        Ok(Self {
            clients,
            hub,
            accept,
            path,
        })
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.clients.lock().len()
    }
}

impl Drop for SocketPublisher {
    fn drop(&mut self) {
        self.accept.abort();
        // the client tasks write what is queued (the final `off` status), then close
        self.clients.lock().clear();
        let _ = std::fs::remove_file(&self.path);
    }
}

#[async_trait::async_trait]
impl Publisher for SocketPublisher {
    fn name(&self) -> &'static str {
        "socket"
    }

    async fn status(&mut self, change: StatusChange<'_>) -> Result<(), PublishError> {
        let lines = lines_for(change, crate::boottime::boottime_ns());
        if lines.is_empty() {
            return Ok(());
        }
        let mut full = Vec::new();
        {
            let clients = self.clients.lock();
            for line in lines {
                let line: Arc<str> = line.into();
                for (id, c) in clients.iter() {
                    if c.tx.try_send(line.clone()).is_err() && !full.contains(id) {
                        full.push(*id);
                    }
                }
            }
        }
        for id in full {
            tracing::warn!("socket client {id} is not reading: its queue is full, disconnected");
            drop_client(&self.clients, &self.hub, id);
        }
        Ok(())
    }
}

/// Remove a stale socket file at `path` (no one listening); refuse anything else.
fn remove_stale(path: &Path) -> Result<(), SocketError> {
    let Ok(meta) = path.symlink_metadata() else {
        return Ok(());
    };
    if !meta.file_type().is_socket() {
        return Err(SocketError::NotASocket {
            path: path.to_path_buf(),
        });
    }
    if std::os::unix::net::UnixStream::connect(path).is_ok() {
        return Err(SocketError::InUse {
            path: path.to_path_buf(),
        });
    }
    std::fs::remove_file(path).map_err(|source| SocketError::Io {
        path: path.to_path_buf(),
        what: "removing the stale socket",
        source,
    })
}

/// Accept clients until aborted: each gets a queue, a claim and a task.
async fn accept_clients(
    listener: UnixListener,
    clients: Clients,
    hub: Arc<Hub>,
    max_clients: usize,
    queue_lines: usize,
) {
    let mut next_id = 0u64;
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            Err(e) => {
                tracing::warn!("socket publisher: accept failed: {e}");
                continue;
            }
        };
        let mut g = clients.lock();
        if g.len() >= max_clients {
            tracing::warn!(
                "socket publisher: {max_clients} clients connected (socket.max_clients): closing a new one"
            );
            continue;
        }
        next_id += 1;
        let id = next_id;
        let (tx, rx) = mpsc::channel(queue_lines);
        let status = hub.status();
        let hello = Line::new(LineKind::Status, &status, crate::boottime::boottime_ns());
        // the queue is empty and at least one line long: the first line always fits
        let _ = tx.try_send(hello.to_line().into());
        let task = tokio::spawn(serve_client(stream, rx, clients.clone(), hub.clone(), id));
        g.insert(id, Client { tx, task });
        drop(g);
        hub.set_claim(&claim_name(id), Claim::Proximity, true);
        tracing::info!("socket client {id} connected: proximity claimed");
    }
}

/// Write the client's queue to it until the queue closes or the client goes (EOF or an
/// error on either direction); then release its claim.
async fn serve_client(
    stream: UnixStream,
    mut rx: mpsc::Receiver<Arc<str>>,
    clients: Clients,
    hub: Arc<Hub>,
    id: u64,
) {
    let (mut read, mut write) = stream.into_split();
    let mut sink = [0u8; 256];
    loop {
        tokio::select! {
            line = rx.recv() => {
                let Some(line) = line else { break };
                if write.write_all(line.as_bytes()).await.is_err() {
                    break;
                }
            }
            n = read.read(&mut sink) => {
                if !matches!(n, Ok(n) if n > 0) {
                    break;
                }
            }
        }
    }
    // not through `drop_client`: that would abort this very task before the claim goes
    clients.lock().remove(&id);
    if hub.client_gone(&claim_name(id)) {
        tracing::info!("socket client {id} disconnected: its proximity claim is released");
    }
}

#[cfg(test)]
mod tests {
    use std::io::{BufRead, BufReader};

    use super::*;
    use crate::config::Config;
    use crate::hub::StatusUpdate;

    fn socket_cfg(dir: &Path, queue_lines: usize) -> SocketConfig {
        SocketConfig {
            path: dir.join("p.sock"),
            queue_lines,
            ..SocketConfig::default()
        }
    }

    /// Wait (yielding to the accept and client tasks) until `f` holds.
    async fn until(what: &str, mut f: impl FnMut() -> bool) {
        for _ in 0..2000 {
            if f() {
                return;
            }
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
        panic!("timed out waiting for {what}");
    }

    #[tokio::test]
    async fn a_client_is_a_claim_and_a_client_that_does_not_read_is_dropped_alone() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = socket_cfg(dir.path(), 8);
        let (hub, _demand) = Hub::new(&Config::default(), "test".into());
        let mut publisher = SocketPublisher::bind(&cfg, hub.clone()).expect("bind");
        let mode = std::fs::metadata(&cfg.path)
            .expect("socket")
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o660);

        // a reader on its own thread, and a client that never reads
        let reader = std::os::unix::net::UnixStream::connect(&cfg.path).expect("connect");
        let _stalled = std::os::unix::net::UnixStream::connect(&cfg.path).expect("connect");
        until("two claims", || hub.claim_counts().proximity == 2).await;
        assert!(hub.demand().proximity);
        let read = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let counter = read.clone();
        let lines = std::thread::spawn(move || {
            BufReader::new(reader)
                .lines()
                .map(|l| {
                    counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    l.expect("line")
                })
                .collect::<Vec<_>>()
        });

        // readings until the stalled client's socket buffer and queue are full
        let mut sent = 0u64;
        while publisher.clients() == 2 {
            sent += 1;
            assert!(sent < 200_000, "the stalled client was never dropped");
            let (before, after) = hub.apply(&StatusUpdate {
                distance_mm: Some(100 + (sent % 50) as u32),
                timestamp_ns: Some(sent),
                valid_reading: true,
                ..StatusUpdate::default()
            });
            publisher
                .status(StatusChange {
                    before: &before,
                    after: &after,
                })
                .await
                .expect("publishing never fails");
            tokio::task::yield_now().await;
            // a reading client keeps up (on a loaded machine its thread may not run for a
            // while: wait for it, so only the client that never reads falls behind)
            let behind = |r: u64| sent.saturating_sub(r) > 64;
            for _ in 0..2000 {
                if !behind(read.load(std::sync::atomic::Ordering::Relaxed)) {
                    break;
                }
                tokio::time::sleep(std::time::Duration::from_millis(1)).await;
            }
        }
        // the stalled client's claim went with it; the reader's stays
        assert_eq!(hub.claim_counts().proximity, 1);
        drop(publisher);
        assert!(!cfg.path.exists(), "the socket file is removed");
        // (joined off the runtime: the reader's task still writes what is queued)
        let lines = tokio::task::spawn_blocking(move || lines.join())
            .await
            .expect("join")
            .expect("reader");
        // the reader got the hello and every reading, in order
        assert_eq!(lines.len() as u64, sent + 1);
        let ts: Vec<u64> = lines[1..]
            .iter()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).expect("json");
                assert_eq!(v["type"], "reading");
                v["timestamp_ns"].as_u64().expect("ts")
            })
            .collect();
        assert_eq!(ts, (1..=sent).collect::<Vec<_>>());
    }

    #[tokio::test]
    async fn a_listening_socket_is_not_taken_over_and_a_file_is_not_removed() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = socket_cfg(dir.path(), 4);
        let (hub, _demand) = Hub::new(&Config::default(), "test".into());
        let first = SocketPublisher::bind(&cfg, hub.clone()).expect("bind");
        let err = SocketPublisher::bind(&cfg, hub.clone())
            .err()
            .expect("in use");
        assert!(matches!(err, SocketError::InUse { .. }), "{err}");
        drop(first);
        // a stale socket file (no one listening) is replaced
        drop(std::os::unix::net::UnixListener::bind(&cfg.path).expect("stale"));
        assert!(cfg.path.exists());
        let again = SocketPublisher::bind(&cfg, hub.clone()).expect("stale replaced");
        drop(again);
        std::fs::write(&cfg.path, "not a socket").expect("file");
        let err = SocketPublisher::bind(&cfg, hub).err().expect("refused");
        assert!(matches!(err, SocketError::NotASocket { .. }), "{err}");
        assert_eq!(
            std::fs::read_to_string(&cfg.path).expect("kept"),
            "not a socket"
        );
    }
}
