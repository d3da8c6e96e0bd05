//! The online corrector (docs/algorithm.md, section "Online correction"): a sliding window of
//! corrected positions, lane matching, trimmed ICP, and the accumulated correction.
//!
//! One corrector serves one odometry source. It works in the lane map's plane: positions come in
//! as the source's anchor places them (frame `anchored`: the odometry placed in the map plane,
//! before any correction; where the corrector estimates the odometry's scale, with the steps
//! multiplied by its estimate, frame `scaled` of [`crate::source_corrector`]) and go out
//! corrected (frame `map`). The accumulated correction is `map_from_anchored` (the paper's
//! `T_acc`); [`crate::source_corrector`] composes it with the anchor into the source's
//! `map_from_odom`.

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::confidence::{
    alignment_information, correction_at, correction_from, Covariance, PoseUncertainty,
};
use crate::icp::{trimmed_icp, IcpParams, IcpScratch};
use crate::lane_map::{Candidate, LaneMap};
use crate::match_cache::MatchCache;
use crate::matching::{match_window, Correspondence, MatchParams};
use crate::params::Params;
use crate::scale::{scale_evidence, ScaleEstimate};
use crate::se2::{distance, Se2};
use crate::stall::Widening;
use crate::window::Window;

/// Why a matching attempt did not produce an accepted correction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RejectReason {
    /// Fewer than `eta |W|` window poses found a lane.
    TooFewMatches,
    /// The trimmed ICP residual was at least epsilon.
    ResidualTooLarge,
}

impl RejectReason {
    /// A short lowercase name: `too_few_matches`, `residual_too_large`.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::TooFewMatches => "too_few_matches",
            RejectReason::ResidualTooLarge => "residual_too_large",
        }
    }
}

/// What happened on one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Status {
    /// The window is still shorter than `M_min` poses or `L_min` metres: no matching ran.
    WarmingUp {
        /// Poses in the window.
        window_len: usize,
    },
    /// A correction was computed and applied (the part of it the evidence supports).
    Accepted {
        /// Mean residual of the kept pairs (metres).
        residual_m: f64,
        /// Of the correction's three directions (two of position, one of heading), how many the
        /// map's evidence supported and were applied (3 for the paper's method).
        applied_directions: u8,
        /// `|C| / |W|`.
        match_ratio: f64,
        /// Poses in the window.
        window_len: usize,
    },
    /// Matching ran but the correction was refused; the oldest window pose was dropped.
    Rejected {
        /// Why.
        reason: RejectReason,
        /// Mean residual (metres); infinite when there were too few matches.
        residual_m: f64,
        /// `|C| / |W|`.
        match_ratio: f64,
        /// Poses in the window after the drop.
        window_len: usize,
    },
    /// A rejection pushed the failure count past `E_max`: the window was cut to `M_min - 1`.
    Reset {
        /// Why the last attempt failed.
        reason: RejectReason,
        /// Mean residual (metres); infinite when there were too few matches.
        residual_m: f64,
        /// `|C| / |W|`.
        match_ratio: f64,
        /// Poses in the window after the cut.
        window_len: usize,
    },
    /// The input pose was not finite: it was not added and nothing changed.
    InvalidInput,
    /// The pose is answered with the correction in force and no alignment ran: it came between
    /// window poses of a source faster than the presets' rate ([`Params::odometry_rate_hz`]), or
    /// the vehicle stood still ([`Params::standstill_speed_mps`]), and it did not enter the
    /// window; or it entered the window less than [`Params::alignment_spacing_m`] of road after
    /// the last accepted alignment.
    Carried {
        /// Poses in the window.
        window_len: usize,
    },
    /// The odometry jumped: the pose is farther from the last than the vehicle can drive between
    /// them ([`Params::max_speed_mps`]). It is answered
    /// with the correction in force where the last motion leads, did not enter the window, and
    /// the poses after it continue from there ([`crate::continuity`]).
    OdometryJump {
        /// Poses in the window.
        window_len: usize,
    },
}

impl Status {
    /// Every status name, in the order of [`Status::name`]'s match.
    pub const NAMES: [&'static str; 7] = [
        "warming_up",
        "accepted",
        "rejected",
        "reset",
        "invalid_input",
        "carried",
        "odometry_jump",
    ];

    /// A short lowercase name: `warming_up`, `accepted`, `rejected`, `reset`, `invalid_input`,
    /// `carried`, `odometry_jump`.
    pub fn name(&self) -> &'static str {
        match self {
            Status::WarmingUp { .. } => Self::NAMES[0],
            Status::Accepted { .. } => Self::NAMES[1],
            Status::Rejected { .. } => Self::NAMES[2],
            Status::Reset { .. } => Self::NAMES[3],
            Status::InvalidInput => Self::NAMES[4],
            Status::Carried { .. } => Self::NAMES[5],
            Status::OdometryJump { .. } => Self::NAMES[6],
        }
    }

    /// Why the attempt failed, for rejected and reset steps.
    pub fn reason(&self) -> Option<RejectReason> {
        match *self {
            Status::Rejected { reason, .. } | Status::Reset { reason, .. } => Some(reason),
            _ => None,
        }
    }

    /// The mean residual of the kept pairs (metres) when matching ran; infinite when too few
    /// poses matched.
    pub fn residual_m(&self) -> Option<f64> {
        match *self {
            Status::Accepted { residual_m, .. }
            | Status::Rejected { residual_m, .. }
            | Status::Reset { residual_m, .. } => Some(residual_m),
            _ => None,
        }
    }

    /// How many directions of the correction were applied: on accepted steps 0 to 3, otherwise 0.
    pub fn applied_directions(&self) -> u8 {
        match *self {
            Status::Accepted {
                applied_directions, ..
            } => applied_directions,
            _ => 0,
        }
    }

    /// The matched fraction of the window when matching ran.
    pub fn match_ratio(&self) -> Option<f64> {
        match *self {
            Status::Accepted { match_ratio, .. }
            | Status::Rejected { match_ratio, .. }
            | Status::Reset { match_ratio, .. } => Some(match_ratio),
            _ => None,
        }
    }

    /// Poses in the window after the step (0 for invalid input).
    pub fn window_len(&self) -> usize {
        match *self {
            Status::WarmingUp { window_len }
            | Status::Carried { window_len }
            | Status::OdometryJump { window_len }
            | Status::Accepted { window_len, .. }
            | Status::Rejected { window_len, .. }
            | Status::Reset { window_len, .. } => window_len,
            Status::InvalidInput => 0,
        }
    }

    /// True when matching ran on this step (the reference figures' "attempts").
    pub fn attempted(&self) -> bool {
        matches!(
            self,
            Status::Accepted { .. } | Status::Rejected { .. } | Status::Reset { .. }
        )
    }
}

/// Where the time of one step went (monotonic clock).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepTiming {
    /// Lane matching of the window, the robust method's distance gate included.
    pub matching: Duration,
    /// Trimmed ICP.
    pub icp: Duration,
    /// The correction's covariance and the share of it the evidence supports (accepted steps).
    pub confidence: Duration,
    /// The whole step, bookkeeping included.
    pub total: Duration,
}

