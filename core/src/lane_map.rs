//! The lane map: lane centerlines as flat arrays of points and segments, indexed by a 2D KD-tree.
//!
//! All coordinates are metres in one planar frame (the frame the map was built in). Every lane is
//! a polyline in its direction of travel. Point `j` of a lane owns the candidate segment that
//! starts at it, `(j, j + 1)`; a lane's last point owns the segment that ends at it; a lane with
//! fewer than two points owns no segment (its points are still in the tree, as the paper's
//! pipeline keeps them).
//!
//! A map is one byte image: little-endian arrays at 16-byte-aligned offsets, followed by the
//! KD-tree archived with rkyv (at a 128-byte-aligned offset: its leaves are cache-line aligned). [`LaneMap::new`] builds the image in memory; a tile file
//! ([`crate::tile`]) is a header and the same image, memory-mapped and used in place. Either way
//! the image is fully validated once, when the map is made, and read without copies after.

use std::num::NonZeroUsize;
use std::ops::Range;

use kiddo::kd_tree::ArchivedKdTree;
use kiddo::leaf_strategy::VecOfArenas;
use kiddo::{Eytzinger, ImmutableKdTree, SquaredEuclidean};
use rkyv::util::AlignedVec;

/// A lane centerline in its direction of travel (metres, map plane).
#[derive(Clone, Debug, PartialEq)]
pub struct Lane {
    /// An identifier kept from the source (OSM way id with a lane suffix, Lanelet2 id, CSV id).
    pub id: u64,
    /// The centerline points in driving order.
    pub points: Vec<[f64; 2]>,
}

/// Marks a point that owns no segment.
pub const NO_SEGMENT: u32 = u32::MAX;

/// The KD-tree as it is archived in the image.
pub type ArchivedTree = ArchivedKdTree<f64, u32, Eytzinger, VecOfArenas<f64, u32, 2, 32>, 2, 32>;

/// What can go wrong when building or validating a lane map.
#[derive(Debug, thiserror::Error)]
pub enum LaneMapError {
    /// The map has no lane points at all.
    #[error("the lane map is empty: no lane has any point")]
    Empty,
    /// A lane point is NaN or infinite.
    #[error("lane {lane_id} has a non-finite point ({x}, {y})")]
    NonFinite {
        /// The lane's identifier.
        lane_id: u64,
        /// x in metres.
        x: f64,
        /// y in metres.
        y: f64,
    },
    /// More points or lanes than a `u32` index can address.
    #[error("the lane map has {0} points; at most {max} are supported", max = u32::MAX - 1)]
    TooManyPoints(usize),
    /// The KD-tree could not be built or archived.
    #[error("building the KD-tree failed: {0}")]
    KdTree(String),
    /// The image does not hold what its counts say, or its content is inconsistent.
    #[error("invalid lane map image: {0}")]
    Invalid(String),
}

/// Where each array lies in the image (byte ranges), from the counts.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Lane points.
    pub point_count: usize,
    /// Lanes.
    pub lane_count: usize,
    points: Range<usize>,
    segment_start: Range<usize>,
    directions: Range<usize>,
    lane_offsets: Range<usize>,
    lane_ids: Range<usize>,
    tree: Range<usize>,
}

/// Alignment (bytes) the image and its KD-tree section need.
pub const IMAGE_ALIGN: usize = 128;

fn align_to(n: usize, align: usize) -> usize {
    n.div_ceil(align) * align
}

impl Layout {
    /// The layout of an image with these counts and an archived tree of `tree_len` bytes.
    pub fn new(point_count: usize, lane_count: usize, tree_len: usize) -> Self {
        let mut at = 0;
        let mut section = |len: usize| {
            let range = at..at + len;
            at = align_to(at + len, 16);
            range
        };
        let points = section(point_count * 16);
        let segment_start = section(point_count * 4);
        let directions = section(point_count * 16);
        let lane_offsets = section((lane_count + 1) * 4);
        let lane_ids = section(lane_count * 8);
        let tree_start = align_to(lane_ids.end, IMAGE_ALIGN);
        let tree = tree_start..tree_start + tree_len;
        Layout {
            point_count,
            lane_count,
            points,
            segment_start,
            directions,
            lane_offsets,
            lane_ids,
            tree,
        }
    }

