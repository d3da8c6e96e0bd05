//! lanealign core: removes odometry drift by aligning the recent trajectory to lane centerlines.
//!
//! Everything here is pure and free of IPC and threads: SE(2) geometry ([`se2`]), the lane map
//! ([`lane_map`]), lane matching ([`matching`]), trimmed ICP ([`icp`]), the online corrector
//! ([`corrector`]) with the paper's presets and lanealign's robust method ([`params`]), smooth
//! output ([`smoothing`]), map projections and anchors ([`geo`]),
//! trajectory files ([`trajectory`]) and accuracy metrics ([`metrics`]).
//!
//! ```
//! use std::sync::Arc;
//! use lanealign_core::{corrector::{Corrector, Status}, lane_map::{Lane, LaneMap}, params::Preset};
//!
//! // One eastbound lane along y = 0 (metres, map plane).
//! let lane = Lane { id: 1, points: (0..200).map(|i| [i as f64 * 3.0, 0.0]).collect() };
//! let map = Arc::new(LaneMap::new(&[lane]).unwrap());
//! let mut corrector = Corrector::new(map, Preset::KissIcp.params());
//! // Odometry that drifted 1 m to the left.
//! let mut last = None;
//! for i in 0..300 {
//!     last = Some(corrector.push([i as f64 * 1.5, 1.0]));
//! }
//! let step = last.unwrap();
//! assert!(matches!(step.status, Status::Accepted { .. }));
//! assert!((step.position_in_map[1]).abs() < 1e-6);
//! ```

pub mod corrector;
pub mod geo;
pub mod icp;
pub mod lane_csv;
pub mod lane_map;
pub mod match_cache;
pub mod matching;
pub mod metrics;
pub mod offline;
pub mod params;
pub mod pose;
pub mod se2;
pub mod smoothing;
pub mod tile;
pub mod trajectory;
