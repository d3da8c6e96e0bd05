//! Exact incremental lane matching (the fast mode).
//!
//! The reference work re-matches every window pose on every step. But between two steps a pose
//! moves little (an accepted correction shifts it by centimetres) and, after a rejected step, not
//! at all. Each window pose therefore keeps:
//!
//! - where it was last matched and the answer, reused outright when that pose and the one after
//!   it (which gives its direction) have not moved since the last step's matching;
//! - a proof (`Proof`) that its answer is one of a few known candidates while it moves less than
//!   `PROOF_MOVE` (0.625 m) and its direction turns by less than a margin (the others, up to
//!   three partners, cover a pose near the joint of two segments, near-coincident lanes, or a
//!   lane's end just passed): checked with one distance and a segment test per candidate that
//!   also recomputes the matched point;
//! - a wide candidate set, complete within an exclusive radius around where it was built. After a
//!   move by `delta`, every lane point closer than `radius - delta` is in it, so the reference
//!   answer (the first passing candidate in (distance, index) order among the `N` nearest) is
//!   decided from the set alone whenever that candidate, or `N` failing ones, lie inside. Only
//!   when they do not is the KD-tree asked again, with a doubled radius.
//!
//! A pose with a finite gate (the robust method's) that lies farther from every lane than the
//! gate plus half the longest segment can have no match within the gate: it is left unmatched
//! without gathering candidates (`Clearance`). A corrector whose odometry jumped off the map
//! would otherwise gather most of the map for each such pose.
//!
//! The answers are identical to [`crate::matching::match_window`], which the tests check on
//! random windows and on real sequences.

use std::collections::VecDeque;

use kiddo::{Eytzinger, QueryScratch, SquaredEuclidean};

use crate::lane_map::LaneMap;
use crate::matching::{trajectory_direction, try_candidate, within, Correspondence, MatchParams};

/// Radius of a new wide set (metres); doubled while the set cannot decide. Lane points are a few
/// metres apart, so this usually holds a handful of lanes.
const FIRST_RADIUS: f64 = 8.0;

/// How far beyond the deciding distance a proof checks candidates (metres). Wider proofs are
/// re-made less often (corrections move the window's old end by centimetres a step) but have
/// more partners to test on every step: 1.25 m against 1 m, instructions -2.8 % on the speed
/// bench, -0.4 to -0.6 % on KITTI 02 and 08 with OSM lanes, +0.06 % on 00; 1.5 m was +2.8 %
/// on 00 with OSM lanes (docs/performance.md, "Output and distances").
const CONTENDER_MARGIN: f64 = 1.25;

/// How far (metres) a pose may move under a [`Proof`]: half the contender margin, so that no
/// point beyond the checked ones can come closer than any checked one that matters.
const PROOF_MOVE: f64 = CONTENDER_MARGIN / 2.0;

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

/// Proof that a pose's answer is its `answer` or one of its `partners` while it moves less than
/// [`PROOF_MOVE`] from `anchor` and its unit direction changes by less than `direction_margin`:
/// at `anchor`, every other lane point that could then rank ahead of any of them (or among the
/// `N` nearest, when there is no answer) failed a test by more than such a change can undo, and
/// fewer than `N` points can get ahead. The check tests the answer and the partners exactly and
/// takes the first that passes in the reference order; it falls back to deciding from the
/// candidate set when none passes (with an answer) or when a partner passes (without one).
///
/// With `n` normal to the direction `d`, the normal shot's `t` is `((x - a) . d) / ((b - a) . d)`,
/// so both tests are signs of dot products: a change of `d` by `e` moves `u . d` by at most
/// `|u| e`, a move of `x` by `m` moves `(x - a) . d` by at most `m`.
///
/// Every step checks the proof of almost every window pose, and after an idle pause each proof
/// it reads is a trip to memory: so a proof fills one cache line and no more, points are
/// [`NO_POINT`] where there is none, and a pose without a proof has [`Proof::NONE`].
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Proof {
    anchor: [f64; 2],
    direction: [f64; 2],
    /// Above [`MIN_MARGIN`] in every proof; 0 in [`Proof::NONE`], which no direction is within.
    direction_margin: f64,
    /// The proof rests on every lane point within this distance of `anchor` (metres).
    rests_on_m: f64,
    /// The answer's lane point, or [`NO_POINT`]: no match.
    answer: u32,
    /// Candidates too close to a test's boundary to be ruled out, tested with the answer on
    /// every check (see [`prove`]); the first [`NO_POINT`] ends the list.
    partners: [u32; MAX_PARTNERS],
}

const _: () = assert!(
    std::mem::size_of::<Proof>() == 64,
    "a proof fills one cache line"
);

impl Proof {
    /// No proof: it holds nowhere.
    const NONE: Proof = Proof {
        anchor: [0.0; 2],
        direction: [0.0; 2],
        direction_margin: 0.0,
        rests_on_m: 0.0,
        answer: NO_POINT,
        partners: [NO_POINT; MAX_PARTNERS],
    };

    /// Whether this is a proof (not [`Proof::NONE`]).
    fn exists(&self) -> bool {
        self.direction_margin > 0.0
    }

