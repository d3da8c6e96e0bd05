//! The lane map: lane centerlines as flat arrays of points and segments, indexed by a 2D KD-tree.
//!
//! All coordinates are metres in one planar frame (the frame the map was built in). Every lane is
//! a polyline in its direction of travel. Point `j` of a lane owns the candidate segment that
//! starts at it, `(j, j + 1)`; a lane's last point owns the segment that ends at it; a lane with
//! fewer than two points owns no segment (its points are still in the tree, as the paper's
//! pipeline keeps them).
//!
//! A map is made from lanes ([`LaneMap::new`]) or from the flat arrays a tile stores
//! ([`LaneMap::from_arrays`]); both go through the same validation, and the KD-tree is always
//! built here from the validated points, never read from outside.

use std::num::NonZeroUsize;
use std::sync::atomic::{AtomicU64, Ordering};

use kiddo::{ImmutableKdTree, SquaredEuclidean};

use crate::grid::Coverage;
use crate::lane_geometry::LaneInfo;
use crate::pose::{within_coordinate_bound, MAX_COORDINATE_M};
use crate::se2::distance;

/// A lane centerline in its direction of travel (metres, map plane).
#[derive(Clone, Debug, PartialEq)]
pub struct Lane {
    /// An identifier kept from the source (OSM way id with a lane suffix, Lanelet2 id, CSV id).
    pub id: u64,
    /// Its road class and what its geometry rests on.
    pub info: LaneInfo,
    /// The centerline points in driving order.
    pub points: Vec<[f64; 2]>,
}

impl Lane {
    /// A lane of unknown class.
    pub fn new(id: u64, points: Vec<[f64; 2]>) -> Lane {
        Lane {
            id,
            info: LaneInfo::default(),
            points,
        }
    }
}

/// Marks a point that owns no segment.
pub const NO_SEGMENT: u32 = u32::MAX;

/// The most lane points a map may hold (point indices are `u32`, one value is reserved).
pub const MAX_POINTS: usize = (u32::MAX - 1) as usize;

/// The KD-tree over the lane points; item `j` is point `j`.
pub type LaneTree = ImmutableKdTree<f64, 2>;

/// What can go wrong when building or validating a lane map.
#[derive(Debug, thiserror::Error)]
pub enum LaneMapError {
    /// The map has no lane points at all.
    #[error("the lane map is empty: no lane has any point")]
    Empty,
    /// A lane point is NaN, infinite or farther than [`MAX_COORDINATE_M`] from the map's
    /// origin on either axis. Beyond it a local plane means nothing, and a segment's squared
    /// length overflowed (its chord error was NaN at 1e155 m).
    #[error(
        "lane {lane_id} has a point ({x:?}, {y:?}) that is not finite or beyond {max:e} m of the \
         map's origin",
        max = MAX_COORDINATE_M
    )]
    PointOutOfRange {
        /// The lane's identifier.
        lane_id: u64,
        /// x in metres.
        x: f64,
        /// y in metres.
        y: f64,
    },
    /// More points than a `u32` index can address.
    #[error("the lane map has {0} points; at most {max} are supported", max = MAX_POINTS)]
    TooManyPoints(usize),
    /// The KD-tree could not be built.
    #[error("building the KD-tree failed: {0}")]
    KdTree(String),
    /// The arrays are inconsistent with each other.
    #[error("invalid lane map: {0}")]
    Invalid(String),
    /// A lane point spacing that is not a number of metres in `(0, MAX_SPACING_M]`.
    #[error(
        "the lane point spacing {0:?} m is outside (0, {max}] m (beyond {max} m lanes lose the \
         curves that fix the position along the road)",
        max = MAX_SPACING_M
    )]
    Spacing(f64),
}

