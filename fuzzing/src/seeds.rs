//! Real-shaped inputs the mutator starts from: small, so that a CI run reaches 10^5 cases per
//! target in seconds, and covering the features each reader handles (tags that change lane
//! counts and directions, relations, comments, signatures, every wire flag).

use std::path::Path;

use lanealign_core::geo::{MapPlane, Projection};
use lanealign_core::lane_geometry::LaneGeometry;
use lanealign_core::lane_map::{Lane, LaneMap};
use lanealign_core::pose::Pose3;
use lanealign_core::tile;
use lanealign_core::trajectory::{self, Format, Trajectory};
use lanealign_service::journal::Snapshot;
use lanealign_service::session::{Session, SessionSetup};
use lanealign_wire::payload::{OdomPose, FLAG_END_SESSION, FLAG_FRESH_START};

/// Raw OSM: two-way and one-way roads, tagged lane counts, a reversed one-way, a footway, a
/// relation and a node with tags.
pub const OSM_XML: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="lanealign-fuzzing">
 <bounds minlat="49.0" minlon="8.4" maxlat="49.003" maxlon="8.403"/>
 <node id="1" lat="49.0000000" lon="8.4000000"/>
 <node id="2" lat="49.0010000" lon="8.4000000"><tag k="highway" v="traffic_signals"/></node>
 <node id="3" lat="49.0020000" lon="8.4010000"/>
 <node id="4" lat="49.0030000" lon="8.4030000"/>
 <node id="5" lat="49.0010000" lon="8.4020000"/>
 <way id="10"><nd ref="1"/><nd ref="2"/><nd ref="3"/><tag k="highway" v="secondary"/><tag k="lanes" v="4"/><tag k="lanes:forward" v="2"/><tag k="width" v="12.5"/></way>
 <way id="11"><nd ref="3"/><nd ref="4"/><tag k="highway" v="residential"/></way>
 <way id="12"><nd ref="4"/><nd ref="5"/><nd ref="2"/><tag k="highway" v="primary_link"/><tag k="oneway" v="-1"/></way>
 <way id="13"><nd ref="2"/><nd ref="5"/><tag k="highway" v="footway"/></way>
 <way id="14"><nd ref="1"/><nd ref="5"/><tag k="highway" v="unclassified"/><tag k="oneway" v="yes"/><tag k="lanes" v="2"/></way>
 <relation id="20"><member type="way" ref="10" role=""/><member type="node" ref="2" role="via"/><tag k="type" v="route"/></relation>
</osm>
"#;

/// Lanelet2: a one-way and a two-way lanelet, and a crosswalk.
pub const LANELET2_XML: &str = r#"<?xml version="1.0"?>
<osm version="0.6" generator="lanealign-fuzzing">
 <node id="1" lat="49.0000000" lon="8.4000000"/>
 <node id="2" lat="49.0010000" lon="8.4000000"/>
 <node id="3" lat="49.0000000" lon="8.4000500"/>
 <node id="4" lat="49.0010000" lon="8.4000500"/>
 <node id="5" lat="49.0000000" lon="8.4001000"/>
 <node id="6" lat="49.0010000" lon="8.4001000"/>
 <way id="10"><nd ref="1"/><nd ref="2"/><tag k="type" v="line_thin"/><tag k="subtype" v="solid"/></way>
 <way id="11"><nd ref="3"/><nd ref="4"/><tag k="type" v="line_thin"/><tag k="subtype" v="dashed"/></way>
 <way id="12"><nd ref="5"/><nd ref="6"/><tag k="type" v="line_thin"/></way>
 <relation id="100"><member type="way" ref="10" role="left"/><member type="way" ref="11" role="right"/><tag k="type" v="lanelet"/><tag k="subtype" v="road"/></relation>
 <relation id="101"><member type="way" ref="11" role="left"/><member type="way" ref="12" role="right"/><tag k="type" v="lanelet"/><tag k="subtype" v="road"/><tag k="one_way" v="no"/></relation>
 <relation id="102"><member type="way" ref="10" role="left"/><member type="way" ref="12" role="right"/><tag k="type" v="lanelet"/><tag k="subtype" v="crosswalk"/></relation>
</osm>
"#;

/// A daemon configuration using every key.
pub const DAEMON_TOML: &str = r#"
tile = "maps/town.tile"
namespace = "fuzz"
metrics_interval_s = 5.0
state_dir = "state"
journal = true
session_timeout_s = 600.0
max_sessions = 16
log_format = "json"
trusted_tile_keys = ["ea4a6c63e29c520abef5507b132ec5f9954776aebebe7b92421eea691446d22c"]

