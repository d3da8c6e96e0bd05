//! The corrector's configuration: the parameters (docs/algorithm.md, section 3), the paper's
//! presets per odometry backend, the two methods, typed overrides, and [`CorrectorConfig`], the
//! one configuration the command line, the daemon's TOML and the tests all use.

use serde::{Deserialize, Serialize};

use crate::corrector::MatchMode;
use crate::lane_geometry::LaneGeometry;
use crate::scale::MAX_SCALE_DRIFT_VAR_PER_M;
use crate::smoothing::Smoothing;

/// Every tunable of the corrector. Lengths in metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Smallest window (poses) before matching runs (M_min).
    pub min_window: usize,
    /// Largest window (poses); older poses are dropped (M_max).
    pub max_window: usize,
    /// Nearest lane points tried per pose (N).
    pub neighbours: usize,
    /// Consecutive failures tolerated before the window is cut back (E_max).
    pub max_failures: u32,
    /// Largest accepted mean residual of the kept pairs (epsilon, metres).
    pub max_residual_m: f64,
    /// Trimmed fraction of pairs in ICP (rho).
    pub trim_ratio: f64,
    /// Smallest fraction of window poses that must match (eta).
    pub min_match_ratio: f64,
    /// Smallest path length of the window before matching runs (L_min, metres).
    pub min_path_length_m: f64,
    /// Smallest cosine between trajectory and lane directions (tau).
    pub min_direction_cos: f64,
    /// ICP iteration limit.
    pub icp_max_iterations: usize,
    /// ICP convergence threshold on the mean residual (metres).
    pub icp_tolerance_m: f64,
    /// Beyond the paper: largest path length of the window (metres); older poses are dropped,
    /// but never below `min_window` poses. Infinite = paper.
    pub max_window_path_m: f64,
    /// Beyond the paper: dead band around the lane centrelines (metres). A pose this close to its
    /// lane match counts as on the lane; ICP pulls farther ones only onto the band's edge. 0 =
    /// paper.
    pub lane_tolerance_m: f64,
    /// Beyond the paper: how many of the window's newest matched poses the trim ranks as fitting
    /// the lanes, whatever their residuals. No alignment has seen them yet, so their residuals
    /// carry the drift since the last step and, with the band, they were the first the trim
    /// dropped as outliers: the fit then never saw the new drift. Ranked as fitting, they are
    /// never trimmed while the fit runs, and they do not by themselves make it run (the gate
    /// still drops a match too far off). 0 = paper.
    pub untrimmed_newest: usize,
    /// Beyond the paper: largest distance between a pose and its lane match (metres) right after
    /// an accepted step; it widens by `drift_per_m` per metre travelled since. Infinite = paper.
    pub max_match_distance_m: f64,
    /// Beyond the paper: drift the odometry may accumulate per metre travelled (ratio) since the
    /// last accepted step (see [`Params::gate_widens_through_null_steps`]), widening the match
    /// distance bound.
    pub drift_per_m: f64,
    /// Beyond the paper: an accepted step that changes nothing while the window's newest pose
    /// has no lane match does not restart the match distance bound's widening. Such steps come
    /// when the older poses fit their lanes and the newer ones have drifted beyond the bound
    /// (after a turn that makes the first road's along-road drift a cross-road offset); closing
    /// the bound again on each of them kept the newer poses unmatched for hundreds of metres.
    /// Without a bound (the paper's) it changes nothing.
    pub gate_widens_through_null_steps: bool,
    /// Position drift of the odometry as a random walk (m^2 of variance per metre travelled), for
    /// the covariance (see [`crate::confidence`]).
    pub drift_var_per_m: f64,
    /// Heading drift of the odometry as a random walk (rad^2 of variance per metre travelled; at
    /// most [`MAX_YAW_DRIFT_VAR_PER_M`]).
    pub yaw_drift_var_per_m: f64,
    /// Uncertainty of the anchor's placement at the first pose: position (metres, 1 sigma).
    pub initial_sigma_m: f64,
    /// Uncertainty of the anchor's placement at the first pose: heading (degrees, 1 sigma; at
    /// most [`MAX_SIGMA_YAW_DEG`]).
    pub initial_sigma_yaw_deg: f64,
    /// Beyond the paper: a direction of the proposed correction is applied only where the
    /// window's information outweighs the pose's current uncertainty by this ratio (0 applies
    /// every correction whole, as the paper does).
    pub min_evidence_ratio: f64,
    /// The rate of the source's poses (Hz). The presets' pose counts (`min_window`,
    /// `max_window`, `max_failures`) were chosen for [`PRESET_RATE_HZ`] odometry; a faster
    /// source has only every `round(odometry_rate_hz / PRESET_RATE_HZ)`-th pose enter the window,
    /// and the poses between are answered with the correction in force
    /// ([`crate::corrector::Status::Carried`]); a slower source has the counts scaled down by
    /// `odometry_rate_hz / PRESET_RATE_HZ` ([`Params::min_window_poses`]). Either way its window
    /// spans the same time and stretch of road.
    pub odometry_rate_hz: f64,
    /// Beyond the paper: how far the odometry must have travelled since the last accepted
    /// alignment before the next is attempted (metres). A pose that comes sooner enters the window
    /// and is answered with the correction in force ([`crate::corrector::Status::Carried`]):
    /// the work follows the road covered, not the odometry's rate (at a standstill, none), and a
    /// pose a few decimetres from the last adds little the lanes have not said. After a refused
    /// attempt every pose tries again. 0 = paper (every pose).
    pub alignment_spacing_m: f64,
    /// Beyond the paper: the speed below which the vehicle counts as standing still (m/s). A pose
    /// closer than `standstill_speed_mps / odometry_rate_hz` metres to the last moving pose
    /// stands still: it does not enter the window, counts no distance travelled (neither for the
    /// alignments nor for the gate nor for the covariance's drift) and is answered with the
    /// correction in force ([`crate::corrector::Status::Carried`]). So a stop at a red light
    /// neither fills the window with one spot (whose poses have no direction to match lanes by)
    /// nor turns the odometry's jitter into road; slower motion is thinned to that spacing. 0 =
    /// paper (every pose moves).
    pub standstill_speed_mps: f64,
    /// Beyond the paper: the fastest the vehicle drives (m/s). A pose farther from the last than
    /// this speed covers in the time between them (their stamps' difference, at least one period
    /// of [`Params::odometry_rate_hz`]) and three times the step before is a jump of the
    /// odometry, not motion (a restarted odometry back at its origin, a SLAM system's
    /// relocalisation): the source corrector continues the odometry from where the vehicle was
    /// ([`crate::continuity`]). inf = paper (every step is motion).
    pub max_speed_mps: f64,
    /// Beyond the paper: an odometry whose speed falls faster than a car can brake has lost
    /// track (a stalled visual odometry; [`crate::stall`]). The window restarts after it, since
    /// the poses before and after the road it missed are no longer one rigid piece, and the
    /// covariance widens along the direction of travel by the distance it may have missed until
    /// it finds its track again. false = paper (every pose is taken as the odometry gives it).
    pub watch_stalls: bool,
    /// Beyond the paper: how far off the odometry's scale may be at the start (a ratio, 1
    /// sigma; 0.05: its distances 5 % long or short). Above 0 the corrector estimates the scale
    /// from the lanes and multiplies the odometry's steps by it ([`crate::scale`]); 0 = paper
    /// (the odometry's scale is taken as it is).
    pub scale_sigma: f64,
    /// Beyond the paper: how fast the odometry's scale drifts, as a random walk (a ratio squared
    /// of variance per metre travelled; 1e-7 is 1 % in a kilometre; at most
    /// [`MAX_SCALE_DRIFT_VAR_PER_M`]).
    pub scale_drift_var_per_m: f64,
}

