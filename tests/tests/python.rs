//! The Python package (`python/`, PyO3 + maturin), built and tested from `cargo test`: pip
//! installs it with its build backend, pytest and Dask, then its tests compare `lanealign.correct` and
//! `lanealign.eval` with the `lanealign` binary bit for bit (on the synthetic straight lane
//! always, on KITTI 07 where `../shared/data` is present).

use std::path::PathBuf;
use std::process::Command;

#[test]
fn the_python_package_equals_the_command_line() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let run = |args: &[&str]| {
        let out = Command::new(&python)
            .args(args)
            .current_dir(&root)
            .env("LANEALIGN_BIN", root.join("target/release/lanealign"))
            .output()
            .unwrap_or_else(|e| panic!("{python} is needed for the Python package's tests: {e}"));
        let text = format!(
            "{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(out.status.success(), "{python} {args:?} failed:\n{text}");
        text
    };
    run(&[
        "-m",
        "pip",
        "install",
        "--quiet",
        "pytest",
        "dask[distributed]",
        "./python",
    ]);
    let report = run(&["-m", "pytest", "python/tests", "-q", "-rs", "-s"]);
    println!("{report}");
    assert!(report.contains("passed"), "{report}");
}
