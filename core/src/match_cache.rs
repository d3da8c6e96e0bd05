//! Exact incremental lane matching (the fast mode).
//!
//! Each window pose keeps two candidate sets, each complete within an exclusive radius around
//! the position it was built at: a wide one from the KD-tree, and a small one of the points that
//! could still decide the answer (those within the deciding distance plus [`CONTENDER_MARGIN`]).
//! When the pose has moved by `delta` since a set was built, every lane point closer than
//! `radius - delta` to its new position is in that set, so the reference answer (the first
//! passing candidate in (distance, index) order among the `N` nearest) can be decided from the set
//! alone whenever that candidate, or `N` failing ones, lie inside `radius - delta`. The small set
//! is tried first, then the wide one, then the KD-tree, wider if needed. The answer is identical
//! to [`crate::matching::match_window`]; only the work differs.
//!
//! A pose whose position and direction are unchanged since its last match (every pose but the
//! newest two after a rejected step) reuses its last answer outright.

use std::collections::VecDeque;

use kiddo::SquaredEuclidean;

use crate::lane_map::LaneMap;
use crate::matching::{trajectory_direction, try_candidate, Correspondence, MatchParams};

/// Radius of a new wide set (metres); doubled while the set cannot decide. Lane points are a
/// few metres apart, so this usually holds a handful of lanes.
const FIRST_RADIUS: f64 = 8.0;

/// How much farther than the deciding distance the small set reaches (metres): the room a pose
/// may move (through accepted corrections) before its small set must be rebuilt.
const CONTENDER_MARGIN: f64 = 0.5;

/// Relative safety margin on radii, so that a point ranked by the KD-tree's own distance
/// arithmetic is never wrongly assumed to be inside a set.
const RADIUS_MARGIN: f64 = 1e-9;

/// Lane points complete within an exclusive radius: every point strictly closer than `radius`
/// to `anchor` is in `points` (metres, map plane; indices in no particular order).
#[derive(Clone, Debug, Default)]
struct CandidateSet {
    anchor: [f64; 2],
    radius: f64,
    points: Vec<u32>,
}

impl CandidateSet {
    fn clear(&mut self) {
        self.points.clear();
        self.radius = f64::NEG_INFINITY;
    }
}

/// A query (position, direction) and its answer.
#[derive(Clone, Copy, Debug)]
struct LastMatch {
    position: [f64; 2],
    direction: [f64; 2],
    answer: Option<[f64; 2]>,
}

#[derive(Clone, Debug, Default)]
struct PoseCache {
    wide: CandidateSet,
    small: CandidateSet,
    /// The last query and its answer, reused when the pose has not moved or turned.
    last: Option<LastMatch>,
}

/// Candidate squared distance and index, the reference order key.
type Key = (f64, u32);

#[inline]
fn key_less(a: Key, b: Key) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// Per-window-pose caches, kept aligned with the corrector's window.
#[derive(Debug, Default)]
pub struct MatchCache {
    poses: VecDeque<PoseCache>,
    spare: Vec<PoseCache>,
    keys: Vec<Key>,
}

/// What a set could tell.
enum Decision {
    /// The answer, and the distance (metres) within which the points that decided it lie.
    Match(Option<[f64; 2]>, f64),
    /// The set cannot decide.
    Unknown,
}

impl MatchCache {
    /// A new pose was appended to the window.
    pub fn push(&mut self) {
        let mut c = self.spare.pop().unwrap_or_default();
        c.wide.clear();
        c.small.clear();
        c.last = None;
        self.poses.push_back(c);
    }

    /// The `count` oldest window poses were dropped.
    pub fn drop_oldest(&mut self, count: usize) {
        for _ in 0..count.min(self.poses.len()) {
            if let Some(c) = self.poses.pop_front() {
                self.spare.push(c);
            }
        }
    }

    /// Matches the whole window; same output as [`crate::matching::match_window`].
    pub fn match_window(
        &mut self,
        map: &LaneMap,
        window: &[[f64; 2]],
        params: &MatchParams,
        out: &mut Vec<Correspondence>,
    ) {
        debug_assert_eq!(window.len(), self.poses.len());
        out.clear();
        for (i, &x) in window.iter().enumerate() {
            let dir = trajectory_direction(window, i);
            let cache = &mut self.poses[i];
            let target = if dir == [0.0, 0.0] {
                None
            } else if let Some(last) = cache.last.filter(|l| l.position == x && l.direction == dir)
            {
                last.answer
            } else {
                let answer = match_one(map, cache, &mut self.keys, x, dir, params);
                cache.last = Some(LastMatch {
                    position: x,
                    direction: dir,
                    answer,
                });
                answer
            };
            if let Some(target) = target {
                out.push(Correspondence {
                    index: i,
                    source: x,
                    target,
                });
            }
        }
    }
}

fn match_one(
    map: &LaneMap,
    cache: &mut PoseCache,
    keys: &mut Vec<Key>,
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
) -> Option<[f64; 2]> {
    if let Decision::Match(answer, _) = decide(map, &cache.small, keys, x, dir, params) {
        return answer;
    }
    let mut radius = FIRST_RADIUS;
    loop {
        if let Decision::Match(answer, reach) = decide(map, &cache.wide, keys, x, dir, params) {
            // `keys` now holds the wide set's reliable candidates at `x`: keep those that could
            // still decide after a small move as the small set.
            let radius = (reach.sqrt() + CONTENDER_MARGIN) * (1.0 - RADIUS_MARGIN);
            let limit = keys_limit(map, &cache.wide, x);
            let radius = radius.min(limit);
            let r2 = radius * radius;
            cache.small.anchor = x;
            cache.small.radius = radius;
            cache.small.points.clear();
            cache
                .small
                .points
                .extend(keys.iter().filter(|k| k.0 < r2).map(|k| k.1));
            return answer;
        }
        rebuild(map, &mut cache.wide, x, radius);
        radius *= 2.0;
    }
}

