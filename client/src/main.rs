//! `lanealign`: correct a recorded odometry run against lanes, evaluate trajectories, and talk
//! to `lanealignd` (replay, soak, demo).

mod cli;

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::{Args, Parser, Subcommand};
use std::time::Duration;

use lanealign_client::connection::Connection;
use lanealign_client::maps::MapSource;
use lanealign_client::replay::{replay, Rate};
use lanealign_client::wire::{pose_from_wire, WireStatus};
use lanealign_core::corrector::{MatchMode, Status};
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::metrics::{ape_2d, associate_by_time};
use lanealign_core::offline::{correct, CorrectedPose, Source};
use lanealign_core::params::{Method, Params, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::smoothing::Smoothing;
use lanealign_core::trajectory::{self, Format, Trajectory};
use lanealign_map::compile::InputReport;
use lanealign_map::osm_lanes::{LaneOptions, Traffic};

#[derive(Parser)]
#[command(
    name = "lanealign",
    version,
    about = "Odometry drift correction against OpenStreetMap lanes"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Correct a recorded trajectory offline.
    Correct(CorrectArgs),
    /// APE-2D of an estimate against ground truth (no alignment).
    Eval(EvalArgs),
    /// Stream a trajectory through a running lanealignd and write the corrected one.
    Replay(ReplayArgs),
    /// Many sources through one daemon: latency and loss, corrected and pass-through.
    Soak {
        /// Number of sources.
        #[arg(long, default_value_t = 8)]
        sources: usize,
        /// Poses per second per source.
        #[arg(long, default_value_t = 100.0)]
        rate: f64,
        /// Seconds per mode.
        #[arg(long, default_value_t = 10.0)]
        duration: f64,
    },
    /// Compile a map, start lanealignd, replay an odometry run through it, print the result.
    Demo,
}

#[derive(Args)]
struct ReplayArgs {
    /// The source name configured in lanealignd.
    #[arg(long)]
    source: String,
    /// Poses per second, or max (flow-controlled, 64 in flight).
    #[arg(long, default_value = "max")]
    rate: Rate,
    /// File format: kitti or tum.
    #[arg(long, default_value = "kitti")]
    format: Format,
    /// Sequence number of the first pose (a restarted replay can continue where it stopped).
    #[arg(long, default_value_t = 1)]
    first_seq: u64,
    /// The trajectory to stream (in the source's axis convention).
    input: PathBuf,
    /// Where to write the corrected trajectory.
    #[arg(short, long)]
    output: PathBuf,
}

#[derive(Args)]
struct MapArgs {
    /// Raw OSM or Lanelet2 road data (.osm, .osm.pbf) to derive lanes from (needs --anchor).
    #[arg(long, conflicts_with_all = ["lanes", "map"], required_unless_present_any = ["lanes", "map"])]
    osm: Option<PathBuf>,
    /// A lane tile compiled by `lanealign-map compile` (needs --anchor).
    #[arg(long, conflicts_with = "lanes")]
    map: Option<PathBuf>,
    /// Lane polylines (`lane_id,x,y`) already in the source's planar odometry frame.
    #[arg(long)]
    lanes: Option<PathBuf>,
    /// Where the odometry frame lies: LAT,LON,YAW_DEG[,EAST_M,NORTH_M] (yaw from East, CCW).
    #[arg(long, allow_hyphen_values = true)]
    anchor: Option<Anchor>,
    /// The projection the anchor was measured in: tangent (true scale) or kitti (spherical).
    #[arg(long, default_value = "tangent")]
    projection: Projection,
    /// Traffic side for lanes derived from OSM: right or left.
    #[arg(long, default_value = "right")]
    traffic: Traffic,
    /// Minimum spacing of derived lane points (metres).
    #[arg(long, default_value_t = 3.0)]
    spacing: f64,
    /// Lanes of unmarked two-way streets (residential, unclassified, living_street without a
    /// lanes tag) at this fraction of their nominal offset from the way line. Default: 0.5 with
    /// the robust method, 1 (the paper's lane geometry) with `--method paper`.
    #[arg(long)]
    unmarked_offset_scale: Option<f64>,
}

