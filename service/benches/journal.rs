//! What crash consistency costs: the journal append a worker adds per pose (timed alone, and a
//! session's whole step with and without it), and the time to restore a session whose window
//! holds 3000 poses.
//!
//! `cargo bench -p lanealign-service --bench journal [-- --rounds N]`
//!
//! KITTI 00 (real LiDAR odometry, lanes from its OSM, the robust kiss-icp and liodom presets)
//! when `../shared/data` is present. The append: `SegmentWriter::append` of each pose's record
//! (a copy of 416 bytes into the mapped segment), and at each full segment the snapshot's encoding. The step:
//! `Session::handle` (correction, protocol, journal) with and without a journal, over the same
//! poses in alternating rounds (default 3), in one run. Restore: `session::restore` of a journal
//! (snapshot plus the tail after it) of the paper method's liodom session (its window reaches
//! 3000 poses; the robust method's is bounded by path length), 20 times. Medians, since this
//! machine is shared.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::params::{CorrectorConfig, Method, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::source_corrector::Placement;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_service::journal::{Record, SegmentWriter, Snapshot, SEGMENT_RECORDS};
use lanealign_service::session::{self, Session, SessionSetup};
use lanealign_wire::payload::OdomPose;

fn percentile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn setup(
    map: &Arc<lanealign_core::lane_map::LaneMap>,
    anchor: &Anchor,
    plane: &lanealign_core::geo::MapPlane,
    (preset, method): (Preset, Method),
    journal: Option<&Path>,
) -> SessionSetup {
    let config = CorrectorConfig::new(preset, method);
    SessionSetup {
        map: map.clone(),
        grid: None,
        params: config.params().expect("preset parameters are valid"),
        mode: config.match_mode,
        placement: Placement {
            convention: AxisConvention::KittiCamera,
            anchored_from_odom: anchor.anchored_from_odom(plane),
            smoothing: None,
        },
        journal_dir: journal.map(Path::to_path_buf),
        fingerprint: 1,
        persistence: None,
        daemon_epoch: 1,
    }
}

fn input(seq: u64, pose: &Pose3) -> OdomPose {
    OdomPose {
        session: 7,
        seq,
        stamp_ns: 0,
        sent_mono_ns: 0,
        pose: pose.to_row_major(),
        flags: 0,
        reserved: 0,
    }
}

