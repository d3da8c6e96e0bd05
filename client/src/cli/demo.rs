//! `lanealign demo`: the whole product in one command. Compiles a map, starts `lanealignd`,
//! replays an odometry run through it over shared memory, and prints raw vs corrected accuracy
//! and latency. Uses KITTI 00 from `../shared/data` when present, else the synthetic town.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use lanealign_client::connection::Connection;
use lanealign_client::daemon_process::DaemonProcess;
use lanealign_client::kitti::{anchors, default_data_dir};
use lanealign_client::replay::{replay, Rate};
use lanealign_client::synthetic;
use lanealign_client::wire::{pose_from_wire, WireStatus};
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::ape_2d;
use lanealign_core::offline::{correct, Source};
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::tile;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};

use super::{percentile_us, write_config};

struct Scenario {
    name: String,
    map: LaneMap,
    plane: MapPlane,
    anchor: Anchor,
    convention: AxisConvention,
    truth: Vec<Pose3>,
    odometry: Vec<Pose3>,
}

fn kitti(data: &Path) -> anyhow::Result<Scenario> {
    let anchor = *anchors(data)?.get("00").context("no anchor for KITTI 00")?;
    let options = CompileOptions {
        origin: Some((anchor.lat, anchor.lon)),
        projection: Projection::Kitti,
        ..CompileOptions::default()
    };
    let (map, plane, _) = compile(&[data.join("osm/kitti_00.osm")], &options)?;
    Ok(Scenario {
        name: "KITTI 00, real LiDAR odometry, lanes from OpenStreetMap".into(),
        map,
        plane,
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
        plane: MapPlane::new(Projection::Tangent, 49.0, 8.4),
        anchor: Anchor {
            lat: 49.0,
            lon: 8.4,
            yaw_deg: 0.0,
            east_m: 0.0,
            north_m: 0.0,
        },
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
    tile::write(&tile_path, &s.map, &s.plane, 3.0)?;
    println!(
        "  map: {} lanes, {} points -> {}",
        s.map.lane_count(),
        s.map.len(),
        tile_path.display()
    );
    let source = format!("demo-{}", std::process::id());
    let frame = match s.convention {
        AxisConvention::Flu => "flu",
        AxisConvention::KittiCamera => "kitti-camera",
    };
    let config = dir.path().join("lanealignd.toml");
    write_config(
        &config,
        &tile_path,
        &[(source.clone(), false)],
        "kiss-icp",
        frame,
        &s.anchor,
    )?;
    let daemon = DaemonProcess::start(&config, &dir.path().join("lanealignd.log"))?;
    println!(
        "  lanealignd started (pid {}), replaying {} poses over iceoryx2 ...",
        daemon.id(),
        s.odometry.len()
    );
    let conn = Connection::connect(&source)?;
    let result = replay(
        &conn,
        &source,
        &s.odometry,
        &[],
        1,
        Rate::Max(64),
        Duration::from_secs(10),
    );
    drop(conn);
    let log = daemon.log();
    let clean = daemon.stop()?;
    let result = result.with_context(|| format!("replay failed; daemon log:\n{log}"))?;
    let corrected: Vec<Pose3> = result
        .answers
        .iter()
        .map(|a| pose_from_wire(&a.pose))
        .collect();
    let planar = |v: &[Pose3]| {
        v.iter()
            .map(|p| s.convention.to_planar(p))
            .collect::<Vec<_>>()
    };
    let truth = planar(&s.truth);
    let raw = ape_2d(&truth, &planar(&s.odometry))?;
    let fixed = ape_2d(&truth, &planar(&corrected))?;
    let accepted = result
        .answers
        .iter()
        .filter(|a| a.status == WireStatus::Accepted as u32)
        .count();
    let offline = correct(
        Arc::new(s.map),
        Method::Robust.params(Preset::KissIcp),
        MatchMode::Fast,
        Source {
            convention: s.convention,
            plane_from_odom: s.anchor.plane_from_odom_in(&s.plane),
            smoothing: None,
        },
        &s.odometry,
    );
    let identical = offline.iter().zip(&corrected).all(|(o, c)| o.pose == *c);
    let mut rt = result.round_trip_ns.clone();
    rt.sort_unstable();
    println!("  APE-2D mean: raw {:.3} m -> corrected {:.3} m (max {:.2} -> {:.2} m); {accepted} corrections accepted", raw.mean_m, fixed.mean_m, raw.max_m, fixed.max_m);
    println!(
        "  every pose came back: {} of {}; identical to offline `lanealign correct`: {}",
        result.answers.len(),
        s.odometry.len(),
        if identical { "yes" } else { "NO" }
    );
    println!("  round trip (publish -> corrected pose received): p50 {:.1} us, p99 {:.1} us, max {:.1} us", percentile_us(&rt, 0.5), percentile_us(&rt, 0.99), percentile_us(&rt, 1.0));
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