impl MapArgs {
    /// The map source; lanes derived from OSM follow `method`'s lane geometry unless
    /// `--unmarked-offset-scale` says otherwise.
    fn source(&self, method: Method) -> anyhow::Result<MapSource> {
        if let Some(path) = &self.lanes {
            return Ok(MapSource::LanesCsv(path.clone()));
        }
        let Some(path) = &self.osm else {
            bail!("give --osm or --lanes")
        };
        let Some(anchor) = self.anchor else {
            bail!("--osm needs --anchor LAT,LON,YAW_DEG[,EAST_M,NORTH_M]")
        };
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            bail!("--spacing must be a positive number of metres");
        }
        let lanes = LaneOptions::for_method(method);
        let unmarked_offset_scale = self
            .unmarked_offset_scale
            .unwrap_or(lanes.unmarked_offset_scale);
        if !(0.0..=2.0).contains(&unmarked_offset_scale) {
            bail!("--unmarked-offset-scale must be between 0 and 2");
        }
        Ok(MapSource::Osm {
            path: path.clone(),
            anchor,
            projection: self.projection,
            options: LaneOptions {
                traffic: self.traffic,
                spacing_m: self.spacing,
                unmarked_offset_scale,
                ..lanes
            },
        })
    }
}

#[derive(Args)]
struct CorrectArgs {
    #[command(flatten)]
    map: MapArgs,
    /// Parameter preset: liodom, basalt, kiss-icp or orb-slam3.
    #[arg(long)]
    preset: Preset,
    /// Override a parameter: --set key=value (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Axis convention of the poses: flu or kitti-camera.
    #[arg(long, default_value = "flu")]
    frame: AxisConvention,
    /// File format: kitti or tum.
    #[arg(long, default_value = "kitti")]
    format: Format,
    /// The correction method: `robust` (lanealign's, docs/method.md) or `paper` (the published
    /// algorithm, SPEC sections 2-3).
    #[arg(long, default_value = "robust")]
    method: Method,
    /// Smooth the output: each correction is spread over the following poses (at most 5 cm and
    /// 0.1 degree per pose beyond the odometry's own motion). The status file's
    /// `map_from_odom` stays the exact estimate.
    #[arg(long)]
    smooth: bool,
    /// Lane matching: fast (exact, incremental) or reference (SPEC section 2 literally).
    #[arg(long, default_value = "fast")]
    match_mode: MatchMode,
    /// The odometry trajectory to correct.
    input: PathBuf,
    /// Where to write the corrected trajectory (same format and convention).
    #[arg(short, long)]
    output: PathBuf,
    /// Also write a CSV of what happened at each pose.
    #[arg(long)]
    status: Option<PathBuf>,
}

