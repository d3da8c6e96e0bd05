//! Lane tiles on real data: every map compiles, PBF gives the same tile as XML, a tile corrects
//! exactly like the OSM it came from, Lanelet2 lanes run in their lanelets' direction, and
//! Lanelet2 inputs given together take their shared lanelets once.

use std::path::PathBuf;
use std::process::Command;

use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::params::Preset;
use lanealign_core::pose::AxisConvention;
use lanealign_core::source_corrector::{correct_trajectory, Placement};
use lanealign_core::tile;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_map::osm::{read_xml_file, tag};
use lanealign_tests::{shared_data, SEQUENCES};

fn kitti_00_anchor() -> Anchor {
    "48.9825452359,8.3903661000,59.5584,0.806,0.365"
        .parse()
        .unwrap()
}

fn kitti_options(anchor: &Anchor) -> CompileOptions {
    CompileOptions {
        origin: Some((anchor.lat(), anchor.lon())),
        projection: Projection::Kitti,
        ..CompileOptions::default()
    }
}

#[test]
fn every_shared_map_compiles_into_a_valid_tile() {
    let Some(data) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut inputs: Vec<PathBuf> = SEQUENCES
        .iter()
        .map(|s| data.join(format!("osm/kitti_{s}.osm")))
        .collect();
    inputs.push(data.join("lanelet2/mapping_example.osm"));
    for input in inputs {
        let compiled = compile(std::slice::from_ref(&input), &CompileOptions::default()).unwrap();
        let (map, plane) = (&compiled.map, compiled.plane);
        assert!(
            map.lane_count() > 50,
            "{}: {} lanes",
            input.display(),
            map.lane_count()
        );
        let out = dir.path().join("t.tile");
        tile::write_bytes(&out, &compiled.tile_bytes(3.0)).unwrap();
        let (loaded, info) = tile::load(&out).unwrap();
        assert!(&loaded == map);
        assert_eq!(info.plane, plane);
        assert_eq!(info.geometry, compiled.geometry);
    }
}