/// The fastest heading drift a corrector may be set for ([`Params::yaw_drift_var_per_m`],
/// square radians per metre): a heading sigma of a radian gained over every metre, far past any
/// odometry. The position's variance grows with the cube of the distance driven without an
/// alignment times this; at 1e6 (allowed until 2026-12-03) it passed what a snapshot may hold
/// ([`crate::confidence::MAX_COVARIANCE_ENTRY`]) after 16 km without lanes, and at 1 after some
/// 1400 km until the heading's variance was bounded
/// ([`crate::confidence::MAX_DRIVEN_VARIANCES`]).
pub const MAX_YAW_DRIFT_VAR_PER_M: f64 = 1.0;

/// The largest uncertainty of the anchor's heading a corrector may start from
/// ([`Params::initial_sigma_yaw_deg`], degrees, 1 sigma): a half turn, a heading not known at
/// all. Beyond it the variance says nothing more and only strains the arithmetic: at 1e6
/// degrees, KITTI 08's position and heading errors became one (their correlation 1 within
/// rounding) within 1.6 km, rounding made their covariance indefinite, and the session's
/// snapshot did not restore.
pub const MAX_SIGMA_YAW_DEG: f64 = 180.0;

/// The odometry rate the presets' pose counts were chosen for (Hz): KITTI's.
pub const PRESET_RATE_HZ: f64 = 10.0;

/// The slowest odometry a corrector is set for (Hz, [`Params::odometry_rate_hz`]): a pose every
/// 1000 s, the slowest `replay` publishes at. At 1e-300 Hz every pose counted as standing still
/// ([`Params::standstill_distance_m`] was 1e300 m) and no alignment was ever tried.
pub const MIN_ODOMETRY_RATE_HZ: f64 = 1e-3;

/// The fastest odometry a corrector is set for (Hz, [`Params::odometry_rate_hz`]).
pub const MAX_ODOMETRY_RATE_HZ: f64 = 100_000.0;

/// The unmarked-street offset scale of lanealign's lane geometry (see
/// [`crate::lane_geometry::LaneGeometry`] and docs/method.md).
pub const UNMARKED_OFFSET_SCALE: f64 = 0.5;

/// Which correction algorithm runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The published algorithm exactly (docs/algorithm.md), on the paper's lane geometry.
    Paper,
    /// lanealign's corrector: the paper's plus a window bounded by path length, a lane tolerance
    /// band and a correspondence gate that follows the odometry's possible drift
    /// (docs/method.md).
    #[default]
    Robust,
}

impl Method {
    /// Both methods.
    pub const ALL: [Method; 2] = [Method::Paper, Method::Robust];

    /// The method's name on the command line and in configs.
    pub fn name(self) -> &'static str {
        match self {
            Method::Paper => "paper",
            Method::Robust => "robust",
        }
    }

    /// The parameters of `preset` under this method.
    pub fn params(self, preset: Preset) -> Params {
        match self {
            Method::Paper => preset.params(),
            Method::Robust => preset.robust_params(),
        }
    }

    /// The unmarked-street offset scale of the lane geometry the method is designed and measured
    /// on: 1 (every lane at its nominal offset) for the paper's, 0.5 for the robust method.
    pub fn unmarked_offset_scale(self) -> f64 {
        match self {
            Method::Paper => 1.0,
            Method::Robust => UNMARKED_OFFSET_SCALE,
        }
    }
}

impl std::str::FromStr for Method {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

/// The paper's presets, one per odometry backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// LiODOM (LiDAR).
    Liodom,
    /// Basalt (visual-inertial).
    Basalt,
    /// KISS-ICP (LiDAR).
    KissIcp,
    /// ORB-SLAM3 (visual).
    OrbSlam3,
}

