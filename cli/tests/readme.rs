//! Every command README.md shows, run as written: each ```sh block is a bash script, run from a
//! scratch folder laid out like a checkout (its `configs/` copied, `../shared` beside it), with
//! this build's binaries first on PATH. Three kinds of line are not run by bash, and why:
//!
//! - `cargo install ...`: it installs into the user's cargo root. It is the build CI does, and
//!   `.ci/run` runs it into a temporary root; here its packages are checked to be the ones that
//!   own the three binaries.
//! - `cargo test ...`: it is the command running this test.
//! - `cargo run --release -p lanealign-cli --example NAME -- ARGS`: cargo would wait for the
//!   build lock the running `cargo test` holds, so the same example binary runs directly, with
//!   the same arguments.

use std::path::{Path, PathBuf};
use std::process::Command;

use lanealign_cli::daemon_config;
use lanealign_tests::shared_data;

/// The ```sh blocks of the README, each as its lines (trailing `\` continuations joined).
fn sh_blocks(readme: &str) -> Vec<Vec<String>> {
    let mut blocks = Vec::new();
    let mut current: Option<Vec<String>> = None;
    for line in readme.lines() {
        match (&mut current, line.trim()) {
            (None, "```sh") => current = Some(Vec::new()),
            (Some(_), "```") => blocks.extend(current.take()),
            (Some(lines), text) => match lines.last_mut() {
                Some(last) if last.ends_with('\\') => {
                    last.pop();
                    last.push_str(text);
                }
                _ if text.is_empty() => {}
                _ => lines.push(text.to_string()),
            },
            (None, _) => {}
        }
    }
    blocks
}

/// The script bash runs for a block: README lines, with the three exceptions handled.
fn script(block: &[String], bin: &Path) -> String {
    let mut out = String::from("set -euxo pipefail\n");
    for line in block {
        if line.starts_with("cargo install") {
            for (package, binary) in [
                ("cli", "lanealign"),
                ("map_tools", "lanealign-map"),
                ("service", "lanealignd"),
            ] {
                assert!(
                    line.contains(&format!("--path {package}")),
                    "the install line must install {package} ({binary}): {line}"
                );
                assert!(
                    bin.join(binary).is_file(),
                    "{binary} was built (cargo test builds a binary for its package's integration tests)"
                );
            }
        } else if line == "pip install ./python" {
            // tests/tests/python.rs runs it (and the package's tests) from the checkout.
        } else if line.starts_with("cargo test") {
            assert_eq!(
                line, "cargo test --release --workspace",
                "the test command changed"
            );
        } else if let Some(rest) =
            line.strip_prefix("cargo run --release -p lanealign-cli --example ")
        {
            let (name, args) = rest.split_once(" -- ").unwrap_or((rest, ""));
            out.push_str(&format!(
                "{} {args}\n",
                bin.join("examples").join(name.trim()).display()
            ));
        } else {
            assert!(
                !line.starts_with("cargo"),
                "a cargo command this test does not know: {line}"
            );
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
    }
}

#[test]
fn every_readme_command_runs_as_written() {
    let Some(data) = shared_data() else { return };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_lanealign"))
        .parent()
        .unwrap()
        .to_path_buf();
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let blocks = sh_blocks(&readme);
    assert!(blocks.len() >= 6, "found {} sh blocks", blocks.len());
    let scratch = tempfile::tempdir().unwrap();
    let checkout = scratch.path().join("main");
    copy_dir(&root.join("configs"), &checkout.join("configs"));
    std::os::unix::fs::symlink(data.parent().unwrap(), scratch.path().join("shared")).unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    for block in &blocks {
        let text = script(block, &bin);
        let out = Command::new("bash")
            .arg("-c")
            .arg(&text)
            .current_dir(&checkout)
            .env("PATH", &path)
            .env_remove("LANEALIGN_DATA")
            // The daemon's state (journals, lock, the newest map version served) in the
            // scratch folder: the user's own would both receive this run's and refuse it a map
            // older than one a daemon of theirs served.
            .env("LANEALIGN_STATE_DIR", scratch.path().join("state"))
            .output()
            .expect("run bash");
        assert!(
            out.status.success(),
            "README block failed:\n{text}\nstdout:\n{}\nstderr:\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // What the commands were for exists.
    for file in [
        "corrected.txt",
        "status.csv",
        "00.tile",
        "00.geojson",
        "corrected_from_tile.txt",
        "grid00/manifest.toml",
        "corrected_from_grid.txt",
        "corrected_07.txt",
        "configs/kitti_00.tile",
        "replayed.txt",
    ] {
        assert!(checkout.join(file).is_file(), "{file} was written");
    }
    // A tile compiled with the anchor's origin corrects exactly like the OSM it came from, and the
    // daemon's answers equal offline correction (same default method and preset).
    let read = |f: &str| std::fs::read(checkout.join(f)).unwrap();
    assert!(
        read("corrected.txt") == read("corrected_from_tile.txt"),
        "--map equals --osm"
    );
    assert!(
        read("corrected_from_tile.txt") == read("replayed.txt"),
        "replay equals correct"
    );
}

/// Without the shared data, `lanealign demo` runs the synthetic town, as README says.
#[test]
fn the_demo_runs_without_data() {
    let empty = tempfile::tempdir().unwrap();
    let demo = Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .arg("demo")
        .env("LANEALIGN_DATA", empty.path())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let namespace = daemon_config::run_namespace("demo", demo.id()).unwrap();
    let out = demo.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("synthetic town"), "{stdout}");
    assert!(
        stdout.contains("identical to offline `lanealign correct`: yes"),
        "{stdout}"
    );
    // It says how well the answers' covariances describe their errors.
    let coverage: f64 = stdout
        .split("confidence: ")
        .nth(1)
        .and_then(|rest| rest.split(" % of the corrected poses").next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no confidence line: {stdout}"));
    assert!((0.0..=100.0).contains(&coverage), "{stdout}");
    // The town's odometry drifts far faster than the preset assumes (README): the verdict says
    // so.
    assert!(
        stdout.contains("independent errors): too confident"),
        "{stdout}"
    );
    // Latency is measured without queueing, throughput separately, and both runs agree.
    assert!(stdout.contains("latency, one pose in flight"), "{stdout}");
    assert!(
        stdout.contains("throughput, 64 poses in flight (a new session, same answers: yes)"),
        "{stdout}"
    );
    assert_eq!(
        namespace.files(),
        Vec::<PathBuf>::new(),
        "the demo's namespace files"
    );
}
