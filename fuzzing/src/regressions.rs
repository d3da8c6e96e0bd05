//! The known bad inputs, generated: each was once accepted, crashed a binary or misled, and each
//! must now be refused with the error named here (or, where `refused_with` is `None`, handled
//! without a crash). `lanealign-regressions DIR` writes them as files for the command-line
//! tests and for anyone reproducing them by hand.

use std::path::Path;

use lanealign_core::plausibility::SpeedChange;
use lanealign_core::pose::Pose3;
use lanealign_core::se2::Se2;
use lanealign_core::tile;
use lanealign_core::trajectory::{self, Format, Trajectory};
use lanealign_map::osm::read_xml;
use lanealign_service::journal::{self, Snapshot};
use lanealign_wire::payload::OdomPose;

use crate::seeds::{self, odom_pose_bytes};
use crate::targets::{snapshot_setup, Target};

/// One regression case.
pub struct Case {
    /// A file name for it (with its format's extension).
    pub name: &'static str,
    /// The harness that reads it.
    pub target: Target,
    /// The input.
    pub bytes: Vec<u8>,
    /// Part of the error it must be refused with; `None`: any outcome but a crash.
    pub refused_with: Option<&'static str>,
}

fn put_u64(bytes: &mut [u8], at: usize, v: u64) {
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

fn tile_cases() -> Vec<Case> {
    let good = seeds::tiles().swap_remove(0);
    let mut huge = good.clone();
    // A point count and a payload length chosen so that unchecked size arithmetic wraps.
    put_u64(&mut huge, 48, 1 << 60);
    put_u64(&mut huge, 104, (good.len() - tile::HEADER_LEN) as u64);
    tile::seal(&mut huge);
    let mut reserved = good.clone();
    reserved[120] = 1;
    tile::seal(&mut reserved);
    let mut point = good.clone();
    let last = point.len() - 5;
    point[last] ^= 0x40;
    tile::seal(&mut point);
    let mut flipped = good.clone();
    flipped[300] ^= 4;
    // Lane 6's end (0, 30) moved to y = 1e155, with the header's bounds, and resealed: it was
    // accepted, the squared length of the segment to it overflowed, and the map held NaN chord
    // errors, which the published covariance adds for a pair kept on that lane.
    let mut far = good.clone();
    let end: Vec<u8> = [0.0f64, -3.0, 0.0, 30.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let at = far
        .windows(end.len())
        .position(|w| w == end.as_slice())
        .expect("the seed tile holds lane 6's end");
    far[at + 24..at + 32].copy_from_slice(&1e155f64.to_le_bytes());
    put_u64(&mut far, 96, 1e155f64.to_bits());
    tile::seal(&mut far);
    vec![
        Case {
            name: "tile_size_arithmetic_wraps.tile",
            target: Target::Tile,
            bytes: huge,
            refused_with: Some("bad header field point count: 1152921504606846976"),
        },
        Case {
            name: "tile_reserved_bytes_set.tile",
            target: Target::Tile,
            bytes: reserved,
            refused_with: Some("present in an unsigned tile"),
        },
        Case {
            name: "tile_point_changed_and_resealed.tile",
            target: Target::Tile,
            bytes: point,
            refused_with: None,
        },
        Case {
            name: "tile_byte_flipped.tile",
            target: Target::Tile,
            bytes: flipped,
            refused_with: Some("checksum mismatch"),
        },
        Case {
            name: "tile_point_beyond_the_pose_bound.tile",
            target: Target::Tile,
            bytes: far,
            refused_with: Some("lane 6 has a point (0.0, 1e155) that is not finite or beyond"),
        },
        Case {
            name: "tile_truncated.tile",
            target: Target::Tile,
            bytes: good[..good.len() / 2].to_vec(),
            refused_with: Some("truncated"),
        },
    ]
}

fn pbf_with_node(lat_nano: i64, lon_nano: i64) -> Vec<u8> {
    let mut osm = read_xml(seeds::OSM_XML.as_bytes(), Path::new("seed.osm")).expect("seed reads");
    osm.nodes.insert(99, (lat_nano, lon_nano));
    crate::pbf_writer::write(&osm)
}

fn kitti_text(poses: Vec<Pose3>) -> Vec<u8> {
    let traj = Trajectory {
        stamps: None,
        poses,
    };
    trajectory::format_text(&traj, Format::Kitti, Path::new("case"))
        .expect("KITTI text needs no stamps")
        .into_bytes()
}

/// Every regression case.
pub fn cases() -> Vec<Case> {
    let mut cases = tile_cases();
    let cut = seeds::OSM_XML
        .find(" <way id=\"11\">")
        .expect("seed has way 11");
    cases.push(Case {
        name: "osm_cut_at_element_boundary.osm",
        target: Target::OsmXml,
        bytes: seeds::OSM_XML.as_bytes()[..cut].to_vec(),
        refused_with: Some("before </osm>"),
    });
    for (name, lat, lon) in [
        ("pbf_lat_91.osm.pbf", 91_000_000_000, 8_400_000_000),
        ("pbf_lon_181.osm.pbf", 49_000_000_000, 181_000_000_000),
        ("pbf_lat_100000.osm.pbf", 100_000_000_000_000, 8_400_000_000),
    ] {
        cases.push(Case {
            name,
            target: Target::Pbf,
            bytes: pbf_with_node(lat, lon),
            refused_with: Some("node 99: coordinates out of range"),
        });
    }
    // Found by the differential harness `pbf_grid`: the streaming compile made an empty grid of
    // a PBF without lanes, and skipped a relation member the in-memory reader refuses.
    let mut seed = read_xml(seeds::OSM_XML.as_bytes(), Path::new("seed.osm")).expect("seed reads");
    seed.ways.clear();
    cases.push(Case {
        name: "pbf_grid_without_lanes.osm.pbf",
        target: Target::PbfGrid,
        bytes: crate::pbf_writer::write(&seed),
        refused_with: Some("no input gave a lane"),
    });
    let mut seed = read_xml(seeds::OSM_XML.as_bytes(), Path::new("seed.osm")).expect("seed reads");
    if let Some(member) = seed
        .relations
        .first_mut()
        .and_then(|r| r.members.first_mut())
    {
        member.kind = "no such kind".into();
    }
    cases.push(Case {
        name: "pbf_grid_relation_member_of_unknown_type.osm.pbf",
        target: Target::PbfGrid,
        bytes: crate::pbf_writer::write(&seed),
        refused_with: Some("a malformed data block"),
    });
    // Found by `lane_csv` once the map harnesses corrected on their maps: the drive along a
    // lane on the coordinates' bound leaves the plane a pose may lie in for its first 16 poses,
    // and the comparison of the two match modes took their NaN covariances (the answer to a
    // pose that is none) for a difference.
    cases.push(Case {
        name: "lane_on_the_coordinate_bound.csv",
        target: Target::LaneCsv,
        bytes: b"lane_id,x,y\n0,0,1e7\n0,3,1e7\n0,6,1e7\n".to_vec(),
        refused_with: None,
    });
    // Read in the code: a grid listing cells of 2^64 - 1 bytes overflowed the sum of the cells'
    // lengths the daemon takes at start and on SIGHUP, and the daemon aborted.
    let seed = String::from_utf8(Target::GridManifest.seeds().swap_remove(0)).expect("TOML text");
    let longest: String = seed
        .lines()
        .map(|line| match line.starts_with("bytes = ") {
            true => format!("bytes = {}\n", u64::MAX),
            false => format!("{line}\n"),
        })
        .collect();
    cases.push(Case {
        name: "grid_manifest_cells_of_2_to_the_64_bytes.toml",
        target: Target::GridManifest,
        bytes: longest.into_bytes(),
        refused_with: Some("longer than a tile may be"),
    });
    let mut far = Pose3::identity();
    far.translation.x = 1e308;
    let zero = Pose3 {
        rotation: nalgebra::Matrix3::zeros(),
        ..Pose3::identity()
    };
    let mut scaled = Pose3::identity();
    scaled.rotation *= 2.0;
    for (name, pose, why) in [
        ("pose_at_1e308_m.txt", far, "beyond 1e7 m"),
        ("pose_zero_rotation.txt", zero, "degenerate"),
        ("pose_scaled_rotation.txt", scaled, "not orthonormal"),
    ] {
        cases.push(Case {
            name,
            target: Target::Kitti,
            bytes: kitti_text(vec![Pose3::identity(), pose]),
            refused_with: Some(why),
        });
    }
    cases.push(Case {
        name: "pose_file_of_zeros.txt",
        target: Target::Kitti,
        bytes: vec![0; 1 << 20],
        refused_with: Some(":1: longer than 4096 bytes"),
    });
    cases.push(Case {
        name: "tum_time_goes_back.txt",
        target: Target::Tum,
        bytes: b"2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n".to_vec(),
        refused_with: Some("timestamps must increase"),
    });
    cases.push(Case {
        name: "daemon_anchor_latitude_91.toml",
        target: Target::DaemonToml,
        bytes: seeds::DAEMON_TOML
            .replace("lat = 49.0", "lat = 91.0")
            .into_bytes(),
        refused_with: Some("latitude 91"),
    });
    let last = OdomPose {
        session: 5,
        seq: u64::MAX,
        stamp_ns: 0,
        sent_mono_ns: 0,
        pose: Pose3::identity().to_row_major(),
        flags: lanealign_wire::payload::FLAG_FRESH_START,
        reserved: 0,
    };
    cases.push(Case {
        name: "wire_last_sequence_number.bin",
        target: Target::Wire,
        bytes: odom_pose_bytes(&last),
        refused_with: None,
    });
    // The same into a journaled session (found by the `journal` harness): the daemon started a
    // session at the last number, which can answer nothing; restored, it expected 1.
    cases.push(Case {
        name: "journal_fresh_start_at_the_last_number.bin",
        target: Target::Journal,
        bytes: odom_pose_bytes(&last),
        refused_with: None,
    });
    // A journal's snapshot after the last sequence number, which no daemon answers: restored,
    // the session's next number wrapped round to 0.
    let mut used_up = seeds::snapshots(&snapshot_setup()).swap_remove(0);
    put_u64(&mut used_up, 8, u64::MAX);
    journal::seal(&mut used_up);
    cases.push(Case {
        name: "snapshot_last_sequence_number.bin",
        target: Target::Snapshot,
        bytes: used_up,
        refused_with: Some("its sequence numbers are used up"),
    });
    // A snapshot whose session watch has a change of speed under way at a pose it never saw
    // (found by the `snapshot` harness in a debug build: the pose's index overflowed when the
    // change was told; a release build told it at a wrapped-round pose).
    let stalled = seeds::snapshots(&snapshot_setup()).swap_remove(1);
    let mut unseen = Snapshot::decode(&stalled).expect("the seed decodes");
    let speed = unseen
        .watch
        .as_mut()
        .and_then(|w| w.source.speed.as_mut())
        .expect("the seed's speed is judged");
    speed.1.open = Some((
        SpeedChange {
            pose: usize::MAX,
            from_mps: 20.0,
            to_mps: 0.1,
            over_s: 0.5,
        },
        usize::MAX,
    ));
    cases.push(Case {
        name: "snapshot_speed_change_at_a_pose_never_seen.bin",
        target: Target::Snapshot,
        bytes: unseen.encode(),
        refused_with: Some("unreadable snapshot"),
    });
    // A snapshot whose corrector has failed as often as its count holds (found by the
    // `snapshot` harness once its sessions aligned: the next failure overflowed the count, and a
    // daemon restarting from such a journal would have crashed at that pose on every restart).
    let mut failed = Snapshot::decode(&stalled).expect("the seed decodes");
    failed.state.corrector.failures = u32::MAX;
    cases.push(Case {
        name: "snapshot_failure_count_at_its_largest.bin",
        target: Target::Snapshot,
        bytes: failed.encode(),
        refused_with: None,
    });
    // A snapshot whose last odometry pose lies 4e307 m away, finite (found by the `snapshot`
    // harness once its sessions aligned). Restored, the next pose's jump from it put the
    // correction 4e307 m off and the covariance at NaN; the harness's input, off in more
    // bytes, went on to accept poses of NaN.
    let mut far = Snapshot::decode(&stalled).expect("the seed decodes");
    let last = far
        .state
        .continuity
        .last
        .as_mut()
        .expect("the seed has a last pose");
    let (cos, sin) = last.0.rotation();
    last.0 = Se2::from_rotation(cos, sin, 39.0, -3.9e307);
    cases.push(Case {
        name: "snapshot_last_pose_out_of_reach.bin",
        target: Target::Snapshot,
        bytes: far.encode(),
        refused_with: Some("unreadable snapshot"),
    });
    // Snapshots whose numbers are finite but no run makes them (found by the `snapshot` harness
    // once its sessions aligned and it checked every corrected answer against docs/wire.md).
    // Restored, each turned a corrected answer's covariance negative, infinite or NaN.
    type Tamper = fn(&mut Snapshot);
    let tampered: [(&'static str, Tamper); 6] = [
        ("snapshot_covariance_not_positive.bin", |s| {
            // A correlation of the heading with the scale above 1.
            if let Some((_, cross)) = &mut s.state.corrector.published_uncertainty {
                cross[2] = 0.068;
            }
        }),
        (
            "snapshot_covariance_asymmetric_beside_a_large_variance.bin",
            |s| {
                // Found by a coverage-guided run: asymmetric by 6e4 beside a variance of 3e17, which
                // a tolerance relative to the largest entry let through.
                if let Some((covariance, _)) = &mut s.state.corrector.published_uncertainty {
                    covariance[0][0] = 2.9e17;
                    covariance[2][1] = 5.9e4;
                }
            },
        ),
        ("snapshot_published_covariance_without_a_scale.bin", |s| {
            // The covariance with the scale kept, the scale not.
            s.state.corrector.scale = None;
        }),
        ("snapshot_scale_variance_out_of_reach.bin", |s| {
            if let Some(scale) = &mut s.state.corrector.scale {
                scale.variance = 4.5e305;
            }
        }),
        ("snapshot_speed_judged_at_no_rate.bin", |s| {
            if let Some((rate_hz, _)) = s.state.stall.as_mut().and_then(|w| w.judged.as_mut()) {
                *rate_hz = 8e-260;
            }
        }),
        ("snapshot_stall_heading_not_a_direction.bin", |s| {
            if let Some(open) = s.state.stall.as_mut().and_then(|w| w.open.as_mut()) {
                open.heading[0] = 1.7e308;
            }
        }),
    ];
    for (name, tamper) in tampered {
        let mut snapshot = Snapshot::decode(&stalled).expect("the seed decodes");
        let before = snapshot.encode();
        tamper(&mut snapshot);
        assert!(
            snapshot.encode() != before,
            "{name}: the seed has the part tampered with"
        );
        cases.push(Case {
            name,
            target: Target::Snapshot,
            bytes: snapshot.encode(),
            refused_with: Some("unreadable snapshot"),
        });
    }
    // A pose of NaNs first in the Python package's `correct` (found by reading a panic, then by
    // the `pose_array` harness): the anchor check asked the lane map what is near it, and the
    // map's tie search underflowed on the empty answer.
    let mut nan_first = seeds::pose_arrays().swap_remove(0);
    for v in nan_first[1 + 8..1 + 13 * 8].chunks_exact_mut(8) {
        v.copy_from_slice(&f64::NAN.to_le_bytes());
    }
    cases.push(Case {
        name: "pose_array_nan_first.bin",
        target: Target::PoseArray,
        bytes: nan_first,
        refused_with: None,
    });
    cases
}

/// Writes every case into `dir` under its name.
pub fn write_all(dir: &Path) -> std::io::Result<Vec<String>> {
    std::fs::create_dir_all(dir)?;
    cases()
        .into_iter()
        .map(|c| {
            std::fs::write(dir.join(c.name), &c.bytes)?;
            Ok(c.name.to_string())
        })
        .collect()
}