/// The result of one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// The corrected position (metres, map plane).
    pub position_in_map: [f64; 2],
    /// The accumulated correction after this step (the paper's `T_acc`): apply it to an anchored
    /// position for the corrected one.
    pub map_from_anchored: Se2,
    /// The covariance of the corrected pose's error (map plane; x, y in metres, yaw in radians):
    /// the filter's, plus the map error the pose inherits from its last alignment.
    pub covariance: Covariance,
    /// What happened.
    pub status: Status,
    /// Where the time went.
    pub timing: StepTiming,
}

/// How the window is matched to the lanes. Both give identical correspondences.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MatchMode {
    /// The algorithm literally (docs/algorithm.md, section 2): every window pose, every step, `N`
    /// nearest from the KD-tree.
    Reference,
    /// Exact incremental matching with per-pose candidate caches (see [`crate::match_cache`]).
    #[default]
    Fast,
}

impl MatchMode {
    /// The mode's name on the command line and in configs.
    pub fn name(self) -> &'static str {
        match self {
            MatchMode::Reference => "reference",
            MatchMode::Fast => "fast",
        }
    }
}

impl std::str::FromStr for MatchMode {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

enum Matcher {
    Reference(Vec<Candidate>),
    Fast(Box<MatchCache>),
}

/// Everything a corrector's future answers depend on: saved with [`Corrector::state`] and given
/// back to [`Corrector::restore`], it continues exactly, bit for bit. (The fast matcher's caches
/// are not part of it: they change how much work matching takes, never its answers.)
#[derive(Clone, Debug, PartialEq)]
pub struct CorrectorState {
    /// The accumulated correction.
    pub map_from_anchored: Se2,
    /// The window's corrected positions, oldest first (metres, map plane).
    pub window: Vec<[f64; 2]>,
    /// The window's path length as the corrector keeps it (metres; kept, not re-summed, so that
    /// its rounding is the same).
    pub window_path_m: f64,
    /// Consecutive failures.
    pub failures: u32,
    /// Odometry path length since the last accepted step (metres).
    pub travelled_m: f64,
    /// Odometry path length the match gate widens by (metres; see
    /// [`Params::gate_widens_through_null_steps`]).
    pub gate_travelled_m: f64,
    /// The last position pushed that did not stand still (metres, frame `anchored`; see
    /// [`Params::standstill_speed_mps`]).
    pub last_position_in_anchored: Option<[f64; 2]>,
    /// The filter's covariance of the current pose (without the inherited map error).
    pub covariance: Covariance,
    /// The map error the pose inherits from its last alignment (x, y; metres squared, map plane).
    pub map_error: [[f64; 2]; 2],
    /// Poses answered as [`Status::Carried`] since the last one that entered the window.
    pub carried: u32,
    /// The estimate of the odometry's scale, when it is estimated ([`Params::scale_sigma`]).
    pub scale: Option<ScaleEstimate>,
    /// When the scale is estimated, the published covariance of the pose (without the inherited
    /// map error) and its covariance with the scale error (see [`Corrector::covariance`]).
    pub published_uncertainty: Option<(Covariance, [f64; 3])>,
}

/// One odometry source's corrector.
pub struct Corrector {
    map: Arc<LaneMap>,
    params: Params,
    map_from_anchored: Se2,
    window: Window,
    failures: u32,
    /// Odometry path length since the last accepted step (metres): what share of the window's
    /// evidence an alignment adds, and when the next alignment is due.
    travelled_m: f64,
    /// Odometry path length since the match gate last closed (metres): since the last accepted
    /// step that moved the window or matched its newest pose. An accepted step that changes
    /// nothing while the newest pose has no match (the older poses fit their lanes, the newer
    /// ones have drifted beyond the gate) does not close it, so it widens until they are
    /// matched ([`Params::gate_widens_through_null_steps`]).
    gate_travelled_m: f64,
    /// The last position that did not stand still ([`Params::standstill_speed_mps`]): where the
    /// distance travelled is measured from.
    last_position_in_anchored: Option<[f64; 2]>,
    uncertainty: PoseUncertainty,
    /// The map error the pose inherits from its last alignment (see
    /// [`Alignment::inherited_map_error`](crate::confidence::Alignment::inherited_map_error)).
    map_error: [[f64; 2]; 2],
    /// Poses carried since the last one that entered the window.
    carried: u32,
    /// Whether the last finite pose pushed stood still ([`Params::standstill_speed_mps`]).
    stood_still: bool,
    matcher: Matcher,
    correspondences: Vec<Correspondence>,
    icp: IcpScratch,
    /// The odometry's scale, when it is estimated ([`Params::scale_sigma`]).
    scale: Option<ScaleTracking>,
}

/// What a corrector that estimates the odometry's scale keeps of it.
#[derive(Clone, Copy, Debug)]
struct ScaleTracking {
    /// The estimate.
    estimate: ScaleEstimate,
    /// The pose's uncertainty with the scale's in it, which is published. The corrector's
    /// `uncertainty` alone decides what of a correction is applied, as it does for an odometry
    /// whose scale is not estimated (with the scale's along-track uncertainty in it, rigid
    /// corrections took the scale error before the scale estimate could: docs/method.md,
    /// "Scale").
    published: PoseUncertainty,
}

impl Corrector {
    /// A corrector on a shared lane map, in the default (fast) match mode. `params` must pass
    /// [`Params::validate`].
    pub fn new(map: Arc<LaneMap>, params: Params) -> Self {
        Self::with_mode(map, params, MatchMode::default())
    }

    /// A corrector with an explicit match mode.
    pub fn with_mode(map: Arc<LaneMap>, params: Params, mode: MatchMode) -> Self {
        Corrector {
            map,
            params,
            map_from_anchored: Se2::IDENTITY,
            window: Window::default(),
            failures: 0,
            travelled_m: 0.0,
            gate_travelled_m: 0.0,
            last_position_in_anchored: None,
            uncertainty: PoseUncertainty::new(&params),
            map_error: [[0.0; 2]; 2],
            carried: 0,
            stood_still: false,
            matcher: match mode {
                MatchMode::Reference => Matcher::Reference(Vec::new()),
                MatchMode::Fast => Matcher::Fast(Box::default()),
            },
            correspondences: Vec::new(),
            icp: IcpScratch::default(),
            scale: (params.scale_sigma > 0.0).then(|| ScaleTracking {
                estimate: ScaleEstimate::new(params.scale_sigma),
                published: PoseUncertainty::new(&params),
            }),
        }
    }

    /// The parameters in use.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// The window's corrected positions, oldest first (metres, map plane).
    pub fn window(&self) -> &[[f64; 2]] {
        self.window.as_slice()
    }