    /// Total image length in bytes.
    pub fn len(&self) -> usize {
        self.tree.end
    }

    /// True for an image with nothing in it (never for a valid map).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Length of the archived tree in bytes.
    pub fn tree_len(&self) -> usize {
        self.tree.len()
    }
}

/// The bytes behind a map: built in memory, or a read-only mapping of a tile file.
enum Image {
    Owned(AlignedVec<IMAGE_ALIGN>),
    Mapped { map: memmap2::Mmap, offset: usize },
}

impl Image {
    fn bytes(&self) -> &[u8] {
        match self {
            Image::Owned(v) => v.as_slice(),
            Image::Mapped { map, offset } => &map[*offset..],
        }
    }
}

/// A lane map ready for matching: flat, index-addressed arrays plus a KD-tree over the points.
pub struct LaneMap {
    image: Image,
    layout: Layout,
}

impl std::fmt::Debug for LaneMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LaneMap")
            .field("lanes", &self.layout.lane_count)
            .field("points", &self.layout.point_count)
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

#[inline]
fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    let dx = b[0] - a[0];
    let dy = b[1] - a[1];
    (dx * dx + dy * dy).sqrt()
}

/// One KD-tree candidate: squared distance (m^2) and point index.
pub type Candidate = (f64, u32);

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

impl LaneMap {
    /// Builds a lane map from lanes whose points are already spaced as wanted (see [`resample`]).
    /// Lanes with no points are skipped; the order of lanes and points fixes the point indices.
    pub fn new(lanes: &[Lane]) -> Result<Self, LaneMapError> {
        let lanes: Vec<&Lane> = lanes.iter().filter(|l| !l.points.is_empty()).collect();
        let total: usize = lanes.iter().map(|l| l.points.len()).sum();
        if total == 0 {
            return Err(LaneMapError::Empty);
        }
        if total >= NO_SEGMENT as usize {
            return Err(LaneMapError::TooManyPoints(total));
        }
        let mut points: Vec<[f64; 2]> = Vec::with_capacity(total);
        let mut segment_start: Vec<u32> = Vec::with_capacity(total);
        let mut directions: Vec<[f64; 2]> = Vec::with_capacity(total);
        let mut lane_offsets = vec![0u32];
        let mut lane_ids = Vec::with_capacity(lanes.len());
        for lane in lanes {
            if let Some(p) = lane
                .points
                .iter()
                .find(|p| !(p[0].is_finite() && p[1].is_finite()))
            {
                return Err(LaneMapError::NonFinite {
                    lane_id: lane.id,
                    x: p[0],
                    y: p[1],
                });
            }
            let first = points.len();
            for (start, dir) in lane_segments(&lane.points) {
                segment_start.push(start.map_or(NO_SEGMENT, |s| (first + s) as u32));
                directions.push(dir);
            }
            points.extend_from_slice(&lane.points);
            lane_offsets.push(points.len() as u32);
            lane_ids.push(lane.id);
        }
        let tree: ImmutableKdTree<f64, 2> = ImmutableKdTree::new_from_slice(&points)
            .map_err(|e| LaneMapError::KdTree(format!("{e:?}")))?;
        let archived = rkyv::to_bytes::<rkyv::rancor::Error>(&tree)
            .map_err(|e| LaneMapError::KdTree(e.to_string()))?;
        let layout = Layout::new(points.len(), lane_ids.len(), archived.len());
        let mut image = AlignedVec::<IMAGE_ALIGN>::with_capacity(layout.len());
        image.resize(layout.len(), 0);
        let bytes = image.as_mut_slice();
        bytes[layout.points.clone()].copy_from_slice(bytemuck::cast_slice(&points));
        bytes[layout.segment_start.clone()].copy_from_slice(bytemuck::cast_slice(&segment_start));
        bytes[layout.directions.clone()].copy_from_slice(bytemuck::cast_slice(&directions));
        bytes[layout.lane_offsets.clone()].copy_from_slice(bytemuck::cast_slice(&lane_offsets));
        bytes[layout.lane_ids.clone()].copy_from_slice(bytemuck::cast_slice(&lane_ids));
        bytes[layout.tree.clone()].copy_from_slice(&archived);
        Self::validated(Image::Owned(image), layout)
    }

