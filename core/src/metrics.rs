//! Accuracy metrics in the plane, without alignment (evo's APE with `--project_to_plane xy`).

use crate::pose::{apply_planar_correction, Pose3};
use crate::rng::Lcg;
use crate::scale::ScaledOdometry;
use crate::se2::wrap_angle;
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// Absolute pose error of an estimate against ground truth, both planar (`flu`) and paired.
/// Serialised with the keys `lanealign eval --json` prints.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Ape2d {
    /// Mean of `|t_xy - t_xy_gt|` (metres).
    #[serde(rename = "ape2d_mean_m")]
    pub mean_m: f64,
    /// Root mean square of the same (metres).
    pub rmse_m: f64,
    /// RMS of the error component perpendicular to the ground-truth heading (metres).
    pub lateral_rmse_m: f64,
    /// Mean absolute heading error (degrees).
    pub heading_mean_deg: f64,
    /// Largest position error (metres).
    pub max_m: f64,
    /// Pairs compared.
    pub poses: usize,
}

/// Metrics that could not be computed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricsError {
    /// The two trajectories have different lengths (index pairing needs equal lengths).
    #[error(
        "ground truth has {gt} poses and the estimate {est}: index pairing needs the same count"
    )]
    LengthMismatch {
        /// Ground-truth poses.
        gt: usize,
        /// Estimated poses.
        est: usize,
    },
    /// Nothing to compare.
    #[error("no pose pairs to compare")]
    Empty,
    /// Paired by time, no estimate stamp lies near a ground-truth stamp.
    #[error(
        "no estimate stamp lies within {max_dt_s} s of a ground-truth stamp: the ground truth's \
         {gt}, the estimate's {est} (a clock offset between them, or stamps of another time base?)"
    )]
    NoStampPairs {
        /// The largest difference a pair may have (seconds).
        max_dt_s: f64,
        /// The ground truth's stamps.
        gt: StampSpan,
        /// The estimate's stamps.
        est: StampSpan,
    },
    /// A pose is not finite, so no figure would be either.
    #[error("pose pair {index} is not finite: no figure can be computed")]
    NotFinite {
        /// The pair's index.
        index: usize,
    },
    /// There is not one covariance per pose pair.
    #[error("{pairs} pose pairs but {covariances} covariances")]
    CovarianceCount {
        /// Pose pairs.
        pairs: usize,
        /// Covariances.
        covariances: usize,
    },
    /// A published covariance is not a covariance.
    #[error("the covariance of pose {index} is not finite and positive definite")]
    NotPositiveDefinite {
        /// The pose's index.
        index: usize,
    },
    /// The normalised errors squared add up beyond what a number holds: a covariance far
    /// smaller than its error (1e-300 m^2 against 10 km).
    #[error(
        "the covariance of pose {index} is too small for its error: the sum of the normalised \
         errors squared overflows"
    )]
    NeesOverflow {
        /// The pose at which the sum overflowed.
        index: usize,
    },
}

/// APE-2D of paired planar poses (`gt[i]` with `est[i]`).
pub fn ape_2d(gt: &[Pose3], est: &[Pose3]) -> Result<Ape2d, MetricsError> {
    if gt.len() != est.len() {
        return Err(MetricsError::LengthMismatch {
            gt: gt.len(),
            est: est.len(),
        });
    }
    if gt.is_empty() {
        return Err(MetricsError::Empty);
    }
    let n = gt.len() as f64;
    let (mut sum, mut sq, mut lat_sq, mut heading, mut max) = (0.0, 0.0, 0.0, 0.0, 0.0f64);
    for (index, (g, e)) in gt.iter().zip(est).enumerate() {
        if !(g.is_finite() && e.is_finite()) {
            return Err(MetricsError::NotFinite { index });
        }
        let [ex, ey] = e.planar_position();
        let [gx, gy] = g.planar_position();
        let (dx, dy) = (ex - gx, ey - gy);
        let d2 = dx * dx + dy * dy;
        let d = d2.sqrt();
        sum += d;
        sq += d2;
        max = max.max(d);
        let h = g.planar_heading();
        let lateral = -h.sin() * dx + h.cos() * dy;
        lat_sq += lateral * lateral;
        heading += wrap_angle(e.planar_heading() - h).abs();
    }
    Ok(Ape2d {
        mean_m: sum / n,
        rmse_m: (sq / n).sqrt(),
        lateral_rmse_m: (lat_sq / n).sqrt(),
        heading_mean_deg: (heading / n).to_degrees(),
        max_m: max,
        poses: gt.len(),
    })
}

