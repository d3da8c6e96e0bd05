//! `lanealign eval`: APE-2D of an estimate against ground truth, without alignment.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;
use lanealign_cli::{evaluation, plots, status_file};
use lanealign_core::input;
use lanealign_core::metrics::{ape_2d, calibration};
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
    /// How TUM files' poses pair.
    #[command(flatten)]
    pairing: evaluation::PairingArgs,
}

/// Runs `lanealign eval`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    input::check_outputs_apart(
        &[args.plot.as_deref()],
        &[Some(&args.gt), Some(&args.est), args.status.as_deref()],
    )?;
    let pairing = args.pairing.pairing(args.format)?;
    let gt = trajectory::read(&args.gt, args.format)?;
    let est = trajectory::read(&args.est, args.format)?;
    let paired = evaluation::pair(&gt, &est, args.frame, pairing)
        .map_err(evaluation::with_pairing_advice)?;
    let (g, e, pairs) = (&paired.gt, &paired.est, &paired.pairs);
    if pairs.len() < est.poses.len() {
        // Paired by time, the figures leave out the estimate's poses without ground truth.
        eprintln!(
            "{} of the estimate's {} poses paired with a ground-truth pose within {} s: the \
             figures are over those",
            pairs.len(),
            est.poses.len(),
            pairing.max_dt_s,
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