[[source]]
name = "lidar"
frame = "kitti-camera"
anchor = { lat = 48.9825452359, lon = 8.3903661, yaw_deg = 59.5584, east_m = 0.806, north_m = 0.365 }
corrector = { preset = "kiss-icp", method = "robust", match_mode = "fast", smooth = true, overrides = { max_window = 800, trim_ratio = 0.8 } }

[[source]]
name = "wheel"
pass_through = true
anchor = { lat = 49.0, lon = 8.4, yaw_deg = 0 }
corrector = { preset = "orb-slam3", method = "paper", unmarked_offset_scale = 1.0 }
"#;

/// Eight lanes on a grid: two of them sharing their points exactly (duplicate points in the
/// KD-tree), one a single segment.
pub fn lanes() -> Vec<Lane> {
    let mut lanes: Vec<Lane> = (0..5)
        .map(|k| {
            let y = k as f64 * 3.5;
            Lane::new(k, (0..15).map(|i| [i as f64 * 3.0, y]).collect())
        })
        .collect();
    lanes.push(Lane::new(
        5,
        (0..15).map(|i| [i as f64 * 3.0, 0.0]).collect(),
    ));
    lanes.push(Lane::new(6, vec![[0.0, -3.0], [0.0, 30.0]]));
    lanes.push(Lane::new(
        7,
        (0..20).map(|i| [45.0 - i as f64, 7.0]).collect(),
    ));
    lanes
}

/// The seed lane map.
pub fn lane_map() -> LaneMap {
    LaneMap::new(&lanes()).expect("the seed lanes make a map")
}

/// The plane and lane geometry of the seed tiles.
pub fn tile_plane_and_geometry() -> (MapPlane, LaneGeometry) {
    let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
    let geometry = LaneGeometry {
        unmarked_offset_scale: Some(0.5),
        ..LaneGeometry::default()
    };
    (plane, geometry)
}

/// Tile bytes: unsigned, and signed with a map version.
pub fn tiles() -> Vec<Vec<u8>> {
    let (plane, geometry) = tile_plane_and_geometry();
    let unsigned = tile::encode(&lane_map(), &plane, 3.0, &geometry);
    let mut signed = unsigned.clone();
    tile::set_map_version(&mut signed, 20_261_207).expect("a version TOML holds");
    tile::sign(&mut signed, &tile::SigningKey::from_bytes(&[9; 32]));
    vec![unsigned, signed]
}

/// A gentle S-curve drive along the seed lanes (planar `flu` poses, 1 m apart).
pub fn drive(n: usize) -> Vec<Pose3> {
    (0..n)
        .map(|i| {
            let x = i as f64;
            let yaw = 0.05 * (x / 10.0).sin();
            Pose3::planar(x, 0.3 * (x / 10.0).cos(), yaw, 0.01 * x)
        })
        .collect()
}

/// [`crate::targets::Target::PoseArray`]'s bytes of the drive (40 poses at 10 Hz), with each
/// option set: stamps, the paper's method, the orb-slam3 preset, KITTI camera axes.
pub fn pose_arrays() -> Vec<Vec<u8>> {
    let mut numbers = Vec::new();
    for (i, pose) in drive(40).iter().enumerate() {
        numbers.extend_from_slice(&(100.0 + i as f64 * 0.1).to_le_bytes());
        for v in pose.to_row_major() {
            numbers.extend_from_slice(&v.to_le_bytes());
        }
    }
    [0b0001u8, 0b0011, 0b0101, 0b1001]
        .into_iter()
        .map(|options| [&[options][..], &numbers].concat())
        .collect()
}

/// KITTI and TUM text of the drive.
pub fn trajectory_text(format: Format) -> Vec<u8> {
    let poses = drive(40);
    let traj = Trajectory {
        stamps: (format == Format::Tum).then(|| (0..40).map(|i| 100.0 + i as f64 * 0.1).collect()),
        poses,
    };
    let mut text = String::new();
    if format == Format::Tum {
        text.push_str("# timestamp tx ty tz qx qy qz qw\n");
    }
    text.push_str(
        &trajectory::format_text(&traj, format, Path::new("seed")).expect("seed formats"),
    );
    text.into_bytes()
}

/// Lane CSV of the seed lanes.
pub fn lane_csv() -> Vec<u8> {
    let mut text = String::from("lane_id,x,y\n");
    for lane in lanes() {
        for p in &lane.points {
            text.push_str(&format!("{},{},{}\n", lane.id, p[0], p[1]));
        }
    }
    text.into_bytes()
}

/// The pose `pose` as session `session`'s number `seq`, stamped `stamp_ns`, without flags.
pub fn odom_pose(session: u64, seq: u64, stamp_ns: i64, pose: &Pose3) -> OdomPose {
    OdomPose {
        session,
        seq,
        stamp_ns,
        sent_mono_ns: 0,
        pose: pose.to_row_major(),
        flags: 0,
        reserved: 0,
    }
}

