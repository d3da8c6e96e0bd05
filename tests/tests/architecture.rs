//! The dependency rules of docs/architecture.md, checked on every crate's manifest: what an
//! odometry process links stays thin, and dependencies point down.

use std::collections::BTreeSet;
use std::path::PathBuf;

/// The normal (not dev, not build) dependencies of the crate in `folder`.
fn dependencies(folder: &str) -> BTreeSet<String> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(folder)
        .join("Cargo.toml");
    let manifest: toml::Table = std::fs::read_to_string(&path).unwrap().parse().unwrap();
    manifest
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map(|d| d.keys().cloned().collect())
        .unwrap_or_default()
}

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
    let lanealign = |folder: &str| -> BTreeSet<String> {
        dependencies(folder)
            .into_iter()
            .filter(|d| d.starts_with("lanealign"))
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