    /// The answer's lane point, if any.
    fn answer(&self) -> Option<u32> {
        (self.answer != NO_POINT).then_some(self.answer)
    }

    /// The partners' lane points.
    fn partners(&self) -> impl Iterator<Item = u32> + '_ {
        self.partners.iter().copied().take_while(|&p| p != NO_POINT)
    }
}

impl Default for Proof {
    fn default() -> Self {
        Proof::NONE
    }
}

/// No lane point: the one index a lane map reserves ([`crate::lane_map::NO_SEGMENT`], above
/// [`crate::lane_map::MAX_POINTS`]), so no map has a point by it.
const NO_POINT: u32 = crate::lane_map::NO_SEGMENT;

/// The most candidates a proof tests exactly besides its answer.
const MAX_PARTNERS: usize = 3;

/// A proof with less room than this (a direction change) is no proof: rounding could undo it.
const MIN_MARGIN: f64 = 1e-9;

/// Where a pose was last matched and its answer.
#[derive(Clone, Copy, Debug)]
struct LastMatch {
    /// NaN before the pose's first match: equal to no position.
    position: [f64; 2],
    answer: Option<([f64; 2], u32)>,
}

impl LastMatch {
    /// A pose not matched yet.
    const NEVER: LastMatch = LastMatch {
        position: [f64::NAN; 2],
        answer: None,
    };
}

impl Default for LastMatch {
    fn default() -> Self {
        LastMatch::NEVER
    }
}

/// How far a pose was from the nearest lane point, where a match was last needed that the wide
/// set could not decide close by: after a move by `delta`, it is at least `nearest_m - delta`
/// away.
#[derive(Clone, Copy, Debug)]
struct Clearance {
    anchor: [f64; 2],
    nearest_m: f64,
}

/// The wide set's radius (metres) from which a pose whose set is still empty is checked for
/// being out of the gate's reach: two doublings of [`FIRST_RADIUS`]; poses along the lanes
/// almost never find nothing within half of it.
const FAR_RADIUS: f64 = 4.0 * FIRST_RADIUS;

#[derive(Clone, Debug, Default)]
struct PoseCache {
    wide: CandidateSet,
    clearance: Option<Clearance>,
}

/// What matching a pose anew found.
enum Anew {
    /// The reference answer: the matched point and the lane point whose segment it lies on.
    Answer(Option<([f64; 2], u32)>),
    /// No match can pass the gate: the pose is too far from every lane.
    BeyondGate,
}

/// Candidate squared distance and index, the reference order key.
type Key = (f64, u32);

#[inline]
fn key_less(a: Key, b: Key) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

#[inline]
fn dot(u: [f64; 2], v: [f64; 2]) -> f64 {
    u[0] * v[0] + u[1] * v[1]
}

/// The KD-tree's traversal stack, kept between queries so that they do not allocate.
type TreeScratch = QueryScratch<Eytzinger, f64, 2>;

/// Per-window-pose caches, kept aligned with the corrector's window.
#[derive(Default)]
pub struct MatchCache {
    poses: VecDeque<PoseCache>,
    /// Beside `poses`, each pose's last match, apart from the rest of its cache: a step that
    /// finds the window where it was (a quarter of the steps) reads 48 bytes a pose. Read from
    /// inside the whole caches, they were about 60 % of matching's cache misses after an idle
    /// core (docs/performance.md, "Between poses").
    lasts: VecDeque<LastMatch>,
    /// Beside `poses` too, each pose's proof, one cache line each (see [`Proof`]).
    proofs: VecDeque<Proof>,
    spare: Vec<PoseCache>,
    keys: Vec<Key>,
    tree_scratch: TreeScratch,
    /// How many of the oldest poses were matched by the last [`MatchCache::match_window`] with
    /// the direction they have as long as their positions stay: all of its poses but the newest
    /// (whose direction is taken backwards until a pose follows it), fewer as poses are dropped.
    settled: usize,
}

/// The candidate points every pose's buffer holds without growing (4 KiB; 4 MiB for a 1000-pose
/// window), reserved when the pose joins the window: the most any pose gathered on the shared
/// KITTI runs was 600 (08), in the soak's synthetic town 595, so matching allocates nothing while
/// driving along the lanes, and a session's memory is set when its window first fills. A pose
/// far from every lane gathers points until `N` of them are in (1300 in the soak, 230 m off the
/// town after a jump of its odometry): its buffer grows for as long as the pose stays in the
/// window and is cut back to this size when it leaves, instead of making every later pose
/// reserve as much.
const RESERVED_POINTS: usize = 1024;

/// What the wide set told.
enum Decision {
    /// The answer (candidate key and matched point), and the squared distance within which the
    /// deciding points lie: the match's, or the `N`-th candidate's when none of the `N` nearest
    /// passes.
    Decided(Option<(Key, [f64; 2])>, f64),
    /// The set cannot decide.
    Unknown,
}

impl std::fmt::Debug for MatchCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MatchCache")
            .field("poses", &self.poses.len())
            .finish_non_exhaustive()
    }
}

