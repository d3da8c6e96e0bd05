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
    /// `independent_samples`).
    #[arg(long)]
    status: Option<PathBuf>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Also draw the position error over the distance driven into this SVG file.
    #[arg(long)]
    plot: Option<PathBuf>,
}

/// Runs `lanealign eval`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    input::check_outputs_apart(
        &[args.plot.as_deref()],
        &[Some(&args.gt), Some(&args.est), args.status.as_deref()],
    )?;
    let gt = trajectory::read(&args.gt, args.format)?;
    let est = trajectory::read(&args.est, args.format)?;
    let paired = evaluation::pair(&gt, &est, args.frame)?;
    let (g, e, pairs) = (&paired.gt, &paired.est, &paired.pairs);
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
            Some(calibration(g, e, &cov).with_context(|| path.display().to_string())?)
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
        let mut json = serde_json::to_value(m)?;
        if let Some(c) = calibration {
            json["cov95_coverage"] = c.cov95_coverage.into();
            json["nees_mean"] = c.nees_mean.into();
            json["independent_samples"] = c.independent_samples.into();
        }
        println!("{json}");
    } else {
        println!("APE-2D mean      {:.6} m", m.mean_m);
        println!("RMSE             {:.6} m", m.rmse_m);
        println!("lateral RMSE     {:.6} m", m.lateral_rmse_m);
        println!("heading mean     {:.6} deg", m.heading_mean_deg);
        println!("max              {:.6} m", m.max_m);
        println!("poses            {}", m.poses);
        if let Some(c) = calibration {
            println!("cov95 coverage   {:.6}", c.cov95_coverage);
            println!("NEES mean        {:.6}", c.nees_mean);
            println!("independent      {:.1} samples", c.independent_samples);
        }
    }
    Ok(())
}
