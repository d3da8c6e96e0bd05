//! Where a corrector's lane map comes from, and how a source is placed on it.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context};
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::grid::{self, correct_trajectory_on_grid, Grid, GridRun, LoadPolicy};
use lanealign_core::lane_csv;
use lanealign_core::lane_geometry::LaneGeometry;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::{CorrectorConfig, Params};
use lanealign_core::plausibility;
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{
    correct_stamped_trajectory, counts, CorrectedPose, Placement,
};
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
    /// For a grid of tiles, the grid: `map` then holds only the cells around the anchor, and
    /// [`LoadedMap::correct`] loads the cells each pose needs.
    pub grid: Option<Arc<Grid>>,
}

impl LoadedMap {
    /// Corrects a recorded trajectory on this map (on a grid, loading the cells each pose needs
    /// under the default [`LoadPolicy`]), its poses stamped `stamps_s` (seconds) when the format
    /// has stamps; for a grid, what it loaded too.
    pub fn correct(
        &self,
        params: Params,
        mode: MatchMode,
        placement: Placement,
        poses: &[Pose3],
        stamps_s: Option<&[f64]>,
    ) -> anyhow::Result<(Vec<CorrectedPose>, Option<GridRun>)> {
        Ok(match &self.grid {
            Some(grid) => {
                let (run, loads) = correct_trajectory_on_grid(
                    grid.clone(),
                    LoadPolicy::default(),
                    params,
                    mode,
                    placement,
                    poses,
                    stamps_s,
                )?;
                (run, Some(loads))
            }
            None => (
                correct_stamped_trajectory(
                    self.map.clone(),
                    params,
                    mode,
                    placement,
                    poses,
                    stamps_s,
                ),
                None,
            ),
        })
    }

    /// What a corrected run says of a setup gone wrong or an odometry that failed
    /// ([`plausibility`]), each a line that says what to try: `poses` (in `convention`, stamped
    /// `stamps_s` in seconds when the format has stamps) and `run`, their corrections under
    /// `params`. `lanealign correct` prints them, Python's `correct` warns them.
    pub fn warnings(
        &self,
        poses: &[Pose3],
        stamps_s: Option<&[f64]>,
        convention: AxisConvention,
        run: &[CorrectedPose],
        params: &Params,
    ) -> Vec<String> {
        // The rate the stamps say the poses come at, where they say one.
        let stamped_rate = stamps_s.and_then(plausibility::rate_from_stamps);
        let counts = counts(run);
        [
            plausibility::axes_warning(poses, convention),
            // The first pose that is one: a pose of NaNs (answered `invalid_input`) is nowhere.
            poses
                .iter()
                .find(|p| p.problem().is_none())
                .and_then(|first| {
                    plausibility::anchor_warning(
                        &self.map,
                        &self.anchored_from_odom,
                        &convention.to_planar(first),
                    )
                }),
            plausibility::refusals_warning(
                run.len(),
                counts.attempts,
                counts.accepted,
                plausibility::CHECK_CORRECT_SETUP,
            ),
            plausibility::odometry_jump_warning(run, params),
            plausibility::poses_missing_warning(poses, stamps_s, convention, params),
            stamped_rate.and_then(|rate| plausibility::rate_warning(rate, params)),
            plausibility::speed_warning(
                poses,
                convention,
                plausibility::judged_rate_hz(stamped_rate, params.odometry_rate_hz),
                params.max_speed_mps,
            ),
        ]
        .into_iter()
        .flatten()
        .collect()
    }
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
    /// A compiled tile, or a grid of them (a folder).
    Tile {
        /// The tile file, or the grid's folder.
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
    /// Loads the map for a corrector configured as `config`, refusing a tile (or grid) whose
    /// lane geometry the method was not made for.
    pub fn load_for(&self, config: &CorrectorConfig) -> anyhow::Result<LoadedMap> {
        let loaded = self.load()?;
        if let (Some(geometry), MapSource::Tile { path, .. }) = (&loaded.geometry, self) {
            config
                .check_geometry(geometry)
                .with_context(|| format!("tile {}", path.display()))?;
        }
        Ok(loaded)
    }

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
                    grid: None,
                })
            }
            MapSource::Tile {
                path,
                anchor,
                projection,
            } => {
                if grid::is_grid(path) {
                    return load_grid(path, anchor, *projection);
                }
                let (map, info) = tile::load(path)?;
                check_projection(path, info.plane.projection, *projection)?;
                Ok(LoadedMap {
                    map: Arc::new(map),
                    anchored_from_odom: anchor.anchored_from_odom(&info.plane),
                    plane: Some(info.plane),
                    geometry: Some(info.geometry),
                    report: None,
                    grid: None,
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
                    grid: None,
                })
            }
        }
    }
}

/// Refuses an anchor given for another projection than the map's.
fn check_projection(
    path: &Path,
    map: Projection,
    anchor: Option<Projection>,
) -> anyhow::Result<()> {
    if let Some(p) = anchor.filter(|&p| p != map) {
        bail!(
            "{}: the map's plane uses the {} projection, the anchor was given for {}",
            path.display(),
            map.name(),
            p.name()
        );
    }
    Ok(())
}

/// Opens a grid and assembles the cells around the anchor's origin.
fn load_grid(
    path: &Path,
    anchor: &Anchor,
    projection: Option<Projection>,
) -> anyhow::Result<LoadedMap> {
    let grid = Arc::new(Grid::open(path)?);
    check_projection(path, grid.plane().projection, projection)?;
    let anchored_from_odom = anchor.anchored_from_odom(&grid.plane());
    let origin = anchored_from_odom.apply([0.0, 0.0]);
    let wanted = grid.wanted(&[origin], &LoadPolicy::default());
    if wanted.is_empty() {
        bail!(
            "{}: no cell of the grid holds lanes within {} m of the anchor",
            path.display(),
            LoadPolicy::default().radius_m
        );
    }
    let map = grid.map_of(wanted)?;
    Ok(LoadedMap {
        map: Arc::new(map),
        anchored_from_odom,
        plane: Some(grid.plane()),
        geometry: Some(grid.geometry()),
        report: None,
        grid: Some(grid),
    })
}