impl MatchCache {
    /// The map changed from `old` to `new`, two maps assembled from cells of one grid: every
    /// proof whose points are the same in both (its disk is covered by both, so both hold the
    /// whole map's points there) is kept, its points renumbered into `new`; everything else is
    /// forgotten (all of it when either map is not a grid's). What is kept answers as it would
    /// have on `new`.
    pub fn carry_over(&mut self, old: &LaneMap, new: &LaneMap) {
        let covered = |x: [f64; 2], r: f64| {
            let both = old.coverage().zip(new.coverage());
            both.is_some_and(|(a, b)| a.covers(x, r) && b.covers(x, r))
        };
        self.settled = 0;
        self.lasts.iter_mut().for_each(|l| *l = LastMatch::NEVER);
        for c in &mut self.poses {
            c.wide.points.clear();
            c.wide.radius = f64::NEG_INFINITY;
            c.clearance = None;
        }
        for proof in &mut self.proofs {
            let kept = || {
                if !proof.exists() || !covered(proof.anchor, proof.rests_on_m) {
                    return None;
                }
                let renumber = |j: u32| match j {
                    NO_POINT => Some(NO_POINT),
                    j => crate::grid::renumber(old, new, j),
                };
                let mut partners = [NO_POINT; MAX_PARTNERS];
                for (to, &from) in partners.iter_mut().zip(&proof.partners) {
                    *to = renumber(from)?;
                }
                Some(Proof {
                    answer: renumber(proof.answer)?,
                    partners,
                    ..*proof
                })
            };
            *proof = kept().unwrap_or(Proof::NONE);
        }
    }

    /// Readies the memory a window of `poses` poses needs (`crate::headroom`): room for
    /// their caches, and the candidate buffer the next pose to join takes when no pose left the
    /// window to free one.
    pub fn make_room(&mut self, poses: usize) {
        crate::headroom::make_room_in_deque(&mut self.poses, poses);
        crate::headroom::make_room_in_deque(&mut self.lasts, poses);
        crate::headroom::make_room_in_deque(&mut self.proofs, poses);
        if self.spare.is_empty() {
            let mut c = PoseCache::default();
            crate::headroom::make_room(&mut c.wide.points, RESERVED_POINTS);
            self.spare.push(c);
        }
    }

    /// How many window poses the cache holds.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        assert_eq!(self.poses.len(), self.lasts.len(), "a last match per pose");
        assert_eq!(self.poses.len(), self.proofs.len(), "a proof per pose");
        self.poses.len()
    }

    /// A new pose was appended to the window.
    pub fn push(&mut self) {
        let mut c = self.spare.pop().unwrap_or_default();
        c.wide.points.clear();
        c.wide.points.shrink_to(RESERVED_POINTS);
        c.wide.points.reserve(RESERVED_POINTS);
        c.wide.radius = f64::NEG_INFINITY;
        c.clearance = None;
        self.poses.push_back(c);
        self.lasts.push_back(LastMatch::NEVER);
        self.proofs.push_back(Proof::NONE);
    }

    /// The `count` oldest window poses were dropped.
    pub fn drop_oldest(&mut self, count: usize) {
        self.settled = self.settled.saturating_sub(count);
        for _ in 0..count.min(self.poses.len()) {
            if let Some(c) = self.poses.pop_front() {
                self.spare.push(c);
            }
            self.lasts.pop_front();
            self.proofs.pop_front();
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
        debug_assert_eq!(window.len(), self.lasts.len());
        debug_assert_eq!(window.len(), self.proofs.len());
        out.clear();
        let from = self.reuse_settled(window, params.max_distance_m, out);
        for (i, &x) in window.iter().enumerate().skip(from) {
            let dir = trajectory_direction(window, i);
            let proof = &mut self.proofs[i];
            let target = if dir == [0.0, 0.0] {
                None
            } else {
                match proven(map, proof, x, dir, params) {
                    Some(answer) => answer,
                    None => {
                        let cache = (&mut self.poses[i], proof);
                        let scratch = (&mut self.keys, &mut self.tree_scratch);
                        match match_anew(map, cache, scratch, x, dir, params) {
                            Anew::Answer(answer) => answer,
                            Anew::BeyondGate => {
                                // Unmatched at this gate; the next step's may reach it.
                                self.lasts[i] = LastMatch::NEVER;
                                continue;
                            }
                        }
                    }
                }
            };
            self.lasts[i] = LastMatch {
                position: x,
                answer: target,
            };
            if let Some((target, point)) = target.filter(|m| within(x, m.0, params.max_distance_m))
            {
                out.push(Correspondence {
                    index: i,
                    source: x,
                    target,
                    point,
                });
            }
        }
        self.settled = window.len().saturating_sub(1);
    }

    /// When no settled pose moved (the step before changed nothing: a quarter of the steps on
    /// KITTI 00, LiDAR, kiss-icp), their directions are those of their last match too, and so
    /// are their answers: those go to `out` without computing either. Returns the first pose
    /// left to match: the first unsettled one, or 0 when a position differs.
    fn reuse_settled(
        &self,
        window: &[[f64; 2]],
        max_distance_m: f64,
        out: &mut Vec<Correspondence>,
    ) -> usize {
        let settled = self.settled;
        // The first unsettled pose gives the last settled one its direction.
        if settled == 0
            || settled >= window.len()
            || self.lasts[settled].position != window[settled]
        {
            return 0;
        }
        for (i, last) in self.lasts.iter().take(settled).enumerate() {
            if last.position != window[i] {
                out.clear();
                return 0;
            }
            if let Some((target, point)) = last
                .answer
                .filter(|m| within(window[i], m.0, max_distance_m))
            {
                out.push(Correspondence {
                    index: i,
                    source: window[i],
                    target,
                    point,
                });
            }
        }
        settled
    }
}