    /// The state to continue from later (see [`CorrectorState`]).
    pub fn state(&self) -> CorrectorState {
        CorrectorState {
            map_from_anchored: self.map_from_anchored,
            window: self.window.as_slice().to_vec(),
            window_path_m: self.window.path_m(),
            failures: self.failures,
            travelled_m: self.travelled_m,
            gate_travelled_m: self.gate_travelled_m,
            last_position_in_anchored: self.last_position_in_anchored,
            covariance: self.uncertainty.covariance(),
            map_error: self.map_error,
            carried: self.carried,
            scale: self.scale.map(|s| s.estimate),
            published_uncertainty: self
                .scale
                .map(|s| (s.published.covariance(), s.published.scale_cross())),
        }
    }

    /// A corrector that continues from `state`, exactly as the one it was saved from would.
    pub fn restore(
        map: Arc<LaneMap>,
        params: Params,
        mode: MatchMode,
        state: CorrectorState,
    ) -> Self {
        let mut c = Self::with_mode(map, params, mode);
        if let Matcher::Fast(cache) = &mut c.matcher {
            for _ in 0..state.window.len() {
                cache.push();
            }
        }
        c.window = Window::restored(state.window, state.window_path_m);
        c.map_from_anchored = state.map_from_anchored;
        c.failures = state.failures;
        c.travelled_m = state.travelled_m;
        c.gate_travelled_m = state.gate_travelled_m;
        c.last_position_in_anchored = state.last_position_in_anchored;
        c.uncertainty = PoseUncertainty::from_covariance(&state.covariance);
        c.map_error = state.map_error;
        c.carried = state.carried;
        // A state saved before the scale was estimated starts the estimate afresh.
        if let Some(scale) = &mut c.scale {
            scale.estimate = state.scale.unwrap_or(scale.estimate);
            scale.published = match state.published_uncertainty {
                Some((covariance, cross)) => PoseUncertainty::from_parts(&covariance, cross),
                None => c.uncertainty,
            };
        }
        c
    }

    /// Drives the current pose's uncertainty over the road an odometry that stalled missed
    /// (`widening`, its direction in the map plane; [`PoseUncertainty::drive_unseen`]), in the
    /// filter that decides what is applied and in the published covariance alike
    /// ([`crate::stall`]).
    pub fn drive_unseen(&mut self, widening: &Widening) {
        self.uncertainty.drive_unseen(widening);
        if let Some(scale) = &mut self.scale {
            scale.published.drive_unseen(widening);
        }
    }

    /// Restarts the window from its newest pose: the poses before it are no longer one rigid
    /// piece of trajectory with the ones to come (an odometry that stalled missed road between
    /// them, [`crate::stall`]). The correction in force and the uncertainty stay; the window
    /// warms up again as at the start.
    pub fn restart_window(&mut self) {
        self.drop_oldest(self.window.len().saturating_sub(1));
        self.failures = 0;
    }

    /// The lane map in use.
    pub fn map(&self) -> &Arc<LaneMap> {
        &self.map
    }

    /// Continues on another lane map (a grid's cells around a moving source): every later step
    /// runs on `map`. The answers stay those of the whole map as long as `map` covers the
    /// window's queries (see [`crate::grid`]).
    pub fn replace_map(&mut self, map: Arc<LaneMap>) {
        if let Matcher::Fast(cache) = &mut self.matcher {
            cache.carry_over(&self.map, &map);
        }
        self.map = map;
    }

    /// The covariance of the current corrected pose (see [`Step::covariance`]): the filter's,
    /// plus the map error inherited from the last alignment.
    pub fn covariance(&self) -> Covariance {
        let mut covariance = self
            .scale
            .map_or(self.uncertainty, |s| s.published)
            .covariance();
        for (row, inherited) in covariance.iter_mut().zip(&self.map_error) {
            row[0] += inherited[0];
            row[1] += inherited[1];
        }
        covariance
    }

    /// The current correction (the paper's `T_acc`).
    pub fn map_from_anchored(&self) -> Se2 {
        self.map_from_anchored
    }

    /// Whether the corrector estimates the odometry's scale ([`Params::scale_sigma`]).
    pub fn estimates_scale(&self) -> bool {
        self.scale.is_some()
    }

    /// What the odometry's steps are multiplied by now: the estimate of its scale (a ratio; 1
    /// where the scale is not estimated, [`Params::scale_sigma`]).
    pub fn odometry_scale(&self) -> f64 {
        self.scale.map_or(1.0, |s| s.estimate.factor)
    }

    /// The standard deviation of [`Corrector::odometry_scale`] (a ratio; 0 where the scale is not
    /// estimated).
    pub fn odometry_scale_sd(&self) -> f64 {
        self.scale.map_or(0.0, |s| s.estimate.variance.sqrt())
    }

    /// Whether the last finite pose pushed stood still ([`Params::standstill_speed_mps`]): it
    /// entered no window and counted no distance.
    pub fn stood_still(&self) -> bool {
        self.stood_still
    }

    /// Readies the memory the next [`Corrector::push`] may need, so that a caller waiting
    /// between poses (the daemon, after publishing an answer) takes its page faults there and
    /// not while an answer is awaited. Optional: `push` does the same work when this was not
    /// called, and the results are the same either way.
    pub fn prepare(&mut self) {
        let poses = self.window.len() + 1;
        self.window.make_room();
        crate::headroom::make_room(&mut self.correspondences, poses);
        self.icp.make_room(poses);
        if let Matcher::Fast(cache) = &mut self.matcher {
            cache.make_room(poses);
        }
    }

    /// Does the part of the next [`Corrector::push`] that needs no pose, for a caller that has
    /// time between poses (the daemon, when no other pose waits): measures the window's
    /// spacings again after a correction moved it (the covariance reads them), and in the fast
    /// match mode matches the window where it now is, so that the step finds the answers of
    /// every window pose but the newest (whose direction the next pose changes) ready and
    /// matches only that one and the next pose. Optional: `push` does the same work when this
    /// was not called, and the results are the same either way; calling it while poses queue
    /// costs their throughput a little (the step reads the answers out again).
    pub fn work_ahead(&mut self) {
        self.window.refresh_spacings();
        let match_params = self.match_params();
        if let Matcher::Fast(cache) = &mut self.matcher {
            // The correspondences are the step's scratch; the next step matches anew into them.
            cache.match_window(
                &self.map,
                self.window.as_slice(),
                &match_params,
                &mut self.correspondences,
            );
        }
    }

    /// The matching parameters of the next step: the preset's, with the distance gate widened
    /// by the drift the odometry may have accumulated since the gate last closed.
    fn match_params(&self) -> MatchParams {
        MatchParams {
            neighbours: self.params.neighbours,
            min_direction_cos: self.params.min_direction_cos,
            max_distance_m: self.widened(self.params.max_match_distance_m),
        }
    }

