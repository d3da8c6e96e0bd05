//! Per-pose cost of the corrector on real KITTI runs, fast vs reference matching, one table.
//!
//! `cargo bench -p lanealign-cli --bench corrector [-- OPTIONS]` (`-- --help` lists them)
//!
//! - `--sequences 00,02,08` (default), `--presets` a comma list (default: all four);
//! - `--methods paper,robust` (default: both, each on its own lane geometry);
//! - `--reference-poses K`: run the reference mode on the first K poses only (default: all; the
//!   reference mode needs 5-30 ms per pose); identity and speed-up are then over those K poses;
//! - `--long-run N`: instead, correct N poses in fast mode by looping KITTI 00 (lidar, kiss-icp)
//!   and print resident memory every N/10 poses, to show it stays flat;
//! - `--paced MS`: instead, correct the first 3000 poses of KITTI 00 (lidar, kiss-icp, OSM lanes)
//!   back to back, then with a sleep of MS milliseconds before each pose (the daemon's worker at
//!   1000/MS Hz, idle between poses), then so and with `Corrector::prepare` and
//!   `Corrector::work_ahead` after each pose (as the daemon calls them after publishing), then
//!   prepared and spinning MS milliseconds between poses (a busy-spinning worker), and print the
//!   step's parts as the daemon's latency event splits them, bookkeeping also apart for the
//!   carried steps and for those that align, side by side, with how many steps took a page
//!   fault; then the step's
//!   p50 / p99 per block of 500 poses, the daemon's 5 s metrics intervals at 100 Hz (its latency
//!   bars are per interval, and the drive's middle blocks cost the most); then how long reading
//!   a 4, 16 and 64 KiB buffer takes back to back and after the same pauses (the machine's
//!   floor under the bookkeeping: memory left alone for MS milliseconds, whatever reads it).
//!
//! Single thread. Times are wall-clock per `Corrector::push`, in microseconds.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use lanealign_cli::kitti::{anchors, default_data_dir};
use lanealign_cli::maps::MapSource;
use lanealign_core::corrector::{Corrector, MatchMode, Status, Step, StepTiming};
use lanealign_core::geo::Projection;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::{Method, Params, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::osm_lanes::LaneOptions;

struct Stats {
    mean: f64,
    p50: f64,
    p99: f64,
    max: f64,
}

fn stats(mut us: Vec<f64>) -> Stats {
    us.sort_by(f64::total_cmp);
    let q = |f: f64| us[((us.len() - 1) as f64 * f).round() as usize];
    Stats {
        mean: us.iter().sum::<f64>() / us.len() as f64,
        p50: q(0.5),
        p99: q(0.99),
        max: us[us.len() - 1],
    }
}

fn run(
    map: &Arc<LaneMap>,
    params: Params,
    mode: MatchMode,
    positions: &[[f64; 2]],
) -> (Vec<Step>, Vec<f64>) {
    let mut c = Corrector::with_mode(map.clone(), params, mode);
    let mut steps = Vec::with_capacity(positions.len());
    let mut us = Vec::with_capacity(positions.len());
    for &p in positions {
        let t = Instant::now();
        let step = c.push(p);
        us.push(t.elapsed().as_secs_f64() * 1e6);
        steps.push(step);
    }
    (steps, us)
}

fn identical(a: &[Step], b: &[Step]) -> bool {
    a.iter().zip(b).all(|(x, y)| {
        x.status == y.status
            && x.position_in_map == y.position_in_map
            && x.map_from_anchored == y.map_from_anchored
    })
}

fn load(
    data: &Path,
    odometry: &str,
    seq: &str,
    lanes: LaneOptions,
) -> anyhow::Result<(Arc<LaneMap>, Vec<[f64; 2]>)> {
    let anchors = anchors(data)?;
    let anchor = anchors
        .get(seq)
        .with_context(|| format!("no anchor for {seq}"))?;
    let loaded = MapSource::Osm {
        path: data.join(format!("osm/kitti_{seq}.osm")),
        anchor: *anchor,
        projection: Projection::Kitti,
        options: lanes,
    }
    .load()?;
    let (map, anchored_from_odom) = (loaded.map, loaded.anchored_from_odom);
    let odom = read(
        &data.join(format!("odometry/{odometry}/{seq}.txt")),
        Format::Kitti,
    )?;
    let cam = AxisConvention::KittiCamera;
    let positions = odom
        .poses
        .iter()
        .map(|p| anchored_from_odom.apply(cam.to_planar(p).planar_position()))
        .collect();
    Ok((map, positions))
}

fn resident_kib() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| {
            s.split_whitespace()
                .nth(1)
                .and_then(|v| v.parse::<u64>().ok())
        })
        .map_or(0, |pages| pages * 4)
}

