//! Room in the shared-memory file system, `/dev/shm` (a tmpfs). iceoryx2 sizes its files with
//! `ftruncate`, which succeeds on a full tmpfs; the first write to a page that then finds no
//! room kills the writing process with SIGBUS (measured: a client replaying into a `/dev/shm`
//! of 240 KiB died so, and the daemon beside it in another run). So a process checks for room
//! before it makes a session's files ([`check_room`]) and reserves the pages of its namespace's
//! files after ([`reserve`], `fallocate`): a full `/dev/shm` becomes an error it reports, and a
//! page it reserved can no longer fail it.

use std::os::unix::fs::MetadataExt;
use std::path::PathBuf;

use crate::service::Namespace;

/// The shared-memory file system: iceoryx2's shared memory, and each namespace's folder
/// ([`crate::service::Namespace::root_path`]).
pub const SHM_DIR: &str = "/dev/shm";

/// What a client's side of a session adds to [`SHM_DIR`] at most (bytes, the sizes of its
/// files): 810 KB measured with iceoryx2 0.10 and this crate's service settings, most of it
/// the data segment of its pose publisher; `cli/tests/daemon.rs` checks that a session stays
/// within it.
pub const CLIENT_SESSION_BYTES: u64 = 1_000_000;
/// What the daemon's side of a session adds to [`SHM_DIR`] at most (bytes): 1.35 MB measured,
/// most of it the data segment of its answer publisher; checked with the client's.
pub const DAEMON_SESSION_BYTES: u64 = 1_600_000;
/// What a whole session adds to [`SHM_DIR`] at most (bytes): a client checks for room for both
/// sides before it connects, so that it hears of a full [`SHM_DIR`] at once rather than from a
/// daemon that cannot answer it.
pub const SESSION_BYTES: u64 = CLIENT_SESSION_BYTES + DAEMON_SESSION_BYTES;

/// What the daemon's side of one source takes in [`SHM_DIR`] before any session (bytes, in
/// the file system's blocks: its pose services' records and the worker's ports): 52 KiB
/// measured, with a margin.
pub const SOURCE_BYTES: u64 = 100_000;

/// The shared-memory file system has no room.
#[derive(Debug, thiserror::Error)]
pub enum ShmError {
    /// Too little room for what is to be made.
    #[error("{SHM_DIR} has {available} bytes free and {what} needs up to {needed} there: make it larger (a tmpfs size, `docker run --shm-size`) or end sessions (docs/operations.md, \"Shared memory\")")]
    Full {
        /// What is to be made: `a session`, `a source`.
        what: &'static str,
        /// Free bytes.
        available: u64,
        /// Bytes needed.
        needed: u64,
    },
    /// A file's pages could not be reserved.
    #[error("reserving the pages of {} in {SHM_DIR} failed: it is full (docs/operations.md, \"Shared memory\")", path.display())]
    Reserve {
        /// The file.
        path: PathBuf,
        /// What failed.
        #[source]
        source: std::io::Error,
    },
    /// The free room could not be read.
    #[error("reading the free room of {SHM_DIR} failed")]
    Stat(#[source] std::io::Error),
}

/// Free bytes in [`SHM_DIR`] for an unprivileged process.
pub fn available_bytes() -> Result<u64, ShmError> {
    let stat = rustix::fs::statvfs(SHM_DIR).map_err(|e| ShmError::Stat(e.into()))?;
    Ok(stat.f_bavail.saturating_mul(stat.f_frsize))
}

/// `Ok` when [`SHM_DIR`] has at least `needed` bytes free for `what` (`a session`, named in
/// the error).
pub fn check_room(what: &'static str, needed: u64) -> Result<(), ShmError> {
    let available = available_bytes()?;
    if available < needed {
        return Err(ShmError::Full {
            what,
            available,
            needed,
        });
    }
    Ok(())
}

/// Reserves every page not backed yet of the namespace's files in [`SHM_DIR`] that this
/// process has mapped ([`Namespace::mapped_files`]; all of the namespace's files when the
/// process's mappings cannot be read), so that writing to them can never fail with SIGBUS: a
/// process writes only to files it maps, and each side reserves its own after making its
/// ports. Returns how many files it reserved pages of. A file that vanished meanwhile (a
/// session ended) or that this process may not write (the namespace's files belong to one user)
/// is passed over; a file system without `fallocate` too (there the pages were never sparse).
/// Costs a `stat` per file when all are reserved.
pub fn reserve(namespace: &Namespace) -> Result<usize, ShmError> {
    let mut reserved = 0;
    let files = namespace
        .mapped_files()
        .unwrap_or_else(|| namespace.files());
    for path in files {
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            continue;
        };
        if !meta.is_file() || meta.blocks().saturating_mul(512) >= meta.size() {
            continue;
        }
        let Ok(file) = std::fs::OpenOptions::new().write(true).open(&path) else {
            continue;
        };
        match rustix::fs::fallocate(&file, rustix::fs::FallocateFlags::empty(), 0, meta.size()) {
            Ok(()) => reserved += 1,
            Err(rustix::io::Errno::NOSPC) => {
                return Err(ShmError::Reserve {
                    path,
                    source: rustix::io::Errno::NOSPC.into(),
                })
            }
            Err(_) => {}
        }
    }
    Ok(reserved)
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::MetadataExt;

    use super::*;
    use crate::service::{Ipc, PoseServices};

    /// Bytes of `path` not backed by pages.
    fn sparse_bytes(path: &std::path::Path) -> u64 {
        let meta = std::fs::metadata(path).unwrap();
        meta.size().saturating_sub(meta.blocks() * 512)
    }

    #[test]
    fn a_process_reserves_the_files_it_maps_and_no_others() {
        let namespace: Namespace = format!("r{}", std::process::id()).parse().unwrap();
        let node = namespace.node::<Ipc>().unwrap();
        let poses = PoseServices::open(&node, &"lidar".parse().unwrap()).unwrap();
        let publisher = poses.publisher().unwrap();
        // Another process's file of the namespace, which this one never maps.
        let foreign = std::path::PathBuf::from(format!(
            "{SHM_DIR}/{}{}.other",
            namespace.prefix(),
            "ab".repeat(20)
        ));
        std::fs::File::create(&foreign)
            .unwrap()
            .set_len(1 << 20)
            .unwrap();
        let mapped = namespace.mapped_files().unwrap();
        assert!(
            !mapped.is_empty() && !mapped.contains(&foreign),
            "{mapped:?}"
        );
        assert!(mapped.iter().all(|f| namespace.files().contains(f)));
        let sparse_before: u64 = mapped.iter().map(|f| sparse_bytes(f)).sum();
        assert!(
            sparse_before > 0,
            "the publisher's data segment is sparse until reserved"
        );
        assert!(reserve(&namespace).unwrap() > 0);
        assert_eq!(mapped.iter().map(|f| sparse_bytes(f)).sum::<u64>(), 0);
        assert_eq!(
            sparse_bytes(&foreign),
            1 << 20,
            "not this process's to reserve"
        );
        drop((publisher, poses, node));
        namespace.remove_files().unwrap();
        assert!(!foreign.exists());
    }
}
