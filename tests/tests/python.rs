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
            // The extension is built on what `cargo test` compiled already: the Python crate
            // has the workspace's release profile and dependency versions (below), and the
            // workspace asks for the features it needs (docs/architecture.md, "Build"), so its
            // third-party dependencies but pyo3, numpy, ndarray and rustc-hash (architecture.md
            // says why) are the workspace's own artifacts (this test 72 s instead of 112 s in CI
            // on a clean clone, 2026-12-02).
            .env("CARGO_TARGET_DIR", root.join("target"))
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

/// The Python package is built with the command line's dependency versions, so that the two
/// run the same code (their results are compared bit for bit) and the package's build reuses
/// the workspace's: every package `python/Cargo.lock` shares with `Cargo.lock` has the same
/// version there. Copy `Cargo.lock` over `python/Cargo.lock` and run `cargo metadata` in
/// `python/` to bring them together again.
#[test]
fn the_python_package_locks_the_workspaces_dependency_versions() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let versions = |path: &str| -> Vec<(String, String)> {
        let text = std::fs::read_to_string(root.join(path)).expect(path);
        let lock: toml::Table = text.parse().expect(path);
        lock["package"]
            .as_array()
            .expect("a lock file lists packages")
            .iter()
            .map(|p| {
                (
                    p["name"].as_str().unwrap().into(),
                    p["version"].as_str().unwrap().into(),
                )
            })
            .collect()
    };
    let workspace = versions("Cargo.lock");
    let python = versions("python/Cargo.lock");
    let differing: Vec<String> = python
        .iter()
        .filter(|(name, _)| workspace.iter().any(|(n, _)| n == name))
        .filter(|package| !workspace.contains(package))
        .map(|(name, version)| format!("{name} {version}"))
        .collect();
    assert!(
        differing.is_empty(),
        "python/Cargo.lock has versions Cargo.lock does not: {differing:?}"
    );
    assert!(python.len() > 200 && python.iter().any(|(n, _)| n == "pyo3"));
}