/// The largest spacing (metres) lane points may be derived with. The spacing drops a road's
/// nodes closer than it ([`resample`]), and with them the shape of its curves: on KITTI 00
/// (LiDAR, kiss-icp preset) the mean APE-2D is 1.026 m at 3 m, 1.022 m at 10 m, 1.245 m at 20 m
/// and 4.99 m at 100 m, worse than the raw 4.01 m. At 10^300 m every lane was one point.
pub const MAX_SPACING_M: f64 = 10.0;

/// Checks a lane point spacing (metres) given to derive a map: in `(0, MAX_SPACING_M]`.
pub fn check_spacing(spacing_m: f64) -> Result<(), LaneMapError> {
    if spacing_m > 0.0 && spacing_m <= MAX_SPACING_M {
        Ok(())
    } else {
        Err(LaneMapError::Spacing(spacing_m))
    }
}

/// One KD-tree candidate: squared distance (m^2) and point index.
pub type Candidate = (f64, u32);

/// A lane map ready for matching: flat, index-addressed arrays plus a KD-tree over the points.
pub struct LaneMap {
    points: Vec<[f64; 2]>,
    segment_start: Vec<u32>,
    directions: Vec<[f64; 2]>,
    lane_offsets: Vec<u32>,
    lane_ids: Vec<u64>,
    lane_info: Vec<LaneInfo>,
    /// The lane of each point (an index into the lane arrays).
    point_lane: Vec<u32>,
    /// How far the road may lie from the segment each point owns (metres; see
    /// [`Self::chord_error_m`]).
    chord_error_m: Vec<f64>,
    /// The longest segment's length (metres; see [`Self::longest_segment_m`]).
    longest_segment_m: f64,
    tree: LaneTree,
    /// For a map assembled from some cells of a grid, where it answers as the whole map would.
    coverage: Option<Coverage>,
    /// Queries that reached beyond the coverage.
    uncovered: AtomicU64,
}

impl PartialEq for LaneMap {
    /// Two maps are equal when their lanes are (ids, attributes, points, bit for bit); segments
    /// and the tree follow from those.
    fn eq(&self, other: &Self) -> bool {
        self.lane_offsets == other.lane_offsets
            && self.lane_ids == other.lane_ids
            && self.lane_info == other.lane_info
            && self.points.len() == other.points.len()
            && self
                .points
                .iter()
                .zip(&other.points)
                .all(|(a, b)| a[0].to_bits() == b[0].to_bits() && a[1].to_bits() == b[1].to_bits())
    }
}

impl std::fmt::Debug for LaneMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LaneMap")
            .field("lanes", &self.lane_ids.len())
            .field("points", &self.points.len())
            .finish()
    }
}

/// Drops every point closer than `spacing_m` to the previously kept point (the first point is
/// always kept). Metres.
pub fn resample(points: &[[f64; 2]], spacing_m: f64) -> Vec<[f64; 2]> {
    let mut kept: Vec<[f64; 2]> = Vec::with_capacity(points.len());
    for &p in points {
        match kept.last() {
            Some(&last) if distance(last, p) < spacing_m => {}
            _ => kept.push(p),
        }
    }
    kept
}

/// The length of a polyline (metres, in the units of its points).
pub fn polyline_length_m(points: &[[f64; 2]]) -> f64 {
    // From +0.0: `sum` starts at -0.0, and a lane of one point was printed "-0.0 lane-km".
    points
        .windows(2)
        .fold(0.0, |length, w| length + distance(w[0], w[1]))
}

/// The segment each point of a lane owns: `(start index, unit direction)`, relative to the
/// lane's first point.
fn lane_segments(points: &[[f64; 2]]) -> impl Iterator<Item = (Option<usize>, [f64; 2])> + '_ {
    let n = points.len();
    (0..n).map(move |j| {
        let start = match n {
            0 | 1 => return (None, [0.0, 0.0]),
            _ if j + 1 < n => j,
            _ => j - 1,
        };
        let (a, b) = (points[start], points[start + 1]);
        let len = distance(a, b);
        if len > 0.0 {
            (Some(start), [(b[0] - a[0]) / len, (b[1] - a[1]) / len])
        } else {
            (None, [0.0, 0.0])
        }
    })
}

