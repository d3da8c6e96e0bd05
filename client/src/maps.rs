//! Where a corrector's lane map comes from, and how a source is placed on it.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::lane_csv;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::se2::Se2;
use lanealign_core::tile;
use lanealign_map::compile::{compile, CompileOptions, InputReport};
use lanealign_map::osm_lanes::LaneOptions;

/// A loaded map, the source's placement on it, and what reading road data reported.
pub struct LoadedMap {
    /// The lane map.
    pub map: Arc<LaneMap>,
    /// `plane_from_odom`: where the source's planar odometry frame lies in the map plane.
    pub plane_from_odom: Se2,
    /// For road data compiled on the fly, what the reader did (skipped ways, missing nodes).
    pub report: Option<InputReport>,
}

/// A lane map source as given on the command line.
#[derive(Clone, Debug)]
pub enum MapSource {
    /// Raw OSM or Lanelet2 (XML or PBF), compiled in memory in the plane at the anchor's origin.
    Osm {
        /// The road data file.
        path: PathBuf,
        /// Where the odometry frame lies on Earth.
        anchor: Anchor,
        /// The projection the anchor was measured in.
        projection: Projection,
        /// Lane derivation options.
        options: LaneOptions,
    },
    /// A compiled tile, memory-mapped.
    Tile {
        /// The tile file.
        path: PathBuf,
        /// Where the odometry frame lies on Earth.
        anchor: Anchor,
    },
    /// Lane polylines already in the source's planar odometry frame (`lane_id,x,y`).
    LanesCsv(PathBuf),
}

impl MapSource {
    /// Loads the map and places the source on it.
    pub fn load(&self) -> anyhow::Result<LoadedMap> {
        match self {
            MapSource::Osm {
                path,
                anchor,
                projection,
                options,
            } => {
                let compile_options = CompileOptions {
                    origin: Some((anchor.lat, anchor.lon)),
                    projection: *projection,
                    lanes: options.clone(),
                };
                let (map, _, mut reports) = compile(std::slice::from_ref(path), &compile_options)?;
                Ok(LoadedMap {
                    map: Arc::new(map),
                    plane_from_odom: anchor.plane_from_odom(),
                    report: reports.pop(),
                })
            }
            MapSource::Tile { path, anchor } => {
                let (map, info) = tile::load(path)?;
                Ok(LoadedMap {
                    map: Arc::new(map),
                    plane_from_odom: anchor.plane_from_odom_in(&info.plane),
                    report: None,
                })
            }
            MapSource::LanesCsv(path) => {
                let lanes = lane_csv::read(path)?;
                let map = LaneMap::new(&lanes)
                    .with_context(|| format!("building the lane map of {}", path.display()))?;
                Ok(LoadedMap {
                    map: Arc::new(map),
                    plane_from_odom: Se2::IDENTITY,
                    report: None,
                })
            }
        }
    }
}
