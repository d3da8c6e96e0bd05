//! Where a corrector's lane map comes from, and how it is placed in the source's frame.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::lane_csv;
use lanealign_core::lane_map::{Lane, LaneMap};
use lanealign_map::osm::read_xml_file;
use lanealign_map::osm_lanes::{derive_lanes, LaneOptions};

/// A lane map source as given on the command line.
#[derive(Clone, Debug)]
pub enum MapSource {
    /// Raw OSM XML, anchored into the source's frame.
    Osm {
        /// The `.osm` file.
        path: PathBuf,
        /// Where the odometry frame lies on Earth.
        anchor: Anchor,
        /// The projection the anchor was measured in.
        projection: Projection,
        /// Lane derivation options.
        options: LaneOptions,
    },
    /// Lane polylines already in the source's planar frame (`lane_id,x,y`).
    LanesCsv(PathBuf),
}

/// Lanes from raw OSM, moved from the map plane at the anchor's origin into the planar odometry
/// frame the anchor describes (`odom_from_plane`).
pub fn osm_lanes_in_odom(
    path: &Path,
    anchor: &Anchor,
    projection: Projection,
    options: &LaneOptions,
) -> anyhow::Result<Vec<Lane>> {
    let osm = read_xml_file(path)?;
    let plane = MapPlane::new(projection, anchor.lat, anchor.lon);
    let (mut lanes, report) = derive_lanes(&osm, &plane, options);
    if report.missing_node_refs > 0 || report.ways_without_geometry > 0 {
        eprintln!(
            "warning: {}: {} node references missing, {} drivable ways without geometry (skipped)",
            path.display(),
            report.missing_node_refs,
            report.ways_without_geometry
        );
    }
    let odom_from_plane = anchor.plane_from_odom().inverse();
    for lane in &mut lanes {
        for p in &mut lane.points {
            *p = odom_from_plane.apply(*p);
        }
    }
    Ok(lanes)
}

impl MapSource {
    /// Loads the lanes and builds the lane map.
    pub fn load(&self) -> anyhow::Result<Arc<LaneMap>> {
        let lanes = match self {
            MapSource::Osm {
                path,
                anchor,
                projection,
                options,
            } => osm_lanes_in_odom(path, anchor, *projection, options)?,
            MapSource::LanesCsv(path) => lane_csv::read(path)?,
        };
        let what = match self {
            MapSource::Osm { path, .. } | MapSource::LanesCsv(path) => path.display().to_string(),
        };
        Ok(Arc::new(LaneMap::new(&lanes).with_context(|| {
            format!("building the lane map of {what}")
        })?))
    }
}
