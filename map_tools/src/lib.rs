//! lanealign map tools: reads road data (OSM XML and PBF, Lanelet2) and compiles lane maps and
//! lane tiles for the corrector.
//!
//! ```no_run
//! use std::path::{Path, PathBuf};
//! use lanealign_map::compile::{compile, CompileOptions};
//!
//! let compiled = compile(&[PathBuf::from("karlsruhe.osm")], &CompileOptions::default())?;
//! lanealign_core::tile::write_bytes(Path::new("karlsruhe.tile"), &compiled.tile_bytes(3.0))?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod compile;
pub mod grid_compile;
pub mod keys;
pub mod lane_spill;
pub mod lanelet2;
pub mod node_store;
pub mod osm;
pub mod osm_lanes;
pub mod pbf;