/// Size of one [`OdomPose`] on the wire harness's byte stream.
pub const ODOM_POSE_BYTES: usize = 136;

/// An [`OdomPose`] as the wire harness reads it (little-endian fields in declaration order).
pub fn odom_pose_bytes(p: &OdomPose) -> Vec<u8> {
    let mut out = Vec::with_capacity(ODOM_POSE_BYTES);
    out.extend_from_slice(&p.session.to_le_bytes());
    out.extend_from_slice(&p.seq.to_le_bytes());
    out.extend_from_slice(&p.stamp_ns.to_le_bytes());
    out.extend_from_slice(&p.sent_mono_ns.to_le_bytes());
    for v in p.pose {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&p.flags.to_le_bytes());
    out.extend_from_slice(&p.reserved.to_le_bytes());
    out
}

/// The payload of [`ODOM_POSE_BYTES`] bytes as [`odom_pose_bytes`] writes them (its inverse).
pub fn odom_pose_from_bytes(chunk: &[u8; ODOM_POSE_BYTES]) -> OdomPose {
    let u64_at = |k: usize| {
        let mut b = [0; 8];
        b.copy_from_slice(&chunk[8 * k..8 * k + 8]);
        u64::from_le_bytes(b)
    };
    let u32_at = |at: usize| {
        let mut b = [0; 4];
        b.copy_from_slice(&chunk[at..at + 4]);
        u32::from_le_bytes(b)
    };
    OdomPose {
        session: u64_at(0),
        seq: u64_at(1),
        stamp_ns: u64_at(2) as i64,
        sent_mono_ns: u64_at(3),
        pose: std::array::from_fn(|k| f64::from_bits(u64_at(4 + k))),
        flags: u32_at(128),
        reserved: u32_at(132),
    }
}

/// Two interleaved sessions streaming the drive's 40 poses on the seed lanes, the second started
/// afresh at the 13th (both aligned once their windows are full); then the first says goodbye and
/// sends one pose more (a session the daemon no longer runs).
pub fn wire_stream() -> Vec<u8> {
    let drive = drive(40);
    let mut out = Vec::new();
    for (i, pose) in drive.iter().enumerate() {
        for session in [1u64, 2] {
            let fresh = session == 2 && i == 12;
            let p = OdomPose {
                session,
                seq: if session == 2 && i >= 12 {
                    i as u64 - 11
                } else {
                    i as u64 + 1
                },
                stamp_ns: i as i64 * 100_000_000,
                sent_mono_ns: i as u64,
                pose: pose.to_row_major(),
                flags: if fresh { FLAG_FRESH_START } else { 0 },
                reserved: 0,
            };
            out.extend(odom_pose_bytes(&p));
        }
    }
    let after = drive.len() as u64 + 1;
    for (flags, pose) in [
        (FLAG_END_SESSION, [f64::NAN; 12]),
        (0, drive[0].to_row_major()),
    ] {
        out.extend(odom_pose_bytes(&OdomPose {
            session: 1,
            seq: after,
            stamp_ns: 0,
            sent_mono_ns: after,
            pose,
            flags,
            reserved: 0,
        }));
    }
    out
}

/// One session streaming 600 poses of the drive: past the first full segment of its journal
/// (512 records), so that its snapshot is written and replayed from.
pub fn long_stream() -> Vec<u8> {
    drive(600)
        .iter()
        .enumerate()
        .flat_map(|(i, pose)| {
            odom_pose_bytes(&odom_pose(1, i as u64 + 1, i as i64 * 100_000_000, pose))
        })
        .collect()
}

/// Snapshots of a session of `setup`'s source, as its journal holds them: after 40 poses of the
/// drive (the first stamps still held for the rate), and after 90 whose last 30 stall (the
/// rate told, a stall under way).
pub fn snapshots(setup: &SessionSetup) -> Vec<Vec<u8>> {
    let moving = drive(60);
    let stalled: Vec<Pose3> = moving
        .iter()
        .copied()
        .chain((0..30).map(|i| {
            let mut p = moving[59];
            p.translation[0] += 0.01 * i as f64;
            p
        }))
        .collect();
    [&moving[..40], &stalled[..]]
        .into_iter()
        .map(|poses| {
            let (mut session, _) = Session::start(1, 1, setup);
            for (i, pose) in poses.iter().enumerate() {
                let input = odom_pose(1, i as u64 + 1, i as i64 * 100_000_000, pose);
                let (handled, _) = session.handle(&input, 0, setup, || false);
                session.watch_answered(&input, &handled.outcome);
            }
            Snapshot {
                last_seq: poses.len() as u64,
                next_segment: 1,
                state: session.state(),
                watch: Some(session.watch.state()),
            }
            .encode()
        })
        .collect()
}
