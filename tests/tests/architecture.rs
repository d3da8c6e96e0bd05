//! The dependency rules of docs/architecture.md, checked on every crate's manifest: what an
//! odometry process links stays thin, and dependencies point down. And its "Build": the installed
//! commands and the Python package resolve their dependencies as the workspace's build does.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::Command;

/// The workspace's root folder.
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The manifest in `folder` (relative to the workspace's root).
fn manifest(folder: &str) -> toml::Table {
    let path = root().join(folder).join("Cargo.toml");
    std::fs::read_to_string(&path).unwrap().parse().unwrap()
}

/// The normal (not dev, not build) dependencies of the crate in `folder`.
fn dependencies(folder: &str) -> BTreeSet<String> {
    manifest(folder)
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map(|d| d.keys().cloned().collect())
        .unwrap_or_default()
}

/// The crate that pins the third-party dependencies' features for the installed commands.
const WORKSPACE_HACK: &str = "lanealign-workspace-hack";

fn names(list: &[&str]) -> BTreeSet<String> {
    list.iter().map(|s| s.to_string()).collect()
}

#[test]
fn what_an_odometry_process_links_is_wire_and_iceoryx2_only() {
    assert_eq!(
        dependencies("client"),
        names(&["iceoryx2", "lanealign-wire", "thiserror"])
    );
    // serde (the wait strategy's configuration form) is in iceoryx2's own tree: nothing more
    // to compile for an odometry process.
    assert_eq!(
        dependencies("wire"),
        names(&["iceoryx2", "rustix", "serde", "thiserror"])
    );
}

#[test]
fn dependencies_point_down() {
    // The workspace hack holds no code (docs/architecture.md, "Build"): not a layer.
    let lanealign = |folder: &str| -> BTreeSet<String> {
        dependencies(folder)
            .into_iter()
            .filter(|d| d.starts_with("lanealign") && d != WORKSPACE_HACK)
            .collect()
    };
    assert_eq!(lanealign("core"), names(&[]));
    assert_eq!(lanealign("map_tools"), names(&["lanealign-core"]));
    assert_eq!(
        lanealign("service"),
        names(&["lanealign-core", "lanealign-wire"])
    );
    // The core is pure: no IPC, command line, threads pool or logging back end.
    for outside in ["iceoryx2", "clap", "rayon", "tracing-subscriber", "anyhow"] {
        assert!(
            !dependencies("core").contains(outside),
            "core depends on {outside}"
        );
    }
}

#[test]
fn only_the_installed_commands_pin_the_workspaces_features() {
    // The hack pulls the features of everything the workspace builds (clap's, regex's, the
    // tests' random numbers) into whoever depends on it: the commands README installs, and
    // no library another program links.
    let workspace = manifest(".");
    let members = workspace["workspace"]["members"]
        .as_array()
        .expect("the workspace lists its members");
    let pinning: BTreeSet<String> = members
        .iter()
        .map(|m| m.as_str().expect("a member is a folder"))
        .filter(|folder| dependencies(folder).contains(WORKSPACE_HACK))
        .map(String::from)
        .collect();
    assert_eq!(pinning, names(&["cli", "map_tools", "service"]));
}

/// The third-party packages a build of `selection` compiles, each with the features it is
/// compiled with, as `cargo tree` resolves them (one `name version [features]` a line).
fn resolved(selection: &[&str]) -> BTreeSet<String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(root())
        .args([
            "tree",
            "--locked",
            "--prefix",
            "none",
            "--format",
            "{p} [{f}]",
        ])
        .args(selection)
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo tree {selection:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|line| line.replace(" (*)", "").replace(" (proc-macro)", ""))
        .filter(|line| !line.is_empty() && !line.starts_with("lanealign"))
        .collect()
}

#[test]
fn installing_a_command_compiles_nothing_the_workspace_build_did_not() {
    // README's install step builds each command's package alone, after (in CI) or instead of
    // the workspace's build. Cargo resolves a dependency's features for what it builds, so a
    // package that needs fewer of them than the whole workspace compiles that dependency and
    // everything above it again (2 min 46 s for the three on this machine). The workspace hack
    // pins them: when this fails, run `cargo hakari generate` (docs/architecture.md, "Build").
    let workspace = resolved(&["--workspace", "--edges", "normal,build,dev"]);
    for package in ["lanealign-cli", "lanealign-map", "lanealign-service"] {
        let alone = resolved(&["--package", package, "--edges", "normal,build"]);
        let differing: Vec<&String> = alone.difference(&workspace).collect();
        assert!(
            differing.is_empty(),
            "{package} alone resolves these otherwise than the workspace: {differing:?}"
        );
    }
}

#[test]
fn the_python_package_builds_on_the_workspaces_compiled_dependencies() {
    // `cargo test` builds the Python package on the workspace's compiled dependencies
    // (tests/tests/python.rs): those it shares with the workspace must resolve alike there too.
    // pyo3's macros need more of `syn` than the workspace: one such crate resolved otherwise
    // makes every crate above it (serde's and clap's derives, so nearly all) compile again.
    let workspace = resolved(&["--workspace", "--edges", "normal,build,dev"]);
    let name_and_version = |line: &str| line.split(" [").next().unwrap_or_default().to_owned();
    let in_workspace: BTreeSet<String> = workspace.iter().map(|l| name_and_version(l)).collect();
    let python = resolved(&[
        "--manifest-path",
        "python/Cargo.toml",
        "--edges",
        "normal,build",
    ]);
    let differing: Vec<&String> = python
        .iter()
        .filter(|line| in_workspace.contains(&name_and_version(line)))
        .filter(|line| !workspace.contains(*line))
        .collect();
    assert!(
        differing.is_empty(),
        "the Python package resolves these otherwise than the workspace: {differing:?}"
    );
}
