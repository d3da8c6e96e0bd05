//! Lane matching (docs/algorithm.md, section 2): for each window pose, the first nearby lane segment that runs
//! in the direction of travel and that the pose's normal hits.
//!
//! Positions and directions are metres / unit vectors in the map plane.

use crate::lane_map::{Candidate, LaneMap};

/// Matching parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchParams {
    /// How many nearest lane points to try (N).
    pub neighbours: usize,
    /// Minimum cosine between the trajectory and lane directions (tau).
    pub min_direction_cos: f64,
    /// A pose matched farther than this from its matched point is left out of the output
    /// (metres; infinite leaves none out): the robust method's gate, applied as each pair is
    /// found instead of in a pass of its own. It changes no pose's match.
    pub max_distance_m: f64,
}

/// `|a - b| <= r` (metres), as `hypot` computes the distance, for less: the squared distance
/// decides where it is clear of the boundary by far more than rounding, `hypot` where not.
#[inline]
pub fn within(a: [f64; 2], b: [f64; 2], r: f64) -> bool {
    let d2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
    let r2 = r * r;
    if d2 < r2 * (1.0 - 1e-9) {
        true
    } else if d2 > r2 * (1.0 + 1e-9) {
        false
    } else {
        (a[0] - b[0]).hypot(a[1] - b[1]) <= r
    }
}

/// One correspondence: window pose `index`, its position, and the matched point on the lane.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Correspondence {
    /// Index of the pose in the window (0 = oldest).
    pub index: usize,
    /// The pose position (metres, map plane).
    pub source: [f64; 2],
    /// The matched point on the lane segment (metres, map plane).
    pub target: [f64; 2],
    /// The lane point whose segment was matched (an index into [`LaneMap::points`]).
    pub point: u32,
}

#[inline]
fn cross(u: [f64; 2], v: [f64; 2]) -> f64 {
    u[0] * v[1] - u[1] * v[0]
}

/// The unit trajectory direction at window pose `i`: forward difference, backward for the last
/// pose; zero where the two poses coincide (or for a window of one pose).
pub fn trajectory_direction(window: &[[f64; 2]], i: usize) -> [f64; 2] {
    let (from, to) = if i + 1 < window.len() {
        (window[i], window[i + 1])
    } else if i > 0 {
        (window[i - 1], window[i])
    } else {
        return [0.0, 0.0];
    };
    let d = [to[0] - from[0], to[1] - from[1]];
    let norm = (d[0] * d[0] + d[1] * d[1]).sqrt();
    if norm > 0.0 {
        [d[0] / norm, d[1] / norm]
    } else {
        [0.0, 0.0]
    }
}

/// Tests one candidate point's segment against a pose at `x` moving along the unit `dir`.
/// Returns the foot of the normal shot on the segment when the direction test and the shot pass.
#[inline]
pub fn try_candidate(
    map: &LaneMap,
    j: u32,
    x: [f64; 2],
    dir: [f64; 2],
    min_direction_cos: f64,
) -> Option<[f64; 2]> {
    let (a, b, d_lane) = map.segment_of(j)?;
    let s = dir[0] * d_lane[0] + dir[1] * d_lane[1];
    if s < min_direction_cos {
        return None;
    }
    let n = [-dir[1], dir[0]];
    let ab = [b[0] - a[0], b[1] - a[1]];
    let denom = cross(ab, n);
    if denom == 0.0 {
        return None;
    }
    let t = cross([x[0] - a[0], x[1] - a[1]], n) / denom;
    if (0.0..=1.0).contains(&t) {
        Some([a[0] + t * ab[0], a[1] + t * ab[1]])
    } else {
        None
    }
}

/// Matches one pose: the first of the `N` nearest candidates (by distance, then index) that
/// passes, as the matched point and the lane point whose segment it lies on. `scratch` holds the
/// candidate list between calls to avoid allocation.
pub fn match_pose(
    map: &LaneMap,
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
    scratch: &mut Vec<Candidate>,
) -> Option<([f64; 2], u32)> {
    if dir == [0.0, 0.0] {
        return None;
    }
    map.nearest(x, params.neighbours, scratch);
    scratch
        .iter()
        .find_map(|&(_, j)| try_candidate(map, j, x, dir, params.min_direction_cos).map(|q| (q, j)))
}

