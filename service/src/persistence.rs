//! The persistence thread: the journal work no worker waits for. It writes snapshots durably and
//! then deletes the segments they replace, removes the journals of ended sessions, and fsyncs
//! the open segments every second (a killed process loses nothing the kernel has; a power loss
//! loses at most the last second).

use std::collections::HashMap;
use std::fs::File;
use std::path::PathBuf;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::journal::{segment_path, segments, write_durably};
use crate::session::PersistJob;

/// How often open segments are synced to disk.
const SYNC_PERIOD: Duration = Duration::from_secs(1);

/// Starts the thread; it ends (after a last sync) when every sender is dropped.
pub fn spawn() -> std::io::Result<(Sender<PersistJob>, JoinHandle<()>)> {
    let (tx, rx) = mpsc::channel();
    let handle = std::thread::Builder::new()
        .name("persistence".into())
        .spawn(move || run(rx))?;
    Ok((tx, handle))
}

fn sync_all(tracked: &HashMap<PathBuf, File>) {
    for (dir, file) in tracked {
        if let Err(e) = file.sync_data() {
            tracing::warn!(dir = %dir.display(), error = %e, "syncing a journal segment failed");
        }
    }
}

fn run(rx: Receiver<PersistJob>) {
    let mut tracked: HashMap<PathBuf, File> = HashMap::new();
    loop {
        match rx.recv_timeout(SYNC_PERIOD) {
            Ok(PersistJob::Track { dir, file }) => {
                if let Some(previous) = tracked.insert(dir, file) {
                    // The segment before: its last records reach the disk too.
                    let _ = previous.sync_data();
                }
            }
            Ok(PersistJob::Snapshot {
                dir,
                bytes,
                keep_from,
            }) => match write_durably(&dir.join("snapshot"), &bytes) {
                Ok(()) => {
                    for n in segments(&dir).unwrap_or_default() {
                        if n < keep_from {
                            if let Err(e) = std::fs::remove_file(segment_path(&dir, n)) {
                                tracing::warn!(dir = %dir.display(), error = %e, "removing an old journal segment failed");
                            }
                        }
                    }
                }
                Err(e) => {
                    tracing::warn!(error = %lanealign_core::report::error_chain(&e), "writing a snapshot failed; the journal keeps its segments")
                }
            },
            Ok(PersistJob::Remove { dir }) => {
                tracked.remove(&dir);
                if let Err(e) = std::fs::remove_dir_all(&dir) {
                    if e.kind() != std::io::ErrorKind::NotFound {
                        tracing::warn!(dir = %dir.display(), error = %e, "removing an ended session's journal failed");
                    }
                }
            }
            Err(RecvTimeoutError::Timeout) => sync_all(&tracked),
            Err(RecvTimeoutError::Disconnected) => {
                sync_all(&tracked);
                return;
            }
        }
    }
}