impl std::str::FromStr for Preset {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

impl Preset {
    /// All presets, in the order of the paper's table.
    pub const ALL: [Preset; 4] = [
        Preset::Liodom,
        Preset::Basalt,
        Preset::KissIcp,
        Preset::OrbSlam3,
    ];

    /// The preset's name as used on the command line and in configs.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Liodom => "liodom",
            Preset::Basalt => "basalt",
            Preset::KissIcp => "kiss-icp",
            Preset::OrbSlam3 => "orb-slam3",
        }
    }

    /// The preset's parameters in the paper's method (every extension off).
    pub fn params(self) -> Params {
        let (min_window, max_window, neighbours, max_failures, max_residual_m) = match self {
            Preset::Liodom => (50, 3000, 100, 50, 2.0),
            Preset::Basalt => (150, 3000, 10, 10, 1.0),
            Preset::KissIcp => (150, 1000, 100, 1000, 1.5),
            Preset::OrbSlam3 => (150, 1000, 50, 100, 1.5),
        };
        // LiDAR odometry drifts 0.1-0.7 % of the distance, visual odometry 1-15 %
        // (../shared/data/README.md): about 0.5 m and 0.05 degree per 100 m against 3 m and
        // 1 degree.
        let (drift_var_per_m, yaw_drift_var_per_m) = match self {
            Preset::Liodom | Preset::KissIcp => (0.0025, 1.2e-7),
            Preset::Basalt | Preset::OrbSlam3 => (0.09, 3e-6),
        };
        Params {
            min_window,
            max_window,
            neighbours,
            max_failures,
            max_residual_m,
            trim_ratio: 0.1,
            min_match_ratio: 0.5,
            min_path_length_m: 10.0,
            min_direction_cos: 0.95,
            icp_max_iterations: 50,
            icp_tolerance_m: 1e-8,
            max_window_path_m: f64::INFINITY,
            lane_tolerance_m: 0.0,
            untrimmed_newest: 0,
            max_match_distance_m: f64::INFINITY,
            drift_per_m: 0.0,
            gate_widens_through_null_steps: false,
            drift_var_per_m,
            yaw_drift_var_per_m,
            initial_sigma_m: 1.0,
            initial_sigma_yaw_deg: 1.0,
            min_evidence_ratio: 0.0,
            odometry_rate_hz: PRESET_RATE_HZ,
            alignment_spacing_m: 0.0,
            standstill_speed_mps: 0.0,
            max_speed_mps: f64::INFINITY,
            watch_stalls: false,
            scale_sigma: 0.0,
            scale_drift_var_per_m: 0.0,
        }
    }

    /// The preset's parameters in lanealign's robust method: the paper's, with the extensions on.
    /// One set per preset, the same for every sequence.
    pub fn robust_params(self) -> Params {
        // Visual odometry drifts in scale and heading far faster than LiDAR odometry: a shorter
        // stretch of it still fits one rigid correction.
        let max_window_path_m = match self {
            Preset::Liodom | Preset::KissIcp => 500.0,
            Preset::Basalt | Preset::OrbSlam3 => 300.0,
        };
        // The correspondence gate opens at a few times the worst drift rate of the odometry kind
        // the preset is for (LiDAR 0.1-0.7 % of the distance, visual 1-15 %,
        // ../shared/data/README.md), as the covariance's drift model does.
        let drift_per_m = match self {
            Preset::Liodom | Preset::KissIcp => 0.02,
            Preset::Basalt | Preset::OrbSlam3 => 0.2,
        };
        // Visual odometry's scale is off by percents and drifts (KITTI 01's stereo run: 8 %
        // short on the highway). LiDAR odometry's is within 0.3 % on every shared run and
        // visual-inertial odometry's is held by its accelerometers: finer than the lanes can
        // measure it (a map a metre off over a window of a few hundred metres reads as 0.3-1 %),
        // so there an estimate would only add the map's errors (docs/method.md, "Scale").
        let scale_sigma = match self {
            Preset::Liodom | Preset::KissIcp | Preset::Basalt => 0.0,
            Preset::OrbSlam3 => 0.05,
        };
        Params {
            max_window_path_m,
            drift_per_m,
            lane_tolerance_m: 1.0,
            max_match_distance_m: 3.0,
            // The town of `lanealign demo` without data lost its lanes for 900 m a lap without
            // it; on the shared runs every pair's figures stay within the noise of jittered
            // copies or improve (docs/method.md, item 8).
            gate_widens_through_null_steps: true,
            // The trim ranks the two newest matched poses as fitting: the matches of both rest on
            // the newest position (a pose's direction is taken towards the next one, the newest's
            // from the one before), which no alignment has seen yet.
            untrimmed_newest: 2,
            // A direction the lanes say next to nothing about (along a straight road) is never
            // applied whole; every other direction is. One ratio for every preset: visual
            // odometry gained from 1 to 0.1 once the newest matches were no longer trimmed, and
            // for LiDAR odometry a stricter ratio (10) keeps every shared sequence within 5 cm of
            // raw but lags behind real drift (docs/method.md, "Confidence").
            min_evidence_ratio: 0.1,
            // An alignment per metre of road: on the shared runs the same results as on every
            // pose (docs/method.md, item 7) for half the alignments at KITTI's town speeds.
            alignment_spacing_m: 1.0,
            // The banded ICP stops once an iteration changes the mean residual by less than
            // 0.1 mm, far below any odometry's or map's precision (the paper's 1e-8 m took 11 %
            // more of the whole process's instructions for the same corrections within the
            // noise, docs/performance.md).
            icp_tolerance_m: 1e-4,
            // Below walking pace the vehicle stands: a minute at a red light would otherwise put
            // 600 poses of one spot into the window and its jitter would count as road (KITTI 00
            // with such a stop every 500 poses: 1.03 -> 1.42 m; docs/method.md, item 9).
            standstill_speed_mps: 1.0,
            // Two and a half times the fastest step of the shared runs (28 m/s on the highway of
            // 01): an odometry that restarts at its origin mid-drive would otherwise put the
            // corrected poses where the drive began (KITTI 00; docs/method.md, item 10).
            max_speed_mps: 70.0,
            // A visual odometry that stalled on the highway of KITTI 01 lost some 100 m of road
            // its covariance said nothing of (docs/method.md, "Confidence").
            watch_stalls: true,
            scale_sigma,
            scale_drift_var_per_m: 1e-7,
            ..self.params()
        }
    }
}

