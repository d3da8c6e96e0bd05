//! Cells and how they are cut from a map and joined back: partition, pieces, assembly, the
//! coverage of an assembled map, and renumbering points between two assembled maps.

use std::collections::{BTreeMap, HashSet};
use std::sync::Arc;

use crate::lane_geometry::LaneInfo;
use crate::lane_map::{Lane, LaneMap};
use crate::tile::PieceOrigin;

use super::{check_spec, existing_cells_near, index_range, CellKey, Grid, GridError};

/// One loaded cell: its pieces and where each comes from.
pub struct GridCell {
    /// The cell's index.
    pub key: CellKey,
    pub(super) pieces: LaneMap,
    pub(super) origins: Vec<PieceOrigin>,
    pub(super) signer: Option<[u8; 32]>,
}

impl GridCell {
    /// The ed25519 public key whose valid signature the cell carries (`None`: unsigned).
    pub fn signer(&self) -> Option<[u8; 32]> {
        self.signer
    }

    /// Lane points in the cell (margin included).
    pub fn points(&self) -> usize {
        self.pieces.len()
    }
}

/// What part of the plane an assembled map answers exactly: every query whose disk lies within
/// `margin` of the squares of loaded cells (or of cells that hold nothing).
#[derive(Clone, Debug)]
pub struct Coverage {
    cell_size_m: f64,
    margin_m: f64,
    loaded: HashSet<CellKey>,
    existing: Arc<HashSet<CellKey>>,
    /// Where each lane of the map starts in the whole map: `[lane, point]`, in map order.
    origins: Vec<PieceOrigin>,
}

impl Coverage {
    /// The cells whose lanes the map holds.
    pub fn loaded(&self) -> &HashSet<CellKey> {
        &self.loaded
    }

    /// Whether the map holds every lane point within `radius_m` of `x` (metres, map plane), each
    /// with its own segment. Conservative: it may say no to a disk that is in fact covered.
    pub fn covers(&self, x: [f64; 2], radius_m: f64) -> bool {
        if self.loaded.len() == self.existing.len() {
            return true;
        }
        if !radius_m.is_finite() {
            return false;
        }
        // Every point of the disk lies within the margin of a point of the disk shrunk by the
        // margin; those lie in the cells the shrunk disk's square touches. The slack covers the
        // rounding of the cell arithmetic.
        let half = (radius_m - self.margin_m).max(0.0) + 1e-6;
        let mut covered = true;
        existing_cells_near(&self.existing, x, half, self.cell_size_m, |key| {
            covered &= self.loaded.contains(&key);
        });
        covered
    }
}

/// Point `j` of `from` as a point of `to`, both assembled from cells of one grid: the same
/// point of the same lane of the whole map. `None` when `to` lacks it (or a map is not a grid's).
pub fn renumber(from: &LaneMap, to: &LaneMap, j: u32) -> Option<u32> {
    let (a, b) = (from.coverage()?, to.coverage()?);
    let k = from.lane_of(j);
    let [lane, first] = *a.origins.get(k)?;
    let point = first + (j - from.lane_offsets()[k]);
    let at = b.origins.partition_point(|o| *o <= [lane, point]);
    let k = at.checked_sub(1)?;
    let [to_lane, to_first] = b.origins[k];
    let offsets = to.lane_offsets();
    let len = offsets[k + 1] - offsets[k];
    (to_lane == lane && point < to_first + len).then(|| offsets[k] + point - to_first)
}

/// One cell's content, made by [`partition`].
pub struct CellContent {
    /// The cell's index.
    pub key: CellKey,
    /// Its pieces as a map (lane `k` is piece `k`).
    pub pieces: LaneMap,
    /// Where each piece comes from.
    pub origins: Vec<PieceOrigin>,
}

/// Splits `map` into cells of `cell_size_m` holding every point within `margin_m` of their
/// square, each run of points extended by the neighbour its segments need.
pub fn partition(
    map: &LaneMap,
    cell_size_m: f64,
    margin_m: f64,
) -> Result<Vec<CellContent>, GridError> {
    let lanes = map
        .lanes()
        .enumerate()
        .map(|(ordinal, (id, info, points))| (ordinal as u32, id, info, points));
    partition_lanes(lanes, cell_size_m, margin_m, |_| true)
}

/// One lane as [`partition_lanes`] takes it: its ordinal in the whole map, id, info and points
/// (metres, map plane).
pub type OrderedLane<'a> = (u32, u64, LaneInfo, &'a [[f64; 2]]);

/// The cells among those `keep` accepts that `lanes` reach, as [`partition`] cuts them.
/// `lanes` are any of the whole map's lanes, in the whole map's order, with their ordinals there;
/// a cell is complete (equal to the one [`partition`] makes of the whole map) when every lane
/// with a point within `margin_m` of its square is among them. A compiler that streams its
/// input cuts a region's cells at a time this way.
pub fn partition_lanes<'a>(
    lanes: impl IntoIterator<Item = OrderedLane<'a>>,
    cell_size_m: f64,
    margin_m: f64,
    keep: impl Fn(CellKey) -> bool,
) -> Result<Vec<CellContent>, GridError> {
    check_spec(cell_size_m, margin_m)?;
    let mut cells: BTreeMap<CellKey, (Vec<Lane>, Vec<PieceOrigin>)> = BTreeMap::new();
    let mut members: BTreeMap<CellKey, Vec<usize>> = BTreeMap::new();
    for (ordinal, id, info, points) in lanes {
        members.clear();
        for (j, p) in points.iter().enumerate() {
            let [[x0, x1], [y0, y1]] = cells_near(*p, cell_size_m, margin_m);
            for cx in x0..=x1 {
                for cy in y0..=y1 {
                    if keep([cx, cy]) && within_reach(p, [cx, cy], cell_size_m, margin_m) {
                        members.entry([cx, cy]).or_default().push(j);
                    }
                }
            }
        }
        for (key, indices) in &members {
            let (lanes, origins) = cells.entry(*key).or_default();
            for [first, last] in pieces_of(indices, points.len()) {
                lanes.push(Lane {
                    id,
                    info,
                    points: points[first..=last].to_vec(),
                });
                origins.push([ordinal, first as u32]);
            }
        }
    }
    cells
        .into_iter()
        .map(|(key, (lanes, origins))| {
            Ok(CellContent {
                key,
                pieces: LaneMap::new(&lanes)?,
                origins,
            })
        })
        .collect()
}

