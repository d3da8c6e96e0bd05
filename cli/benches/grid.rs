//! A grid at region scale, measured: a generated city of about a million lane points compiled
//! into 200 m cells (over 2000), and a drive across it corrected as lanealignd does (cells read
//! and assembled on a loader thread, the map swapped between poses). It prints resident memory
//! against distance driven, cell load and assembly times, and the per-pose correction time on
//! the grid (while a load is in flight and while none is) beside the same drive on the whole map
//! (docs/performance.md, "Grids").
//!
//! `cargo bench -p lanealign-cli --bench grid [-- --streets 80 --cell 200 --margin 50]`

use std::collections::BTreeSet;
use std::hash::Hasher;
use std::sync::Arc;
use std::time::{Duration, Instant};

use clap::Parser;
use lanealign_cli::synthetic::{city_lanes, drive_across, town_geometry, town_plane};
use lanealign_core::corrector::MatchMode;
use lanealign_core::grid::{self, Grid, GridSpec, LoadPolicy};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::Preset;
use lanealign_core::pose::AxisConvention;
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{CorrectedPose, Placement, SourceCorrector};
use lanealign_service::grid_loader::GridLoader;

#[derive(Parser)]
struct Args {
    /// Streets per axis of the generated city (80: 9.5 km square, about a million points).
    #[arg(long, default_value_t = 80)]
    streets: usize,
    /// Cell size (metres).
    #[arg(long, default_value_t = 200.0)]
    cell: f64,
    /// Cell margin (metres).
    #[arg(long, default_value_t = 50.0)]
    margin: f64,
    /// Only write the city's grid into this folder (what the bench runs in a child process).
    #[arg(long, hide = true)]
    write: Option<std::path::PathBuf>,
    /// Cargo passes this to every bench.
    #[arg(long, hide = true)]
    bench: bool,
}

/// Resident memory of this process (MiB), from /proc/self/status.
fn rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// The bits of a corrected pose and its status, hashed (the standard library's fixed-key
/// SipHash): equal records, equal fingerprints.
fn fingerprint(record: &CorrectedPose) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for v in record.pose.to_row_major() {
        h.write_u64(v.to_bits());
    }
    for v in record.covariance.iter().flatten() {
        h.write_u64(v.to_bits());
    }
    h.write(record.status.name().as_bytes());
    h.finish()
}

fn placement() -> Placement {
    Placement {
        convention: AxisConvention::Flu,
        anchored_from_odom: Se2::IDENTITY,
        smoothing: None,
    }
}