    /// A map over a memory-mapped tile whose image starts at `offset` (a multiple of
    /// [`IMAGE_ALIGN`]).
    /// Validates everything; the mapping is used in place.
    pub(crate) fn from_mapping(
        map: memmap2::Mmap,
        offset: usize,
        layout: Layout,
    ) -> Result<Self, LaneMapError> {
        Self::validated(Image::Mapped { map, offset }, layout)
    }

    /// The image bytes (what a tile stores after its header).
    pub fn image(&self) -> &[u8] {
        self.image.bytes()
    }

    /// Where the arrays lie in [`Self::image`].
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    fn validated(image: Image, layout: Layout) -> Result<Self, LaneMapError> {
        let invalid = |what: String| Err(LaneMapError::Invalid(what));
        let bytes = image.bytes();
        if bytes.len() < layout.len() {
            return invalid(format!(
                "{} bytes, the counts need {}",
                bytes.len(),
                layout.len()
            ));
        }
        if !(bytes.as_ptr() as usize).is_multiple_of(IMAGE_ALIGN) {
            return invalid(format!("the image is not {IMAGE_ALIGN}-byte aligned"));
        }
        let (n, lanes) = (layout.point_count, layout.lane_count);
        if n == 0 || n >= NO_SEGMENT as usize || lanes == 0 || lanes > n {
            return invalid(format!("{n} points in {lanes} lanes"));
        }
        let map = LaneMap { image, layout };
        if let Some(p) = map
            .points()
            .iter()
            .position(|p| !(p[0].is_finite() && p[1].is_finite()))
        {
            return invalid(format!("point {p} is not finite"));
        }
        let offsets = map.lane_offsets();
        if offsets[0] != 0
            || offsets[lanes] as usize != n
            || offsets.windows(2).any(|w| w[0] >= w[1])
        {
            return invalid("lane offsets are not increasing from 0 to the point count".into());
        }
        for (k, w) in offsets.windows(2).enumerate() {
            let range = w[0] as usize..w[1] as usize;
            let lane_points = &map.points()[range.clone()];
            for ((start, dir), j) in lane_segments(lane_points).zip(range.clone()) {
                let want = start.map_or(NO_SEGMENT, |s| (range.start + s) as u32);
                let stored = map.segment_start()[j];
                let stored_dir = map.directions()[j];
                let same_dir = (stored_dir[0] - dir[0]).abs() <= 1e-12
                    && (stored_dir[1] - dir[1]).abs() <= 1e-12;
                if stored != want || !same_dir {
                    return invalid(format!(
                        "the segment of point {j} (lane {k}) does not follow its lane"
                    ));
                }
            }
        }
        let tree_bytes = &map.image.bytes()[map.layout.tree.clone()];
        let tree = rkyv::access::<ArchivedTree, rancor::Error>(tree_bytes)
            .map_err(|e| LaneMapError::Invalid(format!("KD-tree: {e}")))?;
        if tree.size() != n {
            return invalid(format!(
                "the KD-tree holds {} points, the map {n}",
                tree.size()
            ));
        }
        let mut seen = vec![false; n];
        for (item, point) in tree.iter() {
            let j = item as usize;
            if j >= n || seen[j] || map.points()[j] != point {
                return invalid(format!("KD-tree item {item} does not match the points"));
            }
            seen[j] = true;
        }
        Ok(map)
    }

    fn section<T: bytemuck::Pod>(&self, range: &Range<usize>) -> &[T] {
        // Validated at construction: in bounds and aligned.
        bytemuck::cast_slice(&self.image.bytes()[range.clone()])
    }

    /// Number of lane points.
    pub fn len(&self) -> usize {
        self.layout.point_count
    }

    /// True when the map has no points (never, for a built map).
    pub fn is_empty(&self) -> bool {
        self.layout.point_count == 0
    }

    /// All lane points (metres, map plane), lane after lane.
    pub fn points(&self) -> &[[f64; 2]] {
        self.section(&self.layout.points)
    }