/// The cells whose square within `margin_m` may hold `p` (metres, map plane): x indices
/// `[0][0]..=[0][1]`, y indices `[1][0]..=[1][1]`. One more cell below on each axis than the
/// margin reaches: a point exactly on a square's far edge plus the margin belongs to it too.
pub fn cells_near(p: [f64; 2], cell_size_m: f64, margin_m: f64) -> [[i32; 2]; 2] {
    let [x0, x1] = index_range(p[0], margin_m, cell_size_m);
    let [y0, y1] = index_range(p[1], margin_m, cell_size_m);
    [[x0.saturating_sub(1), x1], [y0.saturating_sub(1), y1]]
}

/// Whether `p` lies within `margin_m` of cell `key`'s square (closed), per axis.
fn within_reach(p: &[f64; 2], key: CellKey, cell_size_m: f64, margin_m: f64) -> bool {
    (0..2).all(|a| {
        let lo = f64::from(key[a]) * cell_size_m - margin_m;
        let hi = (f64::from(key[a]) + 1.0) * cell_size_m + margin_m;
        lo <= p[a] && p[a] <= hi
    })
}

/// The point ranges `[first, last]` of a lane of `n` points that a cell keeps: runs of its
/// member points (ascending), each extended by the next point (whose segment the run's last
/// point owns) or, for a run of the lane's last point alone, by the one before, and then by one
/// more point at each end where the lane has one, so that every member's segment has the turns
/// at both its ends ([`LaneMap::chord_error_m`]) as in the whole map; overlapping or touching
/// ranges are joined. The extra points lie beyond the margin: no covered query reaches them.
pub(super) fn pieces_of(members: &[usize], n: usize) -> Vec<[usize; 2]> {
    let mut out: Vec<[usize; 2]> = Vec::new();
    let mut k = 0;
    while k < members.len() {
        let first = members[k];
        let mut last = first;
        while k + 1 < members.len() && members[k + 1] == last + 1 {
            k += 1;
            last += 1;
        }
        k += 1;
        let start = if first == n - 1 && first > 0 {
            first - 1
        } else {
            first
        };
        let (start, end) = (start.saturating_sub(1), (last + 2).min(n - 1));
        match out.last_mut() {
            Some(prev) if start <= prev[1] + 1 => prev[1] = prev[1].max(end),
            _ => out.push([start, end]),
        }
    }
    out
}

/// Joins the pieces of `cells` into the lanes they came from, in the whole map's order; the
/// map's coverage is `cells` (see [`Coverage`]).
pub fn assemble(grid: &Grid, cells: &[Arc<GridCell>]) -> Result<LaneMap, GridError> {
    let mut pieces: Vec<(PieceOrigin, &GridCell, usize)> = cells
        .iter()
        .flat_map(|c| {
            c.origins
                .iter()
                .enumerate()
                .map(move |(k, &o)| (o, &**c, k))
        })
        .collect();
    pieces.sort_unstable_by_key(|p| p.0);
    let mut lanes: Vec<Lane> = Vec::new();
    let mut origins: Vec<PieceOrigin> = Vec::new();
    let mut current: Option<(u32, usize)> = None;
    for ([ordinal, first], cell, k) in pieces {
        let (id, info, points) = piece(cell, k);
        let first = first as usize;
        if let (Some((o, start)), Some(lane)) = (current, lanes.last_mut()) {
            let end = start + lane.points.len();
            if o == ordinal && first <= end {
                let overlap = end.min(first + points.len()) - first;
                let at = first - start;
                if lane.points[at..at + overlap] != points[..overlap]
                    || lane.id != id
                    || lane.info != info
                {
                    return Err(GridError::Cell {
                        path: grid.cell_path(cell.key),
                        message: format!("lane {id} differs from the same lane in another cell"),
                    });
                }
                lane.points.extend_from_slice(&points[overlap..]);
                continue;
            }
        }
        current = Some((ordinal, first));
        origins.push([ordinal, first as u32]);
        lanes.push(Lane {
            id,
            info,
            points: points.to_vec(),
        });
    }
    let coverage = Coverage {
        cell_size_m: grid.manifest.cell_size_m,
        margin_m: grid.manifest.margin_m,
        loaded: cells.iter().map(|c| c.key).collect(),
        existing: grid.existing.clone(),
        origins,
    };
    Ok(LaneMap::new(&lanes)?.with_coverage(coverage))
}

fn piece(cell: &GridCell, k: usize) -> (u64, LaneInfo, &[[f64; 2]]) {
    let o = cell.pieces.lane_offsets();
    let range = o[k] as usize..o[k + 1] as usize;
    (
        cell.pieces.lane_ids()[k],
        cell.pieces.lane_info()[k],
        &cell.pieces.points()[range],
    )
}