/// The radius within which the wide set is complete around `x` (metres).
fn keys_limit(map: &LaneMap, set: &CandidateSet, x: [f64; 2]) -> f64 {
    if set.points.len() == map.len() {
        return f64::INFINITY;
    }
    let (dx, dy) = (x[0] - set.anchor[0], x[1] - set.anchor[1]);
    set.radius - (dx * dx + dy * dy).sqrt() * (1.0 + RADIUS_MARGIN)
}

/// Fills `set` with every lane point within `radius` metres of `x`, without allocating once the
/// set's buffer has grown.
fn rebuild(map: &LaneMap, set: &mut CandidateSet, x: [f64; 2], radius: f64) {
    set.anchor = x;
    set.points.clear();
    let points = &mut set.points;
    map.kd_tree()
        .query(&x)
        .within::<SquaredEuclidean<f64>>(radius * radius)
        .unsorted()
        .visit(|r| points.push(r.item));
    set.radius = if set.points.len() == map.len() {
        f64::INFINITY
    } else {
        radius * (1.0 - RADIUS_MARGIN)
    };
}

/// Decides from one set alone. Leaves the set's reliable candidates (closer than the set's
/// radius less the distance moved) in `keys`. On success also returns the squared distance
/// within which the deciding points lie: the match's, or the `N`-th candidate's when none of the
/// `N` nearest passes.
fn decide(
    map: &LaneMap,
    set: &CandidateSet,
    keys: &mut Vec<Key>,
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
) -> Decision {
    keys.clear();
    let whole_map = set.points.len() == map.len();
    let reliable = keys_limit(map, set, x);
    if reliable <= 0.0 {
        return Decision::Unknown;
    }
    let reliable2 = reliable * reliable;
    keys.extend(
        set.points
            .iter()
            .map(|&j| (map.squared_distance(x, j), j))
            .filter(|k| k.0 < reliable2),
    );
    let mut best: Option<(Key, [f64; 2])> = None;
    for &k in keys.iter() {
        if best.is_none_or(|(b, _)| key_less(k, b)) {
            if let Some(q) = try_candidate(map, k.1, x, dir, params.min_direction_cos) {
                best = Some((k, q));
            }
        }
    }
    let n = params.neighbours;
    if let Some((best_key, q)) = best {
        let rank = keys.iter().filter(|&&k| key_less(k, best_key)).count();
        if rank < n {
            return Decision::Match(Some(q), best_key.0);
        }
    } else if keys.len() < n && !whole_map {
        return Decision::Unknown;
    }
    // None of the N nearest passes; they are all reliable. Their reach is the N-th distance.
    let reach = if keys.len() <= n {
        keys.iter().map(|k| k.0).fold(0.0, f64::max)
    } else {
        let (_, nth, _) =
            keys.select_nth_unstable_by(n - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        nth.0
    };
    Decision::Match(None, reach)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;
    use crate::matching::match_window;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, rng_seed: proptest::test_runner::RngSeed::Fixed(11), ..ProptestConfig::default() })]
        /// A window drifting across a grid of crossing lanes with many duplicate points: the
        /// cached matcher gives the reference correspondences at every step.
        #[test]
        fn cached_matching_equals_reference(
            steps in prop::collection::vec((-0.8f64..0.8, -0.8f64..0.8, -0.02f64..0.02), 1..12),
            n in 1usize..40,
        ) {
            let mut lanes = Vec::new();
            for r in 0..6 {
                let y = r as f64 * 4.0;
                let east: Vec<[f64; 2]> = (0..20).map(|i| [i as f64 * 3.0, y]).collect();
                let mut west = east.clone();
                west.reverse();
                lanes.push(Lane { id: 2 * r, points: east });
                lanes.push(Lane { id: 2 * r + 1, points: west });
                let north: Vec<[f64; 2]> = (0..8).map(|i| [r as f64 * 9.0, i as f64 * 3.0]).collect();
                lanes.push(Lane { id: 100 + r, points: north });
            }
            let map = LaneMap::new(&lanes).unwrap();
            let params = MatchParams { neighbours: n, min_direction_cos: 0.95 };
            let mut window: Vec<[f64; 2]> = (0..30).map(|i| [1.0 + i as f64 * 1.7, 5.0 + (i as f64 * 0.3).sin()]).collect();
            let mut cache = MatchCache::default();
            for _ in 0..window.len() { cache.push(); }
            let (mut want, mut got, mut scratch) = (Vec::new(), Vec::new(), Vec::new());
            for (dx, dy, dth) in steps {
                let (s, c) = dth.sin_cos();
                for p in window.iter_mut() {
                    *p = [c * p[0] - s * p[1] + dx, s * p[0] + c * p[1] + dy];
                }
                match_window(&map, &window, &params, &mut scratch, &mut want);
                cache.match_window(&map, &window, &params, &mut got);
                prop_assert_eq!(&got, &want);
            }
        }
    }
}
