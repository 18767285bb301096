//! Running the blocking driver off an async runtime: a dedicated thread owns
//! the [`SensorDriver`] and serves cycle requests; results come back over a
//! bounded channel. The daemon sends one [`CycleRequest`] per reading and
//! awaits the reply (e.g. with `tokio::task::spawn_blocking(move ||
//! rx.recv())` or by polling `try_recv` on its own schedule); the bulk reads
//! never block the runtime's workers.

use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::driver::{CycleOutput, CycleRequest, SensorDriver};
use crate::error::{BridgeError, ErrorKind};
use crate::transport::UsbTransport;

/// A command to the driver thread.
#[derive(Debug, Clone)]
pub enum DriverCommand {
    /// Run one cycle.
    Cycle(CycleRequest),
    /// Put the sensor in reset.
    PowerOff,
}

/// A reply from the driver thread.
#[derive(Debug)]
pub enum DriverReply {
    /// Result of a cycle.
    Cycle(Box<Result<CycleOutput, BridgeError>>),
    /// Result of a power-off.
    PowerOff(Result<(), BridgeError>),
}

/// Handle to a driver thread. Dropping it closes the command channel; the
/// thread powers the sensor off and exits.
#[derive(Debug)]
pub struct DriverThread {
    tx: Option<SyncSender<DriverCommand>>,
    rx: Receiver<DriverReply>,
    join: Option<JoinHandle<()>>,
}

impl DriverThread {
    /// Move `driver` to a new thread named `tofprox-driver`. `depth` bounds
    /// both channels (1 is right for one-reading-at-a-time loops).
    pub fn spawn<T: UsbTransport + 'static>(
        mut driver: SensorDriver<T>,
        depth: usize,
    ) -> Result<Self, BridgeError> {
        let (tx, cmd_rx) = mpsc::sync_channel::<DriverCommand>(depth.max(1));
        let (reply_tx, rx) = mpsc::sync_channel::<DriverReply>(depth.max(1));
        let join = std::thread::Builder::new()
            .name("tofprox-driver".into())
            .spawn(move || {
                while let Ok(cmd) = cmd_rx.recv() {
                    let reply = match cmd {
                        DriverCommand::Cycle(r) => DriverReply::Cycle(Box::new(driver.cycle(&r))),
                        DriverCommand::PowerOff => DriverReply::PowerOff(driver.power_off()),
                    };
                    if reply_tx.send(reply).is_err() {
                        break;
                    }
                }
                let _ = driver.power_off();
            })
            .map_err(|e| BridgeError::with_source(ErrorKind::Io, "spawn driver thread", e))?;
        Ok(DriverThread {
            tx: Some(tx),
            rx,
            join: Some(join),
        })
    }

    /// Queue a command; `Io` error if the queue is full or the thread died.
    pub fn send(&self, cmd: DriverCommand) -> Result<(), BridgeError> {
        let tx = self
            .tx
            .as_ref()
            .ok_or_else(|| BridgeError::new(ErrorKind::Io, "driver thread stopped"))?;
        tx.try_send(cmd).map_err(|e| match e {
            TrySendError::Full(_) => BridgeError::new(ErrorKind::Io, "driver command queue full"),
            TrySendError::Disconnected(_) => {
                BridgeError::new(ErrorKind::Io, "driver thread stopped")
            }
        })
    }

    /// Wait for the next reply (blocking, bounded).
    pub fn recv_timeout(&self, timeout: Duration) -> Result<DriverReply, BridgeError> {
        self.rx.recv_timeout(timeout).map_err(|e| match e {
            RecvTimeoutError::Timeout => {
                BridgeError::new(ErrorKind::Timeout, "no reply from driver thread")
            }
            RecvTimeoutError::Disconnected => {
                BridgeError::new(ErrorKind::Io, "driver thread stopped")
            }
        })
    }

    /// Run one cycle and wait for it (convenience for synchronous callers).
    pub fn cycle(&self, req: CycleRequest, timeout: Duration) -> Result<CycleOutput, BridgeError> {
        self.send(DriverCommand::Cycle(req))?;
        match self.recv_timeout(timeout)? {
            DriverReply::Cycle(r) => *r,
            DriverReply::PowerOff(_) => {
                Err(BridgeError::new(ErrorKind::Protocol, "unexpected reply"))
            }
        }
    }
}

impl Drop for DriverThread {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(j) = self.join.take() {
            let _ = j.join();
        }
    }
}
