//! Corrects the real KITTI odometry runs of `../shared/data` with the paper's method and prints,
//! per sequence, the raw APE-2D, lanealign on lanes it derives from OpenStreetMap, lanealign on
//! the paper pipeline's reference lanes, and the reference implementation's figure
//! (`reference/results.csv`). The robust method's figures come from the `ablation` example.
//!
//! `cargo run --release -p lanealign-cli --example kitti [-- --data DIR] [-- --all-presets]`
//!
//! By default it runs `lidar` with kiss-icp and `stereo_vo` with orb-slam3 (as the paper pairs
//! them); `--all-presets` adds liodom and basalt (the four pairs of `results.csv`). It keeps the
//! table (markdown and CSV) and a plot of the error over distance per run in
//! `results/kitti/<UTC time>/` (`--results DIR` for another parent), `latest` pointing at it.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::Context;
use lanealign_cli::evaluation::Paired;
use lanealign_cli::kitti::{anchors, data_dir_from_args, SEQUENCES};
use lanealign_cli::maps::MapSource;
use lanealign_cli::report::{self, Table};
use lanealign_cli::{plots, results};
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::metrics::{ape_2d, Ape2d};
use lanealign_core::params::Preset;
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::source_corrector::{correct_trajectory, counts, Counts, Placement};
use lanealign_core::trajectory::{read, Format};
use lanealign_map::osm_lanes::LaneOptions;

struct Job {
    odometry: &'static str,
    preset: Preset,
    seq: &'static str,
}

struct Row {
    raw: Ape2d,
    osm: Ape2d,
    osm_counts: Counts,
    reference_lanes: Ape2d,
    /// Distance driven (m), and the position error (m) of raw, OSM-corrected and
    /// reference-lanes-corrected poses at each.
    distance_m: Vec<f64>,
    errors_m: [Vec<f64>; 3],
}

/// `(odometry, preset, seq) -> ape2d_mean_m` of the reference implementation.
fn reference_results(data: &Path) -> anyhow::Result<HashMap<(String, String, String), f64>> {
    let text = std::fs::read_to_string(data.join("reference/results.csv"))?;
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let ape: f64 = f.get(5).context("results.csv: short line")?.parse()?;
            Ok(((f[0].to_string(), f[1].to_string(), f[2].to_string()), ape))
        })
        .collect()
}

fn corrected(
    map_source: MapSource,
    preset: Preset,
    odom: &[Pose3],
    gt: &[Pose3],
) -> anyhow::Result<(Ape2d, Counts, Vec<Pose3>)> {
    let cam = AxisConvention::KittiCamera;
    let loaded = map_source.load()?;
    let placement = Placement {
        convention: cam,
        anchored_from_odom: loaded.anchored_from_odom,
        smoothing: None,
    };
    let run = correct_trajectory(
        loaded.map,
        preset.params(),
        MatchMode::Fast,
        placement,
        odom,
    );
    let est: Vec<Pose3> = run.iter().map(|c| cam.to_planar(&c.pose)).collect();
    Ok((ape_2d(gt, &est)?, counts(&run), est))
}

/// `gt` and `est` as pairs, by index.
fn paired(gt: &[Pose3], est: Vec<Pose3>) -> Paired {
    Paired {
        gt: gt.to_vec(),
        pairs: (0..est.len()).map(|i| (i, i)).collect(),
        est,
    }
}