/// The chi-square quantile of 2 degrees of freedom at 0.95: a planar position error `e` lies
/// inside the 95 % ellipse of covariance `S` when `e' S^-1 e` is at most this.
pub const CHI2_2DOF_95: f64 = 5.991_464_547_107_979;

/// How well published covariances describe the true errors of planar positions. Serialised with
/// the keys `lanealign eval --status --json` prints.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Calibration {
    /// Fraction of poses whose position error lies inside the 95 % ellipse of its covariance
    /// (0.95 for a calibrated covariance).
    pub cov95_coverage: f64,
    /// Mean normalised estimation error squared of the planar position, `e' S^-1 e` (2 for a
    /// calibrated covariance: two degrees of freedom).
    pub nees_mean: f64,
    /// How many independent errors the poses amount to: `poses` over the integrated
    /// autocorrelation time of the whitened errors `S^-1/2 e`
    /// ([`integrated_autocorrelation_time`], about zero). Errors that persist over hundreds of
    /// poses (an offset that a stretch of mapped road shares) make a drive of thousands of poses
    /// a handful of samples, and its coverage as uncertain as a handful's.
    pub independent_samples: f64,
    /// Poses compared.
    pub poses: usize,
}

/// The calibration of position covariances `cov_xy[i]` (metres^2, in the plane of the poses)
/// published with `est[i]`, against `gt[i]` (both planar, `flu`, paired by index). A pose whose
/// covariance is not positive definite is an error.
pub fn calibration(
    gt: &[Pose3],
    est: &[Pose3],
    cov_xy: &[[[f64; 2]; 2]],
) -> Result<Calibration, MetricsError> {
    if gt.len() != est.len() {
        return Err(MetricsError::LengthMismatch {
            gt: gt.len(),
            est: est.len(),
        });
    }
    if cov_xy.len() != est.len() {
        return Err(MetricsError::CovarianceCount {
            pairs: est.len(),
            covariances: cov_xy.len(),
        });
    }
    if gt.is_empty() {
        return Err(MetricsError::Empty);
    }
    let (mut inside, mut nees_sum) = (0usize, 0.0);
    let mut whitened = Vec::with_capacity(gt.len());
    for (index, ((g, e), s)) in gt.iter().zip(est).zip(cov_xy).enumerate() {
        let [ex, ey] = e.planar_position();
        let [gx, gy] = g.planar_position();
        let (dx, dy) = (ex - gx, ey - gy);
        if !(dx.is_finite() && dy.is_finite()) {
            return Err(MetricsError::NotFinite { index });
        }
        let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        if !(det > 0.0 && s[0][0] > 0.0 && det.is_finite()) {
            return Err(MetricsError::NotPositiveDefinite { index });
        }
        // The whitened error L^-1 e, for S = L L' with L lower triangular: its squared length is
        // the NEES.
        let l00 = s[0][0].sqrt();
        let l10 = 0.5 * (s[0][1] + s[1][0]) / l00;
        let l11 = det.sqrt() / l00;
        let w0 = dx / l00;
        let w1 = (dy - l10 * w0) / l11;
        whitened.push([w0, w1]);
        let nees = w0 * w0 + w1 * w1;
        nees_sum += nees;
        // Bounds the autocorrelation's sums of products too: each is at most this sum.
        if !nees_sum.is_finite() {
            return Err(MetricsError::NeesOverflow { index });
        }
        if nees <= CHI2_2DOF_95 {
            inside += 1;
        }
    }
    let n = gt.len() as f64;
    Ok(Calibration {
        cov95_coverage: inside as f64 / n,
        nees_mean: nees_sum / n,
        independent_samples: n / integrated_autocorrelation_time(&whitened),
        poses: gt.len(),
    })
}

