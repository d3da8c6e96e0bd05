//! Which cells a corrector needs, and correcting a recorded drive on a grid (cells loaded on the
//! caller's thread; the daemon loads on a thread of its own).

use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::corrector::MatchMode;
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::Pose3;
use crate::source_corrector::{stamp_at, CorrectedPose, Placement, SourceCorrector};

use super::{assemble, distance, CellKey, Grid, GridCell, GridError};

/// The largest load radius and look-ahead (metres).
pub const MAX_REACH_M: f64 = 10_000.0;

/// How much of a grid a corrector keeps loaded: every cell within `radius_m` of its window,
/// and of the road `ahead_m` further along its direction of travel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadPolicy {
    /// Cells within this distance of any window pose are loaded (metres).
    pub radius_m: f64,
    /// How far ahead of the newest pose, along its direction of travel, cells are prefetched
    /// (metres).
    pub ahead_m: f64,
}

impl Default for LoadPolicy {
    /// 250 m around the window, 300 m ahead: on the KITTI drives' OpenStreetMap lanes (a point
    /// every 26 m on average) the 100 nearest points of a pose lie within about 250 m.
    fn default() -> Self {
        LoadPolicy {
            radius_m: 250.0,
            ahead_m: 300.0,
        }
    }
}

impl LoadPolicy {
    /// Refuses a radius or distance that is negative or beyond [`MAX_REACH_M`].
    pub fn validate(&self) -> Result<(), String> {
        for (key, v) in [("radius_m", self.radius_m), ("ahead_m", self.ahead_m)] {
            if !(0.0..=MAX_REACH_M).contains(&v) {
                return Err(format!("{key} = {v:?}: must be 0 to {MAX_REACH_M} metres"));
            }
        }
        Ok(())
    }
}

/// When a corrector needs cells its map lacks: checked once per quarter cell driven (the cells
/// a window needs change no faster), shared by [`GridMaps`] and the daemon's sessions.
#[derive(Clone, Debug, Default)]
pub struct CellNeeds {
    last_check: Option<[f64; 2]>,
}

impl CellNeeds {
    /// The cells a corrector with `window` (oldest first) about to push `next` needs under
    /// `policy` (metres, map plane), when `current` lacks any of them; `None` when it lacks none,
    /// when no cell is near (a stretch without lanes: the current map keeps serving), or when the
    /// newest pose has not moved a quarter cell since the last check.
    pub fn check(
        &mut self,
        grid: &Grid,
        policy: &LoadPolicy,
        window: &[[f64; 2]],
        next: [f64; 2],
        current: &BTreeSet<CellKey>,
    ) -> Option<BTreeSet<CellKey>> {
        let step = grid.manifest().cell_size_m / 4.0;
        if self.last_check.is_some_and(|q| distance(q, next) < step) {
            return None;
        }
        self.last_check = Some(next);
        let mut path = Vec::with_capacity(window.len() + 1);
        path.extend_from_slice(window);
        path.push(next);
        let wanted = grid.wanted(&path, policy);
        (!wanted.is_empty() && !wanted.is_subset(current)).then_some(wanted)
    }
}

/// Keeps one corrector's map assembled from the cells its window needs, loading them on the
/// caller's thread (for offline correction; the daemon loads on a thread of its own).
pub struct GridMaps {
    grid: Arc<Grid>,
    policy: LoadPolicy,
    cells: HashMap<CellKey, Arc<GridCell>>,
    current: BTreeSet<CellKey>,
    needs: CellNeeds,
    cells_read: u64,
}

impl GridMaps {
    /// Maps from `grid` under `policy`; nothing is loaded yet.
    pub fn new(grid: Arc<Grid>, policy: LoadPolicy) -> GridMaps {
        GridMaps {
            grid,
            policy,
            cells: HashMap::new(),
            current: BTreeSet::new(),
            needs: CellNeeds::default(),
            cells_read: 0,
        }
    }

