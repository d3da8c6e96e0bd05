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
    /// Loads the map and returns it with `plane_from_odom`, the source's placement on it.
    pub fn load(&self) -> anyhow::Result<(Arc<LaneMap>, Se2)> {
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
                let (map, _, reports) = compile(std::slice::from_ref(path), &compile_options)?;
                if let Some(InputReport::Osm(r)) = reports.first() {
                    if r.missing_node_refs > 0 || r.ways_without_geometry > 0 {
                        eprintln!(
                            "warning: {}: {} node references missing, {} drivable ways without geometry (skipped)",
                            path.display(),
                            r.missing_node_refs,
                            r.ways_without_geometry
                        );
                    }
                }
                Ok((Arc::new(map), anchor.plane_from_odom()))
            }
            MapSource::Tile { path, anchor } => {
                let (map, info) = tile::load(path)?;
                Ok((Arc::new(map), anchor.plane_from_odom_in(&info.plane)))
            }
            MapSource::LanesCsv(path) => {
                let lanes = lane_csv::read(path)?;
                let map = LaneMap::new(&lanes)
                    .with_context(|| format!("building the lane map of {}", path.display()))?;
                Ok((Arc::new(map), Se2::IDENTITY))
            }
        }
    }
}