fn long_run(data: &Path, total: usize) -> anyhow::Result<()> {
    let (map, positions) = load(data, "lidar", "00", LaneOptions::paper())?;
    let mut c = Corrector::new(map, Preset::KissIcp.params());
    println!("Long run: KITTI 00 lidar, kiss-icp, fast mode, looped to {total} poses");
    println!(
        "| poses | resident memory (KiB) | mean us/pose since last row | accepted since last row |"
    );
    println!("|---|---|---|---|");
    let (mut t, mut accepted) = (Instant::now(), 0usize);
    for i in 0..total {
        let step = c.push(positions[i % positions.len()]);
        accepted += matches!(step.status, Status::Accepted { .. }) as usize;
        if (i + 1) % (total / 10).max(1) == 0 {
            let n = (total / 10).max(1) as f64;
            println!(
                "| {} | {} | {:.1} | {accepted} |",
                i + 1,
                resident_kib(),
                t.elapsed().as_secs_f64() * 1e6 / n
            );
            t = Instant::now();
            accepted = 0;
        }
    }
    Ok(())
}

/// The quantiles of one part of the step over `steps` (microseconds).
fn part<'a>(
    steps: impl IntoIterator<Item = &'a Step>,
    f: impl Fn(StepTiming) -> Duration,
) -> Stats {
    stats(
        steps
            .into_iter()
            .map(|s| f(s.timing).as_secs_f64() * 1e6)
            .collect(),
    )
}

/// Minor page faults of the calling thread so far (0 where /proc does not tell).
fn minor_faults() -> u64 {
    std::fs::read_to_string("/proc/thread-self/stat")
        .ok()
        .and_then(|s| {
            // The fields after the command's closing parenthesis; minflt is the 10th of all.
            let after = s.rsplit_once(')')?.1;
            after.split_whitespace().nth(7)?.parse().ok()
        })
        .unwrap_or(0)
}