    fn segment_start(&self) -> &[u32] {
        self.section(&self.layout.segment_start)
    }

    fn directions(&self) -> &[[f64; 2]] {
        self.section(&self.layout.directions)
    }

    fn lane_offsets(&self) -> &[u32] {
        self.section(&self.layout.lane_offsets)
    }

    fn lane_ids(&self) -> &[u64] {
        self.section(&self.layout.lane_ids)
    }

    /// Number of lanes.
    pub fn lane_count(&self) -> usize {
        self.layout.lane_count
    }

    /// The lanes as `(id, points)`, in map order.
    pub fn lanes(&self) -> impl Iterator<Item = (u64, &[[f64; 2]])> + '_ {
        let (offsets, points) = (self.lane_offsets(), self.points());
        self.lane_ids()
            .iter()
            .enumerate()
            .map(move |(k, &id)| (id, &points[offsets[k] as usize..offsets[k + 1] as usize]))
    }

    /// The candidate segment of point `j`: `(a, b, unit direction)`, or `None` when the point
    /// owns no segment.
    #[inline]
    pub fn segment_of(&self, j: u32) -> Option<([f64; 2], [f64; 2], [f64; 2])> {
        let s = self.segment_start()[j as usize];
        if s == NO_SEGMENT {
            return None;
        }
        let points = self.points();
        let s = s as usize;
        Some((points[s], points[s + 1], self.directions()[j as usize]))
    }

    /// The KD-tree over [`Self::points`]; item `j` is point `j`.
    #[inline]
    pub fn kd_tree(&self) -> &ArchivedTree {
        let bytes = &self.image.bytes()[self.layout.tree.clone()];
        // SAFETY: these bytes passed `rkyv::access` (full validation) when the map was made, and
        // the image is immutable for the map's lifetime.
        unsafe { rkyv::access_unchecked::<ArchivedTree>(bytes) }
    }

    /// Squared distance (m^2) from `p` to point `j`, computed the one way every matcher uses.
    #[inline]
    pub fn squared_distance(&self, p: [f64; 2], j: u32) -> f64 {
        let q = self.points()[j as usize];
        let dx = q[0] - p[0];
        let dy = q[1] - p[1];
        dx * dx + dy * dy
    }

    /// The `n` nearest points to `p` (all of them if the map has fewer), ordered by increasing
    /// distance and, for equal distances, by point index. `out` is cleared first.
    ///
    /// The KD-tree breaks ties arbitrarily, so when the `n`-th distance is shared by points the
    /// tree left out, the whole tie group at that distance is fetched and cut by index.
    pub fn nearest(&self, p: [f64; 2], n: usize, out: &mut Vec<Candidate>) {
        out.clear();
        let Some(n) = NonZeroUsize::new(n.min(self.len())) else {
            return;
        };
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
    use proptest::prelude::*;

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
            Lane {
                id: 7,
                points: vec![[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]],
            },
            Lane {
                id: 8,
                points: vec![[9.0, 9.0]],
            },
        ];
        let map = LaneMap::new(&lanes).unwrap();
        assert_eq!(map.len(), 4);
        assert_eq!(map.segment_of(0).unwrap().2, [1.0, 0.0]);
        // The last point of a lane uses the segment ending at it.
        let (a, b, d) = map.segment_of(2).unwrap();
        assert_eq!((a, b, d), ([3.0, 0.0], [3.0, 4.0], [0.0, 1.0]));
        assert!(map.segment_of(3).is_none());
    }

    #[test]
    fn non_finite_points_are_refused() {
        let lanes = vec![Lane {
            id: 3,
            points: vec![[0.0, f64::NAN]],
        }];
        assert!(matches!(
            LaneMap::new(&lanes),
            Err(LaneMapError::NonFinite { lane_id: 3, .. })
        ));
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
            let lanes = vec![Lane { id: 1, points: points.clone() }];
            let map = LaneMap::new(&lanes).unwrap();
            let p = [q.0 as f64 * 0.5, q.1 as f64 * 0.5];
            let mut got = Vec::new();
            map.nearest(p, n, &mut got);
            prop_assert_eq!(got, brute_force(&points, p, n));
        }
    }
}