/// The sagitta bound of segment `s` (points `s`, `s + 1`) of `lane` (see
/// [`LaneMap::chord_error_m`]).
fn chord_error(lane: &[[f64; 2]], s: usize) -> f64 {
    let turn = |i: usize| -> f64 {
        if i == 0 || i + 1 >= lane.len() {
            return 0.0;
        }
        let (a, b, c) = (lane[i - 1], lane[i], lane[i + 1]);
        let u = [b[0] - a[0], b[1] - a[1]];
        let v = [c[0] - b[0], c[1] - b[1]];
        (u[0] * v[1] - u[1] * v[0])
            .atan2(u[0] * v[0] + u[1] * v[1])
            .abs()
    };
    distance(lane[s], lane[s + 1]) * (turn(s) + turn(s + 1)) / 16.0
}

impl LaneMap {
    /// Builds a lane map from lanes whose points are already spaced as wanted (see [`resample`]).
    /// Lanes with no points are skipped; the order of lanes and points fixes the point indices.
    pub fn new(lanes: &[Lane]) -> Result<Self, LaneMapError> {
        let lanes: Vec<&Lane> = lanes.iter().filter(|l| !l.points.is_empty()).collect();
        let total: usize = lanes.iter().map(|l| l.points.len()).sum();
        if total > MAX_POINTS {
            return Err(LaneMapError::TooManyPoints(total));
        }
        let mut points = Vec::with_capacity(total);
        let mut lane_offsets = Vec::with_capacity(lanes.len() + 1);
        lane_offsets.push(0u32);
        for lane in &lanes {
            points.extend_from_slice(&lane.points);
            lane_offsets.push(points.len() as u32);
        }
        let lane_ids = lanes.iter().map(|l| l.id).collect();
        let lane_info = lanes.iter().map(|l| l.info).collect();
        Self::from_arrays(lane_offsets, lane_ids, lane_info, points)
    }