fn run(data: &Path, job: &Job, anchor: &Anchor) -> anyhow::Result<Row> {
    let cam = AxisConvention::KittiCamera;
    let seq = job.seq;
    let gt = read(&data.join(format!("kitti/poses/{seq}.txt")), Format::Kitti)?;
    let gt: Vec<Pose3> = gt.poses.iter().map(|p| cam.to_planar(p)).collect();
    let odom = read(
        &data.join(format!("odometry/{}/{seq}.txt", job.odometry)),
        Format::Kitti,
    )?;
    let raw: Vec<Pose3> = odom.poses.iter().map(|p| cam.to_planar(p)).collect();
    let osm_map = MapSource::Osm {
        path: data.join(format!("osm/kitti_{seq}.osm")),
        anchor: *anchor,
        projection: Projection::Kitti,
        options: LaneOptions::paper(),
    };
    let (osm, osm_counts, osm_est) = corrected(osm_map, job.preset, &odom.poses, &gt)?;
    let reference_map = MapSource::LanesCsv(data.join(format!("reference/lanes/lanes_{seq}.csv")));
    let (reference_lanes, _, reference_est) =
        corrected(reference_map, job.preset, &odom.poses, &gt)?;
    let raw_ape = ape_2d(&gt, &raw)?;
    let raw = paired(&gt, raw);
    Ok(Row {
        distance_m: raw.distance_m(),
        errors_m: [
            raw.errors_m(),
            paired(&gt, osm_est).errors_m(),
            paired(&gt, reference_est).errors_m(),
        ],
        raw: raw_ape,
        osm,
        osm_counts,
        reference_lanes,
    })
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let data = data_dir_from_args(&args)?;
    let mut pairs = vec![("lidar", Preset::KissIcp), ("stereo_vo", Preset::OrbSlam3)];
    if args.iter().any(|a| a == "--all-presets") {
        pairs.extend([("lidar", Preset::Liodom), ("stereo_vo", Preset::Basalt)]);
    }
    let anchors = anchors(&data).context("reading georef.csv")?;
    let reference = reference_results(&data).context("reading reference/results.csv")?;
    let jobs: Vec<Job> = pairs
        .iter()
        .flat_map(|&(odometry, preset)| {
            SEQUENCES.iter().map(move |&seq| Job {
                odometry,
                preset,
                seq,
            })
        })
        .collect();
    let next = AtomicUsize::new(0);
    let rows = Mutex::new(Vec::new());
    let progress = report::progress(jobs.len(), "correcting");
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(job) = jobs.get(i) else { break };
                let row = anchors
                    .get(job.seq)
                    .with_context(|| format!("no anchor for sequence {}", job.seq))
                    .and_then(|a| run(&data, job, a));
                rows.lock().expect("no worker panics").push((i, row));
                progress.inc(1);
            });
        }
    });
    progress.finish_and_clear();
    let mut rows = rows.into_inner().expect("no worker panics");
    rows.sort_by_key(|r| r.0);
    let dir = results::create(&results::parent_from_args(&args, "results/kitti"))?;
    let mut table = Table::new(
        "Mean APE-2D in metres (no alignment). OSM: lanealign's lanes from OpenStreetMap; reference lanes: the paper pipeline's (OSM -> CommonRoad -> Lanelet2); reference impl.: reference/results.csv.",
        [
            "odometry",
            "preset",
            "seq",
            "raw",
            "lanealign, OSM lanes",
            "lanealign, reference lanes",
            "reference impl., reference lanes",
            "OSM: max err",
            "OSM: attempts / accepted / resets",
        ]
        .map(String::from)
        .to_vec(),
    );
    let mut sums: Vec<(String, [f64; 4], usize)> = Vec::new();
    for (i, row) in rows {
        let job = &jobs[i];
        let r = row.with_context(|| format!("{} {}", job.odometry, job.seq))?;
        let reference_ape = reference
            .get(&(
                job.odometry.to_string(),
                job.preset.name().to_string(),
                job.seq.to_string(),
            ))
            .copied()
            .unwrap_or(f64::NAN);
        let (a, b, c) = (
            r.osm_counts.attempts,
            r.osm_counts.accepted,
            r.osm_counts.resets,
        );
        table.push(vec![
            job.odometry.into(),
            job.preset.name().into(),
            job.seq.into(),
            format!("{:.3}", r.raw.mean_m),
            format!("{:.3}", r.osm.mean_m),
            format!("{:.3}", r.reference_lanes.mean_m),
            format!("{reference_ape:.3}"),
            format!("{:.2}", r.osm.max_m),
            format!("{a} / {b} / {c}"),
        ]);
        let [raw_err, osm_err, reference_err] = &r.errors_m;
        plots::error_over_distance(
            &dir.join(format!(
                "error_{}_{}_{}.svg",
                job.odometry,
                job.preset.name(),
                job.seq
            )),
            &format!(
                "KITTI {} {}, {} preset, paper's method: error over distance",
                job.seq,
                job.odometry,
                job.preset.name()
            ),
            &r.distance_m,
            &[
                ("raw odometry", raw_err, plots::RAW),
                ("OSM lanes", osm_err, plots::CORRECTED),
                ("reference lanes", reference_err, plots::PALETTE[2]),
            ],
        )?;
        let key = format!("{} | {}", job.odometry, job.preset.name());
        let values = [
            r.raw.mean_m,
            r.osm.mean_m,
            r.reference_lanes.mean_m,
            reference_ape,
        ];
        match sums.iter_mut().find(|s| s.0 == key) {
            Some(s) => {
                for (acc, v) in s.1.iter_mut().zip(values) {
                    *acc += v;
                }
                s.2 += 1;
            }
            None => sums.push((key, values, 1)),
        }
    }
    for (key, v, n) in sums {
        let n = n as f64;
        let (odometry, preset) = key.split_once(" | ").unwrap_or((&key, ""));
        table.push(vec![
            odometry.into(),
            preset.into(),
            "**mean**".into(),
            format!("{:.3}", v[0] / n),
            format!("**{:.3}**", v[1] / n),
            format!("{:.3}", v[2] / n),
            format!("{:.3}", v[3] / n),
            String::new(),
            String::new(),
        ]);
    }
    print!("{}", table.markdown());
    table.save(&dir, "results")?;
    eprintln!("results in {}", dir.display());
    Ok(())
}
