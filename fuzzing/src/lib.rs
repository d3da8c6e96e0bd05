//! Fuzzing every reader of untrusted input, on stable Rust.
//!
//! [`targets`] holds one harness per input kind (tile, OSM XML, PBF, Lanelet2, KITTI and TUM
//! pose files, lane CSV, daemon TOML, the wire payload): each runs the product's own reading
//! path on arbitrary bytes, where refusing the input is fine and a panic, a hang or a crash is
//! the bug. [`mutate`] derives inputs from the real-shaped seeds of [`seeds`] with a fixed-seed
//! generator, so a CI run is reproducible; [`regressions`] generates the known bad inputs every
//! build must refuse. `fuzz/` holds cargo-fuzz targets over the same harnesses for long runs.

pub mod mutate;
pub mod pbf_writer;
pub mod regressions;
pub mod seeds;
pub mod targets;