    /// Processes the next position of the source as its anchor places it in the map plane
    /// (metres, frame `anchored`).
    pub fn push(&mut self, position_in_anchored: [f64; 2]) -> Step {
        let start = Instant::now();
        let mut timing = StepTiming::default();
        let mut step = self.advance(position_in_anchored, &mut timing);
        timing.total = start.elapsed();
        step.timing = timing;
        step
    }

    fn advance(&mut self, position_in_anchored: [f64; 2], timing: &mut StepTiming) -> Step {
        if !(position_in_anchored[0].is_finite() && position_in_anchored[1].is_finite()) {
            return Step {
                position_in_map: [f64::NAN, f64::NAN],
                map_from_anchored: self.map_from_anchored,
                covariance: self.covariance(),
                status: Status::InvalidInput,
                timing: StepTiming::default(),
            };
        }
        let p = self.params;
        let last = self
            .last_position_in_anchored
            .map(|last| (last, distance(last, position_in_anchored)));
        let standing = last.is_some_and(|(_, moved)| moved < p.standstill_distance_m());
        self.stood_still = standing;
        if !standing {
            if let Some((last, moved)) = last {
                self.travelled_m += moved;
                self.gate_travelled_m += moved;
                let motion = [
                    position_in_anchored[0] - last[0],
                    position_in_anchored[1] - last[1],
                ];
                let motion_in_map = self.map_from_anchored.rotate(motion);
                if let Some(scale) = &mut self.scale {
                    let kept = scale.estimate.drive(moved, p.scale_drift_var_per_m);
                    scale.published.scale_bounded(kept);
                    let variance = scale.estimate.variance;
                    scale.published.drive_scaled(motion_in_map, &p, variance);
                }
                self.uncertainty.drive(motion_in_map, &p);
            }
            self.last_position_in_anchored = Some(position_in_anchored);
        }
        // A source faster than the presets' rate feeds only every `window_stride`-th pose to the
        // window (`Params::odometry_rate_hz`); the ones between, and the poses of a standstill
        // (`Params::standstill_speed_mps`), keep the correction in force.
        if (standing || (self.carried as usize) + 1 < p.window_stride()) && !self.window.is_empty()
        {
            // Saturating: a standstill of weeks or a restored state (a tampered journal) may
            // reach any count, and every count past the stride carries alike.
            self.carried = self.carried.saturating_add(1);
            return Step {
                position_in_map: self.map_from_anchored.apply(position_in_anchored),
                ..self.step(Status::Carried {
                    window_len: self.window.len(),
                })
            };
        }
        self.carried = 0;
        self.window
            .push(self.map_from_anchored.apply(position_in_anchored));
        if let Matcher::Fast(cache) = &mut self.matcher {
            cache.push();
        }
        let min_window = p.min_window_poses();
        if self.window.len() > p.max_window_poses() {
            self.drop_oldest(1);
        }
        if p.max_window_path_m.is_finite() {
            let excess = self
                .window
                .excess_over_path(p.max_window_path_m, min_window);
            self.drop_oldest(excess);
        }
        let window_len = self.window.len();
        if window_len < min_window || !self.window.path_at_least(p.min_path_length_m) {
            return self.step(Status::WarmingUp { window_len });
        }
        if self.travelled_m < p.alignment_spacing_m {
            return self.step(Status::Carried { window_len });
        }
        let match_params = self.match_params();
        let matching_start = Instant::now();
        match &mut self.matcher {
            Matcher::Reference(candidates) => match_window(
                &self.map,
                self.window.as_slice(),
                &match_params,
                candidates,
                &mut self.correspondences,
            ),
            Matcher::Fast(cache) => cache.match_window(
                &self.map,
                self.window.as_slice(),
                &match_params,
                &mut self.correspondences,
            ),
        }
        timing.matching = matching_start.elapsed();
        let matched = self.correspondences.len();
        let match_ratio = matched as f64 / window_len as f64;
        let (reason, residual_m) =
            if (matched as f64) < p.min_match_ratio * window_len as f64 || matched < 2 {
                (RejectReason::TooFewMatches, f64::INFINITY)
            } else {
                let icp_params = IcpParams {
                    trim_ratio: p.trim_ratio,
                    max_iterations: p.icp_max_iterations,
                    tolerance_m: p.icp_tolerance_m,
                    tolerance_band_m: p.lane_tolerance_m,
                    untrimmed_newest: p.untrimmed_newest,
                };
                let icp_start = Instant::now();
                let fit = trimmed_icp(&self.correspondences, &icp_params, &mut self.icp);
                timing.icp = icp_start.elapsed();
                if fit.residual_m < p.max_residual_m {
                    let confidence_start = Instant::now();
                    let (correction, applied_directions) = self.supported(&fit.transform);
                    timing.confidence = confidence_start.elapsed();
                    self.map_from_anchored = correction * self.map_from_anchored;
                    // A step that changes nothing (a quarter of the steps on KITTI 00, LiDAR,
                    // kiss-icp) leaves the window's positions, and so its spacings, as they are.
                    let mut changed = correction != Se2::IDENTITY;
                    if changed {
                        for x in self.window.as_mut_slice() {
                            *x = correction.apply(*x);
                        }
                    }
                    changed |= self.rescale(&correction);
                    self.failures = 0;
                    self.travelled_m = 0.0;
                    // A step that changed nothing closes the gate only if its newest pose was
                    // matched (correspondences come in window order: the newest pose's is last).
                    if changed
                        || self
                            .correspondences
                            .last()
                            .is_some_and(|c| c.index == window_len - 1)
                    {
                        self.gate_travelled_m = 0.0;
                    }
                    return self.step(Status::Accepted {
                        residual_m: fit.residual_m,
                        applied_directions,
                        match_ratio,
                        window_len,
                    });
                }
                (RejectReason::ResidualTooLarge, fit.residual_m)
            };
        self.drop_oldest(1);
        // Saturating: a restored state may hold any count (a tampered journal); past
        // `max_failures` the window resets all the same.
        self.failures = self.failures.saturating_add(1);
        if self.failures > p.max_failures_at_rate() {
            let keep = min_window - 1;
            self.drop_oldest(self.window.len().saturating_sub(keep));
            self.failures = 0;
            return self.step(Status::Reset {
                reason,
                residual_m,
                match_ratio,
                window_len: self.window.len(),
            });
        }
        let window_len = self.window.len();
        self.step(Status::Rejected {
            reason,
            residual_m,
            match_ratio,
            window_len,
        })
    }

    /// Of the ICP's proposed `correction`, the part the window's evidence supports, and how many
    /// directions that is; folds the new share of the evidence into the pose's uncertainty.
    fn supported(&mut self, proposed: &Se2) -> (Se2, u8) {
        let current = self.window.as_slice()[self.window.len() - 1];
        let center = proposed.apply(current);
        let alignment = alignment_information(
            &self.map,
            &self.correspondences,
            self.icp.kept(),
            self.icp.fitted_sources(),
            center,
            self.window.spacings(),
        );
        let information = alignment.information;
        let share = self.new_share();
        let min_ratio = self.params.min_evidence_ratio;
        let mut applied = (*proposed, 3);
        if min_ratio > 0.0 {
            let xi = correction_at(proposed, current);
            let supported = self
                .uncertainty
                .supported(&information, &xi, min_ratio, share);
            if supported.directions < 3 {
                applied = (
                    correction_from(&supported.correction, current),
                    supported.directions as u8,
                );
            }
        }
        self.uncertainty.update(&information, share);
        if let Some(scale) = &mut self.scale {
            let variance = scale.estimate.variance;
            scale.published.update_scaled(&information, share, variance);
        }
        if let Some(inherited) = alignment.inherited_map_error {
            self.map_error = inherited;
        }
        applied
    }