/// The integrated autocorrelation time of a series of planar vectors whose mean is zero when
/// they are what they should be, such as whitened errors (samples, at least 1 and at most the
/// series' length): `1 + 2 sum_k rho(k)` of each component, summed over the lags up to Sokal's
/// window (the first lag at least five times the sum so far), averaged over the two components.
/// `rho` is taken about zero, not about the series' own mean: an offset that the whole series
/// shares is an error that persists, and makes the series count as one sample. A series of `n`
/// samples carries about as much as `n` over it independent ones.
pub fn integrated_autocorrelation_time(series: &[[f64; 2]]) -> f64 {
    let n = series.len();
    let component = |c: usize| {
        let values: Vec<f64> = series.iter().map(|v| v[c]).collect();
        let through_fft = (n > DIRECT_LAG_SUMS_UP_TO).then(|| lag_sums(&values));
        let lag_sum = |k: usize| match &through_fft {
            Some(sums) => sums[k],
            None => values[k..]
                .iter()
                .zip(&values)
                .map(|(a, b)| a * b)
                .sum::<f64>(),
        };
        let zero_lag = lag_sum(0);
        if zero_lag <= 0.0 {
            return 1.0;
        }
        let mut tau = 1.0;
        for k in 1..n {
            tau += 2.0 * lag_sum(k) / zero_lag;
            if k as f64 >= 5.0 * tau {
                break;
            }
        }
        tau.clamp(1.0, n as f64)
    };
    if n == 0 {
        return 1.0;
    }
    0.5 * (component(0) + component(1))
}

/// Up to this many poses the lag sums of [`integrated_autocorrelation_time`] are summed one by
/// one, as far as Sokal's window reaches: the same bits from every build (the command line and
/// the Python package agree exactly), at most 0.1 s where the errors persist over the whole
/// drive and the window reaches its end. Beyond, through the FFT ([`lag_sums`]).
const DIRECT_LAG_SUMS_UP_TO: usize = 20_000;

/// `sum_i x[i + k] x[i]` for every lag `k` of `x` (0 to its length - 1): the inverse FFT of the
/// power spectrum of `x` padded with zeros to at least twice its length. O(n log n), where the
/// sums one by one take O(n^2) on a drive whose errors persist (Sokal's window then reaches the
/// drive's end: 0.4 s for 40 000 poses, hours for a day's log at 100 Hz; through the FFT 16 ms
/// and 1.4 s for 4 million). Equal to the direct sums within rounding, but not bit for bit, and
/// not the same bits from every build: used on every drive, the Python wheel and the command
/// line differed in the last digit on KITTI 07 (I did not find which part of the FFT compiles
/// differently).
fn lag_sums(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    let padded = (2 * n).next_power_of_two();
    let mut buffer: Vec<Complex<f64>> = x
        .iter()
        .map(|&v| Complex::new(v, 0.0))
        .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
        .take(padded)
        .collect();
    let mut planner = FftPlanner::<f64>::new();
    planner.plan_fft_forward(padded).process(&mut buffer);
    for z in &mut buffer {
        *z = Complex::new(z.norm_sqr(), 0.0);
    }
    planner.plan_fft_inverse(padded).process(&mut buffer);
    buffer[..n].iter().map(|z| z.re / padded as f64).collect()
}

/// Drives simulated for [`Calibration::if_exact`].
const EXACT_TRIALS: usize = 10_000;
/// Up to this many independent errors the range is simulated; beyond, it is computed from the
/// normal approximation of the coverage's binomial and the mean NEES's chi-square (a thousand
/// degrees of freedom and more; within 0.004 of the simulated range at 500), so that a long
/// drive of white errors costs no billions of draws.
const SIMULATED_UP_TO: f64 = 500.0;
/// The standard normal's 97.5th percentile.
const Z_975: f64 = 1.959_963_984_540_054;
/// The seed of every simulation of exact errors: the same ranges on every run and machine.
const EXACT_SEED: u64 = 14;