/// A configuration the corrector cannot run with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamsError {
    /// A parameter is out of range, alone or together with others.
    #[error("{key} = {value}: {reason}")]
    Invalid {
        /// The parameter.
        key: &'static str,
        /// Its value.
        value: String,
        /// The rule it breaks.
        reason: &'static str,
    },
    /// The map's lanes were derived with another lane geometry than the configuration needs.
    #[error(
        "the map's lanes were derived with unmarked-street offset scale {found}, but the {method} \
         method needs {wanted}: compile the map with `lanealign-map compile ... \
         --unmarked-offset-scale {wanted}`, or set unmarked_offset_scale = {found} to use this \
         map's geometry anyway"
    )]
    LaneGeometry {
        /// The method.
        method: &'static str,
        /// The scale the configuration needs.
        wanted: f64,
        /// The scale the map has.
        found: f64,
    },
    /// Parameter overrides given as text could not be read (an unknown key, a value of the
    /// wrong type, a key given twice): the parser's message.
    #[error("{0}")]
    Overrides(String),
}

impl Params {
    /// Checks that the parameters make sense together; names the first one that does not.
    pub fn validate(&self) -> Result<(), ParamsError> {
        // Debug spells a number as it is written (`1e300`, where Display writes 301 digits).
        fn invalid(
            key: &'static str,
            value: impl std::fmt::Debug,
            reason: &'static str,
        ) -> ParamsError {
            ParamsError::Invalid {
                key,
                value: format!("{value:?}"),
                reason,
            }
        }
        let finite_nonneg = |v: f64| v.is_finite() && v >= 0.0;
        let positive_or_inf = |v: f64| !v.is_nan() && v > 0.0;
        if self.min_window < 2 {
            return Err(invalid("min_window", self.min_window, "must be at least 2"));
        }
        if self.max_window < self.min_window {
            return Err(invalid(
                "max_window",
                self.max_window,
                "must be at least min_window",
            ));
        }
        if self.max_window > 1_000_000 {
            return Err(invalid(
                "max_window",
                self.max_window,
                "must be at most 1e6",
            ));
        }
        if self.untrimmed_newest > 1_000_000 {
            return Err(invalid(
                "untrimmed_newest",
                self.untrimmed_newest,
                "must be at most 1e6",
            ));
        }
        if self.neighbours == 0 || self.neighbours > 10_000 {
            return Err(invalid(
                "neighbours",
                self.neighbours,
                "must be between 1 and 10000",
            ));
        }
        for (key, v) in [
            ("max_residual_m", self.max_residual_m),
            ("min_path_length_m", self.min_path_length_m),
            ("icp_tolerance_m", self.icp_tolerance_m),
            ("lane_tolerance_m", self.lane_tolerance_m),
            ("drift_per_m", self.drift_per_m),
            ("min_evidence_ratio", self.min_evidence_ratio),
            ("alignment_spacing_m", self.alignment_spacing_m),
            ("standstill_speed_mps", self.standstill_speed_mps),
        ] {
            if !finite_nonneg(v) {
                return Err(invalid(key, v, "must be finite and non-negative"));
            }
        }
        if !(0.0..1.0).contains(&self.trim_ratio) {
            return Err(invalid("trim_ratio", self.trim_ratio, "must be in [0, 1)"));
        }
        if !(0.0..=1.0).contains(&self.min_match_ratio) {
            return Err(invalid(
                "min_match_ratio",
                self.min_match_ratio,
                "must be in [0, 1]",
            ));
        }
        if !(-1.0..=1.0).contains(&self.min_direction_cos) {
            return Err(invalid(
                "min_direction_cos",
                self.min_direction_cos,
                "must be in [-1, 1]",
            ));
        }
        for (key, v) in [
            ("max_window_path_m", self.max_window_path_m),
            ("max_match_distance_m", self.max_match_distance_m),
            ("max_speed_mps", self.max_speed_mps),
        ] {
            if !positive_or_inf(v) {
                return Err(invalid(key, v, "must be positive (inf = off)"));
            }
        }
        for (key, v) in [
            ("drift_var_per_m", self.drift_var_per_m),
            ("initial_sigma_m", self.initial_sigma_m),
        ] {
            if !(v.is_finite() && v > 0.0 && v < 1e6) {
                return Err(invalid(key, v, "must be positive and below 1e6"));
            }
        }
        for (key, v, max, reason) in [
            (
                "yaw_drift_var_per_m",
                self.yaw_drift_var_per_m,
                MAX_YAW_DRIFT_VAR_PER_M,
                "must be positive and at most 1 (square radians per metre)",
            ),
            (
                "initial_sigma_yaw_deg",
                self.initial_sigma_yaw_deg,
                MAX_SIGMA_YAW_DEG,
                "must be positive and at most 180 (degrees)",
            ),
        ] {
            if !(v > 0.0 && v <= max) {
                return Err(invalid(key, v, reason));
            }
        }
        if !(MIN_ODOMETRY_RATE_HZ..=MAX_ODOMETRY_RATE_HZ).contains(&self.odometry_rate_hz) {
            return Err(invalid(
                "odometry_rate_hz",
                self.odometry_rate_hz,
                "must be 0.001 to 100000 (Hz)",
            ));
        }
        if !(self.scale_sigma.is_finite() && (0.0..=0.5).contains(&self.scale_sigma)) {
            return Err(invalid(
                "scale_sigma",
                self.scale_sigma,
                "must be between 0 (off) and 0.5",
            ));
        }
        if !(0.0..=MAX_SCALE_DRIFT_VAR_PER_M).contains(&self.scale_drift_var_per_m) {
            return Err(invalid(
                "scale_drift_var_per_m",
                self.scale_drift_var_per_m,
                "must be between 0 and 0.25 (a ratio squared per metre)",
            ));
        }
        if self.icp_max_iterations == 0 || self.icp_max_iterations > 100_000 {
            return Err(invalid(
                "icp_max_iterations",
                self.icp_max_iterations,
                "must be between 1 and 100000",
            ));
        }
        Ok(())
    }

