//! Corrects the real KITTI odometry runs of `../shared/data` against lanes derived from
//! OpenStreetMap and prints raw vs corrected APE-2D per sequence and the mean.
//!
//! `cargo run --release -p lanealign-client --example kitti [-- --data DIR] [-- --lanes reference]`
//!
//! Runs `lidar` with the kiss-icp preset and `stereo_vo` with orb-slam3 (as the paper pairs
//! them), on two threads.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context};
use lanealign_client::maps::osm_lanes_in_odom;
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::lane_csv;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::{ape_2d, Ape2d};
use lanealign_core::offline::{correct, counts};
use lanealign_core::params::Preset;
use lanealign_core::pose::AxisConvention;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::osm_lanes::LaneOptions;

const SEQUENCES: [&str; 10] = ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"];
const RUNS: [(&str, Preset); 2] = [("lidar", Preset::KissIcp), ("stereo_vo", Preset::OrbSlam3)];

struct Row {
    odometry: &'static str,
    preset: Preset,
    seq: &'static str,
    raw: Ape2d,
    corrected: Ape2d,
    counts: (usize, usize, usize),
}

fn anchors(data: &Path) -> anyhow::Result<Vec<(String, Anchor)>> {
    let text = std::fs::read_to_string(data.join("kitti/georef.csv"))?;
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            if f.len() < 7 {
                bail!("georef.csv: bad line '{l}'");
            }
            let anchor: Anchor = format!("{},{},{},{},{}", f[1], f[2], f[4], f[5], f[6])
                .parse()
                .map_err(anyhow::Error::msg)?;
            Ok((f[0].to_string(), anchor))
        })
        .collect()
}

fn run(
    data: &Path,
    reference_lanes: bool,
    odometry: &'static str,
    preset: Preset,
    seq: &'static str,
    anchor: Anchor,
) -> anyhow::Result<Row> {
    let cam = AxisConvention::KittiCamera;
    let lanes = if reference_lanes {
        lane_csv::read(&data.join(format!("reference/lanes/lanes_{seq}.csv")))?
    } else {
        osm_lanes_in_odom(
            &data.join(format!("osm/kitti_{seq}.osm")),
            &anchor,
            Projection::Kitti,
            &LaneOptions::default(),
        )?
    };
    let map = Arc::new(LaneMap::new(&lanes)?);
    let gt = read(&data.join(format!("kitti/poses/{seq}.txt")), Format::Kitti)?;
    let odom = read(
        &data.join(format!("odometry/{odometry}/{seq}.txt")),
        Format::Kitti,
    )?;
    let result = correct(map, preset.params(), MatchMode::Fast, cam, &odom.poses);
    let planar = |poses: Vec<&[[f64; 4]; 3]>| {
        poses
            .into_iter()
            .map(|p| cam.to_planar(p))
            .collect::<Vec<_>>()
    };
    let gt_p = planar(gt.poses.iter().collect());
    Ok(Row {
        odometry,
        preset,
        seq,
        raw: ape_2d(&gt_p, &planar(odom.poses.iter().collect()))?,
        corrected: ape_2d(&gt_p, &planar(result.iter().map(|c| &c.pose).collect()))?,
        counts: counts(&result),
    })
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let flag = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let data = flag("--data")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    let reference_lanes = flag("--lanes").as_deref() == Some("reference");
    if !data.join("kitti/georef.csv").is_file() {
        bail!("no KITTI data at {} (pass --data DIR)", data.display());
    }
    let anchors = anchors(&data).context("reading georef.csv")?;
    let jobs: Vec<(&'static str, Preset, &'static str, Anchor)> = RUNS
        .iter()
        .flat_map(|&(o, p)| {
            let anchors = &anchors;
            SEQUENCES.iter().filter_map(move |&s| {
                anchors
                    .iter()
                    .find(|(a, _)| a == s)
                    .map(|(_, a)| (o, p, s, *a))
            })
        })
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let rows = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(&(o, p, s, a)) = jobs.get(i) else {
                    break;
                };
                let row = run(&data, reference_lanes, o, p, s, a);
                rows.lock().expect("no worker panics").push((i, row));
            });
        }
    });
    let mut rows = rows.into_inner().expect("no worker panics");
    rows.sort_by_key(|r| r.0);
    println!(
        "lanes: {}",
        if reference_lanes {
            "reference (paper pipeline)"
        } else {
            "derived from OSM by lanealign"
        }
    );
    println!("| odometry | preset | seq | raw APE-2D (m) | corrected (m) | RMSE | lateral RMSE | heading (deg) | max (m) | attempts | accepted | resets |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut sums: Vec<(&str, f64, f64, usize)> = Vec::new();
    for (_, row) in rows {
        let r = row?;
        println!(
            "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {} | {} | {} |",
            r.odometry,
            r.preset.name(),
            r.seq,
            r.raw.mean_m,
            r.corrected.mean_m,
            r.corrected.rmse_m,
            r.corrected.lateral_rmse_m,
            r.corrected.heading_mean_deg,
            r.corrected.max_m,
            r.counts.0,
            r.counts.1,
            r.counts.2
        );
        match sums.iter_mut().find(|s| s.0 == r.odometry) {
            Some(s) => {
                s.1 += r.raw.mean_m;
                s.2 += r.corrected.mean_m;
                s.3 += 1;
            }
            None => sums.push((r.odometry, r.raw.mean_m, r.corrected.mean_m, 1)),
        }
    }
    for (o, raw, corr, n) in sums {
        println!(
            "| {o} | mean of {n} | | {:.3} | {:.3} | | | | | | | |",
            raw / n as f64,
            corr / n as f64
        );
    }
    Ok(())
}
