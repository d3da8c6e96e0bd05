//! Compares correction methods on the real KITTI odometry runs of `../shared/data`, on lanes
//! lanealign derives from OpenStreetMap: the paper's method, lanealign's robust method, the robust
//! method with each of its changes switched off in turn, and the smoothed output. Prints the
//! ablation table of `docs/method.md` and, with `--per-sequence`, every sequence.
//!
//! `cargo run --release -p lanealign-client --example ablation [-- --data DIR]
//!  [-- --per-sequence] [-- --variant NAME:key=value,key=value]...`
//!
//! A `--variant` replaces the built-in list: it is the robust method with the given overrides
//! (or the paper's, when NAME starts with `paper`); `+smooth` in the list turns smoothing on.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::{bail, Context};
use lanealign_client::kitti::{anchors, default_data_dir, SEQUENCES};
use lanealign_client::maps::MapSource;
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::Projection;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::{ape_2d, output_jumps};
use lanealign_core::offline::{correct, Source};
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::smoothing::Smoothing;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::osm_lanes::LaneOptions;

/// Every preset on both runs: first the pairs of `reference/results.csv` (the first two are the
/// paper's), then the crossed ones.
const PAIRS: [(&str, Preset); 8] = [
    ("lidar", Preset::KissIcp),
    ("stereo_vo", Preset::OrbSlam3),
    ("lidar", Preset::Liodom),
    ("stereo_vo", Preset::Basalt),
    ("lidar", Preset::OrbSlam3),
    ("stereo_vo", Preset::KissIcp),
    ("lidar", Preset::Basalt),
    ("stereo_vo", Preset::Liodom),
];

#[derive(Clone)]
struct Variant {
    name: String,
    method: Method,
    overrides: Vec<String>,
    smooth: bool,
}

impl Variant {
    fn parse(spec: &str) -> anyhow::Result<Variant> {
        let (name, list) = spec.split_once(':').unwrap_or((spec, ""));
        let mut overrides = Vec::new();
        let mut smooth = false;
        for item in list.split(',').filter(|s| !s.is_empty()) {
            if item == "+smooth" {
                smooth = true;
            } else {
                overrides.push(item.to_string());
            }
        }
        let method = if name.starts_with("paper") {
            Method::Paper
        } else {
            Method::Robust
        };
        Ok(Variant {
            name: name.to_string(),
            method,
            overrides,
            smooth,
        })
    }
}

/// The built-in ablation: each change of the robust method off in turn.
fn ablation() -> anyhow::Result<Vec<Variant>> {
    [
        "paper",
        "robust",
        "robust, no lane tolerance:lane_tolerance_m=0",
        "robust, no match gate:max_match_distance_m=inf",
        "robust, no window path limit:max_window_path_m=inf",
        "robust, smooth:+smooth",
    ]
    .into_iter()
    .map(Variant::parse)
    .collect()
}

struct Sequence {
    gt: Vec<Pose3>,
    odom: Vec<Pose3>,
    map: Arc<LaneMap>,
    plane_from_odom: Se2,
}

struct Outcome {
    raw_mean: f64,
    raw_max: f64,
    mean: f64,
    max: f64,
    jump_m: f64,
    jump_deg: f64,
}

fn load(data: &std::path::Path, odometry: &str, seq: &str) -> anyhow::Result<Sequence> {
    let anchors = anchors(data)?;
    let anchor = *anchors.get(seq).context("no anchor")?;
    let gt = read(&data.join(format!("kitti/poses/{seq}.txt")), Format::Kitti)?;
    let odom = read(
        &data.join(format!("odometry/{odometry}/{seq}.txt")),
        Format::Kitti,
    )?;
    let loaded = MapSource::Osm {
        path: data.join(format!("osm/kitti_{seq}.osm")),
        anchor,
        projection: Projection::Kitti,
        options: LaneOptions::default(),
    }
    .load()?;
    Ok(Sequence {
        gt: gt.poses,
        odom: odom.poses,
        map: loaded.map,
        plane_from_odom: loaded.plane_from_odom,
    })
}