    /// Of the source's poses, every how many enters the window (1: every pose): the source's
    /// rate over the presets' ([`Params::odometry_rate_hz`]), rounded, at least 1.
    pub fn window_stride(&self) -> usize {
        (self.odometry_rate_hz / PRESET_RATE_HZ).round().max(1.0) as usize
    }

    /// A pose count chosen for [`PRESET_RATE_HZ`] odometry (the presets' `min_window`,
    /// `max_window`, `max_failures`) for a source at [`Params::odometry_rate_hz`]: scaled by the
    /// rate over [`PRESET_RATE_HZ`] for a slower source, so that it spans the same time (rounded,
    /// never below 2 unless the count is); unchanged for a faster one, whose window takes every
    /// [`Params::window_stride`]-th pose instead.
    fn count_at_rate(&self, count: usize) -> usize {
        if self.odometry_rate_hz >= PRESET_RATE_HZ {
            return count;
        }
        let scaled = (count as f64 * self.odometry_rate_hz / PRESET_RATE_HZ).round() as usize;
        scaled.max(count.min(2))
    }

    /// [`Params::min_window`] for the source's rate (poses; see [`Params::odometry_rate_hz`]).
    pub fn min_window_poses(&self) -> usize {
        self.count_at_rate(self.min_window)
    }

    /// [`Params::max_window`] for the source's rate (poses; see [`Params::odometry_rate_hz`]).
    pub fn max_window_poses(&self) -> usize {
        self.count_at_rate(self.max_window)
    }

    /// [`Params::max_failures`] for the source's rate (see [`Params::odometry_rate_hz`]).
    pub fn max_failures_at_rate(&self) -> u32 {
        u32::try_from(self.count_at_rate(self.max_failures as usize)).unwrap_or(u32::MAX)
    }

    /// How close to the last moving pose a pose stands still (metres): the distance
    /// [`Params::standstill_speed_mps`] covers between two poses at [`Params::odometry_rate_hz`].
    pub fn standstill_distance_m(&self) -> f64 {
        self.standstill_speed_mps / self.odometry_rate_hz
    }
}

/// Parameter overrides on top of a preset: every field of [`Params`], each optional. Unknown
/// names are refused when parsing (`--set nope=1`, `overrides = { nope = 1 }`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Overrides {
    /// See [`Params::min_window`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_window: Option<usize>,
    /// See [`Params::max_window`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_window: Option<usize>,
    /// See [`Params::neighbours`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub neighbours: Option<usize>,
    /// See [`Params::max_failures`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_failures: Option<u32>,
    /// See [`Params::max_residual_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_residual_m: Option<f64>,
    /// See [`Params::trim_ratio`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trim_ratio: Option<f64>,
    /// See [`Params::min_match_ratio`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_match_ratio: Option<f64>,
    /// See [`Params::min_path_length_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_path_length_m: Option<f64>,
    /// See [`Params::min_direction_cos`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_direction_cos: Option<f64>,
    /// See [`Params::icp_max_iterations`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub icp_max_iterations: Option<usize>,
    /// See [`Params::icp_tolerance_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub icp_tolerance_m: Option<f64>,
    /// See [`Params::max_window_path_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_window_path_m: Option<f64>,
    /// See [`Params::lane_tolerance_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lane_tolerance_m: Option<f64>,
    /// See [`Params::max_match_distance_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_match_distance_m: Option<f64>,
    /// See [`Params::drift_per_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drift_per_m: Option<f64>,
    /// See [`Params::gate_widens_through_null_steps`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gate_widens_through_null_steps: Option<bool>,
    /// See [`Params::drift_var_per_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drift_var_per_m: Option<f64>,
    /// See [`Params::yaw_drift_var_per_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub yaw_drift_var_per_m: Option<f64>,
    /// See [`Params::initial_sigma_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_sigma_m: Option<f64>,
    /// See [`Params::initial_sigma_yaw_deg`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_sigma_yaw_deg: Option<f64>,
    /// See [`Params::min_evidence_ratio`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_evidence_ratio: Option<f64>,
    /// See [`Params::odometry_rate_hz`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub odometry_rate_hz: Option<f64>,
    /// See [`Params::untrimmed_newest`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub untrimmed_newest: Option<usize>,
    /// See [`Params::alignment_spacing_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alignment_spacing_m: Option<f64>,
    /// See [`Params::standstill_speed_mps`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub standstill_speed_mps: Option<f64>,
    /// See [`Params::max_speed_mps`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_speed_mps: Option<f64>,
    /// See [`Params::watch_stalls`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub watch_stalls: Option<bool>,
    /// See [`Params::scale_sigma`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_sigma: Option<f64>,
    /// See [`Params::scale_drift_var_per_m`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_drift_var_per_m: Option<f64>,
}

