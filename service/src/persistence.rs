//! The persistence thread: the journal work no worker waits for. It writes snapshots durably and
//! then deletes the segments they replace, removes the journals of ended sessions, and every
//! second copies the records appended to the open segments into their synced copies (a killed
//! process loses nothing the kernel has; a power loss loses at most the last second). The
//! segments themselves are never synced (crate::journal: a sync would fault the worker's next
//! copy on its latency path).

use lanealign_core::report::error_line;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::journal::{remove_segment, segments, write_durably, SegmentCopier};
use crate::session::PersistJob;

/// How often the open segments' new records are copied and synced to disk.
const SYNC_PERIOD: Duration = Duration::from_secs(1);

/// Starts the thread; it ends (after a last sync) when every sender is dropped.
pub fn spawn() -> std::io::Result<(Sender<PersistJob>, JoinHandle<()>)> {
    let (tx, rx) = mpsc::channel();
    let handle = std::thread::Builder::new()
        .name("persistence".into())
        .spawn(move || run(rx))?;
    Ok((tx, handle))
}

/// Copies and syncs the segment's new records; false (logged) when that failed.
fn sync(dir: &std::path::Path, copier: &mut SegmentCopier) -> bool {
    match copier.sync() {
        Ok(()) => true,
        Err(e) => {
            tracing::warn!(dir = %dir.display(), error = %error_line(&e), "syncing a journal segment's copy failed; this segment is no longer copied (the session's next segment is)");
            false
        }
    }
}

/// Syncs every tracked segment's copy. A copy that failed is no longer tracked: the disk or the
/// folder under it is failing, and trying again every second would log the same failure every
/// second (the worker's own journal then fails at its next segment, or tracks a new one).
fn sync_all(tracked: &mut HashMap<PathBuf, SegmentCopier>) {
    tracked.retain(|dir, copier| sync(dir, copier));
}

fn run(rx: Receiver<PersistJob>) {
    let mut tracked: HashMap<PathBuf, SegmentCopier> = HashMap::new();
    // Due every period whether or not jobs keep arriving (under load they always do).
    let mut next_sync = Instant::now() + SYNC_PERIOD;
    loop {
        let job = rx.recv_timeout(next_sync.saturating_duration_since(Instant::now()));
        if Instant::now() >= next_sync {
            sync_all(&mut tracked);
            next_sync = Instant::now() + SYNC_PERIOD;
        }
        match job {
            Ok(PersistJob::Track { dir, copier }) => {
                if let Some(mut previous) = tracked.insert(dir.clone(), copier) {
                    // The segment before: its last records reach the disk too.
                    sync(&dir, &mut previous);
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
                            if let Err(e) = remove_segment(&dir, n) {
                                tracing::warn!(error = %error_line(&e), "removing an old journal segment failed");
                            }
                        }
                    }
                }
                Err(e) => {
                    tracing::warn!(error = %error_line(&e), "writing a snapshot failed; the journal keeps its segments")
                }
            },
            Ok(PersistJob::Remove { dir }) => {
                tracked.remove(&dir);
                if let Err(e) = std::fs::remove_dir_all(&dir) {
                    if e.kind() != std::io::ErrorKind::NotFound {
                        tracing::warn!(dir = %dir.display(), error = %error_line(&e), "removing an ended session's journal failed");
                    }
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => {
                sync_all(&mut tracked);
                return;
            }
        }
    }
}