/// The coverage and mean NEES (`[coverage, nees_mean]`) of `trials` simulated drives whose
/// errors a covariance describes exactly and that amount to `independent_samples` independent
/// errors: each drive is that many errors, each persisting over an equal share of the poses (the
/// last over the fraction left), as a stretch of mapped road's offset persists. The NEES of an
/// exact planar error is chi-square of two degrees of freedom, an exponential of mean 2, drawn
/// as `-2 ln U`. Of the shapes a correlation could have, errors that persist whole and then
/// change at once spread the figures the most (an AR(1) process of the same integrated time
/// decorrelates its NEES in about half the time, and would show a range some 30 % narrower): a
/// range that errs wide, so that a verdict outside it is not the shape's doing. Fixed seed: the
/// same drives on every call. Counts are summed whole and divided once, so that a drive with
/// every error inside has a coverage of exactly 1.
fn simulate_exact(independent_samples: f64, trials: usize) -> Vec<[f64; 2]> {
    let n = independent_samples.max(1.0);
    let whole = n.floor();
    let part = n - whole;
    let mut rng = Lcg(EXACT_SEED);
    let mut nees = || -2.0 * (1.0 - rng.uniform()).ln();
    (0..trials)
        .map(|_| {
            // Each error's share in whole errors: 1, and the fraction left for the last.
            let shares =
                std::iter::repeat_n(1.0, whole as usize).chain((part > 0.0).then_some(part));
            let (mut inside, mut nees_sum) = (0.0, 0.0);
            for share in shares {
                let e = nees();
                nees_sum += share * e;
                if e <= CHI2_2DOF_95 {
                    inside += share;
                }
            }
            [inside / n, nees_sum / n]
        })
        .collect()
}

/// What a covariance that describes the errors exactly would show over a drive: the middle 95 %
/// (2.5th to 97.5th percentile) of the coverage and of the mean NEES over simulated drives of as
/// many independent errors ([`Calibration::if_exact`]). A drive whose errors amount to a few
/// independent ones has a wide range: a coverage of 1.000 over two independent errors says
/// little, a mean NEES of 0.3 over ten says the covariance is too cautious.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ExactRange {
    /// The coverage's range (fractions of the poses).
    #[serde(rename = "cov95_coverage_if_exact")]
    pub cov95_coverage: [f64; 2],
    /// The mean NEES's range.
    #[serde(rename = "nees_mean_if_exact")]
    pub nees_mean: [f64; 2],
}

/// Whether published covariances describe the errors, judged against [`ExactRange`].
/// Serialised as its [`Verdict::name`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Coverage and mean NEES within what an exact covariance shows.
    Consistent,
    /// The errors are larger than the covariance says: the mean NEES above its range or the
    /// coverage below its range. The direction a fusion filter must not be given.
    TooConfident,
    /// The errors are smaller than the covariance says: the mean NEES below its range or the
    /// coverage above it, and neither says too confident.
    TooCautious,
}

impl Verdict {
    /// The verdict as `eval` prints it and its JSON holds it.
    pub fn name(&self) -> &'static str {
        match self {
            Verdict::Consistent => "consistent",
            Verdict::TooConfident => "too confident",
            Verdict::TooCautious => "too cautious",
        }
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl serde::Serialize for Verdict {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// A calibration with what an exact covariance would show and the verdict: what `lanealign eval
/// --status` reports. Serialised flat, with the keys `eval --status --json` prints.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CalibrationCheck {
    /// The measured figures.
    #[serde(flatten)]
    pub calibration: Calibration,
    /// What an exact covariance would show over as many independent errors.
    #[serde(flatten)]
    pub if_exact: ExactRange,
    /// The two compared.
    #[serde(rename = "calibration_verdict")]
    pub verdict: Verdict,
}

impl Calibration {
    /// What a covariance that describes these errors exactly would show over as many
    /// independent errors ([`ExactRange`]; 10 000 simulated drives, 1.5 ms for 20 independent
    /// errors and 26 ms for 500 on this project's machine; beyond 500 computed from the normal
    /// approximation).
    pub fn if_exact(&self) -> ExactRange {
        let n = self.independent_samples;
        if n > SIMULATED_UP_TO {
            let coverage_sd = (0.95 * 0.05 / n).sqrt();
            let nees_sd = 2.0 / n.sqrt();
            return ExactRange {
                cov95_coverage: [0.95 - Z_975 * coverage_sd, 0.95 + Z_975 * coverage_sd],
                nees_mean: [2.0 - Z_975 * nees_sd, 2.0 + Z_975 * nees_sd],
            };
        }
        let mut outcomes = simulate_exact(n, EXACT_TRIALS);
        let range = |outcomes: &mut Vec<[f64; 2]>, k: usize| {
            outcomes.sort_by(|a, b| a[k].total_cmp(&b[k]));
            // Nearest rank, the 250th and the 9750th of 10 000: at most 2.5 % of the drives lie
            // below the first, and at most 2.5 % above the second.
            let at = |p: f64| outcomes[((p * outcomes.len() as f64).ceil() as usize).max(1) - 1][k];
            [at(0.025), at(0.975)]
        };
        ExactRange {
            cov95_coverage: range(&mut outcomes, 0),
            nees_mean: range(&mut outcomes, 1),
        }
    }