impl Overrides {
    /// Overrides given as `(key, value)` text, the value in TOML's syntax (a number, `inf`,
    /// `true` or `false`), as the command line's `--set KEY=VALUE` and Python's `overrides=`
    /// give them. Unknown keys, values of the wrong type and keys given twice are refused with
    /// the parser's message; a key must be a parameter's name (letters, digits and `_`).
    pub fn from_assignments<'a>(
        pairs: impl IntoIterator<Item = (&'a str, &'a str)>,
    ) -> Result<Overrides, ParamsError> {
        let mut lines = Vec::new();
        for (key, value) in pairs {
            let (key, value) = (key.trim(), value.trim());
            if key.is_empty() || !key.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_') {
                return Err(ParamsError::Overrides(format!(
                    "'{key}' is not a parameter's name"
                )));
            }
            if value.is_empty() || value.contains(['\n', '\r']) {
                return Err(ParamsError::Overrides(format!(
                    "{key}: '{value}' is not a value"
                )));
            }
            lines.push(format!("{key} = {value}"));
        }
        let doc = lines.join("\n");
        toml::from_str(&doc).map_err(|e| {
            // The parser's message names no key: name the assignment it points at.
            let line = e.span().map_or(0, |span| {
                doc[..span.start.min(doc.len())].matches('\n').count()
            });
            let message = e.message().trim();
            ParamsError::Overrides(match lines.get(line) {
                Some(assignment) => format!("{assignment}: {message}"),
                None => message.to_string(),
            })
        })
    }

    /// `base` with every given override applied (not validated: see [`Params::validate`]).
    pub fn apply(&self, base: Params) -> Params {
        Params {
            min_window: self.min_window.unwrap_or(base.min_window),
            max_window: self.max_window.unwrap_or(base.max_window),
            neighbours: self.neighbours.unwrap_or(base.neighbours),
            max_failures: self.max_failures.unwrap_or(base.max_failures),
            max_residual_m: self.max_residual_m.unwrap_or(base.max_residual_m),
            trim_ratio: self.trim_ratio.unwrap_or(base.trim_ratio),
            min_match_ratio: self.min_match_ratio.unwrap_or(base.min_match_ratio),
            min_path_length_m: self.min_path_length_m.unwrap_or(base.min_path_length_m),
            min_direction_cos: self.min_direction_cos.unwrap_or(base.min_direction_cos),
            icp_max_iterations: self.icp_max_iterations.unwrap_or(base.icp_max_iterations),
            icp_tolerance_m: self.icp_tolerance_m.unwrap_or(base.icp_tolerance_m),
            max_window_path_m: self.max_window_path_m.unwrap_or(base.max_window_path_m),
            lane_tolerance_m: self.lane_tolerance_m.unwrap_or(base.lane_tolerance_m),
            max_match_distance_m: self
                .max_match_distance_m
                .unwrap_or(base.max_match_distance_m),
            drift_per_m: self.drift_per_m.unwrap_or(base.drift_per_m),
            gate_widens_through_null_steps: self
                .gate_widens_through_null_steps
                .unwrap_or(base.gate_widens_through_null_steps),
            drift_var_per_m: self.drift_var_per_m.unwrap_or(base.drift_var_per_m),
            yaw_drift_var_per_m: self.yaw_drift_var_per_m.unwrap_or(base.yaw_drift_var_per_m),
            initial_sigma_m: self.initial_sigma_m.unwrap_or(base.initial_sigma_m),
            initial_sigma_yaw_deg: self
                .initial_sigma_yaw_deg
                .unwrap_or(base.initial_sigma_yaw_deg),
            min_evidence_ratio: self.min_evidence_ratio.unwrap_or(base.min_evidence_ratio),
            odometry_rate_hz: self.odometry_rate_hz.unwrap_or(base.odometry_rate_hz),
            untrimmed_newest: self.untrimmed_newest.unwrap_or(base.untrimmed_newest),
            alignment_spacing_m: self.alignment_spacing_m.unwrap_or(base.alignment_spacing_m),
            standstill_speed_mps: self
                .standstill_speed_mps
                .unwrap_or(base.standstill_speed_mps),
            max_speed_mps: self.max_speed_mps.unwrap_or(base.max_speed_mps),
            watch_stalls: self.watch_stalls.unwrap_or(base.watch_stalls),
            scale_sigma: self.scale_sigma.unwrap_or(base.scale_sigma),
            scale_drift_var_per_m: self
                .scale_drift_var_per_m
                .unwrap_or(base.scale_drift_var_per_m),
        }
    }
}

fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

/// Everything that decides what one source's corrector does: the preset, the method, the
/// matching mode, smoothing, parameter overrides and the lane geometry its lanes must have.
/// The command line builds it from flags, the daemon reads it from each `[[source]]` of its
/// TOML; [`CorrectorConfig::params`] is the one place it is validated.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorrectorConfig {
    /// The parameter preset of the odometry backend.
    pub preset: Preset,
    /// The correction method (default robust).
    #[serde(default)]
    pub method: Method,
    /// Lane matching: fast (default) or reference; both give identical corrections.
    #[serde(default)]
    pub match_mode: MatchMode,
    /// Publish smoothed poses (see [`crate::smoothing`]); `map_from_odom` stays exact.
    #[serde(default)]
    pub smooth: bool,
    /// The unmarked-street offset scale the source's lanes must have (see
    /// [`LaneGeometry::unmarked_offset_scale`]); default: the method's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unmarked_offset_scale: Option<f64>,
    /// Parameter overrides.
    #[serde(default, skip_serializing_if = "is_default")]
    pub overrides: Overrides,
}

