//! The daemon stops at its first panic. A panic is a bug (an integer overflow included: the
//! release build checks for them), and a daemon that went on without the thread it ended would
//! leave that worker's sources unanswered while it looked alive to them. Aborting hands the
//! fault to the supervisor instead: systemd restarts the daemon within a second
//! (`Restart=always`) and every session continues from its journal, as after a `kill -9`
//! (docs/operations.md).

/// Makes a panic on any thread print its message (the standard hook's, on stderr, written before
/// anything else happens) and then abort the process (SIGABRT). Called once by `lanealignd`
/// before its workers start.
pub fn abort_on_panic() {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        report(info);
        eprintln!(
            "lanealignd: a thread panicked, which is a bug; aborting so that the supervisor \
             restarts the daemon and its sessions continue from their journals"
        );
        std::process::abort();
    }));
}

#[cfg(test)]
mod tests {
    use std::os::unix::process::ExitStatusExt;
    use std::process::Command;
    use std::time::Duration;

    /// Set in the child process the test below starts.
    const CHILD: &str = "LANEALIGN_FAIL_STOP_CHILD";
    const SIGABRT: i32 = 6;

    /// In a child process (this test binary, running only this test): a worker thread panics
    /// while the main thread goes on. Without the hook the child would join the thread, see its
    /// panic as an error and pass; with it the whole process ends by SIGABRT at once.
    #[test]
    fn a_panic_on_any_thread_aborts_the_process() {
        if std::env::var_os(CHILD).is_some() {
            super::abort_on_panic();
            let worker = std::thread::spawn(|| panic!("a worker's bug"));
            let joined = worker.join();
            std::thread::sleep(Duration::from_secs(5));
            println!("the process went on after {joined:?}");
            return;
        }
        let test_binary = std::env::current_exe().expect("the test binary's path");
        let child = Command::new(test_binary)
            .args([
                "--exact",
                "fail_stop::tests::a_panic_on_any_thread_aborts_the_process",
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
    }
}
