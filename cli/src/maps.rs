//! Where a corrector's lane map comes from, and how a source is placed on it.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Context};
use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::lane_csv;
use lanealign_core::lane_geometry::LaneGeometry;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::se2::Se2;
use lanealign_core::tile;
use lanealign_map::compile::{compile, CompileOptions, InputReport};
use lanealign_map::osm_lanes::LaneOptions;

/// A loaded map, the source's placement on it, and what is known about its lanes.
pub struct LoadedMap {
    /// The lane map.
    pub map: Arc<LaneMap>,
    /// Where the source's anchor places its planar odometry frame in the map plane.
    pub anchored_from_odom: Se2,
    /// The map's plane (`None` for lanes given in the odometry frame).
    pub plane: Option<MapPlane>,
    /// How the lanes were derived (`None` for lanes given as CSV).
    pub geometry: Option<LaneGeometry>,
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
    /// A compiled tile.
    Tile {
        /// The tile file.
        path: PathBuf,
        /// Where the odometry frame lies on Earth.
        anchor: Anchor,
        /// The projection the anchor was measured in, when given: it must be the tile's.
        projection: Option<Projection>,
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
                    origin: Some((anchor.lat(), anchor.lon())),
                    projection: *projection,
                    lanes: options.clone(),
                };
                let mut compiled = compile(std::slice::from_ref(path), &compile_options)?;
                Ok(LoadedMap {
                    anchored_from_odom: anchor.anchored_from_odom(&compiled.plane),
                    plane: Some(compiled.plane),
                    geometry: Some(compiled.geometry),
                    report: compiled.reports.pop(),
                    map: Arc::new(compiled.map),
                })
            }
            MapSource::Tile {
                path,
                anchor,
                projection,
            } => {
                let (map, info) = tile::load(path)?;
                if let Some(p) = projection.filter(|&p| p != info.plane.projection) {
                    bail!(
                        "{}: the tile's plane uses the {} projection, the anchor was given for {}",
                        path.display(),
                        info.plane.projection.name(),
                        p.name()
                    );
                }
                Ok(LoadedMap {
                    map: Arc::new(map),
                    anchored_from_odom: anchor.anchored_from_odom(&info.plane),
                    plane: Some(info.plane),
                    geometry: Some(info.geometry),
                    report: None,
                })
            }
            MapSource::LanesCsv(path) => {
                let lanes = lane_csv::read(path)?;
                let map = LaneMap::new(&lanes)
                    .with_context(|| format!("building the lane map of {}", path.display()))?;
                Ok(LoadedMap {
                    map: Arc::new(map),
                    anchored_from_odom: Se2::IDENTITY,
                    plane: None,
                    geometry: None,
                    report: None,
                })
            }
        }
    }
}