    /// Folds what the accepted alignment `correction` (already applied) says of the odometry's
    /// scale into its estimate, and scales the window about its newest pose by the change
    /// (see [`crate::scale`]). Whether the window moved.
    fn rescale(&mut self, correction: &Se2) -> bool {
        let share = self.new_share();
        let Some(scale) = &mut self.scale else {
            return false;
        };
        let center = self.window.as_slice()[self.window.len() - 1];
        let Some(evidence) = scale_evidence(
            &self.map,
            &self.correspondences,
            self.icp.kept(),
            correction,
            center,
            self.window.spacings(),
            self.params.lane_tolerance_m,
        ) else {
            return false;
        };
        let before = scale.estimate.variance;
        let change = scale.estimate.update(&evidence, share);
        scale
            .published
            .scale_measured(before, scale.estimate.variance);
        if change == 0.0 {
            return false;
        }
        self.window.scale_about(center, 1.0 + change);
        true
    }

    /// The share of the window's evidence an accepted alignment adds: the distance travelled
    /// since the last accepted step over the window's path length (at most 1).
    fn new_share(&self) -> f64 {
        if self.window.path_m() > 0.0 {
            (self.travelled_m / self.window.path_m()).min(1.0)
        } else {
            1.0
        }
    }

    /// `base` widened by the drift the odometry may have accumulated since the gate last closed
    /// (metres), or since the last accepted step without
    /// [`Params::gate_widens_through_null_steps`].
    fn widened(&self, base: f64) -> f64 {
        let driven = if self.params.gate_widens_through_null_steps {
            self.gate_travelled_m
        } else {
            self.travelled_m
        };
        base + self.params.drift_per_m * driven
    }

    fn drop_oldest(&mut self, count: usize) {
        self.window.drop_oldest(count);
        if let Matcher::Fast(cache) = &mut self.matcher {
            cache.drop_oldest(count);
        }
    }

