//! The daemon stops at its first panic. A panic is a bug (an integer overflow included: the
//! release build checks for them), and a daemon that went on without the thread it ended would
//! leave that worker's sources unanswered while it looked alive to them. Aborting hands the
//! fault to the supervisor instead: systemd restarts the daemon within a second
//! (`Restart=always`) and every session continues from its journal, as after a `kill -9`
//! (docs/operations.md).

use std::sync::{Arc, Mutex};
use tracing_appender::non_blocking::WorkerGuard;

/// Holds the daemon's log writer open until it is dropped at exit, when it writes every record
/// still waiting (the non-blocking writer's guard); [`abort_on_panic`]'s hook writes them
/// before it aborts.
pub struct LogFlush(Arc<Mutex<Option<WorkerGuard>>>);

impl Drop for LogFlush {
    fn drop(&mut self) {
        flush(&self.0);
    }
}

/// Waits (1.1 s at most) for the log thread to write every record sent before this call, once:
/// later calls find nothing to flush. Never blocks on the lock, which a panic in this very
/// function's caller could hold.
fn flush(log: &Mutex<Option<WorkerGuard>>) {
    if let Ok(mut guard) = log.try_lock() {
        drop(guard.take());
    }
}

/// A panic's message: what `panic!` formatted, or a placeholder for another payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> &str {
    payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("(a panic without a message)")
}

/// Makes a panic on any thread end the process: its message goes to stderr at once (the
/// standard hook's), then as an `ERROR` record in the daemon's log format with the records
/// before it (the log writer `log` flushed, where an abort would have dropped them), and then
/// the process aborts (SIGABRT). Called once by `lanealignd` before its workers start; the
/// returned [`LogFlush`] flushes the log when the daemon exits normally.
pub fn abort_on_panic(log: WorkerGuard) -> LogFlush {
    let log = Arc::new(Mutex::new(Some(log)));
    let in_hook = Arc::clone(&log);
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        report(info);
        let thread = std::thread::current();
        tracing::error!(
            thread = thread.name().unwrap_or("unnamed"),
            location = info.location().map(|l| l.to_string()),
            "a thread panicked: {}; aborting so that the supervisor restarts the daemon and its \
             sessions continue from their journals",
            panic_message(info.payload())
        );
        flush(&in_hook);
        eprintln!(
            "lanealignd: a thread panicked, which is a bug; aborting so that the supervisor \
             restarts the daemon and its sessions continue from their journals"
        );
        std::process::abort();
    }));
    LogFlush(log)
}

#[cfg(test)]
mod tests {
    use std::os::unix::process::ExitStatusExt;
    use std::process::Command;
    use std::time::Duration;

    /// Set in the child process the test below starts.
    const CHILD: &str = "LANEALIGN_FAIL_STOP_CHILD";
    const SIGABRT: i32 = 6;
    /// Records the worker logs before it panics, every one of which must come out. (Measured on
    /// the hook before: these came out, and the panic's own record, sent last, was lost in 2 of
    /// 3 runs.)
    const RECORDS: usize = 1000;

    /// In a child process (this test binary, running only this test), logging JSON through the
    /// daemon's non-blocking writer: a worker thread logs a thousand records and panics while
    /// the main thread goes on. Without the hook the child would join the thread, see its panic
    /// as an error and pass; with it the whole process ends by SIGABRT at once, after the
    /// records and the panic's own have been written.
    #[test]
    fn a_panic_on_any_thread_aborts_the_process_after_its_log() {
        if std::env::var_os(CHILD).is_some() {
            let (writer, guard) = tracing_appender::non_blocking::NonBlockingBuilder::default()
                .lossy(false)
                .finish(std::io::stderr());
            tracing_subscriber::fmt().with_writer(writer).json().init();
            let _flush = super::abort_on_panic(guard);
            let worker = std::thread::Builder::new()
                .name("worker-3".into())
                .spawn(|| {
                    for k in 0..RECORDS {
                        tracing::info!(k, "before the panic");
                    }
                    panic!("a worker's bug")
                })
                .expect("spawn");
            let joined = worker.join();
            std::thread::sleep(Duration::from_secs(5));
            println!("the process went on after {joined:?}");
            return;
        }
        let test_binary = std::env::current_exe().expect("the test binary's path");
        let child = Command::new(test_binary)
            .args([
                "--exact",
                "fail_stop::tests::a_panic_on_any_thread_aborts_the_process_after_its_log",
                "--nocapture",
            ])
            .env(CHILD, "1")
            .output()
            .expect("starting the child");
        let stdout = String::from_utf8_lossy(&child.stdout);
        let stderr = String::from_utf8_lossy(&child.stderr);
        assert_eq!(
            child.status.signal(),
            Some(SIGABRT),
            "the child ended with {:?}\nstdout: {stdout}\nstderr: {stderr}",
            child.status
        );
        assert!(!stdout.contains("went on"), "{stdout}");
        assert!(stderr.contains("a worker's bug"), "{stderr}");
        assert!(
            stderr.contains("aborting so that the supervisor restarts"),
            "{stderr}"
        );
        let records: Vec<serde_json::Value> = stderr
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect();
        let before = records
            .iter()
            .filter(|r| r["fields"]["message"] == "before the panic")
            .count();
        assert_eq!(before, RECORDS, "{stderr}");
        let last = records.last().expect("no JSON record");
        assert_eq!(last["level"], "ERROR", "{last}");
        assert_eq!(last["fields"]["thread"], "worker-3", "{last}");
        let message = last["fields"]["message"].as_str().unwrap_or_default();
        assert!(
            message.starts_with("a thread panicked: a worker's bug; aborting"),
            "{last}"
        );
        assert!(
            last["fields"]["location"]
                .as_str()
                .is_some_and(|l| l.contains("fail_stop.rs")),
            "{last}"
        );
    }
}