#[derive(Args)]
struct EvalArgs {
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

fn write_status(path: &Path, run: &[CorrectedPose]) -> anyhow::Result<()> {
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    writeln!(out, "index,status,reason,residual_m,match_ratio,window_len,map_from_odom_x,map_from_odom_y,map_from_odom_yaw")?;
    for (i, c) in run.iter().enumerate() {
        let (reason, e, ratio, len) = match c.status {
            Status::WarmingUp { window_len } => ("", f64::NAN, f64::NAN, window_len),
            Status::Accepted {
                residual_m,
                match_ratio,
                window_len,
            } => ("", residual_m, match_ratio, window_len),
            Status::Rejected {
                reason,
                residual_m,
                match_ratio,
                window_len,
            }
            | Status::Reset {
                reason,
                residual_m,
                match_ratio,
                window_len,
            } => (reason.name(), residual_m, match_ratio, window_len),
            Status::InvalidInput => ("", f64::NAN, f64::NAN, 0),
        };
        let [x, y] = c.map_from_odom.translation();
        writeln!(
            out,
            "{i},{},{reason},{e},{ratio},{len},{x},{y},{}",
            c.status.name(),
            c.map_from_odom.yaw()
        )?;
    }
    out.flush()?;
    Ok(())
}

fn run_correct(args: &CorrectArgs) -> anyhow::Result<()> {
    let mut params: Params = args.method.params(args.preset);
    for pair in &args.overrides {
        params.set_pair(pair)?;
    }
    let input = trajectory::read(&args.input, args.format)?;
    if input.poses.is_empty() {
        bail!("{}: no poses", args.input.display());
    }
    let loaded = args.map.source(args.method)?.load()?;
    if let Some(InputReport::Osm(r)) = &loaded.report {
        if r.missing_node_refs > 0 || r.ways_without_geometry > 0 {
            eprintln!(
                "warning: {} node references missing, {} drivable ways without geometry (skipped)",
                r.missing_node_refs, r.ways_without_geometry
            );
        }
    }
    let source = Source {
        convention: args.frame,
        plane_from_odom: loaded.plane_from_odom,
        smoothing: args.smooth.then(Smoothing::default),
    };
    let run = correct(loaded.map, params, args.match_mode, source, &input.poses);
    let output = Trajectory {
        stamps: input.stamps.clone(),
        poses: run.iter().map(|c| c.pose).collect(),
    };
    trajectory::write(&args.output, &output, args.format)?;
    if let Some(path) = &args.status {
        write_status(path, &run)?;
    }
    let (attempts, accepted, resets) = lanealign_core::offline::counts(&run);
    eprintln!(
        "{} poses, method {}: {attempts} match attempts, {accepted} accepted, {resets} resets",
        run.len(),
        args.method.name()
    );
    Ok(())
}

fn run_eval(args: &EvalArgs) -> anyhow::Result<()> {
    let gt = trajectory::read(&args.gt, args.format)?;
    let est = trajectory::read(&args.est, args.format)?;
    let planar = |t: &Trajectory, idx: &[usize]| -> Vec<_> {
        idx.iter()
            .map(|&i| args.frame.to_planar(&t.poses[i]))
            .collect()
    };
    let (g, e) = match (&gt.stamps, &est.stamps) {
        (Some(ts_gt), Some(ts_est)) => {
            let pairs = associate_by_time(ts_gt, ts_est, 0.01);
            let gi: Vec<usize> = pairs.iter().map(|p| p.0).collect();
            let ei: Vec<usize> = pairs.iter().map(|p| p.1).collect();
            (planar(&gt, &gi), planar(&est, &ei))
        }
        _ => {
            let all_g: Vec<usize> = (0..gt.poses.len()).collect();
            let all_e: Vec<usize> = (0..est.poses.len()).collect();
            (planar(&gt, &all_g), planar(&est, &all_e))
        }
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

fn run_replay(args: &ReplayArgs) -> anyhow::Result<()> {
    let input = trajectory::read(&args.input, args.format)?;
    let stamps: Vec<i64> = input
        .stamps
        .as_ref()
        .map(|s| s.iter().map(|t| (t * 1e9).round() as i64).collect())
        .unwrap_or_default();
    let conn = Connection::connect(&args.source)?;
    let result = replay(
        &conn,
        &args.source,
        &input.poses,
        &stamps,
        args.first_seq,
        args.rate,
        Duration::from_secs(10),
    )?;
    let output = Trajectory {
        stamps: input.stamps.clone(),
        poses: result
            .answers
            .iter()
            .map(|a| pose_from_wire(&a.pose))
            .collect(),
    };
    trajectory::write(&args.output, &output, args.format)?;
    let mut rt = result.round_trip_ns.clone();
    rt.sort_unstable();
    let accepted = result
        .answers
        .iter()
        .filter(|a| a.status == WireStatus::Accepted as u32)
        .count();
    eprintln!(
        "{} poses replayed, all answered, {accepted} accepted; round trip p50 {:.1} us, p99 {:.1} us, max {:.1} us",
        result.answers.len(),
        cli::percentile_us(&rt, 0.5),
        cli::percentile_us(&rt, 0.99),
        cli::percentile_us(&rt, 1.0)
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    // iceoryx2 warns on stdout when it runs on its default configuration, which is intended here.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    match &cli.command {
        Command::Correct(args) => run_correct(args),
        Command::Eval(args) => run_eval(args),
        Command::Replay(args) => run_replay(args),
        Command::Soak {
            sources,
            rate,
            duration,
        } => cli::soak::run(*sources, *rate, *duration),
        Command::Demo => cli::demo::run(),
    }
}
