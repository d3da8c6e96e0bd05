//! Lanes from Lanelet2 maps (OSM XML with `type=lanelet` relations).
//!
//! A lanelet's centerline is its `centerline` member way when it has one, else the midline of its
//! `left` and `right` bounds: both resampled at the same fractions of their length and averaged.
//! Bounds may be stored against the lanelet's direction (a way shared by two lanelets has one
//! direction only), so the right bound is first oriented like the left one (by which pairing of
//! their end points is closer); the direction of travel is then the one that has the left bound
//! on the left. `one_way=no` lanelets are driven both ways and yield a lane in each direction.

use lanealign_core::geo::MapPlane;
use lanealign_core::lane_geometry::{LaneInfo, RoadClass};
use lanealign_core::lane_map::{resample, Lane};

use crate::osm::{tag, OsmData, Relation};

/// Lanelet subtypes that cars drive on (an absent subtype is a road).
pub const DRIVABLE_SUBTYPES: [&str; 5] = [
    "road",
    "highway",
    "play_street",
    "bus_lane",
    "emergency_lane",
];

/// What lanelet reading did, for a person to check.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LaneletReport {
    /// Drivable lanelets turned into lanes.
    pub lanelets_used: usize,
    /// Lanelets of other subtypes (crosswalks, bicycle lanes, ...), skipped.
    pub lanelets_not_drivable: usize,
    /// Lanelets whose bounds are missing or have fewer than two known nodes, skipped.
    pub lanelets_broken: usize,
    /// Lanes an earlier Lanelet2 input gave already, with the same id and the same points (tiles
    /// of one map share the lanelets of their borders), skipped.
    pub lanes_in_earlier_input: usize,
}

/// True when the file holds Lanelet2 lanelets.
pub fn is_lanelet2(osm: &OsmData) -> bool {
    osm.relations
        .iter()
        .any(|r| tag(&r.tags, "type") == Some("lanelet"))
}

fn way_line(osm: &OsmData, way_id: i64, plane: &MapPlane) -> Option<Vec<[f64; 2]>> {
    let way = osm
        .ways
        .binary_search_by_key(&way_id, |w| w.id)
        .ok()
        .map(|i| &osm.ways[i])?;
    let line: Vec<[f64; 2]> = way
        .nodes
        .iter()
        .filter_map(|&n| osm.position(n))
        .map(|(lat, lon)| plane.project(lat, lon))
        .collect();
    (line.len() >= 2 && crate::osm_lanes::is_plausible_line(&line)).then_some(line)
}

fn member_line(
    osm: &OsmData,
    rel: &Relation,
    role: &str,
    plane: &MapPlane,
) -> Option<Vec<[f64; 2]>> {
    let m = rel
        .members
        .iter()
        .find(|m| m.role == role && m.kind == "way")?;
    way_line(osm, m.id, plane)
}

fn length(line: &[[f64; 2]]) -> f64 {
    line.windows(2)
        .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
        .sum()
}

/// The point at `fraction` (0..1) of the polyline's length.
fn at_fraction(line: &[[f64; 2]], fraction: f64) -> [f64; 2] {
    let target = fraction * length(line);
    let mut walked = 0.0;
    for w in line.windows(2) {
        let seg = ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt();
        if walked + seg >= target && seg > 0.0 {
            let t = (target - walked) / seg;
            return [
                w[0][0] + t * (w[1][0] - w[0][0]),
                w[0][1] + t * (w[1][1] - w[0][1]),
            ];
        }
        walked += seg;
    }
    line[line.len() - 1]
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// The midline of two bounds (the right one already oriented like the left), sampled at
/// `samples` equal fractions of each bound's length.
fn midline(left: &[[f64; 2]], right: &[[f64; 2]], samples: usize) -> Vec<[f64; 2]> {
    (0..=samples)
        .map(|i| {
            let f = i as f64 / samples as f64;
            let (l, r) = (at_fraction(left, f), at_fraction(right, f));
            [(l[0] + r[0]) / 2.0, (l[1] + r[1]) / 2.0]
        })
        .collect()
}

/// The centerline of a lanelet in its direction of travel, or `None` if its geometry is missing.
pub fn lanelet_centerline(
    osm: &OsmData,
    rel: &Relation,
    plane: &MapPlane,
) -> Option<Vec<[f64; 2]>> {
    let left = member_line(osm, rel, "left", plane)?;
    let mut right = member_line(osm, rel, "right", plane)?;
    let (l0, l1) = (left[0], left[left.len() - 1]);
    if dist(l0, right[right.len() - 1]) + dist(l1, right[0])
        < dist(l0, right[0]) + dist(l1, right[right.len() - 1])
    {
        right.reverse();
    }
    let mut centre = match member_line(osm, rel, "centerline", plane) {
        Some(c) => c,
        None => {
            let samples = (length(&left).max(length(&right)) / 0.5).ceil().max(1.0) as usize;
            midline(&left, &right, samples)
        }
    };
    // Travel so that the left bound is on the left: the left bound's middle must lie on the
    // positive side of the centerline's overall direction.
    let (c0, c1) = (centre[0], centre[centre.len() - 1]);
    let dir = [c1[0] - c0[0], c1[1] - c0[1]];
    let lm = at_fraction(&left, 0.5);
    let cm = at_fraction(&centre, 0.5);
    if dir[0] * (lm[1] - cm[1]) - dir[1] * (lm[0] - cm[0]) < 0.0 {
        centre.reverse();
    }
    Some(centre)
}

/// Lanes of the drivable lanelets of `osm`, projected with `plane` and resampled at
/// `spacing_m`. Lane ids are the lanelet ids (times two, plus one for the reverse lane of a
/// two-way lanelet).
pub fn derive_lanelet_lanes(
    osm: &OsmData,
    plane: &MapPlane,
    spacing_m: f64,
) -> (Vec<Lane>, LaneletReport) {
    let mut report = LaneletReport::default();
    let mut lanes = Vec::new();
    for rel in osm
        .relations
        .iter()
        .filter(|r| tag(&r.tags, "type") == Some("lanelet"))
    {
        let subtype = tag(&rel.tags, "subtype").unwrap_or("road");
        if !DRIVABLE_SUBTYPES.contains(&subtype) {
            report.lanelets_not_drivable += 1;
            continue;
        }
        let Some(centre) = lanelet_centerline(osm, rel, plane) else {
            report.lanelets_broken += 1;
            continue;
        };
        report.lanelets_used += 1;
        let id = rel.id.unsigned_abs() << 1;
        let two_way = tag(&rel.tags, "one_way") == Some("no");
        let mut reverse = two_way.then(|| centre.iter().rev().copied().collect::<Vec<_>>());
        lanes.push(Lane {
            id,
            info: LaneInfo::new(RoadClass::Lanelet, 0),
            points: resample(&centre, spacing_m),
        });
        if let Some(reverse) = reverse.take() {
            lanes.push(Lane {
                id: id | 1,
                info: LaneInfo::new(RoadClass::Lanelet, LaneInfo::BACKWARD),
                points: resample(&reverse, spacing_m),
            });
        }
    }
    (lanes, report)
}
