//! Corrector parameters and the paper's presets per odometry backend (SPEC section 3).

use std::str::FromStr;

/// Every tunable of the corrector. Lengths in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
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
    /// but never below `min_window` poses. Bounds the stretch over which the odometry's scale and
    /// heading drift must fit one rigid correction. Infinite = paper.
    pub max_window_path_m: f64,
    /// Beyond the paper: dead band around the lane centrelines (metres). A pose this close to its
    /// lane match counts as on the lane; ICP pulls farther ones only onto the band's edge. Models
    /// the offset between OSM centrelines and where cars drive. 0 = paper.
    pub lane_tolerance_m: f64,
    /// Beyond the paper: largest distance between a pose and its lane match (metres) right after
    /// an accepted step; it widens by `drift_per_m` per metre travelled since. Infinite = paper.
    pub max_match_distance_m: f64,
    /// Beyond the paper: drift the odometry may accumulate per metre travelled (ratio) since the
    /// last accepted step, widening the match distance bound.
    pub drift_per_m: f64,
}

/// Which correction algorithm runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Method {
    /// The published algorithm exactly (SPEC sections 2-3).
    Paper,
    /// lanealign's corrector: the paper's plus a window bounded by path length, a lane tolerance
    /// band and a correspondence gate that follows the odometry's possible drift
    /// (`docs/method.md`).
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
}

impl FromStr for Method {
    type Err = ParamsError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| ParamsError::UnknownMethod(s.to_string()))
    }
}

/// The paper's presets, one per odometry backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
            max_match_distance_m: f64::INFINITY,
            drift_per_m: 0.0,
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
        Params {
            max_window_path_m,
            lane_tolerance_m: 1.0,
            max_match_distance_m: 3.0,
            drift_per_m: 0.2,
            ..self.params()
        }
    }
}

/// A preset name or parameter override that could not be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ParamsError {
    /// The method name is not `paper` or `robust`.
    #[error("unknown method '{0}' (expected paper or robust)")]
    UnknownMethod(String),
    /// The preset name is not one of the four.
    #[error("unknown preset '{0}' (expected liodom, basalt, kiss-icp or orb-slam3)")]
    UnknownPreset(String),
    /// The override names no parameter.
    #[error("unknown parameter '{0}' (expected one of: {known})", known = Params::KEYS.join(", "))]
    UnknownKey(String),
    /// The value does not parse or is out of range.
    #[error("bad value '{value}' for parameter '{key}': {reason}")]
    BadValue {
        /// The parameter.
        key: String,
        /// The value given.
        value: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The override is not `key=value`.
    #[error("'{0}' is not of the form key=value")]
    NotKeyValue(String),
}

impl FromStr for Preset {
    type Err = ParamsError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| ParamsError::UnknownPreset(s.to_string()))
    }
}

fn parse<T: FromStr>(key: &str, value: &str) -> Result<T, ParamsError>
where
    T::Err: std::fmt::Display,
{
    value.parse().map_err(|e: T::Err| ParamsError::BadValue {
        key: key.to_string(),
        value: value.to_string(),
        reason: e.to_string(),
    })
}

impl Params {
    /// The parameter names [`Params::set`] accepts.
    pub const KEYS: [&'static str; 15] = [
        "min_window",
        "max_window",
        "neighbours",
        "max_failures",
        "max_residual_m",
        "trim_ratio",
        "min_match_ratio",
        "min_path_length_m",
        "min_direction_cos",
        "icp_max_iterations",
        "icp_tolerance_m",
        "max_window_path_m",
        "lane_tolerance_m",
        "max_match_distance_m",
        "drift_per_m",
    ];