/// Matches every pose of the window exactly as docs/algorithm.md section 2 describes (the
/// reference work).
/// `out` is cleared and receives the correspondences in window order.
pub fn match_window(
    map: &LaneMap,
    window: &[[f64; 2]],
    params: &MatchParams,
    scratch: &mut Vec<Candidate>,
    out: &mut Vec<Correspondence>,
) {
    out.clear();
    for (i, &x) in window.iter().enumerate() {
        let dir = trajectory_direction(window, i);
        let matched = match_pose(map, x, dir, params, scratch);
        if let Some((target, point)) = matched.filter(|m| within(x, m.0, params.max_distance_m)) {
            out.push(Correspondence {
                index: i,
                source: x,
                target,
                point,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;

    fn params() -> MatchParams {
        MatchParams {
            neighbours: 10,
            min_direction_cos: 0.95,
            max_distance_m: f64::INFINITY,
        }
    }

    #[test]
    fn the_gate_leaves_out_only_far_matches() {
        let lanes = [
            Lane::new(1, vec![[0.0, 0.0], [50.0, 0.0]]),
            Lane::new(2, vec![[0.0, 6.0], [50.0, 6.0]]),
        ];
        let map = LaneMap::new(&lanes).unwrap();
        // Poses 0.5 m, then 2.5 m beside the first lane.
        let window: Vec<[f64; 2]> = (0..20)
            .map(|i| [i as f64 * 2.0, if i < 10 { 0.5 } else { 2.5 }])
            .collect();
        let (mut scratch, mut all, mut gated) = (Vec::new(), Vec::new(), Vec::new());
        match_window(&map, &window, &params(), &mut scratch, &mut all);
        let near = MatchParams {
            max_distance_m: 1.0,
            ..params()
        };
        match_window(&map, &window, &near, &mut scratch, &mut gated);
        let matched = all.len();
        let kept: Vec<Correspondence> = all
            .into_iter()
            .filter(|c| within(c.source, c.target, 1.0))
            .collect();
        assert!(
            kept.len() >= 9 && kept.len() < matched,
            "{} of {matched}",
            kept.len()
        );
        assert_eq!(gated, kept);
    }

    fn straight(id: u64, y: f64, forward: bool) -> Lane {
        let mut points: Vec<[f64; 2]> = (0..10).map(|i| [i as f64 * 3.0, y]).collect();
        if !forward {
            points.reverse();
        }
        Lane::new(id, points)
    }

    #[test]
    fn direction_filter_picks_the_lane_of_travel() {
        // Two opposite lanes; the eastbound one is farther from the pose but is the only one
        // running in its direction.
        let map = LaneMap::new(&[straight(1, 0.0, false), straight(2, -3.5, true)]).unwrap();
        let mut scratch = Vec::new();
        let q = match_pose(&map, [10.0, -1.0], [1.0, 0.0], &params(), &mut scratch).unwrap();
        assert_eq!(q.0, [10.0, -3.5]);
        assert_eq!(map.lane_ids()[map.lane_of(q.1)], 2);
        let q = match_pose(&map, [10.0, -1.0], [-1.0, 0.0], &params(), &mut scratch).unwrap();
        assert_eq!(q.0, [10.0, 0.0]);
        assert_eq!(map.lane_ids()[map.lane_of(q.1)], 1);
    }

    #[test]
    fn normal_shot_outside_the_segment_is_rejected() {
        // One lane segment from (0,0) to (3,0): poses beyond either end get no match.
        let lane = Lane::new(1, vec![[0.0, 0.0], [3.0, 0.0]]);
        let map = LaneMap::new(&[lane]).unwrap();
        let mut s = Vec::new();
        assert!(match_pose(&map, [-0.5, 1.0], [1.0, 0.0], &params(), &mut s).is_none());
        assert!(match_pose(&map, [3.5, 1.0], [1.0, 0.0], &params(), &mut s).is_none());
        assert_eq!(
            match_pose(&map, [1.5, 1.0], [1.0, 0.0], &params(), &mut s),
            Some(([1.5, 0.0], 0)),
            "nearest points 0 and 1 tie; the lower index goes first"
        );
        // Both ends are inside (t = 0 and t = 1 pass).
        assert_eq!(
            match_pose(&map, [3.0, 1.0], [1.0, 0.0], &params(), &mut s),
            Some(([3.0, 0.0], 1)),
            "the last point owns the segment ending at it"
        );
    }

    #[test]
    fn perpendicular_segments_are_rejected() {
        let lane = Lane::new(1, vec![[0.0, -3.0], [0.0, 0.0], [0.0, 3.0]]);
        let map = LaneMap::new(&[lane]).unwrap();
        let mut s = Vec::new();
        assert!(match_pose(&map, [0.5, 0.0], [1.0, 0.0], &params(), &mut s).is_none());
        // A slight angle within tau still matches.
        let dir = [0.2f64, 1.0];
        let n = (dir[0] * dir[0] + dir[1] * dir[1]).sqrt();
        assert!(match_pose(
            &map,
            [0.5, 0.0],
            [dir[0] / n, dir[1] / n],
            &params(),
            &mut s
        )
        .is_some());
    }

    #[test]
    fn coincident_poses_get_no_direction() {
        let w = [[1.0, 1.0], [1.0, 1.0], [2.0, 1.0]];
        assert_eq!(trajectory_direction(&w, 0), [0.0, 0.0]);
        assert_eq!(trajectory_direction(&w, 1), [1.0, 0.0]);
        assert_eq!(trajectory_direction(&w, 2), [1.0, 0.0]);
    }
}