/// The answer `proof` gives at `x` moving along `dir`, when it still holds there and decides:
/// most poses on most steps (the rest are decided anew by [`match_anew`]). [`Proof::NONE`]
/// holds nowhere.
#[inline]
fn proven(
    map: &LaneMap,
    proof: &Proof,
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
) -> Option<Option<([f64; 2], u32)>> {
    let (dx, dy) = (x[0] - proof.anchor[0], x[1] - proof.anchor[1]);
    let (ex, ey) = (dir[0] - proof.direction[0], dir[1] - proof.direction[1]);
    let holds = (dx * dx + dy * dy).sqrt() < PROOF_MOVE
        && (ex * ex + ey * ey).sqrt() < proof.direction_margin;
    if !holds {
        return None;
    }
    if proof.partners[0] == NO_POINT {
        // The answer alone (most proofs): it passes, or the pose is decided anew. The general
        // case below gives the same, at 1 % more of the whole process's instructions.
        return match proof.answer() {
            None => Some(None),
            Some(j) => {
                try_candidate(map, j, x, dir, params.min_direction_cos).map(|q| Some((q, j)))
            }
        };
    }
    // Of the answer and its partners, the first in the reference order that passes.
    let mut first = None;
    if let Some(j) = proof.answer() {
        test_candidate(map, j, x, dir, params, &mut first);
    }
    for p in proof.partners() {
        test_candidate(map, p, x, dir, params, &mut first);
    }
    match (proof.answer(), first) {
        (Some(_), Some((k, q))) => Some(Some((q, k))),
        (None, None) => Some(None),
        // No answer but a partner passes, or an answer and none passes: decide anew.
        _ => None,
    }
}

/// Decides the pose at `x` moving along `dir` from its candidate set (built again where it is
/// when too narrow), and proves the answer for the steps to come; or finds that no match can
/// pass the gate, once the set would have to grow beyond [`FAR_RADIUS`].
#[inline(never)]
fn match_anew(
    map: &LaneMap,
    (cache, proof): (&mut PoseCache, &mut Proof),
    (keys, tree_scratch): (&mut Vec<Key>, &mut TreeScratch),
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
) -> Anew {
    if cache
        .clearance
        .is_some_and(|c| beyond_gate(map, c, x, params.max_distance_m))
    {
        return Anew::BeyondGate;
    }
    let mut radius = FIRST_RADIUS;
    loop {
        if let Decision::Decided(answer, reach) = decide(map, &cache.wide, keys, x, dir, params) {
            // `keys` holds the wide set's reliable candidates at `x`; a proof needs every point
            // within the deciding distance plus twice the contender margin (a partner may lie
            // up to one margin beyond the answer, and its contenders one more).
            let wanted = (reach.sqrt() + 2.0 * CONTENDER_MARGIN) * (1.0 - RADIUS_MARGIN);
            // A set built where the pose was before it was corrected by metres still decides,
            // but may be too narrow here for a proof, and the pose would then be decided anew
            // on every step: build it here (and decide again, the same answer) instead.
            if wanted > reliable_radius(map, &cache.wide, x) && cache.wide.anchor != x {
                radius = radius.max(2.0 * wanted);
                rebuild(map, &mut cache.wide, tree_scratch, x, radius);
                continue;
            }
            // The answer rests on every point within the deciding distance (and the proof
            // below on two contender margins more); with fewer than N points in the whole
            // map and none passing, on all of them.
            if map.coverage().is_some() {
                let needed = if answer.is_none() && keys.len() < params.neighbours {
                    f64::INFINITY
                } else {
                    reach.sqrt() + 2.0 * CONTENDER_MARGIN
                };
                map.note_query(x, needed);
            }
            *proof = Proof::NONE;
            if wanted <= reliable_radius(map, &cache.wide, x) {
                let w2 = wanted * wanted;
                keys.retain(|k| k.0 < w2);
                let best = answer.map(|a| a.0);
                *proof = prove(map, keys, x, dir, params, best, reach, wanted + PROOF_MOVE)
                    .unwrap_or(Proof::NONE);
            }
            return Anew::Answer(answer.map(|(key, q)| (q, key.1)));
        }
        // Nothing within half this radius yet: the pose may be beyond the gate's reach.
        if radius >= FAR_RADIUS
            && cache.wide.points.is_empty()
            && far_off(map, cache, tree_scratch, x, params.max_distance_m)
        {
            return Anew::BeyondGate;
        }
        rebuild(map, &mut cache.wide, tree_scratch, x, radius);
        radius *= 2.0;
    }
}

