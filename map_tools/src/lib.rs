//! lanealign map tools: reads road data (OSM XML) and derives lane maps for the corrector.
//!
//! ```no_run
//! use std::path::Path;
//! use lanealign_core::geo::{MapPlane, Projection};
//! use lanealign_map::{osm::read_xml_file, osm_lanes::{derive_lanes, LaneOptions}};
//!
//! let osm = read_xml_file(Path::new("karlsruhe.osm"))?;
//! let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
//! let (lanes, report) = derive_lanes(&osm, &plane, &LaneOptions::default());
//! println!("{} lanes from {} ways", lanes.len(), report.ways_used);
//! # Ok::<(), lanealign_map::osm::OsmError>(())
//! ```

pub mod osm;
pub mod osm_lanes;
