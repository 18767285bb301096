//! The stop signals, taken in charge before anything else starts (issue 35 W6, N4).
//!
//! [`StopSignals::block`] is the first thing `tofproxd`'s `main` does: it blocks every stop
//! signal in the calling thread — so in every thread started after it (tokio's, the loop
//! thread, zbus's), which inherit the mask — and starts one thread that takes them with
//! `sigwait(3)`. A signal that arrives at any moment after that, even while the
//! configuration is still being read, is never acted on by its default action: it stays
//! pending until the waiting thread takes it and hands its name to the async side
//! ([`StopSignals::recv`]), which stops the daemon (or the demo) cleanly. Children started
//! with `std::process::Command` begin with an empty mask (the standard library resets it
//! before `exec`), so a private `dbus-daemon` still dies by its own signals.
//!
//! The signals: every one whose default action would end the daemon without the clean stop
//! (sensor to reset, names released, the demo's private bus gone) and that systemd, `timeout`
//! or an administrator may send: SIGTERM (the unit's `KillSignal`, `timeout`'s default),
//! SIGINT, SIGHUP (also sent by systemd with `SendSIGHUP=`; no reload: the daemon stops cleanly
//! and systemd restarts it with the new configuration), SIGQUIT, SIGUSR1, SIGUSR2, SIGALRM.
//! SIGKILL cannot be caught; the watchdog's SIGABRT is left to dump the hung process.
//!
//! Tested through the binary (`tests/signals.rs`): a process-directed signal in a test binary
//! would be taken by the default action of its other threads.

use tokio::sync::mpsc;

/// The stop signals and their names.
pub const STOP_SIGNALS: [(libc::c_int, &str); 7] = [
    (libc::SIGTERM, "SIGTERM"),
    (libc::SIGINT, "SIGINT"),
    (libc::SIGHUP, "SIGHUP"),
    (libc::SIGQUIT, "SIGQUIT"),
    (libc::SIGUSR1, "SIGUSR1"),
    (libc::SIGUSR2, "SIGUSR2"),
    (libc::SIGALRM, "SIGALRM"),
];

/// The blocked stop signals, as they arrive.
#[derive(Debug)]
pub struct StopSignals {
    rx: mpsc::UnboundedReceiver<&'static str>,
}

fn stop_set() -> std::io::Result<libc::sigset_t> {
    // SAFETY: `sigset_t` is plain data; sigemptyset initialises it before any other use.
    #[allow(unsafe_code)]
    let mut set: libc::sigset_t = unsafe { std::mem::zeroed() };
    // SAFETY: `set` is a valid, exclusively borrowed sigset_t.
    #[allow(unsafe_code)]
    if unsafe { libc::sigemptyset(&mut set) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    for (sig, _) in STOP_SIGNALS {
        // SAFETY: as above; `sig` is a valid signal number.
        #[allow(unsafe_code)]
        if unsafe { libc::sigaddset(&mut set, sig) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(set)
}

impl StopSignals {
    /// Block the stop signals in the calling thread (call it first in `main`, before any
    /// other thread exists) and start the thread that waits for them.
    pub fn block() -> std::io::Result<Self> {
        let set = stop_set()?;
        // SAFETY: `set` is initialised; the old mask is not asked for (null).
        #[allow(unsafe_code)]
        let rc = unsafe { libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut()) };
        if rc != 0 {
            return Err(std::io::Error::from_raw_os_error(rc));
        }
        let (tx, rx) = mpsc::unbounded_channel();
        std::thread::Builder::new()
            .name("tofproxd-signals".into())
            .spawn(move || wait_loop(&set, &tx))?;
        Ok(Self { rx })
    }

    /// The name of the next stop signal received (one sent before this call included).
    pub async fn recv(&mut self) -> &'static str {
        match self.rx.recv().await {
            Some(name) => name,
            // the waiting thread ended (sigwait failed): no more signals, never resolve
            None => std::future::pending().await,
        }
    }

    /// A stop signal already received, without waiting.
    pub fn try_recv(&mut self) -> Option<&'static str> {
        self.rx.try_recv().ok()
    }
}

fn wait_loop(set: &libc::sigset_t, tx: &mpsc::UnboundedSender<&'static str>) {
    loop {
        let mut sig: libc::c_int = 0;
        // SAFETY: `set` is an initialised sigset_t whose signals are blocked in this thread
        // (inherited from the thread that spawned it); `sig` is a valid out pointer.
        #[allow(unsafe_code)]
        let rc = unsafe { libc::sigwait(set, &mut sig) };
        if rc != 0 {
            tracing::error!("sigwait: {}", std::io::Error::from_raw_os_error(rc));
            return;
        }
        let name = STOP_SIGNALS
            .iter()
            .find(|(s, _)| *s == sig)
            .map_or("a stop signal", |(_, n)| n);
        if tx.send(name).is_err() {
            return;
        }
    }
}