#[test]
fn pbf_gives_the_same_tile_as_xml() {
    let Some(data) = shared_data() else { return };
    if Command::new("osmium").arg("--version").output().is_err() {
        eprintln!("SKIPPED: osmium (Debian package osmium-tool) is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for name in [
        "osm/kitti_00.osm",
        "osm/kitti_05.osm",
        "lanelet2/mapping_example.osm",
    ] {
        let xml = data.join(name);
        let pbf = dir.path().join("map.osm.pbf");
        let status = Command::new("osmium")
            .args(["cat", "--overwrite", "-o"])
            .arg(&pbf)
            .arg(&xml)
            .status()
            .unwrap();
        assert!(status.success(), "osmium cat {name}");
        let options = CompileOptions::default();
        let from_xml = compile(&[xml], &options).unwrap();
        let from_pbf = compile(&[pbf], &options).unwrap();
        let (plane_xml, plane_pbf) = (from_xml.plane, from_pbf.plane);
        assert_eq!(plane_xml, plane_pbf, "{name}: same origin");
        assert!(
            from_xml.tile_bytes(3.0) == from_pbf.tile_bytes(3.0),
            "{name}: tiles differ"
        );
    }
}

#[test]
fn a_tile_corrects_exactly_like_its_osm() {
    let Some(data) = shared_data() else { return };
    let anchor = kitti_00_anchor();
    let osm = data.join("osm/kitti_00.osm");
    let compiled = compile(std::slice::from_ref(&osm), &kitti_options(&anchor)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("00.tile");
    tile::write_bytes(&path, &compiled.tile_bytes(3.0)).unwrap();
    let (tile_map, info) = tile::load(&path).unwrap();
    let odom = read(&data.join("odometry/lidar/00.txt"), Format::Kitti).unwrap();
    let cam = AxisConvention::KittiCamera;
    let run = |m, anchored_from_odom| {
        let placement = Placement {
            convention: cam,
            anchored_from_odom,
            smoothing: None,
        };
        correct_trajectory(
            std::sync::Arc::new(m),
            Preset::KissIcp.params(),
            MatchMode::Fast,
            placement,
            &odom.poses,
        )
    };
    let from_osm = run(compiled.map, anchor.anchored_from_odom(&compiled.plane));
    let from_tile = run(tile_map, anchor.anchored_from_odom(&info.plane));
    assert_eq!(from_osm, from_tile);
    assert!(from_osm.iter().filter(|c| c.status.attempted()).count() > 4000);
}

/// Signed side (positive: left) of `p` relative to the direction `a -> b`.
fn side(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
}

#[test]
fn lanelet2_lanes_run_in_their_lanelets_direction() {
    let Some(data) = shared_data() else { return };
    let path = data.join("lanelet2/mapping_example.osm");
    let osm = read_xml_file(&path).unwrap();
    let compiled = compile(std::slice::from_ref(&path), &CompileOptions::default()).unwrap();
    let plane = compiled.plane;
    let lanes: std::collections::HashMap<u64, Vec<[f64; 2]>> = compiled
        .map
        .lanes()
        .map(|(id, _, p)| (id, p.to_vec()))
        .collect();
    let bound = |rel: &lanealign_map::osm::Relation, role: &str| -> Vec<[f64; 2]> {
        let id = rel.members.iter().find(|m| m.role == role).unwrap().id;
        let way = osm.ways.iter().find(|w| w.id == id).unwrap();
        way.nodes
            .iter()
            .map(|&n| osm.position(n).unwrap())
            .map(|(lat, lon)| plane.project(lat, lon))
            .collect()
    };
    let mut checked = 0;
    for rel in osm
        .relations
        .iter()
        .filter(|r| tag(&r.tags, "type") == Some("lanelet"))
    {
        let Some(lane) = lanes.get(&(rel.id as u64 * 2)) else {
            continue;
        };
        if lane.len() < 2 {
            continue;
        }
        // The lanelet's left bound lies left of its lane, the right bound right of it, along the
        // whole lane (each bound node against the nearest lane segment). Nodes on the lane itself
        // (where merging lanelets' bounds meet) have no side.
        for (role, sign) in [("left", 1.0), ("right", -1.0)] {
            for node in bound(rel, role) {
                let d = |i: usize| (lane[i][0] - node[0]).hypot(lane[i][1] - node[1]);
                let k = (0..lane.len() - 1)
                    .min_by(|&a, &b| d(a).total_cmp(&d(b)))
                    .unwrap();
                let (a, b) = (lane[k], lane[k + 1]);
                let offset = side(a, b, node) / (b[0] - a[0]).hypot(b[1] - a[1]);
                if offset.abs() < 0.2 {
                    continue;
                }
                let s = offset * sign;
                assert!(
                    s > 0.0,
                    "lanelet {}: a {role} bound node is on the wrong side",
                    rel.id
                );
            }
        }
        checked += 1;
    }
    assert!(checked > 300, "only {checked} lanelets checked");
}

#[test]
fn known_lanelets_start_and_end_between_their_bounds() {
    let Some(data) = shared_data() else { return };
    let path = data.join("lanelet2/mapping_example.osm");
    let compiled = compile(std::slice::from_ref(&path), &CompileOptions::default()).unwrap();
    let (map, plane) = (&compiled.map, compiled.plane);
    let osm = read_xml_file(&path).unwrap();
    let p = |node: i64| {
        let (lat, lon) = osm.position(node).unwrap();
        plane.project(lat, lon)
    };
    let first_last = |way: i64| {
        let w = osm.ways.iter().find(|w| w.id == way).unwrap();
        (p(w.nodes[0]), p(*w.nodes.last().unwrap()))
    };
    // Lanelet 42440: left way 44574, right way 44584 (from the file).
    for (lanelet, left, right) in [
        (42440i64, 44574i64, 44584i64),
        (42526, 43688, 43566),
        (42973, 43226, 43196),
    ] {
        let lane = map
            .lanes()
            .find(|(id, _, _)| *id == lanelet as u64 * 2)
            .map(|(_, _, pts)| pts.to_vec())
            .unwrap();
        let (l0, l1) = first_last(left);
        let (r0, r1) = first_last(right);
        let mid = |a: [f64; 2], b: [f64; 2]| [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
        let near =
            |a: [f64; 2], b: [f64; 2], tolerance: f64| (a[0] - b[0]).hypot(a[1] - b[1]) < tolerance;
        let start = lane[0];
        let ends = [mid(l0, r0), mid(l0, r1), mid(l1, r0), mid(l1, r1)];
        assert!(
            ends.iter().any(|&e| near(e, start, 0.5)),
            "lanelet {lanelet}: start {start:?} is not between bound ends"
        );
        let end = lane[lane.len() - 1];
        assert!(
            ends.iter().any(|&e| near(e, end, 3.5)),
            "lanelet {lanelet}: end {end:?} is not between bound ends"
        );
    }
}

/// Lanelet2 inputs given together: a lane an earlier input gave with the same id and points is
/// the same lanelet (tiles of one map share their borders' lanelets) and is taken once; a map
/// whose ids are another map's own (the same ids, other places) keeps all its lanes. The map
/// given twice gave every lane twice.
#[test]
fn lanelet2_inputs_merge_their_shared_lanelets_once() {
    let Some(data) = shared_data() else { return };
    let example = data.join("lanelet2/mapping_example.osm");
    let dir = tempfile::tempdir().unwrap();
    // The same lanelets 2 km north: other places under the same ids.
    let text = std::fs::read_to_string(&example).unwrap();
    let moved = shifted_north(&text, 0.018);
    let elsewhere = dir.path().join("elsewhere.osm");
    std::fs::write(&elsewhere, moved).unwrap();
    let options = CompileOptions {
        origin: Some((49.0, 8.4)),
        ..CompileOptions::default()
    };
    let once = compile(std::slice::from_ref(&example), &options).unwrap();
    let twice = compile(&[example.clone(), example.clone()], &options).unwrap();
    assert_eq!(twice.map.lane_ids().len(), once.map.lane_ids().len());
    assert!(
        twice.tile_bytes(3.0) == once.tile_bytes(3.0),
        "the same tile"
    );
    let two_maps = compile(&[example.clone(), elsewhere.clone()], &options).unwrap();
    assert_eq!(two_maps.map.lane_ids().len(), 2 * once.map.lane_ids().len());
    // The second map given again is the second map's lanes again, not the first's.
    let again = compile(&[example.clone(), elsewhere.clone(), elsewhere], &options).unwrap();
    assert!(
        again.tile_bytes(3.0) == two_maps.tile_bytes(3.0),
        "the two maps' tile"
    );
}

/// `text` with every `lat='...'` / `lat="..."` value raised by `dlat` degrees.
fn shifted_north(text: &str, dlat: f64) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find("lat=") {
        let quote = rest.as_bytes()[at + 4] as char;
        let start = at + 5;
        let end = start + rest[start..].find(quote).unwrap();
        let lat: f64 = rest[start..end].parse().unwrap();
        out.push_str(&rest[..start]);
        out.push_str(&format!("{:.9}", lat + dlat));
        rest = &rest[end..];
    }
    out.push_str(rest);
    out
}