    /// These figures against what an exact covariance would show ([`Verdict`]).
    pub fn check(self) -> CalibrationCheck {
        let if_exact = self.if_exact();
        let (coverage, nees) = (if_exact.cov95_coverage, if_exact.nees_mean);
        let verdict = if self.nees_mean > nees[1] || self.cov95_coverage < coverage[0] {
            Verdict::TooConfident
        } else if self.nees_mean < nees[0] || self.cov95_coverage > coverage[1] {
            Verdict::TooCautious
        } else {
            Verdict::Consistent
        };
        CalibrationCheck {
            calibration: self,
            if_exact,
            verdict,
        }
    }
}

/// How much an output trajectory changes from one pose to the next beyond the motion of the
/// odometry it was computed from: the jumps a consumer of the output sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputJumps {
    /// Largest position change beyond the odometry's motion (metres).
    pub max_position_m: f64,
    /// Largest yaw change beyond the odometry's rotation (degrees).
    pub max_yaw_deg: f64,
}

/// The largest frame-to-frame jumps of `output` beyond the odometry motion of `raw` (both planar,
/// `flu`, paired by index): for each pose, `output[i-1]` moved by the odometry step
/// `raw[i-1]^-1 raw[i]` is compared with `output[i]`.
pub fn output_jumps(raw: &[Pose3], output: &[Pose3]) -> Result<OutputJumps, MetricsError> {
    if raw.len() != output.len() {
        return Err(MetricsError::LengthMismatch {
            gt: raw.len(),
            est: output.len(),
        });
    }
    let mut jumps = OutputJumps {
        max_position_m: 0.0,
        max_yaw_deg: 0.0,
    };
    for (r, o) in raw.windows(2).zip(output.windows(2)) {
        let predicted = o[0].to_se2() * r[0].to_se2().inverse() * r[1].to_se2();
        let actual = o[1].to_se2();
        let [px, py] = predicted.translation();
        let [ax, ay] = actual.translation();
        jumps.max_position_m = jumps.max_position_m.max((ax - px).hypot(ay - py));
        jumps.max_yaw_deg = jumps.max_yaw_deg.max(
            wrap_angle(actual.yaw() - predicted.yaw())
                .abs()
                .to_degrees(),
        );
    }
    Ok(jumps)
}

/// `raw` (planar, `flu`) with each step's translation multiplied by the scale the corrector
/// applied to it: step `i` (from pose `i - 1` to `i`) by `scale_after[i - 1]`, the estimate in
/// force after the pose before ([`crate::source_corrector::CorrectedPose::odometry_scale`]).
/// The odometry as the corrector moved it: what [`output_jumps`] measures a corrected output's
/// jumps beyond when the corrector estimates the scale ([`crate::scale`]). `raw` itself where
/// every factor is 1.
pub fn scaled_steps(raw: &[Pose3], scale_after: &[f64]) -> Vec<Pose3> {
    let mut odometry = ScaledOdometry::default();
    // The first pose has no step before it; steps past `scale_after` keep their length.
    let factors = std::iter::once(1.0)
        .chain(scale_after.iter().copied())
        .chain(std::iter::repeat(1.0));
    raw.iter()
        .zip(factors)
        .map(|(pose, factor)| {
            odometry.place(pose.planar_position(), factor);
            apply_planar_correction(&odometry.scaled_from_anchored(), pose)
        })
        .collect()
}