    /// A lane map from its flat arrays (what a tile stores): lane `k` holds points
    /// `lane_offsets[k]..lane_offsets[k + 1]`, has id `lane_ids[k]` and info `lane_info[k]`.
    /// Checks that the arrays agree and every point is finite and within [`MAX_COORDINATE_M`]
    /// of the origin, derives the segments and builds the KD-tree.
    pub fn from_arrays(
        lane_offsets: Vec<u32>,
        lane_ids: Vec<u64>,
        lane_info: Vec<LaneInfo>,
        points: Vec<[f64; 2]>,
    ) -> Result<Self, LaneMapError> {
        let invalid = |what: String| Err(LaneMapError::Invalid(what));
        let (n, lanes) = (points.len(), lane_ids.len());
        if n == 0 {
            return Err(LaneMapError::Empty);
        }
        if n > MAX_POINTS {
            return Err(LaneMapError::TooManyPoints(n));
        }
        if lane_offsets.len() != lanes + 1 || lane_info.len() != lanes {
            return invalid(format!(
                "{lanes} lanes with {} offsets and {} infos",
                lane_offsets.len(),
                lane_info.len()
            ));
        }
        if lane_offsets[0] != 0
            || lane_offsets[lanes] as usize != n
            || lane_offsets.windows(2).any(|w| w[0] >= w[1])
        {
            return invalid("lane offsets are not increasing from 0 to the point count".into());
        }
        if let Some(j) = points
            .iter()
            .position(|p| !p.iter().all(|&v| within_coordinate_bound(v)))
        {
            let k = lane_offsets.partition_point(|&o| o as usize <= j) - 1;
            return Err(LaneMapError::PointOutOfRange {
                lane_id: lane_ids[k],
                x: points[j][0],
                y: points[j][1],
            });
        }
        if let Some(info) = lane_info
            .iter()
            .find(|i| i.flags & !LaneInfo::ALL_FLAGS != 0)
        {
            return invalid(format!("unknown lane flags {:#04x}", info.flags));
        }
        let mut segment_start = Vec::with_capacity(n);
        let mut directions = Vec::with_capacity(n);
        for w in lane_offsets.windows(2) {
            let first = w[0] as usize;
            for (start, dir) in lane_segments(&points[first..w[1] as usize]) {
                segment_start.push(start.map_or(NO_SEGMENT, |s| (first + s) as u32));
                directions.push(dir);
            }
        }
        let point_lane = lane_offsets
            .windows(2)
            .enumerate()
            .flat_map(|(k, w)| std::iter::repeat_n(k as u32, (w[1] - w[0]) as usize))
            .collect();
        let tree = LaneTree::new_from_slice(&points)
            .map_err(|e| LaneMapError::KdTree(format!("{e:?}")))?;
        let chord_error_m = lane_offsets
            .windows(2)
            .flat_map(|w| {
                let first = w[0] as usize;
                let lane = &points[first..w[1] as usize];
                segment_start[first..w[1] as usize]
                    .iter()
                    .map(move |&s| match s {
                        NO_SEGMENT => 0.0,
                        s => chord_error(lane, s as usize - first),
                    })
            })
            .collect();
        let longest_segment_m = segment_start
            .iter()
            .filter(|&&s| s != NO_SEGMENT)
            .map(|&s| distance(points[s as usize], points[s as usize + 1]))
            .fold(0.0, f64::max);
        Ok(LaneMap {
            points,
            segment_start,
            directions,
            lane_offsets,
            lane_ids,
            lane_info,
            point_lane,
            chord_error_m,
            longest_segment_m,
            tree,
            coverage: None,
            uncovered: AtomicU64::new(0),
        })
    }

    /// The map, marked as assembled from some cells of a grid: queries beyond `coverage` are
    /// counted (see [`Self::uncovered_queries`]).
    pub fn with_coverage(mut self, coverage: Coverage) -> Self {
        self.coverage = Some(coverage);
        self
    }

    /// For a map assembled from cells of a grid, where it answers as the whole map would.
    pub fn coverage(&self) -> Option<&Coverage> {
        self.coverage.as_ref()
    }

    /// How many neighbour queries reached beyond the map's coverage since it was made: zero
    /// means every answer equals the whole map's (always zero for a whole map).
    pub fn uncovered_queries(&self) -> u64 {
        self.uncovered.load(Ordering::Relaxed)
    }

