//! Ground truth and an estimate side by side: paired (by timestamp for TUM files, by index for
//! KITTI files) and rotated into the planar frame, as `lanealign eval` and `correct --gt` compare
//! them.

use lanealign_core::metrics::{associate_by_time, Ape2d, CalibrationCheck, MetricsError};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::trajectory::Trajectory;

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

/// Pairs `est` with `gt`: by timestamp (within `max_dt_s` seconds) when both have them, else by
/// index (then they must be as long).
pub fn pair(
    gt: &Trajectory,
    est: &Trajectory,
    frame: AxisConvention,
    max_dt_s: f64,
) -> Result<Paired, MetricsError> {
    let pairs: Vec<(usize, usize)> = match (&gt.stamps, &est.stamps) {
        (Some(ts_gt), Some(ts_est)) => associate_by_time(ts_gt, ts_est, max_dt_s)?,
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
