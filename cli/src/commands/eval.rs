//! `lanealign eval`: APE-2D of an estimate against ground truth, without alignment.

use std::path::PathBuf;

use clap::Args;
use lanealign_core::metrics::{ape_2d, associate_by_time};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::trajectory::{self, Format, Trajectory};

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
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

/// Runs `lanealign eval`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let gt = trajectory::read(&args.gt, args.format)?;
    let est = trajectory::read(&args.est, args.format)?;
    let planar = |t: &Trajectory, idx: &mut dyn Iterator<Item = usize>| -> Vec<Pose3> {
        idx.map(|i| args.frame.to_planar(&t.poses[i])).collect()
    };
    let (g, e) = match (&gt.stamps, &est.stamps) {
        (Some(ts_gt), Some(ts_est)) => {
            let pairs = associate_by_time(ts_gt, ts_est, 0.01);
            (
                planar(&gt, &mut pairs.iter().map(|p| p.0)),
                planar(&est, &mut pairs.iter().map(|p| p.1)),
            )
        }
        _ => (
            planar(&gt, &mut (0..gt.poses.len())),
            planar(&est, &mut (0..est.poses.len())),
        ),
    };
    let m = ape_2d(&g, &e)?;
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "ape2d_mean_m": m.mean_m,
                "rmse_m": m.rmse_m,
                "lateral_rmse_m": m.lateral_rmse_m,
                "heading_mean_deg": m.heading_mean_deg,
                "max_m": m.max_m,
                "poses": m.poses,
            })
        );
    } else {
        println!("APE-2D mean      {:.6} m", m.mean_m);
        println!("RMSE             {:.6} m", m.rmse_m);
        println!("lateral RMSE     {:.6} m", m.lateral_rmse_m);
        println!("heading mean     {:.6} deg", m.heading_mean_deg);
        println!("max              {:.6} m", m.max_m);
        println!("poses            {}", m.poses);
    }
    Ok(())
}
