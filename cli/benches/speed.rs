//! Whole-process speed, side by side in one run: the paper's loop in Python (NumPy + SciPy, as its
//! authors' stack runs it) against `lanealign correct` with both methods and both match modes, on
//! the same input (docs/performance.md, "Whole process").
//!
//! `cargo bench -p lanealign-cli --bench speed [-- --poses 1500 --runs 15 --no-literal]`
//!
//! Input: the first `--poses` poses of KITTI 00's LiDAR odometry, the reference lanes of 00, the
//! kiss-icp preset. Every row is the wall time of a whole process (start, read, correct, write),
//! the median of `--runs` runs (3 of the reference modes; the Python loops run once: they take
//! seconds to minutes). The two fast modes alternate, half their runs before the Python loops and
//! half after, so that a burst of load on a shared machine does not decide their row. It
//! checks that the fast and reference match modes write identical files, and that the Python
//! loop agrees with `--method paper` (largest position difference).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::Parser;
use lanealign_cli::kitti::default_data_dir;
use lanealign_core::pose::AxisConvention;
use lanealign_core::trajectory::{read, Format};

#[derive(Parser)]
struct Args {
    /// Poses of KITTI 00 (LiDAR odometry) to correct.
    #[arg(long, default_value_t = 1500)]
    poses: usize,
    /// Runs of each lanealign configuration (at most 3 of the reference modes); the table shows
    /// the median.
    #[arg(long, default_value_t = 15)]
    runs: usize,
    /// Skip the per-candidate Python loop (the slowest row, about 30 s for 1500 poses).
    #[arg(long)]
    no_literal: bool,
    /// Cargo passes this to every bench.
    #[arg(long, hide = true)]
    bench: bool,
}