impl CorrectorConfig {
    /// The configuration of `preset` under `method`, everything else default.
    pub fn new(preset: Preset, method: Method) -> CorrectorConfig {
        CorrectorConfig {
            preset,
            method,
            match_mode: MatchMode::default(),
            smooth: false,
            unmarked_offset_scale: None,
            overrides: Overrides::default(),
        }
    }

    /// The effective parameters: the method's preset with the overrides, validated.
    pub fn params(&self) -> Result<Params, ParamsError> {
        let params = self.overrides.apply(self.method.params(self.preset));
        params.validate()?;
        if let Some(scale) = self.unmarked_offset_scale {
            if crate::lane_geometry::check_unmarked_offset_scale(scale).is_err() {
                return Err(ParamsError::Invalid {
                    key: "unmarked_offset_scale",
                    value: scale.to_string(),
                    reason: "must be between 0 and 2",
                });
            }
        }
        Ok(params)
    }

    /// The smoothing limits, when smooth output is asked for.
    pub fn smoothing(&self) -> Option<Smoothing> {
        self.smooth.then(Smoothing::default)
    }

    /// The unmarked-street offset scale the lanes must have: the configured one, else the
    /// method's.
    pub fn unmarked_offset_scale(&self) -> f64 {
        self.unmarked_offset_scale
            .unwrap_or(self.method.unmarked_offset_scale())
    }

    /// Refuses a map whose lanes were derived with another unmarked-street model than this
    /// configuration needs. Maps with no lanes from raw OSM ways (Lanelet2, CSV) always pass.
    pub fn check_geometry(&self, geometry: &LaneGeometry) -> Result<(), ParamsError> {
        match geometry.unmarked_offset_scale {
            Some(found) if found != self.unmarked_offset_scale() => {
                Err(ParamsError::LaneGeometry {
                    method: self.method.name(),
                    wanted: self.unmarked_offset_scale(),
                    found,
                })
            }
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slower_source_has_its_pose_counts_scaled_and_a_faster_one_a_stride() {
        let p = Preset::KissIcp.robust_params();
        let at = |hz: f64| {
            let mut q = p;
            q.odometry_rate_hz = hz;
            (
                q.min_window_poses(),
                q.max_window_poses(),
                q.max_failures_at_rate(),
                q.window_stride(),
            )
        };
        assert_eq!(at(10.0), (150, 1000, 1000, 1));
        assert_eq!(at(100.0), (150, 1000, 1000, 10));
        assert_eq!(at(5.0), (75, 500, 500, 1));
        assert_eq!(at(2.0), (30, 200, 200, 1));
        // Never below two poses, so that a window has a direction.
        assert_eq!(at(0.01), (2, 2, 2, 1));
    }

    /// A refused value is quoted as it is written: `1e300`, not the 301 digits `Display` spells
    /// it with.
    #[test]
    fn a_refused_value_is_quoted_as_it_is_written() {
        let mut p = Preset::KissIcp.robust_params();
        p.odometry_rate_hz = 1e300;
        assert_eq!(
            p.validate().map_err(|e| e.to_string()),
            Err("odometry_rate_hz = 1e300: must be 0.001 to 100000 (Hz)".to_string())
        );
    }

    /// Below a pose every 1000 s every pose would count as standing still: refused, as `replay`
    /// refuses to publish so slowly.
    #[test]
    fn an_odometry_rate_slower_than_a_pose_every_1000_s_is_refused() {
        let mut p = Preset::KissIcp.robust_params();
        for hz in [
            1e-300,
            9.99e-4,
            0.0,
            -10.0,
            f64::NAN,
            f64::INFINITY,
            100_001.0,
        ] {
            p.odometry_rate_hz = hz;
            assert!(p.validate().is_err(), "{hz} Hz accepted");
        }
        for hz in [MIN_ODOMETRY_RATE_HZ, 0.1, 10.0, MAX_ODOMETRY_RATE_HZ] {
            p.odometry_rate_hz = hz;
            assert!(p.validate().is_ok(), "{hz} Hz refused");
        }
    }

    /// The bounds that keep a session's state one its snapshot restores: a scale drift above
    /// 0.25 a metre (at 1e100 the published covariances were NaN, from 1e3 the scale's variance
    /// passed a snapshot's bound within a kilometre), a heading sigma beyond a half turn (at 1e6
    /// degrees rounding made the filter's covariance indefinite within 1.6 km of KITTI 08) and
    /// a heading drift above a square radian a metre (at 1e6 a drive of 16 km without lanes gave
    /// a covariance no snapshot may hold; `tests/tests/snapshots.rs`). Each is refused beyond
    /// its bound and taken up to it.
    #[test]
    fn drifts_and_sigmas_beyond_their_bounds_are_refused() {
        type Set = fn(&mut Params, f64);
        let bounds: [(&str, Set, &[f64], &[f64]); 3] = [
            (
                "scale_drift_var_per_m",
                |p, v| p.scale_drift_var_per_m = v,
                &[1e100, 0.26, -1e-9, f64::NAN, f64::INFINITY],
                &[0.0, 1e-7, MAX_SCALE_DRIFT_VAR_PER_M],
            ),
            (
                "initial_sigma_yaw_deg",
                |p, v| p.initial_sigma_yaw_deg = v,
                &[999_999.0, 180.1, 0.0, -1.0, f64::NAN, f64::INFINITY],
                &[1e-300, 1.0, MAX_SIGMA_YAW_DEG],
            ),
            (
                "yaw_drift_var_per_m",
                |p, v| p.yaw_drift_var_per_m = v,
                &[999_999.0, 1.01, 0.0, -1.0, f64::NAN, f64::INFINITY],
                &[1e-300, 1.2e-7, MAX_YAW_DRIFT_VAR_PER_M],
            ),
        ];
        for (key, set, refused, taken) in bounds {
            let mut p = Preset::OrbSlam3.robust_params();
            for &v in refused {
                set(&mut p, v);
                assert!(p.validate().is_err(), "{key} = {v} accepted");
            }
            for &v in taken {
                set(&mut p, v);
                assert!(p.validate().is_ok(), "{key} = {v} refused");
            }
        }
    }

    #[test]
    fn presets_match_the_paper_table() {
        let p = Preset::KissIcp.params();
        assert_eq!((p.min_window, p.max_window, p.neighbours), (150, 1000, 100));
        assert_eq!((p.max_failures, p.max_residual_m), (1000, 1.5));
        assert_eq!("orb-slam3".parse::<Preset>(), Ok(Preset::OrbSlam3));
    }

    #[test]
    fn names_round_trip_and_unknown_names_list_the_choices() {
        for p in Preset::ALL {
            assert_eq!(p.name().parse::<Preset>(), Ok(p));
        }
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>(), Ok(m));
        }
        let e = "kiss".parse::<Preset>().unwrap_err().to_string();
        assert!(e.contains("kiss-icp") && e.contains("orb-slam3"), "{e}");
    }

