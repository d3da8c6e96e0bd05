//! What a new session costs a client, with other software's files in `/dev/shm` beside the
//! namespace's: `Connection::connect_in` (no daemon needed), and side by side the two ways of
//! finding the namespace's files, reading all of `/dev/shm` (`Namespace::files`) and reading the
//! process's own mappings (`Namespace::mapped_files`, what reserving pages uses).
//!
//! `cargo bench -p lanealign-client --bench connect`: medians and 90th percentiles of 30 runs per
//! row, milliseconds.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use lanealign_client::connection::new_session_id;
use lanealign_client::Connection;
use lanealign_wire::service::Namespace;
use lanealign_wire::shm::SHM_DIR;

const RUNS: usize = 30;

/// Empty files of another program in `/dev/shm`, removed when dropped.
struct Foreign(Vec<PathBuf>);

impl Foreign {
    fn make(count: usize) -> Foreign {
        let files = (0..count)
            .map(|i| {
                PathBuf::from(format!(
                    "{SHM_DIR}/bench-foreign-{}-{i}",
                    std::process::id()
                ))
            })
            .collect::<Vec<_>>();
        for f in &files {
            std::fs::File::create(f).expect("room for empty files in /dev/shm");
        }
        Foreign(files)
    }
}

impl Drop for Foreign {
    fn drop(&mut self) {
        for f in &self.0 {
            let _ = std::fs::remove_file(f);
        }
    }
}

/// Median and 90th percentile of `runs` timings of `f`, in milliseconds.
fn timed(mut f: impl FnMut()) -> (f64, f64) {
    let mut t: Vec<Duration> = (0..RUNS)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .collect();
    t.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    (ms(t[RUNS / 2]), ms(t[RUNS * 9 / 10]))
}

fn main() {
    let namespace: Namespace = format!("cb{}", std::process::id())
        .parse()
        .expect("a short namespace");
    let source = "lidar".parse().expect("a valid source name");
    println!("| foreign files in {SHM_DIR} | connect p50 / p90 | Namespace::files p50 / p90 | Namespace::mapped_files p50 / p90 |");
    println!("|---|---|---|---|");
    for count in [0, 2_000, 20_000] {
        let _foreign = Foreign::make(count);
        let connect = timed(|| {
            let connection = Connection::connect_in(&namespace, &source, new_session_id())
                .expect("a client connects without a daemon");
            drop(connection);
        });
        // One connection held, so that the process maps some of the namespace's files.
        let _held = Connection::connect_in(&namespace, &source, new_session_id())
            .expect("a client connects without a daemon");
        let files = timed(|| assert!(!namespace.files().is_empty()));
        let mapped = timed(|| {
            assert!(!namespace
                .mapped_files()
                .expect("/proc/self/maps")
                .is_empty())
        });
        println!(
            "| {count} | {:.2} / {:.2} | {:.2} / {:.2} | {:.3} / {:.3} |",
            connect.0, connect.1, files.0, files.1, mapped.0, mapped.1
        );
    }
    let _ = namespace.remove_files();
}