fn paced(data: &Path, pause_ms: u64) -> anyhow::Result<()> {
    let (map, mut positions) = load(data, "lidar", "00", LaneOptions::for_method(Method::Robust))?;
    positions.truncate(3000);
    let pause = Duration::from_millis(pause_ms);
    println!(
        "KITTI 00 lidar, kiss-icp, fast mode, {} poses; per step p50 / p99 (us), as the daemon's latency event splits it",
        positions.len()
    );
    println!("| run | step | matching | ICP | confidence | bookkeeping | bookkeeping, first 1200 poses | bookkeeping, carried | bookkeeping, aligned | steps with a page fault |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let runs = [
        ("back to back", Pause::None, false),
        ("back to back, prepared between poses", Pause::None, true),
        ("paced", Pause::Sleep, false),
        ("paced, prepared between poses", Pause::Sleep, true),
        ("paced spinning, prepared between poses", Pause::Spin, true),
    ];
    let mut blocks = Vec::new();
    for (name, between, prepared) in runs {
        let mut c = Corrector::new(map.clone(), Method::Robust.params(Preset::KissIcp));
        let mut steps = Vec::with_capacity(positions.len());
        let mut faulting = 0;
        for &p in &positions {
            between.wait(pause);
            let before = minor_faults();
            let step = c.push(p);
            faulting += usize::from(minor_faults() > before);
            steps.push(step);
            if prepared {
                c.prepare();
                c.work_ahead();
            }
        }
        let bookkeeping = |t: StepTiming| t.total.saturating_sub(t.matching + t.icp + t.confidence);
        let parts = [
            part(&steps, |t| t.total),
            part(&steps, |t| t.matching),
            part(&steps, |t| t.icp),
            part(&steps, |t| t.confidence),
            part(&steps, bookkeeping),
            part(&steps[..1200.min(steps.len())], bookkeeping),
            part(
                steps
                    .iter()
                    .filter(|s| matches!(s.status, Status::Carried { .. })),
                bookkeeping,
            ),
            part(steps.iter().filter(|s| s.status.attempted()), bookkeeping),
        ];
        let cells: Vec<String> = parts
            .iter()
            .map(|q| format!("{:.1} / {:.1}", q.p50, q.p99))
            .collect();
        let name = name.replace("paced", &format!("{pause_ms} ms apart"));
        println!("| {name} | {} | {faulting} |", cells.join(" | "));
        let per_block: Vec<String> = steps
            .chunks(INTERVAL_POSES)
            .map(|block| {
                let q = part(block, |t| t.total);
                format!("{:.1} / {:.1}", q.p50, q.p99)
            })
            .collect();
        blocks.push(format!("| {name} | {} |", per_block.join(" | ")));
    }
    let count = positions.len().div_ceil(INTERVAL_POSES);
    println!();
    println!("Step p50 / p99 (us) per {INTERVAL_POSES} poses (the daemon's 5 s metrics intervals at 100 Hz)");
    let header: Vec<String> = (0..count)
        .map(|b| {
            format!(
                "{}-{}",
                b * INTERVAL_POSES,
                ((b + 1) * INTERVAL_POSES).min(positions.len()) - 1
            )
        })
        .collect();
    println!("| run | {} |", header.join(" | "));
    println!("|---|{}", "---|".repeat(count));
    for row in blocks {
        println!("{row}");
    }
    memory_floor(pause_ms);
    Ok(())
}

/// Reads per buffer size and pause of [`memory_floor`].
const FLOOR_READS: usize = 500;

/// Prints how long reading a buffer (one byte of each 64-byte line) takes back to back and after
/// the paced runs' pauses: what memory left alone for the pause costs on this machine whatever
/// code touches it, the floor under the paced steps' bookkeeping.
fn memory_floor(pause_ms: u64) {
    let pause = Duration::from_millis(pause_ms);
    println!();
    println!("Reading a buffer once (a byte of each 64-byte line) after the same pauses, {FLOOR_READS} reads, p50 / p99 (us): the machine's floor");
    println!("| buffer | back to back | {pause_ms} ms apart | {pause_ms} ms apart spinning |");
    println!("|---|---|---|---|");
    for kib in [4, 16, 64] {
        let buffer = vec![1u8; kib << 10];
        let cells: Vec<String> = [Pause::None, Pause::Sleep, Pause::Spin]
            .into_iter()
            .map(|between| {
                let times = (0..FLOOR_READS)
                    .map(|_| {
                        between.wait(pause);
                        let lines = std::hint::black_box(buffer.as_slice());
                        let start = Instant::now();
                        let sum = lines.iter().step_by(64).map(|&b| u64::from(b)).sum::<u64>();
                        std::hint::black_box(sum);
                        start.elapsed().as_secs_f64() * 1e6
                    })
                    .collect();
                let q = stats(times);
                format!("{:.2} / {:.2}", q.p50, q.p99)
            })
            .collect();
        println!("| {kib} KiB | {} |", cells.join(" | "));
    }
}

/// What the paced runs do between two poses.
#[derive(Clone, Copy)]
enum Pause {
    /// Nothing: the poses back to back.
    None,
    /// Sleep (the daemon's worker waiting on events).
    Sleep,
    /// Spin on the clock without touching memory (a busy-spinning worker).
    Spin,
}

