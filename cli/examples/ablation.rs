//! Compares correction methods on the real KITTI odometry runs of `../shared/data`, on lanes
//! lanealign derives from OpenStreetMap: the paper's method, lanealign's robust method, the robust
//! method with each of its changes switched off in turn, and the smoothed output. Prints the
//! ablation table of `docs/method.md` and, with `--per-sequence`, every sequence.
//!
//! `cargo run --release -p lanealign-cli --example ablation [-- --data DIR]
//!  [-- --per-sequence] [-- --variant NAME:key=value,key=value]...`
//!
//! A `--variant` replaces the built-in list: it is the robust method with the given overrides
//! (or the paper's, when NAME starts with `paper`); `+smooth` in the list turns smoothing on.
//! `--pairs RUN:PRESET,...` replaces the (run, preset) pairs; the run `gt` feeds the ground truth
//! itself as odometry, which shows the error the map alone induces (a perfect corrector leaves
//! it untouched); the run `drift-DEG` is odometry made from the ground truth whose heading drifts
//! as a seeded random walk of DEG degrees per square root of 100 m driven (`drift-0.2` drifts as
//! the kiss-icp preset assumes): odometry of any accuracy, to see where correcting stops paying.
//!
//! `--jitter N` also corrects N copies of every run whose translations are moved by a seeded
//! uniform amount of at most [`JITTER_M`] (1 micrometre, far below any odometry's precision), and
//! adds to the summary the range of each figure over the copies. The runs are chaotic across the
//! step's thresholds (docs/method.md, "Caveats"): a difference between variants inside that range
//! is noise.
//!
//! It keeps the tables (markdown and CSV) and, per pair, a plot of each variant's mean APE-2D per
//! sequence in `results/ablation/<UTC time>/` (`--results DIR` for another parent), `latest`
//! pointing at it.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::Context;
use lanealign_cli::kitti::{anchors, data_dir_from_args, SEQUENCES};
use lanealign_cli::maps::MapSource;
use lanealign_cli::report::{self, Table};
use lanealign_cli::synthetic::{heading_drifted, Lcg};
use lanealign_cli::{plots, results, status_file};
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::Projection;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::{
    ape_2d, calibration, output_jumps, scaled_steps, Calibration, CHI2_2DOF_95,
};
use lanealign_core::params::{CorrectorConfig, Method, Overrides, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::smoothing::Smoothing;
use lanealign_core::source_corrector::{correct_trajectory, Placement};
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

/// How far `--jitter` moves each coordinate of an odometry position at most (metres).
const JITTER_M: f64 = 1e-6;

/// `odom` with every translation coordinate moved by a uniform amount in `[-JITTER_M, JITTER_M)`,
/// the same on every machine for one `seed`.
fn jittered(odom: &[Pose3], seed: u64) -> Vec<Pose3> {
    let mut poses = odom.to_vec();
    let mut rng = Lcg(seed);
    for pose in &mut poses {
        for v in pose.translation.iter_mut() {
            *v += (2.0 * rng.uniform() - 1.0) * JITTER_M;
        }
    }
    poses
}

/// The prefix of a `--pairs` run made from the ground truth with a drifting heading.
const DRIFT_RUN: &str = "drift-";

#[derive(Clone)]
struct Variant {
    name: String,
    method: Method,
    overrides: Overrides,
    smooth: bool,
    /// The lane geometry: [`LaneOptions::unmarked_offset_scale`].
    unmarked: f64,
}

impl Variant {
    fn parse(spec: &str) -> anyhow::Result<Variant> {
        let (name, list) = spec.split_once(':').unwrap_or((spec, ""));
        let mut pairs = String::new();
        let mut smooth = false;
        let method = if name.starts_with("paper") {
            Method::Paper
        } else {
            Method::Robust
        };
        let mut unmarked = LaneOptions::for_method(method).unmarked_offset_scale;
        for item in list.split(',').filter(|s| !s.is_empty()) {
            if item == "+smooth" {
                smooth = true;
            } else if let Some(v) = item.strip_prefix("unmarked_offset_scale=") {
                unmarked = v.parse()?;
            } else {
                let (key, value) = item.split_once('=').context("KEY=VALUE")?;
                pairs.push_str(&format!("{key} = {value}\n"));
            }
        }
        let overrides: Overrides = toml::from_str(&pairs)?;
        Ok(Variant {
            name: name.to_string(),
            method,
            overrides,
            smooth,
            unmarked,
        })
    }
}

/// Issue 14's band for the fraction of poses inside their 95 % ellipse.
const ISSUE_14_BAND: std::ops::RangeInclusive<f64> = 0.85..=0.99;

/// The chance that a covariance describing a sequence's errors exactly puts its coverage in
/// [`ISSUE_14_BAND`]: the fraction of 2000 series (fixed seed) of `poses` two-dimensional
/// whitened errors whose coverage lies in the band. Each series is an AR(1) process with as many
/// independent samples as the sequence's errors (coefficient `(tau - 1) / (tau + 1)` for the
/// integrated time `tau`).
fn band_chance_if_calibrated(poses: usize, independent_samples: f64) -> f64 {
    const TRIALS: usize = 2000;
    let tau = poses as f64 / independent_samples;
    let phi = (tau - 1.0) / (tau + 1.0);
    let q = (1.0 - phi * phi).sqrt();
    let mut rng = Lcg(14);
    let in_band = (0..TRIALS)
        .filter(|_| {
            let mut x = [rng.normal(), rng.normal()];
            let mut inside = 0usize;
            for i in 0..poses {
                if i > 0 {
                    x = [phi * x[0] + q * rng.normal(), phi * x[1] + q * rng.normal()];
                }
                inside += usize::from(x[0] * x[0] + x[1] * x[1] <= CHI2_2DOF_95);
            }
            ISSUE_14_BAND.contains(&(inside as f64 / poses as f64))
        })
        .count();
    in_band as f64 / TRIALS as f64
}

/// The calibration of a run's sequences taken together: every pose of every sequence counts
/// once, and the independent samples add up (the sequences' errors are taken as independent of
/// each other).
#[derive(Clone, Copy, Default)]
struct Pooled {
    inside: f64,
    nees_sum: f64,
    independent_samples: f64,
    poses: usize,
}

impl Pooled {
    fn add(&mut self, c: &Calibration) {
        self.inside += (c.cov95_coverage * c.poses as f64).round();
        self.nees_sum += c.nees_mean * c.poses as f64;
        self.independent_samples += c.independent_samples;
        self.poses += c.poses;
    }

    fn calibration(&self) -> Calibration {
        let n = self.poses as f64;
        Calibration {
            cov95_coverage: self.inside / n,
            nees_mean: self.nees_sum / n,
            independent_samples: self.independent_samples,
            poses: self.poses,
        }
    }
}

/// The built-in ablation: each change of the robust method off in turn.
fn ablation() -> anyhow::Result<Vec<Variant>> {
    [
        "paper",
        "robust",
        "robust, paper lane geometry:unmarked_offset_scale=1",
        "robust, no lane tolerance:lane_tolerance_m=0",
        "robust, no match gate:max_match_distance_m=inf",
        "robust, no window path limit:max_window_path_m=inf",
        "robust, newest matches trimmed:untrimmed_newest=0",
        "robust, gate since the last accepted step:gate_widens_through_null_steps=false",
        "robust, an alignment on every pose:alignment_spacing_m=0",
        "robust, every standing pose in the window:standstill_speed_mps=0",
        "robust, no scale estimate:scale_sigma=0",
        "robust, stalls not watched:watch_stalls=false",
        "robust, smooth:+smooth",
    ]
    .into_iter()
    .map(Variant::parse)
    .collect()
}

struct Sequence {
    gt: Vec<Pose3>,
    /// The odometry run, then its jittered copies (`--jitter`).
    odom: Vec<Vec<Pose3>>,
}

struct Map {
    lanes: Arc<LaneMap>,
    anchored_from_odom: Se2,
}

struct Outcome {
    raw_mean: f64,
    raw_max: f64,
    mean: f64,
    max: f64,
    jump_m: f64,
    jump_deg: f64,
    calibration: Calibration,
}

fn load(
    data: &std::path::Path,
    odometry: &str,
    seq: &str,
    jitter: u64,
) -> anyhow::Result<Sequence> {
    let gt = read(&data.join(format!("kitti/poses/{seq}.txt")), Format::Kitti)?;
    // One seed per copy, run and sequence, so that no two runs are moved alike.
    let name = odometry
        .bytes()
        .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(u64::from(b)));
    let seq_number = seq.parse::<u64>().unwrap_or(0);
    let odom_poses = match odometry {
        "gt" => gt.poses.clone(),
        run => match run.strip_prefix(DRIFT_RUN) {
            Some(level) => {
                let level: f64 = level
                    .parse()
                    .with_context(|| format!("{run}: not {DRIFT_RUN}DEGREES"))?;
                heading_drifted(
                    &gt.poses,
                    AxisConvention::KittiCamera,
                    level,
                    name.wrapping_add(seq_number),
                )
            }
            None => {
                read(
                    &data.join(format!("odometry/{run}/{seq}.txt")),
                    Format::Kitti,
                )?
                .poses
            }
        },
    };
    let seed = |copy: u64| {
        copy.wrapping_mul(1_000_003)
            .wrapping_add(name.wrapping_mul(101))
            .wrapping_add(seq_number)
    };
    let copies: Vec<Vec<Pose3>> = (1..=jitter)
        .map(|copy| jittered(&odom_poses, seed(copy)))
        .collect();
    Ok(Sequence {
        gt: gt.poses,
        odom: std::iter::once(odom_poses).chain(copies).collect(),
    })
}

