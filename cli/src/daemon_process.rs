//! Running `lanealignd` as a child process (for `demo`, `soak` and tests).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// The daemon process could not be found, started or stopped.
#[derive(Debug, thiserror::Error)]
pub enum DaemonProcessError {
    /// No `lanealignd` binary was found.
    #[error("lanealignd not found next to {0} (build the workspace, or set LANEALIGND)")]
    NotFound(PathBuf),
    /// Starting, signalling or waiting for it failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: String,
        /// The error.
        source: std::io::Error,
    },
    /// It exited or did not become ready in time.
    #[error("lanealignd did not become ready ({status}); its log:\n{log}")]
    NotReady {
        /// How it ended, or that it is still starting.
        status: String,
        /// Its log.
        log: String,
    },
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> DaemonProcessError {
    let what = what.into();
    move |source| DaemonProcessError::Io { what, source }
}

/// A running daemon; stopped with SIGTERM when dropped.
pub struct DaemonProcess {
    child: Child,
    log: PathBuf,
}

/// `lanealignd` next to the running executable (cargo puts all binaries of a workspace in one
/// folder, and tests' executables one level below), or `$LANEALIGND`.
pub fn daemon_binary() -> Result<PathBuf, DaemonProcessError> {
    if let Some(path) = std::env::var_os("LANEALIGND") {
        return Ok(PathBuf::from(path));
    }
    let exe = std::env::current_exe().map_err(io("locating the running executable"))?;
    for dir in exe.ancestors().skip(1).take(2) {
        let candidate = dir.join("lanealignd");
        if candidate.is_file() {
            return Ok(candidate);
        }
    }
    Err(DaemonProcessError::NotFound(exe))
}

impl DaemonProcess {
    /// Starts `lanealignd --config CONFIG`, logging to `log`.
    pub fn start(config: &Path, log: &Path) -> Result<Self, DaemonProcessError> {
        let binary = daemon_binary()?;
        let log_file =
            std::fs::File::create(log).map_err(io(format!("creating {}", log.display())))?;
        let child = Command::new(&binary)
            .arg("--config")
            .arg(config)
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "info".into()),
            )
            .stdout(Stdio::null())
            .stderr(log_file)
            .spawn()
            .map_err(io(format!("starting {}", binary.display())))?;
        Ok(DaemonProcess {
            child,
            log: log.to_path_buf(),
        })
    }

    /// Starts it and waits until it says it is ready (every worker up, sessions restored).
    pub fn start_ready(
        config: &Path,
        log: &Path,
        timeout: Duration,
    ) -> Result<Self, DaemonProcessError> {
        let mut daemon = Self::start(config, log)?;
        daemon.wait_ready(timeout)?;
        Ok(daemon)
    }

    /// Waits until the daemon logs that it is ready; an error with its log when it exits first
    /// or takes longer than `timeout`.
    pub fn wait_ready(&mut self, timeout: Duration) -> Result<(), DaemonProcessError> {
        let until = Instant::now() + timeout;
        loop {
            if self.log().contains(" ready") {
                return Ok(());
            }
            if let Some(status) = self.child.try_wait().map_err(io("polling lanealignd"))? {
                return Err(DaemonProcessError::NotReady {
                    status: status.to_string(),
                    log: self.log(),
                });
            }
            if Instant::now() > until {
                return Err(DaemonProcessError::NotReady {
                    status: format!("still starting after {timeout:?}"),
                    log: self.log(),
                });
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Kills it with SIGKILL (no clean-up at all) and reaps it.
    pub fn kill(mut self) -> Result<(), DaemonProcessError> {
        self.child.kill().map_err(io("killing lanealignd"))?;
        self.child.wait().map_err(io("waiting for lanealignd"))?;
        Ok(())
    }

    /// Waits for it to exit on its own.
    pub fn wait(mut self) -> Result<ExitStatus, DaemonProcessError> {
        self.child.wait().map_err(io("waiting for lanealignd"))
    }

    /// The process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// The daemon's log so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Sends SIGTERM and waits for a clean exit; returns whether it exited successfully.
    pub fn stop(mut self) -> Result<bool, DaemonProcessError> {
        self.terminate()
    }

    fn terminate(&mut self) -> Result<bool, DaemonProcessError> {
        if let Some(status) = self.child.try_wait().map_err(io("polling lanealignd"))? {
            return Ok(status.success());
        }
        if let Some(pid) = rustix::process::Pid::from_raw(self.child.id() as i32) {
            rustix::process::kill_process(pid, rustix::process::Signal::TERM).map_err(|e| {
                DaemonProcessError::Io {
                    what: "signalling lanealignd".into(),
                    source: e.into(),
                }
            })?;
        }
        Ok(self
            .child
            .wait()
            .map_err(io("waiting for lanealignd"))?
            .success())
    }
}

impl Drop for DaemonProcess {
    fn drop(&mut self) {
        if self.terminate().is_err() {
            let _ = self.child.kill();
        }
    }
}
