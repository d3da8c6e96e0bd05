//! The daemon's request to the kernel to keep every CPU quick to wake (Linux PM QoS,
//! `/dev/cpu_dma_latency`).
//!
//! An idle CPU that halts takes tens of microseconds to run again, and comes back with cold
//! caches: on a 10 Hz or 100 Hz source that is every pose's wake-up. While a process holds the
//! device open with a latency written to it, the kernel keeps every CPU in idle states it can
//! leave within that latency (0: polling, never halting). The request ends when the file is
//! closed, so it lasts exactly as long as the daemon holds a [`CpuLatencyRequest`], and a
//! crashed daemon leaves none behind. Measured in docs/performance.md ("Waking up").

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The kernel's device for CPU wake-up latency requests.
pub const DEVICE: &str = "/dev/cpu_dma_latency";

/// The largest latency a configuration may ask for (microseconds): one second. The kernel's own
/// default is 2000 seconds, which asks nothing.
pub const MAX_US: u32 = 1_000_000;

/// A request that could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CpuLatencyError {
    /// The device could not be opened for writing.
    #[error("{path}: {source} (cpu_dma_latency_us needs write access to it: run the daemon as root, or give its user the device with a udev rule, docs/operations.md \"Waking up\"; or remove the key)")]
    Open {
        /// The device.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The latency could not be written.
    #[error("{path}: writing {us} us: {source}")]
    Write {
        /// The device.
        path: PathBuf,
        /// The latency asked for (microseconds).
        us: u32,
        /// Why.
        source: std::io::Error,
    },
}

/// A wake-up latency request, held until dropped.
#[derive(Debug)]
pub struct CpuLatencyRequest {
    /// The open device: closing it ends the request.
    _device: File,
}

impl CpuLatencyRequest {
    /// Asks the kernel ([`DEVICE`]) to keep every CPU able to run within `us` microseconds.
    pub fn hold(us: u32) -> Result<Self, CpuLatencyError> {
        Self::hold_at(Path::new(DEVICE), us)
    }

    /// [`CpuLatencyRequest::hold`] on the device at `path`: the latency as the kernel reads it,
    /// a native-endian 32-bit integer.
    pub fn hold_at(path: &Path, us: u32) -> Result<Self, CpuLatencyError> {
        let mut device = open_for_writing(path)?;
        // At most MAX_US once validated; a larger value would still be a valid request.
        let value = i32::try_from(us).unwrap_or(i32::MAX);
        device
            .write_all(&value.to_ne_bytes())
            .map_err(|source| CpuLatencyError::Write {
                path: path.to_path_buf(),
                us,
                source,
            })?;
        Ok(CpuLatencyRequest { _device: device })
    }
}

/// Checks, asking nothing, that the daemon may make a request at `path`: opening the device
/// without writing leaves the kernel's latency as it is.
pub fn check(path: &Path) -> Result<(), CpuLatencyError> {
    open_for_writing(path).map(drop)
}

/// The latency every CPU is kept to now (microseconds; the smallest of all requests), as the
/// device at `path` reads.
pub fn current(path: &Path) -> std::io::Result<i32> {
    let mut bytes = [0u8; 4];
    File::open(path)?.read_exact(&mut bytes)?;
    Ok(i32::from_ne_bytes(bytes))
}

fn open_for_writing(path: &Path) -> Result<File, CpuLatencyError> {
    OpenOptions::new()
        .write(true)
        .open(path)
        .map_err(|source| CpuLatencyError::Open {
            path: path.to_path_buf(),
            source,
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_writes_the_latency_as_the_kernel_reads_it_and_a_missing_device_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let device = dir.path().join("cpu_dma_latency");
        std::fs::write(&device, [0xff; 4]).unwrap();
        let request = CpuLatencyRequest::hold_at(&device, 20).unwrap();
        assert_eq!(current(&device).unwrap(), 20);
        drop(request);
        check(&device).unwrap();
        assert_eq!(current(&device).unwrap(), 20, "a check writes nothing");
        let missing = dir.path().join("absent");
        for e in [
            CpuLatencyRequest::hold_at(&missing, 0).unwrap_err(),
            check(&missing).unwrap_err(),
        ] {
            let text = e.to_string();
            assert!(
                text.contains("absent") && text.contains("udev rule"),
                "{text}"
            );
        }
    }
}
