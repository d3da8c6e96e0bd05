//! Fuzzing every reader of untrusted input, on stable Rust.
//!
//! [`targets`] holds one harness per input kind (tile, OSM XML, PBF, Lanelet2, KITTI and TUM
//! pose files, lane CSV, daemon TOML, the wire payload, the daemon's journal snapshot): each
//! runs the product's own reading path on arbitrary bytes, where refusing the input is fine and
//! a panic, a hang or a crash is the bug. [`mutate`] derives inputs from the real-shaped seeds of [`seeds`] with a fixed-seed
//! generator, so a CI run is reproducible; [`regressions`] generates the known bad inputs every
//! build must refuse. `fuzz/` holds cargo-fuzz targets over the same harnesses for long runs, and
//! [`corpus`] writes their starting corpora.

pub mod corpus;
pub mod mutate;
pub mod pbf_writer;
pub mod regressions;
pub mod seeds;
pub mod targets;

/// Lets panics raised inside osmpbf unwind to the product's `catch_unwind` (osmpbf 0.3.8 panics
/// on some malformed relation members, which `lanealign_map::pbf` turns into an error), and
/// hands every other panic to the hook installed before (libFuzzer's, which aborts so that the
/// run stops at the finding). For the cargo-fuzz PBF targets: without it their first malformed
/// member ended a long run as a crash that is none.
pub fn let_osmpbf_panics_unwind() {
    let before = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let in_osmpbf = info
            .location()
            .is_some_and(|l| l.file().contains("/osmpbf-") || l.file().contains("/protobuf-"));
        if !in_osmpbf {
            before(info);
        }
    }));
}