    fn step(&self, status: Status) -> Step {
        Step {
            position_in_map: self.window.as_slice()[self.window.len() - 1],
            map_from_anchored: self.map_from_anchored,
            covariance: self.covariance(),
            status,
            timing: StepTiming::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;

    /// A long straight eastbound lane along y = 0 and a northbound one along x = 300, so that
    /// an L-shaped drive constrains both axes.
    fn l_shaped_map() -> Arc<LaneMap> {
        let east: Vec<[f64; 2]> = (0..=100).map(|i| [i as f64 * 3.0, 0.0]).collect();
        let north: Vec<[f64; 2]> = (1..=100).map(|i| [300.0, i as f64 * 3.0]).collect();
        Arc::new(LaneMap::new(&[Lane::new(1, east), Lane::new(2, north)]).unwrap())
    }

    fn small_params() -> Params {
        let mut p = crate::params::Preset::KissIcp.params();
        p.min_window = 20;
        p.max_window = 200;
        p.max_failures = 3;
        p
    }

    fn l_drive(offset: [f64; 2]) -> Vec<[f64; 2]> {
        let mut v: Vec<[f64; 2]> = (0..150).map(|i| [i as f64 * 2.0, 0.0]).collect();
        v.extend((1..150).map(|i| [300.0, i as f64 * 2.0]));
        v.into_iter()
            .map(|p| [p[0] + offset[0], p[1] + offset[1]])
            .collect()
    }

    /// `drive` with `k - 1` poses interpolated between each two.
    fn densified(drive: &[[f64; 2]], k: usize) -> Vec<[f64; 2]> {
        drive
            .windows(2)
            .flat_map(|w| {
                (0..k).map(move |j| {
                    let f = j as f64 / k as f64;
                    [
                        w[0][0] + f * (w[1][0] - w[0][0]),
                        w[0][1] + f * (w[1][1] - w[0][1]),
                    ]
                })
            })
            .collect()
    }

    /// A corrector given `drive` up to each of `cuts`, saved and restored, answers the rest as
    /// `steps` (one uninterrupted run) did, bit for bit.
    fn assert_restores_bit_for_bit(
        params: Params,
        drive: &[[f64; 2]],
        steps: &[Step],
        cuts: &[usize],
    ) {
        for &cut in cuts {
            let mut first = Corrector::new(l_shaped_map(), params);
            drive[..cut].iter().for_each(|&p| {
                first.push(p);
            });
            let mut restored =
                Corrector::restore(l_shaped_map(), params, MatchMode::Fast, first.state());
            for (i, &p) in drive.iter().enumerate().skip(cut) {
                let mut got = restored.push(p);
                got.timing = steps[i].timing;
                assert_eq!(got, steps[i], "cut at {cut}, pose {i}");
            }
        }
    }

    #[test]
    fn warms_up_then_accepts_and_removes_an_offset() {
        let mut c = Corrector::new(l_shaped_map(), small_params());
        let steps: Vec<Step> = l_drive([0.0, 1.0]).into_iter().map(|p| c.push(p)).collect();
        assert!(matches!(
            steps[0].status,
            Status::WarmingUp { window_len: 1 }
        ));
        assert!(matches!(
            steps[18].status,
            Status::WarmingUp { window_len: 19 }
        ));
        assert!(matches!(
            steps[19].status,
            Status::Accepted { window_len: 20, .. }
        ));
        let last = steps.last().unwrap();
        assert!(matches!(last.status, Status::Accepted { .. }));
        let [x, y] = last.map_from_anchored.translation();
        assert!(x.abs() < 1e-6 && (y + 1.0).abs() < 1e-6, "{x} {y}");
    }

    #[test]
    fn alignments_follow_the_road_covered_not_the_pose_rate() {
        // The L-shaped drive with a pose every 0.5 m, an alignment at most every 1.2 m.
        let drive = densified(&l_drive([0.0, 1.0]), 4);
        let mut params = small_params();
        params.alignment_spacing_m = 1.2;
        let mut c = Corrector::new(l_shaped_map(), params);
        let steps: Vec<Step> = drive.iter().map(|&p| c.push(p)).collect();
        let mut since_accepted = f64::INFINITY;
        let (mut attempts, mut carried) = (0, 0);
        for (i, step) in steps.iter().enumerate() {
            if i > 0 {
                since_accepted += distance(drive[i - 1], drive[i]);
            }
            match step.status {
                Status::WarmingUp { .. } => {}
                Status::Carried { window_len } => {
                    // Sooner than the spacing: into the window, the correction in force.
                    carried += 1;
                    assert!(since_accepted < 1.2, "pose {i}");
                    let grown = (steps[i - 1].status.window_len() + 1).min(params.max_window);
                    assert_eq!(window_len, grown, "pose {i}");
                    assert_eq!(step.map_from_anchored, steps[i - 1].map_from_anchored);
                }
                Status::Accepted { .. } => {
                    attempts += 1;
                    assert!(since_accepted >= 1.2, "pose {i}: {since_accepted}");
                    since_accepted = 0.0;
                }
                other => panic!("pose {i}: {other:?}"),
            }
        }
        // Two of every three poses wait (0.5 m apart, 1.2 m between alignments; fewer at the
        // corner, where they are 0.71 m apart), and the offset is removed as with an alignment on
        // every pose.
        assert!(
            carried <= 2 * attempts && 10 * carried >= 19 * attempts,
            "{carried} carried, {attempts} alignments"
        );
        let [x, y] = steps.last().unwrap().map_from_anchored.translation();
        assert!(x.abs() < 1e-6 && (y + 1.0).abs() < 1e-6, "{x} {y}");
        // A corrector restored between alignments continues where it was.
        assert_restores_bit_for_bit(params, &drive, &steps, &[30, 91, 500]);
    }

    /// Every covariance and scale estimate a run saves is one a restored corrector continues
    /// from, before the first alignment, while aligned and after the road turns, with the
    /// preset's scale drift and with the largest a corrector may be set for.
    #[test]
    fn every_saved_covariance_is_one_to_continue_from() {
        for scale_drift in [1e-7, crate::scale::MAX_SCALE_DRIFT_VAR_PER_M] {
            let mut params = crate::params::Preset::OrbSlam3.robust_params();
            params.min_window = 20;
            params.scale_drift_var_per_m = scale_drift;
            let mut c = Corrector::new(l_shaped_map(), params);
            for p in l_drive([0.5, 1.0]) {
                c.push(p);
                let state = c.state();
                assert!(
                    crate::confidence::is_covariance(&state.covariance),
                    "{state:?}"
                );
                let (published, cross) =
                    state.published_uncertainty.expect("the scale is estimated");
                let scale = state.scale.expect("the scale is estimated");
                assert!(
                    crate::confidence::is_joint_covariance(&published, cross, scale.variance)
                        && scale.is_valid(),
                    "{scale_drift}: {state:?}"
                );
            }
        }
    }

    /// A restored state may hold any count (a journal tampered with under its checksum; found by
    /// the `snapshot` fuzz harness): the next failure resets the window and a standstill carries
    /// on, as from the largest counts that arise in a run, without an overflow.
    #[test]
    fn counts_restored_at_their_largest_saturate() {
        let mut params = small_params();
        params.standstill_speed_mps = 1.0;
        // Driving west on an eastbound-only map: nothing matches.
        let west: Vec<[f64; 2]> = (0..20).map(|i| [250.0 - i as f64 * 2.0, 0.0]).collect();
        let mut c = Corrector::new(l_shaped_map(), params);
        for &p in &west[..19] {
            c.push(p);
        }
        let mut state = c.state();
        state.failures = u32::MAX;
        state.carried = u32::MAX;
        let restore = || Corrector::restore(l_shaped_map(), params, MatchMode::Fast, state.clone());
        let mut failing = restore();
        assert!(matches!(
            failing.push(west[19]).status,
            Status::Reset {
                reason: RejectReason::TooFewMatches,
                ..
            }
        ));
        assert_eq!(failing.failures, 0);
        let mut standing = restore();
        assert!(matches!(
            standing.push(west[18]).status,
            Status::Carried { window_len: 19 }
        ));
        assert_eq!(standing.carried, u32::MAX);
    }

    #[test]
    fn rejection_drops_the_oldest_pose_and_counts_failures() {
        // Driving west on an eastbound-only map: nothing matches.
        let mut c = Corrector::new(l_shaped_map(), small_params());
        let drive: Vec<[f64; 2]> = (0..40).map(|i| [250.0 - i as f64 * 2.0, 0.0]).collect();
        let mut statuses = Vec::new();
        let mut failures = Vec::new();
        for p in drive {
            statuses.push(c.push(p).status);
            failures.push(c.failures);
        }
        let rejected = |s: &Status| {
            matches!(
                s,
                Status::Rejected {
                    reason: RejectReason::TooFewMatches,
                    window_len: 19,
                    ..
                }
            )
        };
        // Pose 20 fills the window; each rejection drops the oldest pose (20 -> 19) and counts.
        assert!(matches!(statuses[18], Status::WarmingUp { .. }));
        assert!(rejected(&statuses[19]) && failures[19] == 1);
        assert!(rejected(&statuses[20]) && failures[20] == 2);
        assert!(rejected(&statuses[21]) && failures[21] == 3);
        // The fourth failure (E = 4 > E_max = 3) resets and clears the count.
        assert!(matches!(statuses[22], Status::Reset { .. }) && failures[22] == 0);
        assert!(rejected(&statuses[23]) && failures[23] == 1);
        assert_eq!(c.map_from_anchored(), Se2::IDENTITY);
    }

    #[test]
    fn reset_cuts_a_long_window_to_min_window_minus_one() {
        // Accepted steps grow the window past M_min; a U-turn then makes every step fail.
        let mut c = Corrector::new(l_shaped_map(), small_params());
        let mut drive: Vec<[f64; 2]> = (0..100).map(|i| [i as f64 * 2.0, 0.0]).collect();
        drive.extend((1..150).map(|i| [198.0 - i as f64 * 1.0, 0.0]));
        let mut previous = None;
        for p in drive {
            let step = c.push(p);
            if let Status::Reset { window_len, .. } = step.status {
                let Some(Status::Rejected {
                    window_len: before, ..
                }) = previous
                else {
                    panic!("a reset follows rejections, got {previous:?}");
                };
                assert!(
                    before > 19,
                    "the window was longer than M_min - 1: {before}"
                );
                assert_eq!(window_len, 19);
                assert_eq!(c.window.len(), 19);
                assert_eq!(c.window.as_slice()[18], step.position_in_map, "newest kept");
                return;
            }
            previous = Some(step.status);
        }
        panic!("no reset happened");
    }

    #[test]
    fn the_robust_gate_ignores_a_parallel_street_the_paper_jumps_to() {
        // Only a road 40 m north exists for the stretch driven: the paper's matching takes it
        // (no distance bound) and the output jumps 40 m; the robust method finds no match.
        let far: Vec<[f64; 2]> = (0..200).map(|i| [i as f64 * 3.0, 40.0]).collect();
        let map = Arc::new(LaneMap::new(&[Lane::new(1, far)]).unwrap());
        let drive: Vec<[f64; 2]> = (0..200).map(|i| [i as f64 * 2.0, 0.0]).collect();
        let last = |params: Params| {
            let mut c = Corrector::new(map.clone(), params);
            drive.iter().map(|&p| c.push(p)).last().unwrap()
        };
        let mut paper = small_params();
        paper.max_window = 300;
        let jumped = last(paper);
        assert!(
            (jumped.position_in_map[1] - 40.0).abs() < 1e-6,
            "{jumped:?}"
        );
        let robust = Params {
            max_match_distance_m: 5.0,
            drift_per_m: 0.05,
            ..paper
        };
        let stayed = last(robust);
        assert_eq!(stayed.map_from_anchored, Se2::IDENTITY, "{stayed:?}");
        assert!(matches!(
            stayed.status,
            Status::Rejected {
                reason: RejectReason::TooFewMatches,
                ..
            } | Status::Reset { .. }
        ));
    }

    #[test]
    fn the_gate_widens_while_the_newest_poses_find_no_lane() {
        // East along y = 0, then north; the odometry's north leg runs 6 m east of its lane
        // (along-road drift on the first leg that the turn made cross-road), twice the robust
        // preset's 3 m gate. The first leg's poses keep fitting their lane, so the steps after
        // the turn are accepted and change nothing. Widening through such steps, the gate
        // reaches the north leg and it is matched; closed again by each of them, the north leg
        // stays 6 m off its lane for 300 m and more, until the first leg's poses are too few
        // to accept a step.
        let east: Vec<[f64; 2]> = (0..=100).map(|i| [i as f64 * 3.0, 0.0]).collect();
        let north: Vec<[f64; 2]> = (1..=300).map(|i| [300.0, i as f64 * 3.0]).collect();
        let map = Arc::new(LaneMap::new(&[Lane::new(1, east), Lane::new(2, north)]).unwrap());
        let mut drive: Vec<[f64; 2]> = (0..150).map(|i| [i as f64 * 2.0, 0.0]).collect();
        drive.extend((1..400).map(|i| [306.0, i as f64 * 2.0]));
        let off_lane = |s: &Step| (s.position_in_map[0] - 300.0).abs() > 1.0;
        // Poses after the turn until the pose is back on its lane, and the steps of the drive.
        let back = |gate_widens_through_null_steps: bool| {
            let mut params = crate::params::Preset::KissIcp.robust_params();
            params.min_window = 20;
            params.gate_widens_through_null_steps = gate_widens_through_null_steps;
            let mut c = Corrector::new(map.clone(), params);
            let steps: Vec<Step> = drive.iter().map(|&p| c.push(p)).collect();
            let back = steps[150..].iter().position(|s| !off_lane(s));
            (back.expect("the north leg comes back to its lane"), steps)
        };
        let (late, _) = back(false);
        assert!(late >= 150, "{} m", 2 * late);
        let (soon, steps) = back(true);
        assert!(
            soon <= 100,
            "back on the lane {} m after the turn",
            2 * soon
        );
        assert!(
            steps[150..150 + soon]
                .iter()
                .all(|s| matches!(s.status, Status::Accepted { .. } | Status::Carried { .. })),
            "the steps before were accepted: the first leg fit"
        );
        assert!(
            !steps[150 + soon..].iter().any(off_lane),
            "and it stays there"
        );
    }

    #[test]
    fn the_window_path_limit_drops_old_poses_but_keeps_min_window() {
        let mut params = small_params();
        params.max_window_path_m = 100.0;
        let mut c = Corrector::new(l_shaped_map(), params);
        for p in l_drive([0.0, 0.5]) {
            c.push(p);
            let w = c.window.as_slice();
            let length: f64 = w.windows(2).map(|s| distance(s[0], s[1])).sum();
            assert!(length <= 100.0 + 1e-9 || w.len() <= params.min_window);
        }
        assert_eq!(c.window.len(), 51, "50 steps of 2 m");
    }

    #[test]
    fn a_restored_corrector_continues_bit_for_bit() {
        let drive = l_drive([0.3, 1.0]);
        for mode in [MatchMode::Fast, MatchMode::Reference] {
            let run = |c: &mut Corrector, from: usize| -> Vec<Step> {
                drive[from..]
                    .iter()
                    .map(|&p| {
                        let mut s = c.push(p);
                        s.timing = StepTiming::default();
                        s
                    })
                    .collect()
            };
            let mut whole = Corrector::with_mode(l_shaped_map(), small_params(), mode);
            let uninterrupted = run(&mut whole, 0);
            for cut in [5, 30, 120, 200] {
                let mut first = Corrector::with_mode(l_shaped_map(), small_params(), mode);
                let before: Vec<Step> = drive[..cut].iter().map(|&p| first.push(p)).collect();
                assert!(before.len() == cut);
                let mut restored =
                    Corrector::restore(l_shaped_map(), small_params(), mode, first.state());
                assert_eq!(restored.state(), first.state());
                let after = run(&mut restored, cut);
                assert_eq!(after, uninterrupted[cut..], "{mode:?}, cut at {cut}");
            }
        }
    }

    #[test]
    fn work_between_poses_changes_no_answer() {
        // A drive with a rejected stretch and a reset (a jump off the lanes), so that the window
        // grows, shrinks and grows again, with `prepare` and `work_ahead` between the poses of
        // one run only.
        let mut drive = l_drive([0.3, 1.0]);
        for p in &mut drive[200..230] {
            p[0] += 40.0;
        }
        for mode in [MatchMode::Fast, MatchMode::Reference] {
            let run = |prepared: bool| -> Vec<Step> {
                let mut c = Corrector::with_mode(l_shaped_map(), small_params(), mode);
                let steps: Vec<Step> = drive
                    .iter()
                    .map(|&p| {
                        let mut s = c.push(p);
                        s.timing = StepTiming::default();
                        if prepared {
                            c.prepare();
                            c.work_ahead();
                        }
                        if let Matcher::Fast(cache) = &c.matcher {
                            assert_eq!(cache.len(), c.window.len(), "a cache per window pose");
                        }
                        s
                    })
                    .collect();
                assert!(steps
                    .iter()
                    .any(|s| matches!(s.status, Status::Reset { .. })));
                steps
            };
            assert_eq!(run(true), run(false), "{mode:?}");
        }
    }

    #[test]
    fn a_faster_source_feeds_its_window_at_the_presets_rate() {
        // The L-shaped drive at ten times the rate: nine interpolated poses between each two.
        let slow = l_drive([0.0, 1.0]);
        let fast = densified(&slow, 10);
        let paper = small_params();
        let mut at_rate = paper;
        at_rate.odometry_rate_hz = 100.0;
        assert_eq!((paper.window_stride(), at_rate.window_stride()), (1, 10));
        let mut c = Corrector::new(l_shaped_map(), at_rate);
        let steps: Vec<Step> = fast.iter().map(|&p| c.push(p)).collect();
        let mut reference = Corrector::new(l_shaped_map(), paper);
        for (i, step) in steps.iter().enumerate() {
            if i % 10 == 0 {
                // Every tenth pose enters the window and is corrected as at the preset's rate.
                let mut expected = reference.push(slow[i / 10]);
                expected.covariance = step.covariance;
                let mut got = *step;
                got.timing = expected.timing;
                assert_eq!(got, expected, "pose {i}");
            } else {
                // The poses between get the correction in force, and the window stays.
                let before = &steps[i - 1];
                assert_eq!(
                    step.status,
                    Status::Carried {
                        window_len: before.status.window_len()
                    },
                    "pose {i}"
                );
                assert_eq!(step.map_from_anchored, before.map_from_anchored);
                assert_eq!(
                    step.position_in_map,
                    before.map_from_anchored.apply(fast[i]),
                    "pose {i}"
                );
            }
        }
        let last_window_step = steps
            .iter()
            .rev()
            .find(|s| !matches!(s.status, Status::Carried { .. }));
        assert!(matches!(
            last_window_step.map(|s| s.status),
            Some(Status::Accepted { .. })
        ));
        // A corrector restored between window poses continues the count.
        assert_restores_bit_for_bit(at_rate, &fast, &steps, &[1, 13, 205, 1111]);
    }

    #[test]
    fn a_standstill_changes_nothing_but_the_poses_that_stand() {
        // The L-shaped drive with two stops of 600 poses each (a minute at 10 Hz), one on each
        // road, the odometry jittering by up to 2 cm about the stopping point as it does when
        // standing still; a pose every 2 m otherwise.
        let drive = l_drive([0.0, 1.0]);
        let stops = [100, 200];
        let jitter = |k: usize| {
            let k = k as f64;
            [0.02 * (1.7 * k).sin(), 0.02 * (2.3 * k).cos()]
        };
        let mut stopped = Vec::new();
        for (i, &p) in drive.iter().enumerate() {
            stopped.push((p, Some(i)));
            if stops.contains(&i) {
                stopped.extend((0..600).map(|k| {
                    let d = jitter(k);
                    ([p[0] + d[0], p[1] + d[1]], None)
                }));
            }
        }
        let positions: Vec<[f64; 2]> = stopped.iter().map(|&(p, _)| p).collect();
        let steps_of = |params: Params, drive: &[[f64; 2]]| -> Vec<Step> {
            let mut c = Corrector::new(l_shaped_map(), params);
            drive.iter().map(|&p| c.push(p)).collect()
        };
        let mut params = small_params();
        params.standstill_speed_mps = 1.0;
        assert_eq!(params.standstill_distance_m(), 0.1);
        let moving = steps_of(params, &drive);
        let steps = steps_of(params, &positions);
        for (j, (step, &(p, index))) in steps.iter().zip(&stopped).enumerate() {
            let mut got = *step;
            match index {
                // A moving pose gets the answer it gets without the stops, bit for bit.
                Some(i) => {
                    got.timing = moving[i].timing;
                    assert_eq!(got, moving[i], "pose {i}");
                }
                // A standing one, the correction in force; the window, the covariance and the
                // distance travelled stay as they were.
                None => {
                    let before = &steps[j - 1];
                    let window_len = before.status.window_len();
                    assert_eq!(step.status, Status::Carried { window_len }, "pose {j}");
                    assert_eq!(step.map_from_anchored, before.map_from_anchored);
                    assert_eq!(step.position_in_map, before.map_from_anchored.apply(p));
                    assert_eq!(step.covariance, before.covariance, "pose {j}");
                }
            }
        }
        assert!(matches!(
            steps.last().map(|s| s.status),
            Some(Status::Accepted { .. })
        ));
        // Without it (the paper's method) the stops fill the window, and the answers differ.
        let paper = steps_of(small_params(), &positions);
        assert_eq!(
            paper[stops[0] + 600].status.window_len(),
            small_params().max_window
        );
        let paper_moving = steps_of(small_params(), &drive);
        assert!(stopped.iter().zip(&paper).any(|(&(_, index), step)| {
            index.is_some_and(|i| step.position_in_map != paper_moving[i].position_in_map)
        }));
        // A corrector restored in the middle of a stop continues as the uninterrupted one.
        assert_restores_bit_for_bit(params, &positions, &steps, &[stops[0] + 300, 1000]);
    }

    #[test]
    fn a_straight_road_constrains_only_the_cross_road_direction() {
        // East along y = 0 with the odometry 1 m to the left, then north after the corner at
        // x = 300: on the straight the lanes say nothing along the road, and the covariance and
        // the applied directions say so; after the corner every direction is constrained.
        let params = Params {
            min_evidence_ratio: 10.0,
            ..small_params()
        };
        let mut c = Corrector::new(l_shaped_map(), params);
        // Each step with the filter's covariance (the published one adds the map's error).
        let (steps, filter): (Vec<Step>, Vec<Covariance>) = l_drive([0.0, 1.0])
            .into_iter()
            .map(|p| (c.push(p), c.state().covariance))
            .unzip();
        let along_east = |k: usize| filter[k][0][0];
        let across_east = |k: usize| filter[k][1][1];
        let straight = &steps[140];
        assert!(matches!(straight.status, Status::Accepted { .. }));
        assert!(straight.status.applied_directions() < 3, "{straight:?}");
        assert!(
            along_east(140) > 3.0 * across_east(140),
            "{:?}",
            filter[140]
        );
        assert!(along_east(140) > along_east(60), "grows");
        // The published covariance adds the lanes' error across the road only.
        assert!(
            (straight.covariance[0][0] - along_east(140)).abs() < 1e-9,
            "{:?}",
            straight.covariance
        );
        assert!(
            straight.covariance[1][1] > across_east(140) + 0.1,
            "{:?}",
            straight.covariance
        );
        assert!(
            straight.position_in_map[1].abs() < 0.5,
            "across: corrected {:?}",
            straight.position_in_map
        );
        let [x, _] = straight.map_from_anchored.translation();
        assert!(x.abs() < 0.01, "along: not moved, {x}");
        let after = &steps[280];
        assert!(matches!(after.status, Status::Accepted { .. }));
        assert!(
            along_east(280) < 0.5 * along_east(140),
            "{:?} then {:?}",
            filter[140],
            filter[280]
        );
    }

    #[test]
    fn the_paper_method_applies_every_correction_whole() {
        let mut c = Corrector::new(l_shaped_map(), small_params());
        for p in l_drive([0.0, 1.0]) {
            let s = c.push(p);
            if s.status.attempted() && s.status.name() == "accepted" {
                assert_eq!(s.status.applied_directions(), 3);
            }
        }
    }

    #[test]
    fn non_finite_input_changes_nothing() {
        let mut c = Corrector::new(l_shaped_map(), small_params());
        c.push([0.0, 0.0]);
        let s = c.push([f64::NAN, 1.0]);
        assert_eq!(s.status, Status::InvalidInput);
        assert_eq!(c.window.len(), 1);
        let s = c.push([f64::INFINITY, 1.0]);
        assert_eq!(s.status, Status::InvalidInput);
    }
}