/// Whether the pose at `x` is beyond the reach of a finite `gate` (metres), measured from the
/// nearest lane point and kept in `cache` for the steps to come. Only a whole map is asked: one
/// assembled from a grid's cells knows the longest of its own segments, not the whole map's.
#[cold]
#[inline(never)]
fn far_off(
    map: &LaneMap,
    cache: &mut PoseCache,
    scratch: &mut TreeScratch,
    x: [f64; 2],
    gate: f64,
) -> bool {
    if !gate.is_finite() || map.coverage().is_some() {
        return false;
    }
    let nearest = map
        .kd_tree()
        .query(&x)
        .nearest_one::<SquaredEuclidean<f64>>()
        .with_scratch(scratch)
        .execute();
    let clearance = Clearance {
        anchor: x,
        nearest_m: map.squared_distance(x, nearest.item).sqrt(),
    };
    cache.clearance = Some(clearance);
    beyond_gate(map, clearance, x, gate)
}

/// Whether a pose at `x` is, by `clearance`, farther than `gate` (metres) from every lane
/// segment, with room for rounding: then no matched point passes the gate.
fn beyond_gate(map: &LaneMap, clearance: Clearance, x: [f64; 2], gate: f64) -> bool {
    let (dx, dy) = (x[0] - clearance.anchor[0], x[1] - clearance.anchor[1]);
    let nearest_m = clearance.nearest_m - (dx * dx + dy * dy).sqrt();
    let reach_m = gate + 0.5 * map.longest_segment_m();
    nearest_m > reach_m * (1.0 + 1e-6) + 1e-6
}

/// Tests candidate `k` at `x` moving along `dir`, and keeps it and its matched point in `first`
/// when it passes and ranks ahead of what `first` holds (the reference order; keys are
/// computed only to compare two that pass).
#[inline(always)]
fn test_candidate(
    map: &LaneMap,
    k: u32,
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
    first: &mut Option<(u32, [f64; 2])>,
) {
    if let Some(q) = try_candidate(map, k, x, dir, params.min_direction_cos) {
        let key = |j: u32| (map.squared_distance(x, j), j);
        if first.is_none_or(|(lead, _)| key_less(key(k), key(lead))) {
            *first = Some((k, q));
        }
    }
}

/// Builds a [`Proof`] for the answer `best` at `x`, decided within squared distance `reach`,
/// from `keys`: every lane point within the deciding distance plus twice [`CONTENDER_MARGIN`]
/// (the proof then rests on every point within `rests_on_m` metres of `x`).
/// Every point that could rank ahead of the answer must fail a test by more than the proof's
/// bounds can undo, except at most [`MAX_PARTNERS`], the partners (typically the neighbouring
/// segments of the same lane, where the pose is near their joint, a lane's last point, which
/// shares its segment, or, without an answer, a lane the pose has just passed the end of): the
/// check tests them exactly. `None` when more candidates are too close to a test's boundary, or
/// too many could rank ahead.
#[allow(clippy::too_many_arguments)]
fn prove(
    map: &LaneMap,
    keys: &[Key],
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
    best: Option<Key>,
    reach: f64,
    rests_on_m: f64,
) -> Option<Proof> {
    // Per candidate: how far the direction test passes, how far (metres along `dir`) the normal
    // shot lands inside the segment, and the larger of |x - a|, |x - b|. Negative means fails.
    let margins = |j: u32| {
        map.segment_of(j).map(|(a, b, d_lane)| {
            let (xa, xb) = ([x[0] - a[0], x[1] - a[1]], [x[0] - b[0], x[1] - b[1]]);
            let inside = dot(xa, dir).min(-dot(xb, dir));
            let reach = dot(xa, xa).max(dot(xb, xb)).sqrt();
            (dot(dir, d_lane) - params.min_direction_cos, inside, reach)
        })
    };
    // The direction change under which a failing candidate surely still fails.
    let fails_within = |j: u32| match margins(j) {
        None => f64::INFINITY,
        Some((direction, inside, reach)) => (-direction).max((-inside - PROOF_MOVE) / reach),
    };
    // Could `k` rank ahead of `lead` once the pose has moved less than `PROOF_MOVE`?
    let could_lead =
        |k: Key, lead: Key| key_less(k, lead) || k.0.sqrt() - lead.0.sqrt() <= 2.0 * PROOF_MOVE;
    // The contenders sorted into partners (no room) and others: the others' least room and their
    // count; `None` when more than MAX_PARTNERS have no room.
    struct Contenders {
        partners: [Option<Key>; MAX_PARTNERS],
        margin: f64,
        others: usize,
    }
    fn sort(
        contenders: impl Iterator<Item = Key>,
        fails_within: impl Fn(u32) -> f64,
    ) -> Option<Contenders> {
        let mut sorted = Contenders {
            partners: [None; MAX_PARTNERS],
            margin: f64::INFINITY,
            others: 0,
        };
        let mut count = 0;
        for k in contenders {
            let room = fails_within(k.1);
            if room > MIN_MARGIN {
                sorted.margin = sorted.margin.min(room);
                sorted.others += 1;
            } else if count < MAX_PARTNERS {
                sorted.partners[count] = Some(k);
                count += 1;
            } else {
                return None;
            }
        }
        Some(sorted)
    }
    let (partners, margin) = match best {
        None => {
            // Every point among the `N` nearest after a move lies within this distance now.
            let limit = reach.sqrt() + CONTENDER_MARGIN;
            let sorted = sort(
                keys.iter().copied().filter(|k| k.0.sqrt() < limit),
                fails_within,
            )?;
            (sorted.partners, sorted.margin)
        }
        Some(best) => {
            // The chosen one may be any of the answer and the partners: whichever of them ranks
            // last decides who could get ahead of it. Each pass may find partners that rank
            // later still; the contenders only grow, so this ends within MAX_PARTNERS passes.
            let mut lead = best;
            loop {
                let sorted = sort(
                    keys.iter()
                        .copied()
                        .filter(|k| k.1 != best.1 && could_lead(*k, lead)),
                    fails_within,
                )?;
                let partners = sorted.partners.iter().flatten();
                let last = partners
                    .clone()
                    .fold(best, |a, &p| if key_less(a, p) { p } else { a });
                // The keys reach two contender margins beyond the answer: enough for the
                // contenders of a lead one margin beyond it, and no farther.
                if !could_lead(last, best) {
                    return None;
                }
                if last == lead {
                    if partners.count() + sorted.others >= params.neighbours {
                        return None;
                    }
                    break (sorted.partners, sorted.margin);
                }
                lead = last;
            }
        }
    };
    // Keep clear of rounding: a proof with almost no room is no proof.
    (margin > MIN_MARGIN).then(|| Proof {
        anchor: x,
        direction: dir,
        direction_margin: margin * (1.0 - 1e-6),
        rests_on_m,
        answer: best.map_or(NO_POINT, |k| k.1),
        partners: partners.map(|p| p.map_or(NO_POINT, |k| k.1)),
    })
}

