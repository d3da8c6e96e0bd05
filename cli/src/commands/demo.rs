//! `lanealign demo`: the whole product in one command. Compiles a map, starts `lanealignd`,
//! replays an odometry run through it over shared memory, and prints raw vs corrected accuracy
//! and latency. Uses KITTI 00 from `../shared/data` when present, else the synthetic town.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use lanealign_cli::daemon_config;
use lanealign_cli::daemon_process::DaemonProcess;
use lanealign_cli::kitti::{anchors, default_data_dir};
use lanealign_cli::replay::{replay, Rate, Replay};
use lanealign_cli::{status_file, synthetic};
use lanealign_client::Connection;
use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::lane_geometry::LaneGeometry;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::{ape_2d, calibration};
use lanealign_core::params::{CorrectorConfig, Method, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::source_corrector::{correct_trajectory, Placement};
use lanealign_core::tile;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_wire::payload::{from_upper_triangle, StatusCode};
use lanealign_wire::wait::WaitStrategy;

use super::percentile_us;

struct Scenario {
    name: String,
    map: LaneMap,
    plane: MapPlane,
    geometry: LaneGeometry,
    anchor: Anchor,
    convention: AxisConvention,
    truth: Vec<Pose3>,
    odometry: Vec<Pose3>,
}

fn kitti(data: &Path) -> anyhow::Result<Scenario> {
    let anchor = *anchors(data)?.get("00").context("no anchor for KITTI 00")?;
    let options = CompileOptions {
        origin: Some((anchor.lat(), anchor.lon())),
        projection: Projection::Kitti,
        ..CompileOptions::default()
    };
    let compiled = compile(&[data.join("osm/kitti_00.osm")], &options)?;
    Ok(Scenario {
        name: "KITTI 00, real LiDAR odometry, lanes from OpenStreetMap".into(),
        map: compiled.map,
        plane: compiled.plane,
        geometry: compiled.geometry,
        anchor,
        convention: AxisConvention::KittiCamera,
        truth: read(&data.join("kitti/poses/00.txt"), Format::Kitti)?.poses,
        odometry: read(&data.join("odometry/lidar/00.txt"), Format::Kitti)?.poses,
    })
}

fn town() -> anyhow::Result<Scenario> {
    let (truth, odometry) = synthetic::drive(3, 42);
    Ok(Scenario {
        name: "synthetic town (no ../shared/data), drifting odometry from a fixed seed".into(),
        map: LaneMap::new(&synthetic::town_lanes())?,
        plane: synthetic::town_plane(),
        geometry: synthetic::town_geometry(),
        anchor: synthetic::town_anchor(),
        convention: AxisConvention::Flu,
        truth,
        odometry,
    })
}

/// Runs the demo.
pub fn run() -> anyhow::Result<()> {
    let data = default_data_dir();
    let s = if data.join("osm/kitti_00.osm").is_file() {
        kitti(&data)?
    } else {
        town()?
    };
    println!("lanealign demo: {}", s.name);
    let dir = tempfile::tempdir()?;
    let tile_path = dir.path().join("map.tile");
    tile::write(&tile_path, &s.map, &s.plane, 3.0, &s.geometry)?;
    println!(
        "  map: {} lanes, {} points -> {}",
        s.map.lane_count(),
        s.map.len(),
        tile_path.display()
    );
    let source = format!("demo-{}", std::process::id());
    let namespace = daemon_config::run_namespace("demo", std::process::id())?;
    let corrector = CorrectorConfig::new(Preset::KissIcp, Method::Robust);
    let config = dir.path().join("lanealignd.toml");
    daemon_config::write(
        &config,
        &daemon_config::config(
            &tile_path,
            namespace.as_str(),
            5.0,
            &dir.path().join("state"),
            &[daemon_config::Source {
                name: source.clone(),
                corrector,
                frame: s.convention,
                anchor: s.anchor,
                pass_through: false,
                wait: WaitStrategy::Event,
            }],
        ),
    )?;
    let daemon = DaemonProcess::start(&config, &dir.path().join("lanealignd.log"))?;
    println!(
        "  lanealignd started (pid {}), replaying {} poses over iceoryx2 ...",
        daemon.id(),
        s.odometry.len()
    );
    // Latency: one pose in flight, so no pose waits behind another (the daemon's answer time as
    // an odometry process publishing at its own rate sees it). Throughput: a fresh session
    // flooded with 64 in flight, whose round trips are mostly queueing.
    let run = |in_flight: usize| -> anyhow::Result<(Replay, Duration)> {
        let mut conn = Connection::connect_in(
            &namespace,
            &source.parse()?,
            lanealign_client::connection::new_session_id(),
        )?;
        let start = Instant::now();
        let result = replay(
            &mut conn,
            &source,
            &s.odometry,
            &[],
            Rate::Max(in_flight),
            Duration::from_secs(10),
            Duration::from_secs(10),
        )?;
        Ok((result, start.elapsed()))
    };
    let runs = run(1).and_then(|latency| Ok((latency, run(64)?)));
    let log = daemon.log();
    let clean = daemon.stop()?;
    // The daemon and both sessions are gone: so goes the demo's namespace.
    if let Err(e) = namespace.remove_files() {
        eprintln!("warning: removing the demo's namespace files: {e}");
    }
    let ((result, _), (flood, flood_time)) =
        runs.with_context(|| format!("replay failed; daemon log:\n{log}"))?;
    let corrected: Vec<Pose3> = result
        .answers
        .iter()
        .map(|a| Pose3::from_row_major(&a.pose))
        .collect();
    let planar = |v: &[Pose3]| {
        v.iter()
            .map(|p| s.convention.to_planar(p))
            .collect::<Vec<_>>()
    };
    let truth = planar(&s.truth);
    let raw = ape_2d(&truth, &planar(&s.odometry))?;
    let fixed = ape_2d(&truth, &planar(&corrected))?;
    // How sure the corrections said they were: each answer's covariance, turned from the map
    // plane into the odometry frame, against the true error.
    let covariances: Vec<[[f64; 2]; 2]> = result
        .answers
        .iter()
        .map(|a| {
            status_file::position_covariance_in_odom(
                a.anchor_yaw,
                &from_upper_triangle(&a.covariance),
            )
        })
        .collect();
    let confidence = calibration(&truth, &planar(&corrected), &covariances)?.check();
    let accepted = result
        .answers
        .iter()
        .filter(|a| a.status() == Some(StatusCode::Accepted))
        .count();
    let offline = correct_trajectory(
        Arc::new(s.map),
        corrector.params()?,
        corrector.match_mode,
        Placement {
            convention: s.convention,
            anchored_from_odom: s.anchor.anchored_from_odom(&s.plane),
            smoothing: None,
        },
        &s.odometry,
    );
    let identical = offline.iter().zip(&corrected).all(|(o, c)| o.pose == *c)
        && flood.answers.len() == result.answers.len()
        && flood
            .answers
            .iter()
            .zip(&result.answers)
            .all(|(f, r)| f.pose == r.pose);
    let mut rt = result.round_trip_ns.clone();
    rt.sort_unstable();
    println!("  APE-2D mean: raw {:.3} m -> corrected {:.3} m (max {:.2} -> {:.2} m); {accepted} corrections accepted", raw.mean_m, fixed.mean_m, raw.max_m, fixed.max_m);
    let exact = confidence.if_exact.cov95_coverage;
    println!(
        "  confidence: {:.1} % of the corrected poses lie within the 95 % ellipse of their covariance (an exact covariance gives {:.0}-{:.0} % over these {:.0} independent errors): {}",
        100.0 * confidence.calibration.cov95_coverage,
        100.0 * exact[0],
        100.0 * exact[1],
        confidence.calibration.independent_samples,
        confidence.verdict
    );
    println!(
        "  every pose came back: {} of {}; identical to offline `lanealign correct`: {}",
        result.answers.len(),
        s.odometry.len(),
        if identical { "yes" } else { "NO" }
    );
    println!("  latency, one pose in flight (publish -> corrected pose received): p50 {:.1} us, p99 {:.1} us, max {:.1} us", percentile_us(&rt, 0.5), percentile_us(&rt, 0.99), percentile_us(&rt, 1.0));
    println!(
        "  throughput, 64 poses in flight (a new session, same answers: {}): {:.0} poses/s",
        if identical { "yes" } else { "NO" },
        flood.answers.len() as f64 / flood_time.as_secs_f64()
    );
    println!(
        "  lanealignd stopped {}",
        if clean {
            "cleanly (SIGTERM)"
        } else {
            "with an error"
        }
    );
    anyhow::ensure!(identical && clean, "the demo did not behave as expected");
    Ok(())
}