    /// The map a corrector whose window is `window` needs (plus the position about to be pushed,
    /// `next`), when it differs from the last one returned: cells are loaded, those no longer
    /// needed dropped. `None` when the last map still serves (it holds every cell needed, or
    /// no cell is near). Checks only after the newest pose moved a quarter cell since the last
    /// check.
    pub fn update(
        &mut self,
        window: &[[f64; 2]],
        next: [f64; 2],
    ) -> Result<Option<LaneMap>, GridError> {
        let Some(wanted) = self
            .needs
            .check(&self.grid, &self.policy, window, next, &self.current)
        else {
            return Ok(None);
        };
        self.cells.retain(|k, _| wanted.contains(k));
        for &key in &wanted {
            if !self.cells.contains_key(&key) {
                self.cells.insert(key, Arc::new(self.grid.load_cell(key)?));
                self.cells_read += 1;
            }
        }
        let cells: Vec<Arc<GridCell>> = wanted.iter().map(|k| self.cells[k].clone()).collect();
        self.current = wanted;
        Ok(Some(assemble(&self.grid, &cells)?))
    }
}

/// What a run on a grid loaded and whether every answer was the whole map's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct GridRun {
    /// Maps assembled (the first and every change of the set of cells).
    pub maps: u64,
    /// Cells read from disk.
    pub cells_read: u64,
    /// The most cells loaded at once.
    pub most_cells: usize,
    /// Neighbour queries beyond the loaded cells: zero means every correction equals the whole
    /// map's, bit for bit.
    pub uncovered_queries: u64,
}

impl GridMaps {
    /// The map for a corrector about to push `next` with window `window`, counted in `run`.
    fn next_map(
        &mut self,
        window: &[[f64; 2]],
        next: [f64; 2],
        run: &mut GridRun,
    ) -> Result<Option<LaneMap>, GridError> {
        let map = self.update(window, next)?;
        if map.is_some() {
            run.maps += 1;
            run.most_cells = run.most_cells.max(self.current.len());
        }
        run.cells_read = self.cells_read;
        Ok(map)
    }
}

/// Corrects a whole recorded trajectory on a grid, as [`crate::source_corrector::correct_trajectory`] does on one map:
/// before each pose, the cells its corrector needs under `policy` are loaded (on this thread).
/// `stamps_s` as for [`crate::source_corrector::correct_stamped_trajectory`].
pub fn correct_trajectory_on_grid(
    grid: Arc<Grid>,
    policy: LoadPolicy,
    params: Params,
    mode: MatchMode,
    placement: Placement,
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
) -> Result<(Vec<CorrectedPose>, GridRun), GridError> {
    let mut maps = GridMaps::new(grid, policy);
    let mut run = GridRun::default();
    let Some(first) = poses.first() else {
        return Ok((Vec::new(), run));
    };
    let start = placement.position_in_anchored(first);
    let map = maps
        .next_map(&[], start, &mut run)?
        .ok_or_else(|| GridError::Cell {
            path: maps.grid.dir.clone(),
            message: format!(
                "no cell holds lanes within {} m of the first pose {start:?}",
                policy.radius_m
            ),
        })?;
    let mut corrector = SourceCorrector::new(Arc::new(map), params, mode, placement);
    let mut out = Vec::with_capacity(poses.len());
    for (i, pose) in poses.iter().enumerate() {
        if pose.problem().is_none() {
            let next = corrector.predicted_position_in_map(pose);
            if let Some(map) = maps.next_map(corrector.window(), next, &mut run)? {
                run.uncovered_queries += corrector.map().uncovered_queries();
                corrector.replace_map(Arc::new(map));
            }
        }
        out.push(corrector.correct_at(pose, stamp_at(stamps_s, i)).0);
    }
    run.uncovered_queries += corrector.map().uncovered_queries();
    Ok((out, run))
}