/// Per-pose times (us) of one session over `poses`.
fn run(setup: &SessionSetup, poses: &[Pose3]) -> Vec<f64> {
    let (mut session, failure) = Session::start(7, 1, setup);
    assert!(failure.is_none(), "the journal could be created");
    poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let t = Instant::now();
            let (handled, failure) = session.handle(&input(i as u64 + 1, p), 0, setup, || false);
            let us = t.elapsed().as_secs_f64() * 1e6;
            assert!(failure.is_none());
            std::hint::black_box(handled.answer);
            us
        })
        .collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let rounds: usize = args
        .iter()
        .position(|a| a == "--rounds")
        .and_then(|i| args.get(i + 1))
        .map(|v| v.parse())
        .transpose()?
        .unwrap_or(3);
    let data = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    if !data.join("osm/kitti_00.osm").is_file() {
        println!("SKIPPED: no KITTI data at {}", data.display());
        return Ok(());
    }
    let anchor: Anchor = "48.9825452359,8.3903661,59.5584,0.806,0.365".parse()?;
    let options = CompileOptions {
        origin: Some((anchor.lat(), anchor.lon())),
        projection: Projection::Kitti,
        ..CompileOptions::default()
    };
    let compiled = compile(&[data.join("osm/kitti_00.osm")], &options)?;
    let map = Arc::new(compiled.map);
    let poses = read(&data.join("odometry/lidar/00.txt"), Format::Kitti)?.poses;
    let dir = tempfile::tempdir()?;
    // The append alone: every pose's record, and the snapshot encoding when a segment fills.
    let record_setup = setup(
        &map,
        &anchor,
        &compiled.plane,
        (Preset::KissIcp, Method::Robust),
        None,
    );
    let (mut session, _) = Session::start(7, 1, &record_setup);
    let records: Vec<Record> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let input = input(i as u64 + 1, p);
            let (handled, _) = session.handle(&input, 0, &record_setup, || false);
            session.watch_answered(&input, &handled.outcome);
            Record {
                input,
                answer: handled.answer,
            }
        })
        .collect();
    let (state, watch) = (session.state(), session.watch.state());
    let mut append_us = Vec::new();
    let mut snapshot_us = Vec::new();
    for round in 0..rounds {
        let folder = dir.path().join(format!("append-{round}"));
        std::fs::create_dir_all(&folder)?;
        let mut segment = SegmentWriter::create(&folder, 0)?;
        for (i, r) in records.iter().enumerate() {
            let t = Instant::now();
            segment.append(r);
            if segment.is_full() {
                let bytes = Snapshot {
                    last_seq: i as u64,
                    next_segment: 1,
                    state: state.clone(),
                    watch: Some(watch.clone()),
                }
                .encode();
                std::hint::black_box(bytes);
                segment = SegmentWriter::create(&folder, segment.number + 1)?;
                snapshot_us.push(t.elapsed().as_secs_f64() * 1e6);
            } else {
                append_us.push(t.elapsed().as_secs_f64() * 1e6);
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let per_pose = mean(&append_us) + mean(&snapshot_us) / SEGMENT_RECORDS as f64;
    println!("Journal append per pose, KITTI 00 lidar ({} poses x {rounds} rounds; microseconds): median {:.2}, p99 {:.2}, mean {:.2}; segment roll with snapshot encoding (every {SEGMENT_RECORDS} poses, window {} poses) median {:.1}; amortised per pose {per_pose:.2}.\n", poses.len(), percentile(append_us.clone(), 0.5), percentile(append_us.clone(), 0.99), mean(&append_us), state.corrector.window.len(), percentile(snapshot_us.clone(), 0.5));
    println!("Per pose, Session::handle on KITTI 00 lidar ({} poses), robust method; microseconds, {rounds} alternating rounds, one run.\n", poses.len());
    println!(
        "| preset | journal | median | p99 | mean | journal cost (median) | journal cost (mean) |"
    );
    println!("|---|---|---|---|---|---|---|");
    for preset in [Preset::KissIcp, Preset::Liodom] {
        let (mut off, mut on) = (Vec::new(), Vec::new());
        let method = (preset, Method::Robust);
        for round in 0..rounds {
            let journal = dir.path().join(format!("{}-{round}", preset.name()));
            std::fs::create_dir_all(&journal)?;
            off.extend(run(
                &setup(&map, &anchor, &compiled.plane, method, None),
                &poses,
            ));
            on.extend(run(
                &setup(&map, &anchor, &compiled.plane, method, Some(&journal)),
                &poses,
            ));
        }
        let (m_off, m_on) = (percentile(off.clone(), 0.5), percentile(on.clone(), 0.5));
        for (name, v) in [("off", &off), ("on", &on)] {
            let cost = if name == "on" {
                format!("{:+.2} | {:+.2}", m_on - m_off, mean(&on) - mean(&off))
            } else {
                " | ".to_string()
            };
            println!(
                "| {} | {name} | {:.2} | {:.2} | {:.2} | {cost} |",
                preset.name(),
                percentile(v.to_vec(), 0.5),
                percentile(v.to_vec(), 0.99),
                mean(v)
            );
        }
    }
    // Restore: a liodom session of the paper method (M_max 3000) run until its window is full,
    // its journal restored again and again.
    let journal = dir.path().join("restore");
    std::fs::create_dir_all(&journal)?;
    let s = setup(
        &map,
        &anchor,
        &compiled.plane,
        (Preset::Liodom, Method::Paper),
        Some(&journal),
    );
    let (mut session, _) = Session::start(7, 1, &s);
    let mut window = 0;
    let mut used = 0;
    for (i, p) in poses.iter().enumerate() {
        session.handle(&input(i as u64 + 1, p), 0, &s, || false);
        used = i + 1;
        window = session_window(&session);
        // Stop half-way into a segment: the restore replays a typical tail.
        if window >= 3000 && used % 512 == 256 {
            break;
        }
    }
    let session_dir = session
        .journal_dir()
        .map(Path::to_path_buf)
        .ok_or_else(|| anyhow::anyhow!("no journal"))?;
    drop(session);
    // Without the persistence thread the snapshot is written here, as that thread would.
    write_snapshot(&session_dir, &s, &poses[..used])?;
    let mut times = Vec::new();
    for _ in 0..20 {
        let t = Instant::now();
        let restored = session::restore(&session_dir, &s).map_err(|e| anyhow::anyhow!("{e}"))?;
        times.push(t.elapsed());
        assert_eq!(restored.expected_seq(), used as u64 + 1);
    }
    times.sort();
    println!("\nRestore of a paper-method liodom session after {used} poses (window {window} poses; snapshot plus {} records replayed): median {:.1} ms, max {:.1} ms over 20.", used % 512, ms(times[10]), ms(times[19]));
    Ok(())
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The window length of a session (from its corrector's state).
fn session_window(session: &Session) -> usize {
    session.window_len()
}

/// Writes the snapshot the persistence thread would have written at the last segment boundary:
/// the state of a session run over the poses up to it.
fn write_snapshot(dir: &Path, s: &SessionSetup, poses: &[Pose3]) -> anyhow::Result<()> {
    let boundary = poses.len() / 512 * 512;
    let no_journal = SessionSetup {
        journal_dir: None,
        ..s.clone()
    };
    let (mut replica, _) = Session::start(7, 1, &no_journal);
    for (i, p) in poses[..boundary].iter().enumerate() {
        let input = input(i as u64 + 1, p);
        let (handled, _) = replica.handle(&input, 0, &no_journal, || false);
        replica.watch_answered(&input, &handled.outcome);
    }
    let snapshot = Snapshot {
        last_seq: boundary as u64,
        next_segment: (boundary / 512) as u64,
        state: replica.state(),
        watch: Some(replica.watch.state()),
    };
    lanealign_service::journal::write_durably(&dir.join("snapshot"), &snapshot.encode())?;
    Ok(())
}