fn run(s: &Sequence, preset: Preset, v: &Variant) -> anyhow::Result<Outcome> {
    let cam = AxisConvention::KittiCamera;
    let mut params = v.method.params(preset);
    for o in &v.overrides {
        params.set_pair(o)?;
    }
    let source = Source {
        convention: cam,
        plane_from_odom: s.plane_from_odom,
        smoothing: v.smooth.then(Smoothing::default),
    };
    let out = correct(s.map.clone(), params, MatchMode::Fast, source, &s.odom);
    let planar = |p: &[Pose3]| -> Vec<Pose3> { p.iter().map(|p| cam.to_planar(p)).collect() };
    let gt = planar(&s.gt);
    let raw = planar(&s.odom);
    let est: Vec<Pose3> = out.iter().map(|c| cam.to_planar(&c.pose)).collect();
    let raw_ape = ape_2d(&gt, &raw)?;
    let ape = ape_2d(&gt, &est)?;
    let jumps = output_jumps(&raw, &est)?;
    Ok(Outcome {
        raw_mean: raw_ape.mean_m,
        raw_max: raw_ape.max_m,
        mean: ape.mean_m,
        max: ape.max_m,
        jump_m: jumps.max_position_m,
        jump_deg: jumps.max_yaw_deg,
    })
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let data = args
        .iter()
        .position(|a| a == "--data")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from)
        .unwrap_or_else(default_data_dir);
    if !data.join("kitti/georef.csv").is_file() {
        bail!("no KITTI data at {} (pass --data DIR)", data.display());
    }
    let per_sequence = args.iter().any(|a| a == "--per-sequence");
    let custom: Vec<Variant> = args
        .windows(2)
        .filter(|w| w[0] == "--variant")
        .map(|w| Variant::parse(&w[1]))
        .collect::<anyhow::Result<_>>()?;
    let variants = if custom.is_empty() {
        ablation()?
    } else {
        custom
    };
    let odometries = ["lidar", "stereo_vo"];
    let mut loaded = HashMap::new();
    for odometry in odometries {
        for seq in SEQUENCES {
            loaded.insert((odometry, seq), load(&data, odometry, seq)?);
        }
    }
    let jobs: Vec<(usize, usize, &str)> = (0..PAIRS.len())
        .flat_map(|p| (0..variants.len()).flat_map(move |v| SEQUENCES.map(|s| (p, v, s))))
        .collect();
    let next = AtomicUsize::new(0);
    let results = Mutex::new(HashMap::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&(p, v, seq)) = jobs.get(i) else {
                    break;
                };
                let (odometry, preset) = PAIRS[p];
                let outcome = run(&loaded[&(odometry, seq)], preset, &variants[v]);
                results
                    .lock()
                    .expect("no worker panics")
                    .insert((p, v, seq), outcome);
            });
        }
    });
    let results = results.into_inner().expect("no worker panics");
    let get = |p: usize, v: usize, seq: &'static str| -> anyhow::Result<&Outcome> {
        results[&(p, v, seq)]
            .as_ref()
            .map_err(|e| anyhow::anyhow!("{} {seq}: {e:#}", PAIRS[p].0))
    };
    println!("Mean APE-2D over the ten sequences (metres); worst excess: the largest (corrected - raw) mean APE of a sequence; worst max excess: the largest (corrected - raw) maximum error; jumps: the largest frame-to-frame change beyond the odometry's motion.\n");
    println!("| odometry | preset | variant | mean APE-2D | worst excess | worst max excess | jumps (m / deg) |");
    println!("|---|---|---|---|---|---|---|");
    for (p, (odometry, preset)) in PAIRS.iter().enumerate() {
        let raw: f64 = SEQUENCES
            .iter()
            .map(|&s| get(p, 0, s).map(|o| o.raw_mean))
            .sum::<anyhow::Result<f64>>()?
            / SEQUENCES.len() as f64;
        println!("| {odometry} | {} | raw | {raw:.3} | | | |", preset.name());
        for (v, variant) in variants.iter().enumerate() {
            let (mut mean, mut excess, mut max_excess, mut jm, mut jd) =
                (0.0, f64::MIN, f64::MIN, 0.0f64, 0.0f64);
            for seq in SEQUENCES {
                let o = get(p, v, seq)?;
                mean += o.mean / SEQUENCES.len() as f64;
                excess = excess.max(o.mean - o.raw_mean);
                max_excess = max_excess.max(o.max - o.raw_max);
                jm = jm.max(o.jump_m);
                jd = jd.max(o.jump_deg);
            }
            println!(
                "| {odometry} | {} | {} | {mean:.3} | {excess:+.3} | {max_excess:+.2} | {jm:.3} / {jd:.3} |",
                preset.name(),
                variant.name
            );
        }
    }
    if per_sequence {
        println!("\nPer sequence: mean APE-2D (max error), metres.\n");
        let header: Vec<String> = variants.iter().map(|v| v.name.clone()).collect();
        println!("| odometry | preset | seq | raw | {} |", header.join(" | "));
        println!("|---|---|---|---|{}", "---|".repeat(variants.len()));
        for (p, (odometry, preset)) in PAIRS.iter().enumerate() {
            for seq in SEQUENCES {
                let raw = get(p, 0, seq)?;
                let cells: Vec<String> = (0..variants.len())
                    .map(|v| get(p, v, seq).map(|o| format!("{:.3} ({:.1})", o.mean, o.max)))
                    .collect::<anyhow::Result<_>>()?;
                println!(
                    "| {odometry} | {} | {seq} | {:.3} ({:.1}) | {} |",
                    preset.name(),
                    raw.raw_mean,
                    raw.raw_max,
                    cells.join(" | ")
                );
            }
        }
    }
    Ok(())
}