fn load_map(data: &std::path::Path, seq: &str, unmarked: f64) -> anyhow::Result<Map> {
    let anchors = anchors(data)?;
    let anchor = *anchors.get(seq).context("no anchor")?;
    let loaded = MapSource::Osm {
        path: data.join(format!("osm/kitti_{seq}.osm")),
        anchor,
        projection: Projection::Kitti,
        options: LaneOptions {
            unmarked_offset_scale: unmarked,
            ..LaneOptions::default()
        },
    }
    .load()?;
    Ok(Map {
        lanes: loaded.map,
        anchored_from_odom: loaded.anchored_from_odom,
    })
}

fn run(
    s: &Sequence,
    copy: usize,
    map: &Map,
    preset: Preset,
    v: &Variant,
) -> anyhow::Result<Outcome> {
    let cam = AxisConvention::KittiCamera;
    let params = CorrectorConfig {
        overrides: v.overrides,
        ..CorrectorConfig::new(preset, v.method)
    }
    .params()?;
    let placement = Placement {
        convention: cam,
        anchored_from_odom: map.anchored_from_odom,
        smoothing: v.smooth.then(Smoothing::default),
    };
    let out = correct_trajectory(
        map.lanes.clone(),
        params,
        MatchMode::Fast,
        placement,
        &s.odom[copy],
    );
    let planar = |p: &[Pose3]| -> Vec<Pose3> { p.iter().map(|p| cam.to_planar(p)).collect() };
    let gt = planar(&s.gt);
    let raw = planar(&s.odom[copy]);
    let est: Vec<Pose3> = out.iter().map(|c| cam.to_planar(&c.pose)).collect();
    let raw_ape = ape_2d(&gt, &raw)?;
    let ape = ape_2d(&gt, &est)?;
    // Beyond the odometry as the corrector scaled it (the orb-slam3 preset estimates the scale).
    let scale_after: Vec<f64> = out.iter().map(|c| c.odometry_scale).collect();
    let jumps = output_jumps(&scaled_steps(&raw, &scale_after), &est)?;
    let anchor_yaw = map.anchored_from_odom.yaw();
    let cov: Vec<[[f64; 2]; 2]> = out
        .iter()
        .map(|c| status_file::position_covariance_in_odom(anchor_yaw, &c.covariance))
        .collect();
    Ok(Outcome {
        calibration: calibration(&gt, &est, &cov)?,
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
    let data = data_dir_from_args(&args)?;
    let per_sequence = args.iter().any(|a| a == "--per-sequence");
    let jitter: u64 = match args.iter().position(|a| a == "--jitter") {
        Some(i) => args
            .get(i + 1)
            .context("--jitter takes a number of copies")?
            .parse()
            .context("--jitter takes a number of copies")?,
        None => 0,
    };
    let copies = jitter as usize + 1;
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
    let pairs: Vec<(String, Preset)> = match args
        .iter()
        .position(|a| a == "--pairs")
        .and_then(|i| args.get(i + 1))
    {
        Some(list) => list
            .split(',')
            .map(|p| {
                let (run, preset) = p.split_once(':').context("--pairs takes RUN:PRESET,...")?;
                Ok((run.to_string(), preset.parse()?))
            })
            .collect::<anyhow::Result<_>>()?,
        None => PAIRS.iter().map(|&(r, p)| (r.to_string(), p)).collect(),
    };
    let mut odometries: Vec<&str> = pairs.iter().map(|(r, _)| r.as_str()).collect();
    odometries.sort_unstable();
    odometries.dedup();
    let mut loaded = HashMap::new();
    for &odometry in &odometries {
        for seq in SEQUENCES {
            loaded.insert((odometry, seq), load(&data, odometry, seq, jitter)?);
        }
    }
    let mut maps = HashMap::new();
    for v in &variants {
        for seq in SEQUENCES {
            if let std::collections::hash_map::Entry::Vacant(e) =
                maps.entry((seq, v.unmarked.to_bits()))
            {
                e.insert(load_map(&data, seq, v.unmarked)?);
            }
        }
    }
    let jobs: Vec<(usize, usize, &str, usize)> = (0..pairs.len())
        .flat_map(|p| (0..variants.len()).flat_map(move |v| SEQUENCES.map(|s| (p, v, s))))
        .flat_map(|(p, v, s)| (0..copies).map(move |c| (p, v, s, c)))
        .collect();
    let next = AtomicUsize::new(0);
    let results = Mutex::new(HashMap::new());
    let progress = report::progress(jobs.len(), "correcting");
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&(p, v, seq, copy)) = jobs.get(i) else {
                    break;
                };
                let (odometry, preset) = (pairs[p].0.as_str(), pairs[p].1);
                let variant = &variants[v];
                let map = &maps[&(seq, variant.unmarked.to_bits())];
                let outcome = run(&loaded[&(odometry, seq)], copy, map, preset, variant);
                results
                    .lock()
                    .expect("no worker panics")
                    .insert((p, v, seq, copy), outcome);
                progress.inc(1);
            });
        }
    });
    progress.finish_and_clear();
    let dir = results::create(&results::parent_from_args(&args, "results/ablation"))?;
    let results = results.into_inner().expect("no worker panics");
    let get_copy =
        |p: usize, v: usize, seq: &'static str, copy: usize| -> anyhow::Result<&Outcome> {
            results[&(p, v, seq, copy)]
                .as_ref()
                .map_err(|e| anyhow::anyhow!("{} {seq}: {e:#}", pairs[p].0))
        };
    let get = |p: usize, v: usize, seq: &'static str| get_copy(p, v, seq, 0);
    // The mean over the sequences and the worst (corrected - raw) mean of one, for one copy.
    let figures = |p: usize, v: usize, copy: usize| -> anyhow::Result<(f64, f64)> {
        let (mut mean, mut excess) = (0.0, f64::MIN);
        for seq in SEQUENCES {
            let o = get_copy(p, v, seq, copy)?;
            mean += o.mean / SEQUENCES.len() as f64;
            excess = excess.max(o.mean - o.raw_mean);
        }
        Ok((mean, excess))
    };
    let names = |first: &[&str]| -> Vec<String> {
        first
            .iter()
            .map(|s| s.to_string())
            .chain(variants.iter().map(|v| v.name.clone()))
            .collect()
    };
    let mut columns: Vec<String> = [
        "odometry",
        "preset",
        "variant",
        "mean APE-2D",
        "worst excess",
        "worst max excess",
        "jumps (m / deg)",
    ]
    .map(String::from)
    .to_vec();
    if jitter > 0 {
        columns.push(format!("mean, {jitter} jittered copies"));
        columns.push(format!("worst excess, {jitter} jittered copies"));
    }
    let mut summary = Table::new(
        "Mean APE-2D over the ten sequences (metres); worst excess: the largest (corrected - raw) mean APE of a sequence; worst max excess: the largest (corrected - raw) maximum error; jumps: the largest frame-to-frame change beyond the odometry's motion; with --jitter, the range (min - max) of the first two over copies of the runs moved by at most 1 micrometre.",
        columns,
    );
    for (p, (odometry, preset)) in pairs.iter().enumerate() {
        let raw: f64 = SEQUENCES
            .iter()
            .map(|&s| get(p, 0, s).map(|o| o.raw_mean))
            .sum::<anyhow::Result<f64>>()?
            / SEQUENCES.len() as f64;
        let row = |cells: &[&str]| {
            [odometry.as_str(), preset.name()]
                .into_iter()
                .chain(cells.iter().copied())
                .map(String::from)
                .collect()
        };
        let raw_text = format!("{raw:.3}");
        let mut raw_cells = vec!["raw", raw_text.as_str(), "", "", ""];
        if jitter > 0 {
            raw_cells.extend(["", ""]);
        }
        summary.push(row(&raw_cells));
        for (v, variant) in variants.iter().enumerate() {
            let (mean, excess) = figures(p, v, 0)?;
            let (mut max_excess, mut jm, mut jd) = (f64::MIN, 0.0f64, 0.0f64);
            for seq in SEQUENCES {
                let o = get(p, v, seq)?;
                max_excess = max_excess.max(o.max - o.raw_max);
                jm = jm.max(o.jump_m);
                jd = jd.max(o.jump_deg);
            }
            let mut cells = vec![
                variant.name.clone(),
                format!("{mean:.3}"),
                format!("{excess:+.3}"),
                format!("{max_excess:+.2}"),
                format!("{jm:.3} / {jd:.3}"),
            ];
            if jitter > 0 {
                let copies: Vec<(f64, f64)> = (1..copies)
                    .map(|c| figures(p, v, c))
                    .collect::<anyhow::Result<_>>()?;
                let range = |f: fn(&(f64, f64)) -> f64, signed: bool| {
                    let lo = copies.iter().map(f).fold(f64::INFINITY, f64::min);
                    let hi = copies.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
                    if signed {
                        format!("{lo:+.3} - {hi:+.3}")
                    } else {
                        format!("{lo:.3} - {hi:.3}")
                    }
                };
                cells.push(range(|c| c.0, false));
                cells.push(range(|c| c.1, true));
            }
            summary.push(row(&cells.iter().map(String::as_str).collect::<Vec<_>>()));
        }
        let seqs: Vec<f64> = SEQUENCES
            .iter()
            .map(|s| s.parse().unwrap_or(f64::NAN))
            .collect();
        let means: Vec<Vec<f64>> = (0..variants.len())
            .map(|v| {
                SEQUENCES
                    .iter()
                    .map(|&s| get(p, v, s).map(|o| o.mean))
                    .collect::<anyhow::Result<_>>()
            })
            .collect::<anyhow::Result<_>>()?;
        let raw_means: Vec<f64> = SEQUENCES
            .iter()
            .map(|&s| get(p, 0, s).map(|o| o.raw_mean))
            .collect::<anyhow::Result<_>>()?;
        let mut series = vec![("raw", raw_means.as_slice(), plots::GROUND_TRUTH)];
        for (v, variant) in variants.iter().enumerate() {
            let color = plots::PALETTE[v % plots::PALETTE.len()];
            series.push((variant.name.as_str(), means[v].as_slice(), color));
        }
        plots::lines(
            &dir.join(format!("ape_{odometry}_{}.svg", preset.name())),
            &format!(
                "{odometry}, {} preset: mean APE-2D per sequence",
                preset.name()
            ),
            ("KITTI sequence", "mean APE-2D (m)"),
            &seqs,
            &series,
        )?;
    }
    print!("{}", summary.markdown());
    summary.save(&dir, "summary")?;
    if args.iter().any(|a| a == "--calibration") {
        let mut table = Table::new(
            "Calibration per sequence: fraction of poses inside the 95 % ellipse of their covariance / mean NEES of the planar position (2 when calibrated) / independent samples (the poses over the integrated autocorrelation time of their whitened errors) / the chance that a covariance describing the errors exactly puts the sequence in issue 14's band (0.85-0.99), given as many poses correlated alike. Last per pair: how many sequences are in the band, how many a calibrated covariance would put there on average, and the chance it puts all of them there; and the same four figures over all poses of the pair's sequences taken together.",
            names(&["odometry", "preset", "seq"]),
        );
        for (p, (odometry, preset)) in pairs.iter().enumerate() {
            let mut in_band = vec![(0, 0.0, 1.0); variants.len()];
            let mut pooled = vec![Pooled::default(); variants.len()];
            for seq in SEQUENCES {
                let mut cells = vec![odometry.clone(), preset.name().into(), seq.into()];
                for (v, (band, pool)) in in_band.iter_mut().zip(&mut pooled).enumerate() {
                    let c = get(p, v, seq)?.calibration;
                    let chance = band_chance_if_calibrated(c.poses, c.independent_samples);
                    band.0 += usize::from(ISSUE_14_BAND.contains(&c.cov95_coverage));
                    band.1 += chance;
                    band.2 *= chance;
                    pool.add(&c);
                    cells.push(format!(
                        "{:.3} / {:.2} / {:.0} / {chance:.2}",
                        c.cov95_coverage, c.nees_mean, c.independent_samples
                    ));
                }
                table.push(cells);
            }
            let mut cells = vec![odometry.clone(), preset.name().into(), "in band".into()];
            for (count, expected, all) in in_band {
                cells.push(format!(
                    "{count} of {}; calibrated {expected:.1}, all {all:.2}",
                    SEQUENCES.len()
                ));
            }
            table.push(cells);
            let mut cells = vec![odometry.clone(), preset.name().into(), "all poses".into()];
            for pool in &pooled {
                let c = pool.calibration();
                let chance = band_chance_if_calibrated(c.poses, c.independent_samples);
                cells.push(format!(
                    "{:.3} / {:.2} / {:.0} / {chance:.2}",
                    c.cov95_coverage, c.nees_mean, c.independent_samples
                ));
            }
            table.push(cells);
        }
        print!("\n{}", table.markdown());
        table.save(&dir, "calibration")?;
    }
    if per_sequence {
        let mut table = Table::new(
            "Per sequence: mean APE-2D (max error), metres.",
            names(&["odometry", "preset", "seq", "raw"]),
        );
        for (p, (odometry, preset)) in pairs.iter().enumerate() {
            for seq in SEQUENCES {
                let raw = get(p, 0, seq)?;
                let mut cells = vec![
                    odometry.clone(),
                    preset.name().into(),
                    seq.into(),
                    format!("{:.3} ({:.1})", raw.raw_mean, raw.raw_max),
                ];
                for v in 0..variants.len() {
                    let o = get(p, v, seq)?;
                    cells.push(format!("{:.3} ({:.1})", o.mean, o.max));
                }
                table.push(cells);
            }
        }
        print!("\n{}", table.markdown());
        table.save(&dir, "per_sequence")?;
    }
    eprintln!("results in {}", dir.display());
    Ok(())
}
