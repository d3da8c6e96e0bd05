//! Ground truth and an estimate side by side: paired (by timestamp for TUM files, by index for
//! KITTI files) and rotated into the planar frame, as `lanealign eval` and `correct --gt` compare
//! them.

use lanealign_core::metrics::{associate_by_time, Ape2d, CalibrationCheck, MetricsError};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::trajectory::{Format, Trajectory};

/// The figures `lanealign eval --json` prints and Python's `lanealign.eval` returns, as one flat
/// object: the keys of [`Ape2d`], and with published covariances those of [`CalibrationCheck`]
/// (`poses` is in both, with the same count).
pub fn figures_json(
    ape: &Ape2d,
    calibration: Option<&CalibrationCheck>,
) -> serde_json::Result<serde_json::Value> {
    let mut json = serde_json::to_value(ape)?;
    if let (Some(object), Some(serde_json::Value::Object(check))) = (
        json.as_object_mut(),
        calibration.map(serde_json::to_value).transpose()?,
    ) {
        object.extend(check);
    }
    Ok(json)
}

/// Paired planar poses: `gt[k]` and `est[k]` are the `k`-th pair.
pub struct Paired {
    /// Ground truth, planar frame.
    pub gt: Vec<Pose3>,
    /// Estimate, planar frame.
    pub est: Vec<Pose3>,
    /// Indices `(ground truth, estimate)` of each pair in the files.
    pub pairs: Vec<(usize, usize)>,
}

/// The largest difference (seconds) between the stamps of a ground-truth and an estimated pose
/// that pair, unless told otherwise: evo's `--t_max_diff`.
pub const DEFAULT_MAX_DT_S: f64 = 0.01;

/// Longest pairing tolerance (seconds): beyond an hour, stamps pair with poses of another drive.
pub const MAX_MAX_DT_S: f64 = 3600.0;

/// Largest offset of the estimate's stamps (seconds, either way): 300 years, more than between
/// any two time bases a pose file's stamps are in (Unix seconds are 1.7e9 today).
pub const MAX_T_OFFSET_S: f64 = 1e10;

/// `max_dt_s` if it is a pairing tolerance: above 0 and at most [`MAX_MAX_DT_S`] seconds.
pub fn checked_max_dt_s(max_dt_s: f64) -> Result<f64, String> {
    if max_dt_s > 0.0 && max_dt_s <= MAX_MAX_DT_S {
        Ok(max_dt_s)
    } else {
        Err(format!(
            "must be a number of seconds above 0 and at most {MAX_MAX_DT_S}"
        ))
    }
}

/// How the poses of two stamped trajectories pair: each estimated pose with the ground-truth
/// pose nearest in time, within `max_dt_s` seconds, after `est_offset_s` seconds are added to
/// the estimate's stamps (evo's `--t_max_diff` and `--t_offset`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pairing {
    /// The largest difference of two stamps that pair (seconds).
    pub max_dt_s: f64,
    /// Added to the estimate's stamps before pairing (seconds).
    pub est_offset_s: f64,
}

/// The command line's pairing options (`eval`, `correct --gt`).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct PairingArgs {
    /// With --format tum: the largest difference (seconds) between the stamps of a ground-truth
    /// and an estimated pose that pair (as evo's --t_max_diff) [default: 0.01].
    #[arg(long, value_parser = max_dt_arg, requires = "gt")]
    max_dt: Option<f64>,
    /// With --format tum: seconds added to the estimate's stamps (`correct`'s input's) before
    /// pairing, for clocks apart by a known offset (as evo's --t_offset).
    #[arg(long, value_parser = t_offset_arg, allow_negative_numbers = true, requires = "gt")]
    t_offset: Option<f64>,
}

impl PairingArgs {
    /// The pairing asked for; refused for files of `format` when they have no stamps.
    pub fn pairing(&self, format: Format) -> anyhow::Result<Pairing> {
        if format != Format::Tum && (self.max_dt.is_some() || self.t_offset.is_some()) {
            anyhow::bail!(
                "--max-dt and --t-offset pair poses by their stamps: only with --format tum"
            );
        }
        Ok(Pairing {
            max_dt_s: self.max_dt.unwrap_or(DEFAULT_MAX_DT_S),
            est_offset_s: self.t_offset.unwrap_or(0.0),
        })
    }
}

/// `--max-dt`: a number of seconds [`checked_max_dt_s`] takes.
fn max_dt_arg(text: &str) -> Result<f64, String> {
    checked_max_dt_s(text.parse::<f64>().unwrap_or(f64::NAN))
}

/// `--t-offset`: a number of seconds, at most [`MAX_T_OFFSET_S`] either way.
fn t_offset_arg(text: &str) -> Result<f64, String> {
    text.parse::<f64>()
        .ok()
        .filter(|t| t.abs() <= MAX_T_OFFSET_S)
        .ok_or_else(|| {
            format!("must be a number of seconds from -{MAX_T_OFFSET_S} to {MAX_T_OFFSET_S}")
        })
}

/// `e`, with what the command line offers when stamps pair nowhere.
pub fn with_pairing_advice(e: MetricsError) -> anyhow::Error {
    match e {
        MetricsError::NoStampPairs { .. } => anyhow::anyhow!(
            "{e}; --t-offset shifts the estimate's stamps, --max-dt widens the tolerance"
        ),
        e => e.into(),
    }
}

/// Pairs `est` with `gt`: by timestamp as `pairing` says when both have them, else by index
/// (then they must be as long).
pub fn pair(
    gt: &Trajectory,
    est: &Trajectory,
    frame: AxisConvention,
    pairing: Pairing,
) -> Result<Paired, MetricsError> {
    let pairs: Vec<(usize, usize)> = match (&gt.stamps, &est.stamps) {
        (Some(ts_gt), Some(ts_est)) => {
            let shifted: Vec<f64> = ts_est.iter().map(|t| t + pairing.est_offset_s).collect();
            associate_by_time(ts_gt, &shifted, pairing.max_dt_s)?
        }
        _ if gt.poses.len() == est.poses.len() => (0..gt.poses.len()).map(|i| (i, i)).collect(),
        _ => {
            return Err(MetricsError::LengthMismatch {
                gt: gt.poses.len(),
                est: est.poses.len(),
            })
        }
    };
    Ok(Paired {
        gt: pairs
            .iter()
            .map(|p| frame.to_planar(&gt.poses[p.0]))
            .collect(),
        est: pairs
            .iter()
            .map(|p| frame.to_planar(&est.poses[p.1]))
            .collect(),
        pairs,
    })
}

impl Paired {
    /// The distance driven along the ground truth up to each pair (metres, from 0).
    pub fn distance_m(&self) -> Vec<f64> {
        let mut total = 0.0;
        let mut last: Option<[f64; 2]> = None;
        self.gt
            .iter()
            .map(|g| {
                let p = g.planar_position();
                if let Some(l) = last {
                    total += (p[0] - l[0]).hypot(p[1] - l[1]);
                }
                last = Some(p);
                total
            })
            .collect()
    }

    /// The planar position error of each pair (metres).
    pub fn errors_m(&self) -> Vec<f64> {
        self.gt
            .iter()
            .zip(&self.est)
            .map(|(g, e)| {
                let (g, e) = (g.planar_position(), e.planar_position());
                (g[0] - e[0]).hypot(g[1] - e[1])
            })
            .collect()
    }
}