    /// Overrides one parameter by name, then checks that the whole set is still consistent.
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), ParamsError> {
        let mut next = *self;
        match key {
            "min_window" => next.min_window = parse(key, value)?,
            "max_window" => next.max_window = parse(key, value)?,
            "neighbours" => next.neighbours = parse(key, value)?,
            "max_failures" => next.max_failures = parse(key, value)?,
            "max_residual_m" => next.max_residual_m = parse(key, value)?,
            "trim_ratio" => next.trim_ratio = parse(key, value)?,
            "min_match_ratio" => next.min_match_ratio = parse(key, value)?,
            "min_path_length_m" => next.min_path_length_m = parse(key, value)?,
            "min_direction_cos" => next.min_direction_cos = parse(key, value)?,
            "icp_max_iterations" => next.icp_max_iterations = parse(key, value)?,
            "icp_tolerance_m" => next.icp_tolerance_m = parse(key, value)?,
            "max_window_path_m" => next.max_window_path_m = parse(key, value)?,
            "lane_tolerance_m" => next.lane_tolerance_m = parse(key, value)?,
            "max_match_distance_m" => next.max_match_distance_m = parse(key, value)?,
            "drift_per_m" => next.drift_per_m = parse(key, value)?,
            _ => return Err(ParamsError::UnknownKey(key.to_string())),
        }
        next.validate().map_err(|reason| ParamsError::BadValue {
            key: key.to_string(),
            value: value.to_string(),
            reason,
        })?;
        *self = next;
        Ok(())
    }

    /// Applies a `key=value` override.
    pub fn set_pair(&mut self, pair: &str) -> Result<(), ParamsError> {
        let (key, value) = pair
            .split_once('=')
            .ok_or_else(|| ParamsError::NotKeyValue(pair.to_string()))?;
        self.set(key.trim(), value.trim())
    }

    /// Checks that the parameters make sense together; says what does not.
    pub fn validate(&self) -> Result<(), String> {
        let finite_nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if self.min_window < 2 {
            return Err("min_window must be at least 2".into());
        }
        if self.max_window < self.min_window {
            return Err("max_window must be at least min_window".into());
        }
        if self.neighbours == 0 {
            return Err("neighbours must be at least 1".into());
        }
        if !finite_nonneg(self.max_residual_m)
            || !finite_nonneg(self.min_path_length_m)
            || !finite_nonneg(self.icp_tolerance_m)
        {
            return Err("lengths must be finite and non-negative".into());
        }
        if !(0.0..1.0).contains(&self.trim_ratio) || !(0.0..=1.0).contains(&self.min_match_ratio) {
            return Err("trim_ratio must be in [0, 1) and min_match_ratio in [0, 1]".into());
        }
        if !(-1.0..=1.0).contains(&self.min_direction_cos) {
            return Err("min_direction_cos must be in [-1, 1]".into());
        }
        if !finite_nonneg(self.lane_tolerance_m) || !finite_nonneg(self.drift_per_m) {
            return Err("lane_tolerance_m and drift_per_m must be finite and non-negative".into());
        }
        if self.max_window_path_m.is_nan() || self.max_window_path_m <= 0.0 {
            return Err("max_window_path_m must be positive (inf = off)".into());
        }
        if self.max_match_distance_m.is_nan() || self.max_match_distance_m <= 0.0 {
            return Err("max_match_distance_m must be positive (inf = off)".into());
        }
        if self.icp_max_iterations == 0 {
            return Err("icp_max_iterations must be at least 1".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_match_the_paper_table() {
        let p = Preset::KissIcp.params();
        assert_eq!((p.min_window, p.max_window, p.neighbours), (150, 1000, 100));
        assert_eq!((p.max_failures, p.max_residual_m), (1000, 1.5));
        assert_eq!("orb-slam3".parse::<Preset>(), Ok(Preset::OrbSlam3));
    }

    #[test]
    fn overrides_are_checked() {
        let mut p = Preset::Basalt.params();
        p.set_pair("neighbours=25").unwrap();
        assert_eq!(p.neighbours, 25);
        assert!(matches!(
            p.set_pair("nope=1"),
            Err(ParamsError::UnknownKey(_))
        ));
        assert!(matches!(
            p.set_pair("max_window=3"),
            Err(ParamsError::BadValue { .. })
        ));
        assert!(matches!(
            p.set_pair("tau"),
            Err(ParamsError::NotKeyValue(_))
        ));
        assert_eq!(p.max_window, 3000, "a refused override changes nothing");
    }
}