    #[test]
    fn overrides_are_typed_and_checked() {
        let config: CorrectorConfig = toml::from_str(
            "preset = \"basalt\"\nmethod = \"paper\"\noverrides = { neighbours = 25, max_match_distance_m = inf }",
        )
        .unwrap();
        let p = config.params().unwrap();
        assert_eq!(p.neighbours, 25);
        assert_eq!(p.max_match_distance_m, f64::INFINITY);
        let unknown =
            toml::from_str::<CorrectorConfig>("preset = \"basalt\"\noverrides = { nope = 1 }");
        assert!(unknown.unwrap_err().to_string().contains("nope"));
        let wrong_type = toml::from_str::<CorrectorConfig>(
            "preset = \"basalt\"\noverrides = { neighbours = 2.5 }",
        );
        assert!(wrong_type.is_err());
        let mut small = CorrectorConfig::new(Preset::Basalt, Method::Paper);
        small.overrides.max_window = Some(3);
        let e = small.params().unwrap_err().to_string();
        assert!(e.starts_with("max_window = 3"), "{e}");
    }

    #[test]
    fn overrides_given_as_text_are_typed_and_checked() {
        let o = Overrides::from_assignments([
            ("max_window", "800"),
            (" lane_tolerance_m ", "1"),
            ("max_match_distance_m", "inf"),
            ("gate_widens_through_null_steps", "false"),
        ])
        .unwrap();
        assert_eq!(o.max_window, Some(800));
        assert_eq!(o.lane_tolerance_m, Some(1.0));
        assert_eq!(o.max_match_distance_m, Some(f64::INFINITY));
        assert_eq!(o.gate_widens_through_null_steps, Some(false));
        let refused = |pairs: &[(&str, &str)], says: &str| {
            let e = Overrides::from_assignments(pairs.iter().copied())
                .unwrap_err()
                .to_string();
            assert!(e.contains(says), "{pairs:?}: {e}");
        };
        refused(&[("nope", "1")], "nope");
        refused(&[("neighbours", "2.5")], "neighbours = 2.5: invalid type");
        refused(
            &[
                ("max_window", "8"),
                ("neighbours", "9"),
                ("max_window", "9"),
            ],
            "max_window = 9: duplicate key",
        );
        // A key or value that would be more than one assignment is not read as several.
        refused(
            &[("max_window = 8\nneighbours", "9")],
            "not a parameter's name",
        );
        refused(&[("max_window", "8\nneighbours = 9")], "not a value");
        refused(&[("max_window", "")], "not a value");
    }

    #[test]
    fn a_config_round_trips_through_toml() {
        let mut config = CorrectorConfig::new(Preset::OrbSlam3, Method::Robust);
        config.smooth = true;
        config.overrides.lane_tolerance_m = Some(0.5);
        let text = toml::to_string(&config).unwrap();
        assert_eq!(toml::from_str::<CorrectorConfig>(&text).unwrap(), config);
        let params = toml::to_string(&config.params().unwrap()).unwrap();
        assert!(params.contains("max_match_distance_m = 3.0"), "{params}");
        assert_eq!(
            toml::from_str::<Params>(&params).unwrap(),
            config.params().unwrap()
        );
    }

    #[test]
    fn the_lane_geometry_must_be_the_methods() {
        let robust_tile = LaneGeometry::default();
        let paper_tile = LaneGeometry {
            unmarked_offset_scale: Some(1.0),
            ..LaneGeometry::default()
        };
        let paper = CorrectorConfig::new(Preset::KissIcp, Method::Paper);
        let robust = CorrectorConfig::new(Preset::KissIcp, Method::Robust);
        assert!(robust.check_geometry(&robust_tile).is_ok());
        assert!(paper.check_geometry(&paper_tile).is_ok());
        let e = paper.check_geometry(&robust_tile).unwrap_err().to_string();
        assert!(e.contains("--unmarked-offset-scale 1"), "{e}");
        let lanelets = LaneGeometry {
            unmarked_offset_scale: None,
            ..LaneGeometry::default()
        };
        assert!(paper.check_geometry(&lanelets).is_ok());
        let accept_any = CorrectorConfig {
            unmarked_offset_scale: Some(0.5),
            ..paper
        };
        assert!(accept_any.check_geometry(&robust_tile).is_ok());
    }
}