impl Pause {
    /// Waits `pause` this way (`None`: not at all).
    fn wait(self, pause: Duration) {
        match self {
            Pause::None => {}
            Pause::Sleep => std::thread::sleep(pause),
            Pause::Spin => {
                let until = Instant::now() + pause;
                while Instant::now() < until {
                    std::hint::spin_loop();
                }
            }
        }
    }
}

/// Poses per block of the paced run's second table: the daemon's metrics interval (5 s by
/// default) at 100 Hz.
const INTERVAL_POSES: usize = 500;

#[derive(Parser)]
struct Args {
    /// KITTI sequences, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "00,02,08")]
    sequences: Vec<String>,
    /// Presets, comma-separated (default: all four).
    #[arg(long, value_delimiter = ',')]
    presets: Vec<Preset>,
    /// Methods, comma-separated (default: both, each on its own lane geometry).
    #[arg(long, value_delimiter = ',')]
    methods: Vec<Method>,
    /// Run the reference mode on the first K poses only (default: all).
    #[arg(long)]
    reference_poses: Option<usize>,
    /// Instead, correct this many poses in fast mode by looping KITTI 00 and print resident
    /// memory every tenth of them.
    #[arg(long)]
    long_run: Option<usize>,
    /// Instead, correct KITTI 00's first 3000 poses back to back and this many milliseconds
    /// apart, and print the step's parts side by side.
    #[arg(long)]
    paced: Option<u64>,
    /// Cargo passes this to every bench.
    #[arg(long, hide = true)]
    bench: bool,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let data = default_data_dir();
    if !data.join("kitti/georef.csv").is_file() {
        println!("SKIPPED: no KITTI data at {}", data.display());
        return Ok(());
    }
    if let Some(n) = args.long_run {
        return long_run(&data, n);
    }
    if let Some(ms) = args.paced {
        return paced(&data, ms);
    }
    let Args {
        sequences,
        mut presets,
        mut methods,
        reference_poses,
        ..
    } = args;
    if presets.is_empty() {
        presets = Preset::ALL.to_vec();
    }
    if methods.is_empty() {
        methods = Method::ALL.to_vec();
    }
    println!("Per-pose time of Corrector::push in microseconds, single thread, lanes from OSM.");
    println!("| odometry | seq | method | preset | poses | fast mean | fast p50 | fast p99 | fast max | fast: matching / ICP mean | ref. poses | ref. mean | ref. p99 | speed-up (mean, same poses) | identical |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for odometry in ["lidar", "stereo_vo"] {
        for seq in &sequences {
            for &method in &methods {
                let lanes = LaneOptions::for_method(method);
                let (map, positions) = load(&data, odometry, seq, lanes)?;
                for &preset in &presets {
                    let params = method.params(preset);
                    let (fast_steps, fast_us) = run(&map, params, MatchMode::Fast, &positions);
                    let k = reference_poses
                        .unwrap_or(positions.len())
                        .min(positions.len());
                    let (ref_steps, ref_us) =
                        run(&map, params, MatchMode::Reference, &positions[..k]);
                    let f = stats(fast_us.clone());
                    let n = fast_steps.len() as f64;
                    let matching = fast_steps
                        .iter()
                        .map(|s| s.timing.matching.as_secs_f64())
                        .sum::<f64>()
                        * 1e6
                        / n;
                    let icp = fast_steps
                        .iter()
                        .map(|s| s.timing.icp.as_secs_f64())
                        .sum::<f64>()
                        * 1e6
                        / n;
                    let r = stats(ref_us);
                    let fast_prefix = stats(fast_us[..k].to_vec());
                    println!(
                    "| {odometry} | {seq} | {} | {} | {} | {:.1} | {:.1} | {:.1} | {:.0} | {matching:.1} / {icp:.1} | {k} | {:.0} | {:.0} | {:.0}x | {} |",
                    method.name(), preset.name(), positions.len(), f.mean, f.p50, f.p99, f.max, r.mean, r.p99,
                    r.mean / fast_prefix.mean, if identical(&fast_steps[..k], &ref_steps) { "yes" } else { "NO" }
                );
                }
            }
        }
    }
    Ok(())
}