/// One timed process: wall time in seconds and what it wrote.
fn timed(command: &mut Command) -> anyhow::Result<f64> {
    let start = Instant::now();
    let output = command.output().context("starting a process")?;
    let seconds = start.elapsed().as_secs_f64();
    if !output.status.success() {
        bail!(
            "{:?} failed: {}",
            command,
            String::from_utf8_lossy(&output.stderr)
        );
    }
    Ok(seconds)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Planar positions of a KITTI camera pose file.
fn planar_positions(path: &Path) -> anyhow::Result<Vec<[f64; 2]>> {
    let camera = AxisConvention::KittiCamera;
    Ok(read(path, Format::Kitti)?
        .poses
        .iter()
        .map(|p| camera.to_planar(p).planar_position())
        .collect())
}

/// `x y` lines, as the Python loop writes them.
fn xy_lines(path: &Path) -> anyhow::Result<Vec<[f64; 2]>> {
    let text = std::fs::read_to_string(path)?;
    text.lines()
        .map(|line| {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(str::parse)
                .collect::<Result<_, _>>()?;
            match v.as_slice() {
                [x, y] => Ok([*x, *y]),
                _ => bail!("{}: not an `x y` line", path.display()),
            }
        })
        .collect()
}

fn largest_difference(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    a.iter()
        .zip(b)
        .map(|(p, q)| (p[0] - q[0]).hypot(p[1] - q[1]))
        .fold(0.0, f64::max)
}

struct Row {
    name: String,
    seconds: f64,
    runs: usize,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let data = default_data_dir();
    let lanes = data.join("reference/lanes/lanes_00.csv");
    let odometry = data.join("odometry/lidar/00.txt");
    if !lanes.is_file() || !odometry.is_file() {
        println!("SKIPPED: no KITTI data at {}", data.display());
        return Ok(());
    }
    let dir = tempfile::tempdir()?;
    let input = dir.path().join("input.txt");
    let text = std::fs::read_to_string(&odometry)?;
    let lines: Vec<&str> = text.lines().take(args.poses).collect();
    std::fs::write(&input, lines.join("\n") + "\n")?;
    let poses = lines.len();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/paper_loop.py");
    let lanealign = env!("CARGO_BIN_EXE_lanealign");

    let output = |method: &str, mode: &str| dir.path().join(format!("{method}_{mode}.txt"));
    let run_lanealign = |method: &str, mode: &str| -> anyhow::Result<f64> {
        timed(
            Command::new(lanealign)
                .args(["correct", "--lanes"])
                .arg(&lanes)
                .args(["--frame", "kitti-camera", "--preset", "kiss-icp"])
                .args(["--method", method, "--match-mode", mode])
                .arg(&input)
                .arg("-o")
                .arg(output(method, mode)),
        )
    };
    // The fast modes take tens of milliseconds, the Python loops tens of seconds: a burst of
    // load on this shared machine can cover every fast run in a row and none of a loop's. So
    // the fast modes alternate, and half their runs come before the Python loops, half after.
    let methods = ["paper", "robust"];
    let mut fast_times: [Vec<f64>; 2] = Default::default();
    let fast_rounds = |times: &mut [Vec<f64>; 2], rounds: usize| -> anyhow::Result<()> {
        for _ in 0..rounds {
            for (method, t) in methods.iter().zip(times.iter_mut()) {
                t.push(run_lanealign(method, "fast")?);
            }
        }
        Ok(())
    };
    fast_rounds(&mut fast_times, args.runs / 2)?;

    let mut rows = Vec::new();
    let mut python_paper = None;
    let python_variants: &[(&str, &[&str])] = if args.no_literal {
        &[("vectorized", &["--vectorized"])]
    } else {
        &[("vectorized", &["--vectorized"]), ("literal", &[])]
    };
    for (name, extra) in python_variants {
        let out = dir.path().join(format!("python_{name}.txt"));
        let mut command = Command::new("python3");
        command
            .arg(&script)
            .arg(&lanes)
            .arg(&input)
            .arg("kiss-icp")
            .arg(&out)
            .args(*extra);
        match timed(&mut command) {
            Ok(seconds) => {
                rows.push(Row {
                    name: format!("paper's loop, Python ({name} matching)"),
                    seconds,
                    runs: 1,
                });
                python_paper.get_or_insert(out);
            }
            Err(e) => println!("Python loop ({name}) not run: {e:#} (needs numpy and scipy)"),
        }
    }
    fast_rounds(&mut fast_times, args.runs - args.runs / 2)?;

    let mut outputs = Vec::new();
    for (method, fast) in methods.into_iter().zip(fast_times) {
        let reference = (0..args.runs.min(3))
            .map(|_| run_lanealign(method, "reference"))
            .collect::<anyhow::Result<Vec<f64>>>()?;
        for (mode, times) in [("fast", fast), ("reference", reference)] {
            rows.push(Row {
                name: format!("lanealign --method {method} --match-mode {mode}"),
                runs: times.len(),
                seconds: median(times),
            });
            outputs.push((method, mode, output(method, mode)));
        }
    }

    let literal = rows
        .iter()
        .find(|r| r.name.contains("literal"))
        .map(|r| r.seconds);
    let vectorized = rows
        .iter()
        .find(|r| r.name.contains("vectorized"))
        .map(|r| r.seconds);
    let ratio = |base: Option<f64>, s: f64| base.map_or("-".into(), |b| format!("{:.0}x", b / s));
    println!(
        "Whole process on the first {poses} poses of KITTI 00 (LiDAR odometry), reference lanes, \
         kiss-icp preset; median wall time of the runs."
    );
    println!("| run | runs | whole process (ms) | per pose (us) | vs Python literal | vs Python vectorized |");
    println!("|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {:.1} | {:.1} | {} | {} |",
            r.name,
            r.runs,
            r.seconds * 1e3,
            r.seconds * 1e6 / poses as f64,
            ratio(literal, r.seconds),
            ratio(vectorized, r.seconds),
        );
    }
    for method in ["paper", "robust"] {
        let files: Vec<&PathBuf> = outputs
            .iter()
            .filter(|(m, _, _)| *m == method)
            .map(|(_, _, p)| p)
            .collect();
        let same = std::fs::read(files[0])? == std::fs::read(files[1])?;
        println!(
            "--method {method}: fast and reference outputs {}",
            if same { "identical" } else { "DIFFER" }
        );
    }
    if let Some(python) = python_paper {
        let (_, _, paper) = &outputs[0];
        let d = largest_difference(&xy_lines(&python)?, &planar_positions(paper)?);
        println!("Python loop vs --method paper: largest position difference {d:.2e} m");
    }
    Ok(())
}