/// Writes the city's grid into `folder` (in a process of its own, so that the drive's resident
/// memory is the drive's alone).
fn write_city(args: &Args, folder: &std::path::Path) -> anyhow::Result<()> {
    let start = Instant::now();
    let (points, lane_km, cells) = {
        let map = LaneMap::new(&city_lanes(args.streets))?;
        let spec = GridSpec {
            plane: &town_plane(),
            spacing_m: 3.0,
            geometry: &town_geometry(),
            cell_size_m: args.cell,
            margin_m: args.margin,
            sign: None,
            map_version: 0,
        };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let manifest = grid::write(folder, &map, &spec, threads)?;
        (
            map.len(),
            map.lane_length_m() / 1000.0,
            manifest.cells.len(),
        )
    };
    println!(
        "city: {} streets, {points} lane points, {lane_km:.0} lane-km -> {cells} cells of {} m (margin {} m), written in {:.1} s",
        args.streets, args.cell, args.margin, start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if let Some(folder) = &args.write {
        return write_city(&args, folder);
    }
    let dir = tempfile::tempdir()?;
    let folder = dir.path().join("city");
    let status = std::process::Command::new(std::env::current_exe()?)
        .args([
            "--streets",
            &args.streets.to_string(),
            "--cell",
            &args.cell.to_string(),
        ])
        .args(["--margin", &args.margin.to_string(), "--write"])
        .arg(&folder)
        .status()?;
    anyhow::ensure!(status.success(), "writing the city failed");
    let grid = Arc::new(Grid::open(&folder)?);
    let (_, odometry) = drive_across(args.streets, 7);
    let params = Preset::KissIcp.robust_params();

    // The drive on the grid, as a daemon session runs it.
    let policy = LoadPolicy::default();
    let (loader, loader_thread) =
        GridLoader::spawn(grid.clone(), policy, None, Duration::from_secs(3600))?;
    let first = odometry[0].planar_position();
    let wanted = grid.wanted(&[first], &policy);
    let start_map = Arc::new(grid.map_of(wanted)?);
    let mut corrector = SourceCorrector::new(start_map, params, MatchMode::Fast, placement());
    let mut view = loader.view(1);
    // Every buffer the drive fills is allocated up front: the memory curve is the grid's.
    let n = odometry.len();
    let (mut quiet_us, mut loading_us) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut swap_us = Vec::with_capacity(n);
    let (mut swaps, mut uncovered, mut accepted) = (0u64, 0u64, 0usize);
    let mut used: BTreeSet<grid::CellKey> = BTreeSet::new();
    println!(
        "\n| driven (km) | resident memory (MiB) | cells in the map | lane points in the map |"
    );
    println!("|---:|---:|---:|---:|");
    let mut grid_run = Vec::with_capacity(n);
    for (i, pose) in odometry.iter().enumerate() {
        let t = Instant::now();
        let loading = view.loading();
        // As a session that keeps up: it never waits for the loader (one that is behind would).
        let arrived = view.arrived(|| false);
        let swapped = arrived.is_some();
        if let Some(map) = arrived {
            uncovered += corrector.map().uncovered_queries();
            corrector.replace_map(map);
            swaps += 1;
        }
        let next = corrector.predicted_position_in_map(pose);
        view.request_if_needed(corrector.window(), next);
        let (record, _) = corrector.correct(pose);
        let us = t.elapsed().as_secs_f64() * 1e6;
        accepted += usize::from(record.status.name() == "accepted");
        if swapped {
            swap_us.push(us);
        } else if loading || view.loading() {
            loading_us.push(us);
        } else {
            quiet_us.push(us);
        }
        grid_run.push(fingerprint(&record));
        if let Some(c) = corrector.map().coverage() {
            used.extend(c.loaded().iter().copied());
        }
        if i % 1000 == 0 || i + 1 == odometry.len() {
            let (cells_now, points_now) = corrector
                .map()
                .coverage()
                .map_or((0, 0), |c| (c.loaded().len(), corrector.map().len()));
            println!(
                "| {:.0} | {:.1} | {cells_now} | {points_now} |",
                i as f64 / 1000.0,
                rss_mib()
            );
        }
    }
    uncovered += corrector.map().uncovered_queries();
    drop(view);
    drop(loader);
    let _ = loader_thread.join();

    // Cell loads and assembly, timed alone over the cells the drive used.
    let mut load_us = Vec::new();
    let mut loaded = Vec::new();
    for &key in &used {
        let t = Instant::now();
        let cell = grid.load_cell(key)?;
        load_us.push(t.elapsed().as_secs_f64() * 1e6);
        loaded.push(Arc::new(cell));
    }
    let mut assemble_us = Vec::new();
    for window in loaded.chunks(30) {
        let t = Instant::now();
        let _ = grid::assemble(&grid, window)?;
        assemble_us.push(t.elapsed().as_secs_f64() * 1e6);
    }

    // The same drive on the whole map, in memory.
    let whole = Arc::new(LaneMap::new(&city_lanes(args.streets))?);
    let mut whole_corrector = SourceCorrector::new(whole, params, MatchMode::Fast, placement());
    let mut whole_us = Vec::with_capacity(odometry.len());
    let mut equal = true;
    for (pose, on_grid) in odometry.iter().zip(&grid_run) {
        let t = Instant::now();
        let (record, _) = whole_corrector.correct(pose);
        whole_us.push(t.elapsed().as_secs_f64() * 1e6);
        equal &= fingerprint(&record) == *on_grid;
    }
    println!(
        "\ndrive: {:.1} km, {} poses ({accepted} accepted), {swaps} map swaps, {} cells used, {uncovered} queries past the loaded cells; equal to the whole map bit for bit: {equal}",
        odometry.len() as f64 / 1000.0,
        odometry.len(),
        used.len()
    );
    println!("\n| | poses | p50 (us) | p99 (us) | max (us) |");
    println!("|---|---:|---:|---:|---:|");
    for (name, v) in [
        ("correction, whole map in memory", &mut whole_us),
        ("correction on the grid, no load in flight", &mut quiet_us),
        ("correction on the grid, a load in flight", &mut loading_us),
        ("correction on the grid, first on a new map", &mut swap_us),
        ("cell load (read, validate)", &mut load_us),
        ("map assembly (30 cells)", &mut assemble_us),
    ] {
        let n = v.len();
        let (p50, p99, max) = (quantile(v, 0.5), quantile(v, 0.99), quantile(v, 1.0));
        println!("| {name} | {n} | {p50:.1} | {p99:.1} | {max:.1} |");
    }
    Ok(())
}
