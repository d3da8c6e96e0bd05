//! `lanealign correct`: corrects a recorded trajectory offline, exactly as the daemon would.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{anyhow, bail, Context};
use clap::Args;
use lanealign_cli::evaluation::{self, Pairing};
use lanealign_cli::maps::MapSource;
use lanealign_cli::{plots, report, results, status_file};
use lanealign_core::corrector::{MatchMode, Status};
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::grid::{Grid, LoadPolicy};
use lanealign_core::input;
use lanealign_core::lane_geometry::{RoadClasses, Traffic};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::{ape_2d, calibration};
use lanealign_core::params::{CorrectorConfig, Method, Overrides, Params, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{counts, CorrectedPose, Placement};
use lanealign_core::trajectory::{self, Format, Trajectory};
use lanealign_map::compile::InputReport;
use lanealign_map::osm_lanes::LaneOptions;
use serde::Serialize;

use super::params::AtRate;

/// Where the lanes come from and where the odometry lies on them.
#[derive(Args)]
pub struct MapArgs {
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
    /// Default tangent for --osm; for --map, the tile's (a different one is an error).
    #[arg(long)]
    projection: Option<Projection>,
    /// Traffic side for lanes derived from OSM: right or left.
    #[arg(long, default_value = "right")]
    traffic: Traffic,
    /// Minimum spacing of derived lane points (metres).
    #[arg(long, default_value_t = 3.0)]
    spacing: f64,
}

/// What the corrector does.
#[derive(Args, Clone)]
pub struct CorrectorArgs {
    /// Parameter preset: liodom, basalt, kiss-icp or orb-slam3.
    #[arg(long)]
    preset: Preset,
    /// The correction method: `robust` (lanealign's, docs/method.md) or `paper` (the published
    /// algorithm, docs/algorithm.md).
    #[arg(long, default_value = "robust")]
    method: Method,
    /// Lane matching: fast (exact, incremental) or reference (the algorithm literally); both
    /// give identical corrections.
    #[arg(long, default_value = "fast")]
    match_mode: MatchMode,
    /// Smooth the output: each correction is spread over the following poses (at most 5 cm and
    /// 0.1 degree per pose beyond the odometry's own motion). The status file's
    /// `map_from_odom` stays the exact estimate.
    #[arg(long)]
    smooth: bool,
    /// Override a parameter: --set key=value (repeatable; `lanealign params` lists them).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Lanes of unmarked two-way streets (residential, unclassified, living_street without a
    /// lanes tag) at this fraction of their nominal offset from the way line. Default: the
    /// method's (0.5 robust, 1 paper). With --map, the tile must have been compiled with it.
    #[arg(long)]
    unmarked_offset_scale: Option<f64>,
}

/// Parses `--set key=value` pairs into typed overrides: unknown keys, bad values and repeated
/// keys are refused with the parser's message.
pub fn parse_overrides(pairs: &[String]) -> anyhow::Result<Overrides> {
    let assignments = pairs
        .iter()
        .map(|pair| {
            pair.split_once('=')
                .ok_or_else(|| anyhow!("--set '{pair}': expected KEY=VALUE"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Overrides::from_assignments(assignments).map_err(|e| anyhow!("--set: {e}"))
}

impl CorrectorArgs {
    /// The corrector configuration these flags describe, validated.
    pub fn config(&self) -> anyhow::Result<CorrectorConfig> {
        let config = CorrectorConfig {
            preset: self.preset,
            method: self.method,
            match_mode: self.match_mode,
            smooth: self.smooth,
            unmarked_offset_scale: self.unmarked_offset_scale,
            overrides: parse_overrides(&self.overrides)?,
        };
        config.params()?;
        Ok(config)
    }
}

impl MapArgs {
    /// The map source; lanes derived from OSM follow `config`'s lane geometry.
    fn source(&self, config: &CorrectorConfig) -> anyhow::Result<MapSource> {
        if let Some(path) = &self.lanes {
            return Ok(MapSource::LanesCsv(path.clone()));
        }
        let Some(anchor) = self.anchor else {
            bail!("--osm and --map need --anchor LAT,LON,YAW_DEG[,EAST_M,NORTH_M]")
        };
        if let Some(path) = &self.map {
            return Ok(MapSource::Tile {
                path: path.clone(),
                anchor,
                projection: self.projection,
            });
        }
        let Some(path) = &self.osm else {
            bail!("give --osm, --map or --lanes")
        };
        lanealign_core::lane_map::check_spacing(self.spacing)
            .map_err(|e| anyhow!("--spacing: {e}"))?;
        Ok(MapSource::Osm {
            path: path.clone(),
            anchor,
            projection: self.projection.unwrap_or_default(),
            options: LaneOptions {
                classes: RoadClasses::DEFAULT,
                traffic: self.traffic,
                spacing_m: self.spacing,
                unmarked_offset_scale: config.unmarked_offset_scale(),
            },
        })
    }
}

/// The `lanealign correct` arguments.
#[derive(Args)]
pub struct CorrectArgs {
    #[command(flatten)]
    map: MapArgs,
    #[command(flatten)]
    corrector: CorrectorArgs,
    /// Axis convention of the poses: flu or kitti-camera.
    #[arg(long, default_value = "flu")]
    frame: AxisConvention,
    /// File format: kitti or tum.
    #[arg(long, default_value = "kitti")]
    format: Format,
    /// The odometry trajectory to correct.
    input: PathBuf,
    /// Where to write the corrected trajectory (same format and convention).
    #[arg(short, long, required_unless_present = "results")]
    output: Option<PathBuf>,
    /// Also write a CSV of what happened at each pose (beside `--output`).
    #[arg(long, requires = "output")]
    status: Option<PathBuf>,
    /// Also write a results folder below this one (`<UTC time>/`, with `latest` pointing at it):
    /// the corrected trajectory, the status CSV and `params.toml` (every effective parameter, the
    /// map and the anchor); with `--gt`, `metrics.json` and SVG plots.
    #[arg(long)]
    results: Option<PathBuf>,
    /// Ground truth (same format and convention as the input) for the results folder's metrics
    /// and plots.
    #[arg(long, requires = "results")]
    gt: Option<PathBuf>,
    /// How the ground truth's poses pair with TUM input's.
    #[command(flatten)]
    pairing: evaluation::PairingArgs,
}

/// What `params.toml` of a results folder holds: the run, then the effective configuration.
#[derive(Serialize)]
struct ParamsFile<'a> {
    unmarked_offset_scale: f64,
    run: RunRecord<'a>,
    corrector: CorrectorConfig,
    params: Params,
    at_rate: AtRate,
}

/// The input and the map of a run.
#[derive(Serialize)]
struct RunRecord<'a> {
    input: &'a Path,
    frame: AxisConvention,
    format: &'static str,
    map: &'static str,
    map_path: &'a Path,
    #[serde(skip_serializing_if = "Option::is_none")]
    anchor: Option<Anchor>,
    #[serde(skip_serializing_if = "Option::is_none")]
    projection: Option<Projection>,
}

impl<'a> RunRecord<'a> {
    fn new(args: &'a CorrectArgs, source: &'a MapSource) -> Self {
        let (map, map_path, anchor, projection) = match source {
            MapSource::Osm {
                path,
                anchor,
                projection,
                ..
            } => ("osm", path.as_path(), Some(*anchor), Some(*projection)),
            MapSource::Tile {
                path,
                anchor,
                projection,
            } => ("tile", path.as_path(), Some(*anchor), *projection),
            MapSource::LanesCsv(path) => ("lanes-csv", path.as_path(), None, None),
        };
        RunRecord {
            input: &args.input,
            frame: args.frame,
            format: args.format.name(),
            map,
            map_path,
            anchor,
            projection,
        }
    }
}

/// Runs `lanealign correct`.
pub fn run(args: &CorrectArgs) -> anyhow::Result<()> {
    input::check_outputs_apart(
        &[args.output.as_deref(), args.status.as_deref()],
        &[
            Some(&args.input),
            args.gt.as_deref(),
            args.map.osm.as_deref(),
            args.map.map.as_deref(),
            args.map.lanes.as_deref(),
        ],
    )?;
    if let Some(parent) = &args.results {
        results::check_parent(parent)?;
    }
    let config = args.corrector.config()?;
    let params = config.params()?;
    let input = trajectory::read(&args.input, args.format)?;
    if input.poses.is_empty() {
        bail!("{}: no poses", args.input.display());
    }
    // Checked before anything is corrected or written: a ground truth that does not pair with
    // the run made a results folder without metrics, `latest` pointing at it, and exit 1.
    let pairing = args.pairing.pairing(args.format)?;
    let gt = match &args.gt {
        Some(path) => {
            let gt = trajectory::read(path, args.format)?;
            let paired = evaluation::pair(&gt, &input, args.frame, pairing)
                .map_err(evaluation::with_pairing_advice)
                .and_then(|p| Ok(ape_2d(&p.gt, &p.est)?));
            paired.with_context(|| {
                format!("--gt {} against {}", path.display(), args.input.display())
            })?;
            Some(gt)
        }
        None => None,
    };
    let source = args.map.source(&config)?;
    let loaded = source.load_for(&config)?;
    if let Some(InputReport::Osm(r)) = &loaded.report {
        if r.missing_node_refs > 0 || r.ways_without_geometry > 0 {
            eprintln!(
                "warning: {} node references missing, {} drivable ways without geometry (skipped)",
                r.missing_node_refs, r.ways_without_geometry
            );
        }
    }
    let placement = Placement {
        convention: args.frame,
        anchored_from_odom: loaded.anchored_from_odom,
        smoothing: config.smoothing(),
    };
    let (loaded_map, anchored_from_odom) = (loaded.map.clone(), loaded.anchored_from_odom);
    let spinner = report::spinner(format!("correcting {} poses", input.poses.len()));
    let (run, grid_run) = loaded.correct(
        params,
        config.match_mode,
        placement,
        &input.poses,
        input.stamps.as_deref(),
    )?;
    spinner.finish_and_clear();
    if let Some(g) = grid_run {
        eprintln!(
            "grid: {} maps assembled, {} cells read, at most {} loaded at once; {} queries beyond the loaded cells",
            g.maps, g.cells_read, g.most_cells, g.uncovered_queries
        );
        if g.uncovered_queries > 0 {
            eprintln!("WARN {} neighbour queries reached beyond the loaded cells: those corrections may differ from the whole map's (compile the grid with a larger --margin)", g.uncovered_queries);
        }
    }
    let output = Trajectory {
        stamps: input.stamps.clone(),
        poses: run.iter().map(|c| c.pose).collect(),
    };
    // Formatting the status CSV is a few percent of a whole run: only when a file takes it.
    let status = (args.status.is_some() || args.results.is_some())
        .then(|| status_file::of_run(&run, &anchored_from_odom));
    if let Some(path) = &args.output {
        let status = args.status.as_deref().zip(status.as_deref());
        status_file::write_run(path, &output, args.format, status)?;
    }
    let warnings = loaded.warnings(
        &input.poses,
        input.stamps.as_deref(),
        args.frame,
        &run,
        &params,
    );
    if let Some(parent) = &args.results {
        let dir = results::create(parent)?;
        // The run's record keeps what its standard error says of it: one line each, none when
        // the file is empty.
        let path = dir.join("warnings.txt");
        let text: String = warnings.iter().map(|w| format!("{w}\n")).collect();
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
        let extension = match args.format {
            Format::Kitti => "txt",
            Format::Tum => "tum",
        };
        let corrected = dir.join(format!("corrected.{extension}"));
        let status_path = dir.join("status.csv");
        status_file::write_run(
            &corrected,
            &output,
            args.format,
            status.as_deref().map(|s| (status_path.as_path(), s)),
        )?;
        let params_file = ParamsFile {
            unmarked_offset_scale: config.unmarked_offset_scale(),
            run: RunRecord::new(args, &source),
            corrector: config,
            at_rate: AtRate::of(&params),
            params,
        };
        let path = dir.join("params.toml");
        std::fs::write(&path, toml::to_string(&params_file)?)
            .with_context(|| format!("writing {}", path.display()))?;
        if let Some(gt) = &gt {
            // On a grid, the lanes along the whole corrected drive.
            let lanes = match &loaded.grid {
                Some(grid) => Arc::new(lanes_along(grid, &run, &input.poses, args.frame)?),
                None => loaded_map.clone(),
            };
            write_comparison(
                &dir,
                (gt, pairing),
                &input,
                &output,
                &run,
                &lanes,
                &anchored_from_odom,
                args.frame,
            )?;
        }
        eprintln!("results in {}", dir.display());
    }
    let c = counts(&run);
    eprintln!(
        "{} poses, method {}: {} match attempts, {} accepted, {} resets",
        run.len(),
        config.method.name(),
        c.attempts,
        c.accepted,
        c.resets
    );
    let estimates = run.iter().map(|c| (c.odometry_scale, c.odometry_scale_sd));
    if let Some(line) = status_file::scale_summary(estimates) {
        eprintln!("{line}");
    }
    for warning in warnings {
        eprintln!("WARN {warning}");
    }
    Ok(())
}

/// The lanes of every cell of `grid` the corrected drive passes through.
fn lanes_along(
    grid: &Grid,
    run: &[CorrectedPose],
    poses: &[Pose3],
    frame: AxisConvention,
) -> anyhow::Result<LaneMap> {
    let positions: Vec<[f64; 2]> = run
        .iter()
        .zip(poses)
        .map(|(c, p)| c.map_from_odom.apply(frame.to_planar(p).planar_position()))
        .filter(|p| p[0].is_finite() && p[1].is_finite())
        .collect();
    let along = LoadPolicy {
        radius_m: 0.0,
        ahead_m: 0.0,
    };
    Ok(grid.map_of(grid.wanted(&positions, &along))?)
}

/// `metrics.json` and the plots of a results folder: raw and corrected against ground truth.
#[allow(clippy::too_many_arguments)]
fn write_comparison(
    dir: &Path,
    (gt, pairing): (&Trajectory, Pairing),
    raw: &Trajectory,
    corrected: &Trajectory,
    run: &[CorrectedPose],
    map: &LaneMap,
    anchored_from_odom: &Se2,
    frame: AxisConvention,
) -> anyhow::Result<()> {
    let raw_pairs = evaluation::pair(gt, raw, frame, pairing)?;
    let corrected_pairs = evaluation::pair(gt, corrected, frame, pairing)?;
    let (raw_m, corrected_m) = (
        ape_2d(&raw_pairs.gt, &raw_pairs.est)?,
        ape_2d(&corrected_pairs.gt, &corrected_pairs.est)?,
    );
    // The corrected poses' covariances in the plane of the poses, as `eval --status` reads them.
    let anchor_yaw = anchored_from_odom.yaw();
    let covariances: Vec<[[f64; 2]; 2]> = corrected_pairs
        .pairs
        .iter()
        .map(|p| status_file::position_covariance_in_odom(anchor_yaw, &run[p.1].covariance))
        .collect();
    let calibration = match calibration(&corrected_pairs.gt, &corrected_pairs.est, &covariances) {
        Ok(c) => serde_json::to_value(c.check())?,
        Err(e) => serde_json::json!({ "error": e.to_string() }),
    };
    let metrics = serde_json::json!({
        "raw": raw_m,
        "corrected": corrected_m,
        "calibration": calibration,
    });
    let path = dir.join("metrics.json");
    std::fs::write(&path, serde_json::to_string_pretty(&metrics)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    // In the map plane, where the lanes are.
    let placed = |t: &Trajectory| -> Vec<[f64; 2]> {
        t.poses
            .iter()
            .map(|p| anchored_from_odom.apply(frame.to_planar(p).planar_position()))
            .collect()
    };
    let (gt_xy, raw_xy, corrected_xy) = (placed(gt), placed(raw), placed(corrected));
    let rejected: Vec<[f64; 2]> = run
        .iter()
        .zip(&corrected_xy)
        .filter(|(c, _)| matches!(c.status, Status::Rejected { .. } | Status::Reset { .. }))
        .map(|(_, p)| *p)
        .collect();
    let lanes: Vec<&[[f64; 2]]> = map.lanes().map(|(_, _, points)| points).collect();
    plots::trajectories(
        &dir.join("trajectory.svg"),
        &format!(
            "APE-2D mean: raw {:.2} m, corrected {:.2} m",
            raw_m.mean_m, corrected_m.mean_m
        ),
        &lanes,
        &[
            plots::Track {
                name: "ground truth",
                points: &gt_xy,
                color: plots::GROUND_TRUTH,
            },
            plots::Track {
                name: "raw odometry",
                points: &raw_xy,
                color: plots::RAW,
            },
            plots::Track {
                name: "corrected",
                points: &corrected_xy,
                color: plots::CORRECTED,
            },
        ],
        ("correction rejected", &rejected),
    )?;
    plots::error_over_distance(
        &dir.join("error.svg"),
        "Position error over distance (APE-2D, no alignment)",
        &corrected_pairs.distance_m(),
        &[
            ("raw odometry", &raw_pairs.errors_m(), plots::RAW),
            ("corrected", &corrected_pairs.errors_m(), plots::CORRECTED),
        ],
    )?;
    Ok(())
}