/// How many stamps a trajectory has and the time they span (seconds).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampSpan {
    /// Stamps.
    pub count: usize,
    /// The first stamp (seconds).
    pub first_s: f64,
    /// The last stamp (seconds).
    pub last_s: f64,
}

impl StampSpan {
    /// The span of `stamps` (sorted), `None` when there are none.
    pub fn of(stamps: &[f64]) -> Option<StampSpan> {
        Some(StampSpan {
            count: stamps.len(),
            first_s: *stamps.first()?,
            last_s: *stamps.last()?,
        })
    }
}

impl std::fmt::Display for StampSpan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} stamps run from {:.3} to {:.3} s",
            self.count, self.first_s, self.last_s
        )
    }
}

/// Pairs two timestamped trajectories: for each estimate stamp, the ground-truth pose with the
/// nearest stamp if it is within `max_dt` seconds (each ground-truth pose used at most once, as
/// evo's association does). Both stamp lists must be sorted. Returns `(gt index, est index)`;
/// when both have stamps and none pair, [`MetricsError::NoStampPairs`] says where each lies.
pub fn associate_by_time(
    gt_stamps: &[f64],
    est_stamps: &[f64],
    max_dt: f64,
) -> Result<Vec<(usize, usize)>, MetricsError> {
    let mut pairs = Vec::new();
    let mut used = vec![false; gt_stamps.len()];
    for (j, &t) in est_stamps.iter().enumerate() {
        let k = gt_stamps.partition_point(|&g| g < t);
        let best = [k.checked_sub(1), (k < gt_stamps.len()).then_some(k)]
            .into_iter()
            .flatten()
            .filter(|&i| !used[i])
            .min_by(|&a, &b| {
                (gt_stamps[a] - t)
                    .abs()
                    .total_cmp(&(gt_stamps[b] - t).abs())
            });
        if let Some(i) = best.filter(|&i| (gt_stamps[i] - t).abs() <= max_dt) {
            used[i] = true;
            pairs.push((i, j));
        }
    }
    match (
        pairs.is_empty(),
        StampSpan::of(gt_stamps),
        StampSpan::of(est_stamps),
    ) {
        (true, Some(gt), Some(est)) => Err(MetricsError::NoStampPairs {
            max_dt_s: max_dt,
            gt,
            est,
        }),
        _ => Ok(pairs),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f64, y: f64, yaw: f64) -> Pose3 {
        Pose3::planar(x, y, yaw, 5.0)
    }

    #[test]
    fn lateral_error_is_perpendicular_to_the_gt_heading() {
        // Heading east: a 3 m error along x is longitudinal, 4 m along y lateral.
        let gt = [at(0.0, 0.0, 0.0), at(10.0, 0.0, 0.0)];
        let est = [at(3.0, 0.0, 0.0), at(10.0, 4.0, 0.1)];
        let m = ape_2d(&gt, &est).unwrap();
        assert!((m.mean_m - 3.5).abs() < 1e-12);
        assert!((m.rmse_m - (12.5f64).sqrt()).abs() < 1e-12);
        assert!((m.lateral_rmse_m - (8.0f64).sqrt()).abs() < 1e-12);
        assert!((m.heading_mean_deg - 0.05f64.to_degrees()).abs() < 1e-9);
        assert_eq!(m.max_m, 4.0);
    }

    #[test]
    fn mismatched_lengths_are_an_error() {
        assert_eq!(
            ape_2d(&[at(0.0, 0.0, 0.0)], &[]),
            Err(MetricsError::LengthMismatch { gt: 1, est: 0 })
        );
    }

    #[test]
    fn calibration_counts_errors_inside_the_95_ellipse() {
        // sigma 1 m in x, 2 m in y: 2 m in x is inside (NEES 4 < 5.99), 5 m in x outside (25),
        // 4 m in y inside (4).
        let gt = [at(0.0, 0.0, 0.0); 3];
        let est = [at(2.0, 0.0, 0.0), at(5.0, 0.0, 0.0), at(0.0, 4.0, 0.0)];
        let s = [[1.0, 0.0], [0.0, 4.0]];
        let c = calibration(&gt, &est, &[s; 3]).unwrap();
        assert!((c.cov95_coverage - 2.0 / 3.0).abs() < 1e-12);
        assert!((c.nees_mean - (4.0 + 25.0 + 4.0) / 3.0).abs() < 1e-12);
        let singular = [[1.0, 1.0], [1.0, 1.0]];
        assert_eq!(
            calibration(&gt[..1], &est[..1], &[singular]),
            Err(MetricsError::NotPositiveDefinite { index: 0 })
        );
    }

    /// A status CSV's covariance of 1e-300 m^2 across 10 km of error: each NEES is finite, their
    /// sum is not, and `eval` printed a mean NEES of inf.
    #[test]
    fn a_covariance_too_small_for_its_error_is_refused() {
        let gt = [at(0.0, 0.0, 0.0); 3];
        let est = [at(1e4, 0.0, 0.0); 3];
        let tiny = [[1e-300, 0.0], [0.0, 1e290]];
        assert_eq!(
            calibration(&gt, &est, &[tiny; 3]),
            Err(MetricsError::NeesOverflow { index: 1 })
        );
        let c = calibration(&gt[..1], &est[..1], &[tiny]).unwrap();
        assert!(c.nees_mean.is_finite() && c.independent_samples.is_finite());
    }

    /// White noise is as many samples as it has; an AR(1) series of coefficient `phi` has the
    /// integrated time `(1 + phi) / (1 - phi)` (19 for 0.9). Fixed seed, 100 000 samples.
    #[test]
    fn correlated_errors_count_as_fewer_samples() {
        let mut rng = Lcg(0x9e37_79b9_7f4a_7c15);
        let mut ar1 = |phi: f64| {
            let q = (1.0 - phi * phi).sqrt();
            let mut x = [0.0, 0.0];
            (0..100_000)
                .map(|_| {
                    x = [phi * x[0] + q * rng.normal(), phi * x[1] + q * rng.normal()];
                    x
                })
                .collect::<Vec<_>>()
        };
        let white = integrated_autocorrelation_time(&ar1(0.0));
        assert!((0.9..1.1).contains(&white), "{white}");
        let correlated = integrated_autocorrelation_time(&ar1(0.9));
        assert!((16.0..22.0).contains(&correlated), "{correlated}");
        // An offset shared by every sample is one error, however many samples carry it.
        let offset = integrated_autocorrelation_time(&[[0.3, -0.2]; 100]);
        assert_eq!(offset, 100.0);
        // The same beyond the direct sums, through the FFT.
        let long = integrated_autocorrelation_time(&vec![[0.3, -0.2]; 30_000]);
        assert!((long - 30_000.0).abs() < 1e-6, "{long}");
        assert_eq!(integrated_autocorrelation_time(&[[0.0, 0.0]; 10]), 1.0);
    }

    /// Errors drawn from the covariance they are published with are judged consistent; with a
    /// covariance of half their variance, too confident; of twice, too cautious. The errors are
    /// an AR(1) series (coefficient 0.9: about 160 independent errors in 3000 poses), fixed
    /// seed.
    #[test]
    fn the_verdict_tells_an_exact_covariance_from_wrong_ones() {
        let mut rng = Lcg(7);
        let (phi, q) = (0.9, (1.0f64 - 0.81).sqrt());
        let mut x = [rng.normal(), rng.normal()];
        let est: Vec<Pose3> = (0..3000)
            .map(|i| {
                if i > 0 {
                    x = [phi * x[0] + q * rng.normal(), phi * x[1] + q * rng.normal()];
                }
                at(x[0], x[1], 0.0)
            })
            .collect();
        let gt = vec![at(0.0, 0.0, 0.0); est.len()];
        let judged = |variance: f64| {
            let check = calibration(&gt, &est, &vec![[[variance, 0.0], [0.0, variance]]; 3000])
                .unwrap()
                .check();
            let c = check.calibration;
            let [lo, hi] = check.if_exact.nees_mean;
            assert!(lo < 2.0 && 2.0 < hi && hi - lo < 1.0, "{check:?}");
            assert!((100.0..250.0).contains(&c.independent_samples), "{c:?}");
            check.verdict
        };
        assert_eq!(judged(1.0), Verdict::Consistent);
        assert_eq!(judged(0.5), Verdict::TooConfident);
        assert_eq!(judged(2.0), Verdict::TooCautious);
    }

    /// The range an exact covariance shows is about 0.95 and 2 and narrows with more
    /// independent errors: over 500 of them the coverage's binomial spread (95 %: +-0.019)
    /// and the mean NEES's (+-0.18), over three most of the unit interval's top.
    #[test]
    fn the_exact_range_narrows_with_independent_errors() {
        let of = |independent_samples: f64| {
            Calibration {
                cov95_coverage: 0.95,
                nees_mean: 2.0,
                independent_samples,
                poses: 5000,
            }
            .if_exact()
        };
        let many = of(500.0);
        let [lo, hi] = many.cov95_coverage;
        assert!(
            (0.927..0.935).contains(&lo) && (0.965..0.973).contains(&hi),
            "{many:?}"
        );
        let [lo, hi] = many.nees_mean;
        assert!(
            (1.80..1.85).contains(&lo) && (2.16..2.20).contains(&hi),
            "{many:?}"
        );
        // Beyond the simulated, the normal approximation, which meets the simulation there.
        let beyond = of(500.5);
        for k in 0..2 {
            let ([a, b], [c, d]) = if k == 0 {
                (many.cov95_coverage, beyond.cov95_coverage)
            } else {
                (many.nees_mean, beyond.nees_mean)
            };
            assert!(
                (a - c).abs() < 0.004 && (b - d).abs() < 0.01,
                "{many:?} {beyond:?}"
            );
        }
        let white_million = of(1e6);
        assert!(
            (white_million.nees_mean[1] - 2.0039).abs() < 1e-4,
            "{white_million:?}"
        );
        let few = of(3.0);
        assert!(
            few.cov95_coverage[0] < 0.85 && few.cov95_coverage[1] == 1.0,
            "{few:?}"
        );
        assert!(few.nees_mean[0] < 1.2 && few.nees_mean[1] > 3.0, "{few:?}");
    }

    /// The lag sums through the FFT equal the direct sums, on a correlated series of a length
    /// that is no power of two.
    #[test]
    fn lag_sums_equal_the_direct_sums() {
        let mut rng = Lcg(11);
        let mut v = 0.0;
        let x: Vec<f64> = (0..1237)
            .map(|_| {
                v = 0.95 * v + rng.normal();
                v
            })
            .collect();
        let fast = lag_sums(&x);
        assert_eq!(fast.len(), x.len());
        for (k, sum) in fast.iter().enumerate() {
            let direct: f64 = x[k..].iter().zip(&x).map(|(a, b)| a * b).sum();
            assert!(
                (sum - direct).abs() <= 1e-9 * fast[0],
                "lag {k}: {sum} against {direct}"
            );
        }
        assert!(lag_sums(&[]).is_empty());
    }

    #[test]
    fn association_pairs_nearest_stamps_once() {
        let pairs = associate_by_time(&[0.0, 0.1, 0.2, 0.3], &[0.09, 0.11, 0.31, 0.5], 0.02);
        assert_eq!(pairs, Ok(vec![(1, 0), (3, 2)]));
    }

    #[test]
    fn stamps_that_pair_nowhere_are_told_where_each_lies() {
        let gt = [100.0, 100.1, 100.2];
        let late = [100.05, 100.15];
        let e = associate_by_time(&gt, &late, 0.01).unwrap_err();
        assert_eq!(
            e.to_string(),
            "no estimate stamp lies within 0.01 s of a ground-truth stamp: the ground truth's 3 \
             stamps run from 100.000 to 100.200 s, the estimate's 2 stamps run from 100.050 to \
             100.150 s (a clock offset between them, or stamps of another time base?)"
        );
        assert_eq!(associate_by_time(&gt, &late, 0.05).map(|p| p.len()), Ok(2));
        assert_eq!(associate_by_time(&gt, &[], 0.01), Ok(vec![]));
    }
}
