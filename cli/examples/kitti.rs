//! Corrects the real KITTI odometry runs of `../shared/data` with the paper's method and prints,
//! per sequence, the raw APE-2D, lanealign on lanes it derives from OpenStreetMap, lanealign on
//! the paper pipeline's reference lanes, and the reference implementation's figure
//! (`reference/results.csv`). The robust method's figures come from the `ablation` example.
//!
//! `cargo run --release -p lanealign-cli --example kitti [-- --data DIR] [-- --all-presets]`
//!
//! By default it runs `lidar` with kiss-icp and `stereo_vo` with orb-slam3 (as the paper pairs
//! them); `--all-presets` adds liodom and basalt (the four pairs of `results.csv`).

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::Context;
use lanealign_cli::kitti::{anchors, data_dir_from_args, SEQUENCES};
use lanealign_cli::maps::MapSource;
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
) -> anyhow::Result<(Ape2d, Counts)> {
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
    Ok((ape_2d(gt, &est)?, counts(&run)))
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
    let (osm, osm_counts) = corrected(osm_map, job.preset, &odom.poses, &gt)?;
    let reference_map = MapSource::LanesCsv(data.join(format!("reference/lanes/lanes_{seq}.csv")));
    let (reference_lanes, _) = corrected(reference_map, job.preset, &odom.poses, &gt)?;
    Ok(Row {
        raw: ape_2d(&gt, &raw)?,
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
            });
        }
    });
    let mut rows = rows.into_inner().expect("no worker panics");
    rows.sort_by_key(|r| r.0);
    println!("Mean APE-2D in metres (no alignment). OSM: lanealign's lanes from OpenStreetMap; reference lanes: the paper pipeline's (OSM -> CommonRoad -> Lanelet2); reference impl.: reference/results.csv.\n");
    println!("| odometry | preset | seq | raw | lanealign, OSM lanes | lanealign, reference lanes | reference impl., reference lanes | OSM: max err | OSM: attempts / accepted / resets |");
    println!("|---|---|---|---|---|---|---|---|---|");
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
        println!(
            "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} | {a} / {b} / {c} |",
            job.odometry,
            job.preset.name(),
            job.seq,
            r.raw.mean_m,
            r.osm.mean_m,
            r.reference_lanes.mean_m,
            reference_ape,
            r.osm.max_m
        );
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
        println!(
            "| {key} | **mean** | {:.3} | **{:.3}** | {:.3} | {:.3} | | |",
            v[0] / n,
            v[1] / n,
            v[2] / n,
            v[3] / n
        );
    }
    Ok(())
}