/// The radius (metres) within which `set` is complete around `x`.
fn reliable_radius(map: &LaneMap, set: &CandidateSet, x: [f64; 2]) -> f64 {
    if set.points.len() == map.len() {
        return f64::INFINITY;
    }
    let (dx, dy) = (x[0] - set.anchor[0], x[1] - set.anchor[1]);
    set.radius - (dx * dx + dy * dy).sqrt() * (1.0 + RADIUS_MARGIN)
}

/// Fills `set` with every lane point within `radius` metres of `x`, without allocating once the
/// set's buffer has grown.
fn rebuild(
    map: &LaneMap,
    set: &mut CandidateSet,
    scratch: &mut TreeScratch,
    x: [f64; 2],
    radius: f64,
) {
    set.anchor = x;
    set.points.clear();
    let points = &mut set.points;
    map.kd_tree()
        .query(&x)
        .within::<SquaredEuclidean<f64>>(radius * radius)
        .unsorted()
        .with_scratch(scratch)
        .visit(|r| points.push(r.item));
    set.radius = if set.points.len() == map.len() {
        f64::INFINITY
    } else {
        radius * (1.0 - RADIUS_MARGIN)
    };
}

/// Decides from the wide set alone, in one pass over its reliable candidates (closer than its
/// radius less the distance moved, left in `keys`): the smallest-key candidate that passes, and
/// its rank (how many keys are smaller).
fn decide(
    map: &LaneMap,
    set: &CandidateSet,
    keys: &mut Vec<Key>,
    x: [f64; 2],
    dir: [f64; 2],
    params: &MatchParams,
) -> Decision {
    keys.clear();
    let reliable = reliable_radius(map, set, x);
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
    match best {
        Some((best_key, _)) if keys.iter().filter(|&&k| key_less(k, best_key)).count() < n => {
            return Decision::Decided(best, best_key.0);
        }
        None if keys.len() < n && reliable.is_finite() => return Decision::Unknown,
        _ => {}
    }
    // None of the N nearest passes, and they are all reliable: they reach the N-th distance.
    let reach = if keys.len() <= n {
        keys.iter().map(|k| k.0).fold(0.0, f64::max)
    } else {
        // Only the N-th distance is wanted, which ties between indices do not change; squared
        // distances are finite and never negative, so they order as their bits do.
        let (_, nth, _) = keys.select_nth_unstable_by_key(n - 1, |k| k.0.to_bits());
        nth.0
    };
    Decision::Decided(None, reach)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::{Candidate, Lane};
    use crate::matching::match_window;
    use proptest::prelude::*;

    /// The cached matcher beside the reference one, on one window.
    struct SideBySide {
        cache: MatchCache,
        want: Vec<Correspondence>,
        got: Vec<Correspondence>,
        scratch: Vec<Candidate>,
    }

    impl SideBySide {
        /// For a window of `len` poses.
        fn new(len: usize) -> Self {
            let mut cache = MatchCache::default();
            for _ in 0..len {
                cache.push();
            }
            SideBySide {
                cache,
                want: Vec::new(),
                got: Vec::new(),
                scratch: Vec::new(),
            }
        }

        /// `window` matched by the cache and by the reference matcher.
        fn matched(
            &mut self,
            map: &LaneMap,
            window: &[[f64; 2]],
            params: &MatchParams,
        ) -> (&[Correspondence], &[Correspondence]) {
            match_window(map, window, params, &mut self.scratch, &mut self.want);
            self.cache.match_window(map, window, params, &mut self.got);
            (&self.got, &self.want)
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 96, rng_seed: proptest::test_runner::RngSeed::Fixed(11), ..ProptestConfig::default() })]
        /// A window drifting across a grid of crossing and diagonal lanes with many duplicate
        /// points, by moves both inside and beyond the proofs' bounds: the cached matcher gives
        /// the reference correspondences at every step.
        #[test]
        fn cached_matching_equals_reference(
            steps in prop::collection::vec((-0.3f64..0.3, -0.3f64..0.3, -0.01f64..0.01, 0u8..10), 1..40),
            n in 1usize..40,
            gate in prop_oneof![Just(f64::INFINITY), 0.2f64..3.0],
        ) {
            let mut lanes = Vec::new();
            for r in 0..6 {
                let y = r as f64 * 4.0;
                let east: Vec<[f64; 2]> = (0..20).map(|i| [i as f64 * 3.0, y]).collect();
                let mut west = east.clone();
                west.reverse();
                lanes.push(Lane::new(2 * r, east));
                lanes.push(Lane::new(2 * r + 1, west));
                let north: Vec<[f64; 2]> = (0..8).map(|i| [r as f64 * 9.0, i as f64 * 3.0]).collect();
                lanes.push(Lane::new(100 + r, north));
                let diagonal: Vec<[f64; 2]> = (0..10).map(|i| [r as f64 * 9.0 + i as f64 * 2.9, i as f64 * 0.8 - 1.0]).collect();
                lanes.push(Lane::new(200 + r, diagonal));
            }
            let map = LaneMap::new(&lanes).unwrap();
            let params = MatchParams { neighbours: n, min_direction_cos: 0.95, max_distance_m: gate };
            let mut window: Vec<[f64; 2]> = (0..30).map(|i| [1.0 + i as f64 * 1.7, 5.0 + (i as f64 * 0.3).sin()]).collect();
            let mut both = SideBySide::new(window.len());
            for (dx, dy, dth, jump) in steps {
                // One step in ten jumps by up to 3 m, far beyond every proof's bound.
                let scale = if jump == 0 { 10.0 } else { 1.0 };
                let (s, c) = (dth * scale).sin_cos();
                for p in window.iter_mut() {
                    *p = [c * p[0] - s * p[1] + dx * scale, s * p[0] + c * p[1] + dy * scale];
                }
                let (got, want) = both.matched(&map, &window, &params);
                prop_assert_eq!(got, want);
            }
        }

        /// A window sliding along the lanes as the corrector's does: a new pose at the front and
        /// sometimes the oldest dropped each step, the positions moved on some steps, only the
        /// newest on others, and left exactly as they were on the rest (where the cache reuses
        /// its settled poses' answers), with standing still (zero directions) mixed in: the
        /// reference correspondences at every step.
        #[test]
        fn a_sliding_window_reuses_only_what_did_not_move(
            steps in prop::collection::vec((0u8..3, -0.4f64..0.4, 0u8..3, 0u8..4), 1..60),
            n in 1usize..20,
            gate in prop_oneof![Just(f64::INFINITY), 0.2f64..3.0],
        ) {
            let lanes: Vec<Lane> = (0..4)
                .map(|r| Lane::new(r, (0..40).map(|i| [i as f64 * 2.5, r as f64 * 3.5 + (i as f64 * 0.2).sin()]).collect()))
                .collect();
            let map = LaneMap::new(&lanes).unwrap();
            let params = MatchParams { neighbours: n, min_direction_cos: 0.9, max_distance_m: gate };
            let mut window: Vec<[f64; 2]> = (0..12).map(|i| [1.0 + i as f64 * 1.3, 4.0]).collect();
            let mut both = SideBySide::new(window.len());
            for (moved, shift, drop, stand) in steps {
                match moved {
                    0 => window.iter_mut().for_each(|p| *p = [p[0] + shift * 0.1, p[1] + shift]),
                    // Only the newest moves: the direction of the one before it changes.
                    1 => {
                        let newest = window.len() - 1;
                        window[newest][1] += shift;
                    }
                    _ => {}
                }
                let last = window[window.len() - 1];
                let next = if stand == 0 { last } else { [last[0] + 1.3, last[1] + shift * 0.2] };
                window.push(next);
                both.cache.push();
                if drop == 0 && window.len() > 3 {
                    window.remove(0);
                    both.cache.drop_oldest(1);
                }
                let (got, want) = both.matched(&map, &window, &params);
                prop_assert_eq!(got, want);
            }
        }

    }

    /// Lanes a block apart with points 3 m apart, both ways, as the synthetic town's.
    fn blocks() -> LaneMap {
        let mut lanes = Vec::new();
        for r in 0..3 {
            let y = r as f64 * 60.0;
            let east: Vec<[f64; 2]> = (0..40).map(|i| [i as f64 * 3.0, y]).collect();
            let mut west: Vec<[f64; 2]> = east.iter().map(|p| [p[0], p[1] + 3.5]).collect();
            west.reverse();
            lanes.push(Lane::new(2 * r, east));
            lanes.push(Lane::new(2 * r + 1, west));
        }
        LaneMap::new(&lanes).unwrap()
    }

    /// A window driving along a lane, moved off the map by `offset` metres.
    fn window_off_by(offset: [f64; 2]) -> Vec<[f64; 2]> {
        (0..30)
            .map(|i| [10.0 + i as f64 * 1.5 + offset[0], 1.0 + offset[1]])
            .collect()
    }

    /// A window that jumps 200 m off the lanes and back, under a gate that is first too narrow
    /// to reach them and then wide enough: the reference correspondences at every step, and
    /// while out of reach the poses gather no candidates.
    #[test]
    fn poses_beyond_the_gate_gather_nothing() {
        let map = blocks();
        let mut both = SideBySide::new(30);
        let gated = |gate: f64| MatchParams {
            neighbours: 10,
            min_direction_cos: 0.95,
            max_distance_m: gate,
        };
        // (offset, gate, whether any pose is matched within the gate, whether any candidates
        // were gathered: the last but one step is decided by the proofs of the one before).
        let steps = [
            ([0.0, 0.0], 3.0, true, true),
            ([0.0, -200.0], 3.0, false, false),
            ([0.0, -200.5], 150.0, false, false),
            ([0.0, -200.0], 250.0, true, true),
            ([0.0, -200.0], 3.0, false, true),
            ([0.0, 0.3], 3.0, true, true),
        ];
        for (offset, gate, matched, gathered) in steps {
            let (got, want) = both.matched(&map, &window_off_by(offset), &gated(gate));
            assert_eq!(got, want, "{offset:?} at gate {gate}");
            assert_eq!(!got.is_empty(), matched, "{offset:?} at gate {gate}");
            let points: usize = both.cache.poses.iter().map(|c| c.wide.points.len()).sum();
            assert_eq!(points > 0, gathered, "{offset:?} at gate {gate}: {points}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, rng_seed: proptest::test_runner::RngSeed::Fixed(13), ..ProptestConfig::default() })]
        /// A window moved anywhere up to 300 m off the lanes under gates from 0.5 m to 300 m,
        /// about as often within the gate's reach as beyond it: the reference correspondences
        /// at every step.
        #[test]
        fn far_poses_match_as_the_reference_at_any_gate(
            steps in prop::collection::vec((-300.0f64..300.0, -300.0f64..300.0, 0.5f64..300.0), 1..8),
            n in 1usize..20,
        ) {
            let map = blocks();
            let mut both = SideBySide::new(30);
            for (dx, dy, gate) in steps {
                let params = MatchParams { neighbours: n, min_direction_cos: 0.95, max_distance_m: gate };
                let (got, want) = both.matched(&map, &window_off_by([dx, dy]), &params);
                prop_assert_eq!(got, want);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, rng_seed: proptest::test_runner::RngSeed::Fixed(12), ..ProptestConfig::default() })]
        /// A bundle of nearly coincident lanes, their nodes at nearly the same places and some
        /// turned to about the direction test's limit, so that several candidates sit at a
        /// test's boundary at once (proofs with partners, ranked either side of the answer), and a
        /// window moved by small steps: the reference correspondences at every step.
        #[test]
        fn a_bundle_of_near_ties_needs_every_partner(
            lanes in prop::collection::vec((-0.4f64..0.4, -0.6f64..0.6, -0.33f64..0.33), 2..7),
            steps in prop::collection::vec((-0.2f64..0.2, -0.2f64..0.2, -0.004f64..0.004), 1..30),
            n in 1usize..12,
        ) {
            let lanes: Vec<Lane> = lanes
                .iter()
                .enumerate()
                .map(|(id, &(offset, shift, turn))| {
                    let (s, c) = turn.sin_cos();
                    let points = (0..12)
                        .map(|i| {
                            let along = i as f64 * 2.0 + shift;
                            [c * along, s * along + offset]
                        })
                        .collect();
                    Lane::new(id as u64, points)
                })
                .collect();
            let map = LaneMap::new(&lanes).unwrap();
            let params = MatchParams { neighbours: n, min_direction_cos: 0.95, max_distance_m: f64::INFINITY };
            let mut window: Vec<[f64; 2]> = (0..10).map(|i| [1.0 + i as f64 * 1.9, 0.1]).collect();
            let mut both = SideBySide::new(window.len());
            for (dx, dy, dth) in steps {
                let (s, c) = dth.sin_cos();
                for p in window.iter_mut() {
                    *p = [c * p[0] - s * p[1] + dx, s * p[0] + c * p[1] + dy];
                }
                let (got, want) = both.matched(&map, &window, &params);
                prop_assert_eq!(got, want);
            }
        }
    }
}
