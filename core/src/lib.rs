//! lanealign core: removes odometry drift by aligning the recent trajectory to lane centerlines.
//!
//! Everything here is pure and free of IPC, threads and logging back ends: SE(2) geometry
//! ([`se2`]), 3D poses and axis conventions ([`pose`]), projections and anchors ([`geo`]), the
//! lane map ([`lane_map`]) and what its lanes rest on ([`lane_geometry`]), lane matching
//! ([`matching`], [`match_cache`]), trimmed ICP ([`icp`]), the online corrector ([`corrector`])
//! with its configuration ([`params`]) and its covariance ([`confidence`]), smooth output ([`smoothing`]), a source's corrector with
//! its placement ([`source_corrector`]), accuracy metrics ([`metrics`]) and the file formats
//! every tool shares: lane tiles ([`tile`]) and grids of them ([`grid`]), trajectories ([`trajectory`]) and lane CSV
//! ([`lane_csv`]), with bounded readers and atomic outputs ([`input`]) and numbers as they are written ([`number_text`]); [`plausibility`] warns
//! about runs that are probably set up wrongly; [`rng`] makes data from a fixed seed. The algorithm as implemented is described in `docs/algorithm.md`.
//!
//! ```
//! use std::sync::Arc;
//! use lanealign_core::{corrector::{Corrector, Status}, lane_map::{Lane, LaneMap}, params::Preset};
//!
//! // One eastbound lane along y = 0 (metres, map plane).
//! let lane = Lane::new(1, (0..200).map(|i| [i as f64 * 3.0, 0.0]).collect());
//! let map = Arc::new(LaneMap::new(&[lane]).unwrap());
//! let mut corrector = Corrector::new(map, Preset::KissIcp.params());
//! // Odometry, placed in the map plane by its anchor, that drifted 1 m to the left.
//! let mut last = None;
//! for i in 0..300 {
//!     last = Some(corrector.push([i as f64 * 1.5, 1.0]));
//! }
//! let step = last.unwrap();
//! assert!(matches!(step.status, Status::Accepted { .. }));
//! assert!((step.position_in_map[1]).abs() < 1e-6);
//! ```

pub mod confidence;
pub mod continuity;
pub mod corrector;
pub mod geo;
pub mod grid;
mod headroom;
pub mod icp;
pub mod input;
pub mod lane_csv;
pub mod lane_geometry;
pub mod lane_map;
pub mod match_cache;
pub mod matching;
pub mod metrics;
pub mod names;
pub mod number_text;
pub mod params;
pub mod plausibility;
pub mod pose;
pub mod report;
pub mod rng;
pub mod scale;
pub mod se2;
pub mod smoothing;
pub mod source_corrector;
pub mod stall;
pub mod tile;
pub mod trajectory;
mod window;