    /// Records a query that needs every lane point within `radius_m` of `x` (metres, map
    /// plane); counted when the map's coverage does not vouch for that disk.
    #[inline]
    pub fn note_query(&self, x: [f64; 2], radius_m: f64) {
        if let Some(c) = &self.coverage {
            if !c.covers(x, radius_m) {
                self.uncovered.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Number of lane points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the map has no points (never, for a built map).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// All lane points (metres, map plane), lane after lane.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// Lane `k` holds points `lane_offsets()[k]..lane_offsets()[k + 1]`.
    pub fn lane_offsets(&self) -> &[u32] {
        &self.lane_offsets
    }

    /// The lanes' identifiers, in map order.
    pub fn lane_ids(&self) -> &[u64] {
        &self.lane_ids
    }

    /// The lanes' attributes, in map order.
    pub fn lane_info(&self) -> &[LaneInfo] {
        &self.lane_info
    }

    /// Number of lanes.
    pub fn lane_count(&self) -> usize {
        self.lane_ids.len()
    }

    /// The summed length of every lane's centreline (metres).
    pub fn lane_length_m(&self) -> f64 {
        self.lanes().map(|(_, _, pts)| polyline_length_m(pts)).sum()
    }

    /// The lane (index in map order) that point `j` belongs to.
    pub fn lane_of(&self, j: u32) -> usize {
        self.point_lane[j as usize] as usize
    }

    /// The lanes as `(id, info, points)`, in map order.
    pub fn lanes(&self) -> impl Iterator<Item = (u64, LaneInfo, &[[f64; 2]])> + '_ {
        self.lane_ids.iter().enumerate().map(move |(k, &id)| {
            let range = self.lane_offsets[k] as usize..self.lane_offsets[k + 1] as usize;
            (id, self.lane_info[k], &self.points[range])
        })
    }

    /// The candidate segment of point `j`: `(a, b, unit direction)`, or `None` when the point
    /// owns no segment.
    #[inline]
    pub fn segment_of(&self, j: u32) -> Option<([f64; 2], [f64; 2], [f64; 2])> {
        let s = self.segment_start[j as usize];
        if s == NO_SEGMENT {
            return None;
        }
        let s = s as usize;
        Some((
            self.points[s],
            self.points[s + 1],
            self.directions[j as usize],
        ))
    }

    /// The unit direction of the candidate segment of point `j` (map plane), or `None` when the
    /// point owns no segment: [`Self::segment_of`]'s third value alone.
    #[inline]
    pub fn direction_of(&self, j: u32) -> Option<[f64; 2]> {
        (self.segment_start[j as usize] != NO_SEGMENT).then(|| self.directions[j as usize])
    }

    /// The longest lane segment (metres). Every point of a segment lies within half of it from
    /// a lane point, so a pose farther than `r` plus half of it from every lane point is
    /// farther than `r` from every segment.
    #[inline]
    pub fn longest_segment_m(&self) -> f64 {
        self.longest_segment_m
    }

    /// How far the road may lie from the segment point `j` owns (metres): a lane is a polyline
    /// through the mapped nodes, and a road that turns by `theta` at a node curves away from the
    /// chords beside it; over a segment of length `L` between turns `theta_a` and `theta_b` the
    /// arc's sagitta is about `L (theta_a + theta_b) / 16`. Zero on straight runs and for a
    /// lane's first and last turn, which have no neighbour.
    #[inline]
    pub fn chord_error_m(&self, j: u32) -> f64 {
        self.chord_error_m[j as usize]
    }

    /// The KD-tree over [`Self::points`]; item `j` is point `j`.
    #[inline]
    pub fn kd_tree(&self) -> &LaneTree {
        &self.tree
    }

    /// Squared distance (m^2) from `p` to point `j`, computed the one way every matcher uses.
    #[inline]
    pub fn squared_distance(&self, p: [f64; 2], j: u32) -> f64 {
        let q = self.points[j as usize];
        let dx = q[0] - p[0];
        let dy = q[1] - p[1];
        dx * dx + dy * dy
    }

    /// The `n` nearest points to `p` (all of them if the map has fewer), ordered by increasing
    /// distance and, for equal distances, by point index. `out` is cleared first.
    ///
    /// The KD-tree breaks ties arbitrarily, so when the `n`-th distance is shared by points the
    /// tree left out, the whole tie group at that distance is fetched and cut by index.
    ///
    /// A point that is not finite is near nothing: `out` stays empty (the tree found no point for
    /// a NaN, and the tie search then underflowed).
    pub fn nearest(&self, p: [f64; 2], n: usize, out: &mut Vec<Candidate>) {
        out.clear();
        let Some(n) = NonZeroUsize::new(n.min(self.len())) else {
            return;
        };
        if !(p[0].is_finite() && p[1].is_finite()) {
            return;
        }
        let tree = self.kd_tree();
        let found = tree
            .query(&p)
            .nearest_n::<SquaredEuclidean<f64>>(n)
            .execute();
        out.extend(
            found
                .iter()
                .map(|r| (self.squared_distance(p, r.item), r.item)),
        );
        out.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        if self.coverage.is_some() {
            let reach = if n.get() == self.len() {
                f64::INFINITY
            } else {
                out[out.len() - 1].0.sqrt()
            };
            self.note_query(p, reach);
        }
        if n.get() == self.len() {
            return;
        }
        let last = out[out.len() - 1].0;
        let tie_start = out.partition_point(|c| c.0 < last);
        let kiddo_radius = found.iter().map(|r| r.distance).fold(0.0, f64::max);
        let mut ties: Vec<Candidate> = tree
            .query(&p)
            .within::<SquaredEuclidean<f64>>(kiddo_radius)
            .execute()
            .iter()
            .map(|r| (self.squared_distance(p, r.item), r.item))
            .filter(|c| c.0 == last)
            .collect();
        ties.sort_unstable_by_key(|c| c.1);
        out.truncate(tie_start);
        let room = n.get() - tie_start;
        out.extend(ties.into_iter().take(room));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spacing_is_a_number_of_metres_up_to_ten() {
        for ok in [1e-300, 0.5, 3.0, MAX_SPACING_M] {
            assert!(check_spacing(ok).is_ok(), "{ok}");
        }
        for bad in [0.0, -3.0, f64::NAN, 10.000_001, f64::INFINITY, 1e300] {
            assert!(
                matches!(check_spacing(bad), Err(LaneMapError::Spacing(v)) if v.to_bits() == bad.to_bits()),
                "{bad}"
            );
        }
        assert_eq!(
            check_spacing(1e300).unwrap_err().to_string(),
            "the lane point spacing 1e300 m is outside (0, 10] m (beyond 10 m lanes lose the \
             curves that fix the position along the road)"
        );
    }
    use proptest::prelude::*;

    /// A query that is not finite finds nothing, and the map's other queries still answer (a
    /// NaN panicked in the tie search: the Python package's `correct` on a pose of NaNs).
    #[test]
    fn a_point_that_is_not_finite_is_near_nothing() {
        let map = LaneMap::new(&[Lane::new(1, vec![[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]])]).unwrap();
        let mut out = vec![(1.0, 7)];
        for p in [
            [f64::NAN, 0.0],
            [0.0, f64::INFINITY],
            [f64::NEG_INFINITY, f64::NAN],
        ] {
            for n in [1, 2, 3, 10] {
                map.nearest(p, n, &mut out);
                assert!(out.is_empty(), "{p:?}, {n}: {out:?}");
            }
        }
        map.nearest([2.0, 1.0], 2, &mut out);
        assert_eq!(out, vec![(2.0, 1), (5.0, 0)]);
    }

    /// A lane of one point (what a coarse `--spacing` leaves) has length +0, which prints as
    /// "0.0"; `Iterator::sum` of no lengths is -0.0, which printed "-0.0 lane-km".
    #[test]
    fn a_lane_of_one_point_has_length_plus_zero() {
        assert!(polyline_length_m(&[[3.0, 4.0]]).is_sign_positive());
        let map = LaneMap::new(&[Lane::new(1, vec![[3.0, 4.0]])]).unwrap();
        assert_eq!(format!("{:.1}", map.lane_length_m() / 1000.0), "0.0");
    }

    fn brute_force(points: &[[f64; 2]], p: [f64; 2], n: usize) -> Vec<Candidate> {
        let mut all: Vec<Candidate> = points
            .iter()
            .enumerate()
            .map(|(j, q)| {
                let dx = q[0] - p[0];
                let dy = q[1] - p[1];
                (dx * dx + dy * dy, j as u32)
            })
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        all.truncate(n);
        all
    }

    #[test]
    fn resample_drops_close_points() {
        let pts = [[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [4.0, 0.0], [6.5, 0.0]];
        assert_eq!(
            resample(&pts, 3.0),
            vec![[0.0, 0.0], [3.0, 0.0], [6.5, 0.0]]
        );
    }

    #[test]
    fn segments_follow_lanes() {
        let lanes = vec![
            Lane::new(7, vec![[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]]),
            Lane::new(8, vec![[9.0, 9.0]]),
        ];
        let map = LaneMap::new(&lanes).unwrap();
        assert_eq!(map.len(), 4);
        assert_eq!(map.segment_of(0).unwrap().2, [1.0, 0.0]);
        // The last point of a lane uses the segment ending at it.
        let (a, b, d) = map.segment_of(2).unwrap();
        assert_eq!((a, b, d), ([3.0, 0.0], [3.0, 4.0], [0.0, 1.0]));
        assert!(map.segment_of(3).is_none());
        assert_eq!((map.lane_of(2), map.lane_of(3)), (0, 1));
        // Between lanes there is no segment: the longest is the first lane's second.
        assert_eq!(map.longest_segment_m(), 4.0);
    }

    #[test]
    fn inconsistent_arrays_are_refused() {
        let info = vec![LaneInfo::default(); 2];
        let points = vec![[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]];
        let ok = LaneMap::from_arrays(vec![0, 2, 3], vec![1, 2], info.clone(), points.clone());
        assert!(ok.is_ok());
        for offsets in [vec![0, 3, 3], vec![1, 2, 3], vec![0, 2, 4], vec![0, 2]] {
            let e = LaneMap::from_arrays(offsets, vec![1, 2], info.clone(), points.clone());
            assert!(matches!(e, Err(LaneMapError::Invalid(_))), "{e:?}");
        }
        let bad_flags = vec![LaneInfo::new(Default::default(), 0x80); 2];
        let e = LaneMap::from_arrays(vec![0, 2, 3], vec![1, 2], bad_flags, points);
        assert!(matches!(e, Err(LaneMapError::Invalid(_))));
        let e = LaneMap::from_arrays(vec![0], vec![], vec![], vec![]);
        assert!(matches!(e, Err(LaneMapError::Empty)));
    }

    #[test]
    fn points_not_finite_or_beyond_the_pose_bound_are_refused() {
        let near = |k: u32| [k as f64, 0.0];
        for bad in [
            [0.0, f64::NAN],
            [f64::INFINITY, 0.0],
            [-1.000_000_1e7, 0.0],
            [0.0, 1e155],
        ] {
            let lanes = vec![
                Lane::new(2, (0..3).map(near).collect()),
                Lane::new(3, vec![near(5), bad]),
            ];
            match LaneMap::new(&lanes) {
                Err(LaneMapError::PointOutOfRange { lane_id: 3, x, y }) => {
                    assert_eq!([x.to_bits(), y.to_bits()], bad.map(f64::to_bits))
                }
                Err(e) => panic!("{bad:?}: {e}"),
                Ok(_) => panic!("{bad:?}: accepted"),
            }
        }
        let bound = vec![Lane::new(
            3,
            vec![[-MAX_COORDINATE_M, MAX_COORDINATE_M], near(0)],
        )];
        let map = LaneMap::new(&bound).unwrap();
        assert!(map.chord_error_m(0).is_finite());
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 200, rng_seed: proptest::test_runner::RngSeed::Fixed(7), ..ProptestConfig::default() })]
        /// Candidates equal brute force, ties included: points sit on a coarse grid so that
        /// equal distances and duplicate points are common.
        #[test]
        fn nearest_equals_brute_force(
            raw in prop::collection::vec((0i32..12, 0i32..12), 1..300),
            q in (0i32..24, 0i32..24),
            n in 1usize..40,
        ) {
            let points: Vec<[f64; 2]> = raw.iter().map(|&(x, y)| [x as f64, y as f64]).collect();
            let lanes = vec![Lane::new(1, points.clone())];
            let map = LaneMap::new(&lanes).unwrap();
            let p = [q.0 as f64 * 0.5, q.1 as f64 * 0.5];
            let mut got = Vec::new();
            map.nearest(p, n, &mut got);
            prop_assert_eq!(got, brute_force(&points, p, n));
        }
    }
}
