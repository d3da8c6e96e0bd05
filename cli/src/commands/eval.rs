//! `lanealign eval`: APE-2D of an estimate against ground truth, without alignment.

use std::path::PathBuf;

use anyhow::{anyhow, bail, Context};
use clap::Args;
use lanealign_cli::{evaluation, plots, status_file};
use lanealign_core::input;
use lanealign_core::metrics::{ape_2d, calibration, MetricsError};
use lanealign_core::pose::AxisConvention;
use lanealign_core::trajectory::{self, Format};

/// The `lanealign eval` arguments.
#[derive(Args)]
pub struct EvalArgs {
    /// Ground-truth trajectory.
    #[arg(long)]
    gt: PathBuf,
    /// Estimated trajectory.
    #[arg(long)]
    est: PathBuf,
    /// Axis convention of both files: flu or kitti-camera.
    #[arg(long, default_value = "flu")]
    frame: AxisConvention,
    /// File format of both: kitti (paired by index) or tum (paired by timestamp).
    #[arg(long, default_value = "kitti")]
    format: Format,
    /// The status CSV written with the estimate (`correct --status`, `replay --status`): also
    /// report how well its covariances describe the errors (`cov95_coverage`, `nees_mean`,
    /// `independent_samples`), what a covariance describing them exactly would show over as
    /// many independent errors (`cov95_coverage_if_exact`, `nees_mean_if_exact`: 2.5th and
    /// 97.5th percentiles) and the verdict (`calibration_verdict`: consistent, too confident or
    /// too cautious).
    #[arg(long)]
    status: Option<PathBuf>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Also draw the position error over the distance driven into this SVG file.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// With --format tum: the largest difference (seconds) between the stamps of a ground-truth
    /// and an estimated pose that pair (as evo's --t_max_diff) [default: 0.01].
    #[arg(long, value_parser = max_dt_s)]
    max_dt: Option<f64>,
    /// With --format tum: seconds added to the estimate's stamps before pairing, for clocks
    /// apart by a known offset (as evo's --t_offset).
    #[arg(long, value_parser = t_offset_s, allow_negative_numbers = true)]
    t_offset: Option<f64>,
}

/// Largest `--t-offset` (seconds, either way): 300 years, more than between any two time bases
/// a pose file's stamps are in (Unix seconds are 1.7e9 today).
const MAX_T_OFFSET_S: f64 = 1e10;

/// `--max-dt`: a number of seconds [`evaluation::checked_max_dt_s`] takes.
fn max_dt_s(text: &str) -> Result<f64, String> {
    evaluation::checked_max_dt_s(text.parse::<f64>().unwrap_or(f64::NAN))
}

/// `--t-offset`: a number of seconds, at most [`MAX_T_OFFSET_S`] either way.
fn t_offset_s(text: &str) -> Result<f64, String> {
    text.parse::<f64>()
        .ok()
        .filter(|t| t.abs() <= MAX_T_OFFSET_S)
        .ok_or_else(|| {
            format!("must be a number of seconds from -{MAX_T_OFFSET_S} to {MAX_T_OFFSET_S}")
        })
}

/// Runs `lanealign eval`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    input::check_outputs_apart(
        &[args.plot.as_deref()],
        &[Some(&args.gt), Some(&args.est), args.status.as_deref()],
    )?;
    if args.format != Format::Tum && (args.max_dt.is_some() || args.t_offset.is_some()) {
        bail!("--max-dt and --t-offset pair poses by their stamps: only with --format tum");
    }
    let max_dt_s = args.max_dt.unwrap_or(evaluation::DEFAULT_MAX_DT_S);
    let gt = trajectory::read(&args.gt, args.format)?;
    let mut est = trajectory::read(&args.est, args.format)?;
    if let (Some(stamps), Some(offset)) = (&mut est.stamps, args.t_offset) {
        stamps.iter_mut().for_each(|t| *t += offset);
    }
    let paired = evaluation::pair(&gt, &est, args.frame, max_dt_s).map_err(|e| match e {
        MetricsError::NoStampPairs { .. } => {
            anyhow!("{e}; --t-offset shifts the estimate's stamps, --max-dt widens the tolerance")
        }
        e => e.into(),
    })?;
    let (g, e, pairs) = (&paired.gt, &paired.est, &paired.pairs);
    if pairs.len() < est.poses.len() {
        // Paired by time, the figures leave out the estimate's poses without ground truth.
        eprintln!(
            "{} of the estimate's {} poses paired with a ground-truth pose within {max_dt_s} s: \
             the figures are over those",
            pairs.len(),
            est.poses.len(),
        );
    }
    let m = ape_2d(g, e)?;
    let calibration = match &args.status {
        None => None,
        Some(path) => {
            let all = status_file::read_position_covariances(path)?;
            if all.len() != est.poses.len() {
                bail!(
                    "{} has {} rows and {} {} poses: they were not written together",
                    path.display(),
                    all.len(),
                    args.est.display(),
                    est.poses.len()
                );
            }
            let cov: Vec<[[f64; 2]; 2]> = pairs.iter().map(|p| all[p.1]).collect();
            Some(
                calibration(g, e, &cov)
                    .with_context(|| path.display().to_string())?
                    .check(),
            )
        }
    };
    if let Some(path) = &args.plot {
        plots::error_over_distance(
            path,
            "Position error over distance (APE-2D, no alignment)",
            &paired.distance_m(),
            &[("estimate", &paired.errors_m(), plots::CORRECTED)],
        )?;
    }
    if args.json {
        println!("{}", evaluation::figures_json(&m, calibration.as_ref())?);
    } else {
        println!("APE-2D mean      {:.6} m", m.mean_m);
        println!("RMSE             {:.6} m", m.rmse_m);
        println!("lateral RMSE     {:.6} m", m.lateral_rmse_m);
        println!("heading mean     {:.6} deg", m.heading_mean_deg);
        println!("max              {:.6} m", m.max_m);
        println!("poses            {}", m.poses);
        if let Some(check) = calibration {
            let (c, exact) = (check.calibration, check.if_exact);
            println!(
                "cov95 coverage   {:.6}  (an exact covariance: {:.3}-{:.3})",
                c.cov95_coverage, exact.cov95_coverage[0], exact.cov95_coverage[1]
            );
            println!(
                "NEES mean        {:.6}  (an exact covariance: {:.2}-{:.2})",
                c.nees_mean, exact.nees_mean[0], exact.nees_mean[1]
            );
            println!("independent      {:.1} samples", c.independent_samples);
            println!("calibration      {}", check.verdict);
        }
    }
    Ok(())
}
