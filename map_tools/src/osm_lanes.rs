//! Lanes derived from raw OSM ways and their tags (docs/algorithm.md, section 1).
//!
//! Each drivable way yields one centerline per lane: the way line offset sideways to the lane's
//! centre and pointing in the lane's direction of travel. Coordinates are metres in the map plane.

use lanealign_core::geo::MapPlane;
use lanealign_core::lane_geometry::{LaneGeometry, LaneInfo, RoadClass, RoadClasses, Traffic};
use lanealign_core::lane_map::{resample, Lane};
use lanealign_core::params::{Method, UNMARKED_OFFSET_SCALE};

use crate::osm::{is_shared_id, tag, NodePositions, OsmData, Tags, Way};

/// How lanes are derived.
#[derive(Clone, Debug, PartialEq)]
pub struct LaneOptions {
    /// The `highway` classes to use (default [`RoadClasses::DEFAULT`]; add `service` to
    /// include it).
    pub classes: RoadClasses,
    /// Traffic side.
    pub traffic: Traffic,
    /// Minimum spacing of the resampled centerline points (metres).
    pub spacing_m: f64,
    /// Where the lanes of unmarked two-way streets lie (`residential`, `unclassified` and
    /// `living_street` ways with no `lanes` tag), as a fraction of the nominal offset of half a
    /// lane width from the way line. On such streets, with parked cars and little oncoming
    /// traffic, cars drive between their lane's nominal centre and the road's middle (measured on
    /// the KITTI drives: median 0.5 m right of the way line, against a nominal 1.375 m).
    /// 1 is the paper's geometry ([`LaneOptions::paper`]); the default is 0.5.
    pub unmarked_offset_scale: f64,
}

impl Default for LaneOptions {
    fn default() -> Self {
        LaneOptions {
            classes: RoadClasses::DEFAULT,
            traffic: Traffic::Right,
            spacing_m: 3.0,
            unmarked_offset_scale: UNMARKED_OFFSET_SCALE,
        }
    }
}

impl LaneOptions {
    /// The paper's lane geometry: every lane at its nominal offset from the way line.
    pub fn paper() -> Self {
        LaneOptions {
            unmarked_offset_scale: 1.0,
            ..LaneOptions::default()
        }
    }

    /// The lane geometry `method` is designed and measured on: the paper's for
    /// [`Method::Paper`], the default for [`Method::Robust`].
    pub fn for_method(method: Method) -> Self {
        LaneOptions {
            unmarked_offset_scale: method.unmarked_offset_scale(),
            ..LaneOptions::default()
        }
    }

    /// The lane geometry these options give lanes derived from raw OSM ways.
    pub fn geometry(&self) -> LaneGeometry {
        LaneGeometry {
            traffic: self.traffic,
            classes: self.classes,
            unmarked_offset_scale: Some(self.unmarked_offset_scale),
        }
    }
}

/// What lane derivation did with the input, for a person to check.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DeriveReport {
    /// Ways skipped because they are not a road of the selected classes (no `highway` tag, a
    /// class not selected, or `area=yes`).
    pub ways_not_drivable: usize,
    /// Drivable ways turned into lanes.
    pub ways_used: usize,
    /// Drivable ways skipped because fewer than two of their nodes exist in the file, two
    /// consecutive nodes are more than [`MAX_NODE_GAP_M`] apart, or a node lies more than
    /// [`MAX_PLANE_RADIUS_M`] from the plane's origin.
    pub ways_without_geometry: usize,
    /// References to nodes that no OSM input contains (skipped).
    pub missing_node_refs: usize,
    /// Ways skipped because an earlier OSM input holds them as roads (the overlap of two
    /// extracts): a way's lanes come from the first input that holds it.
    pub ways_in_earlier_input: usize,
    /// Lanes produced.
    pub lanes: usize,
}

impl DeriveReport {
    /// Ways in the input: every way is used, not drivable or without geometry.
    pub fn ways_read(&self) -> usize {
        self.ways_used
            + self.ways_not_drivable
            + self.ways_without_geometry
            + self.ways_in_earlier_input
    }

    /// Adds the counts of `other` (a part of the same input derived apart).
    pub fn add(&mut self, other: &DeriveReport) {
        self.ways_not_drivable += other.ways_not_drivable;
        self.ways_used += other.ways_used;
        self.ways_without_geometry += other.ways_without_geometry;
        self.missing_node_refs += other.missing_node_refs;
        self.ways_in_earlier_input += other.ways_in_earlier_input;
        self.lanes += other.lanes;
    }
}

/// The default lane width (metres) of a highway class, used when `width` is absent.
pub fn default_lane_width(class: &str) -> f64 {
    match class.trim_end_matches("_link") {
        "motorway" | "trunk" => 3.5,
        "primary" => 3.25,
        "secondary" | "tertiary" => 3.0,
        "living_street" | "service" => 2.5,
        _ => 2.75,
    }
}

/// Lanes of a way in each direction, and whether a single lane is shared by both.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LaneCounts {
    /// Lanes in the way's direction.
    pub forward: u32,
    /// Lanes against the way's direction.
    pub backward: u32,
    /// One lane used both ways (`lanes=1` on a two-way road).
    pub shared: bool,
}

fn count(tags: &Tags, key: &str) -> Option<u32> {
    tag(tags, key)
        .and_then(|v| v.split(';').next())
        .and_then(|v| v.trim().parse::<u32>().ok())
        .filter(|&n| (1..=16).contains(&n))
}

/// Lane counts from `lanes`, `lanes:forward`, `lanes:backward` and `oneway` (with the implied
/// oneway of motorways and roundabouts). A `oneway=-1` way counts its lanes as forward; the
/// caller reverses its geometry.
pub fn lane_counts(class: &str, tags: &Tags) -> LaneCounts {
    let oneway = match tag(tags, "oneway") {
        Some("yes" | "true" | "1" | "-1" | "reverse") => true,
        Some("no" | "false" | "0") => false,
        _ => {
            class == "motorway"
                || class == "motorway_link"
                || matches!(tag(tags, "junction"), Some("roundabout" | "circular"))
        }
    };
    let lanes = count(tags, "lanes");
    if oneway {
        let forward = count(tags, "lanes:forward")
            .or(lanes)
            .unwrap_or(if class == "motorway" { 2 } else { 1 });
        return LaneCounts {
            forward,
            backward: 0,
            shared: false,
        };
    }
    let (fw, bw) = (count(tags, "lanes:forward"), count(tags, "lanes:backward"));
    let (forward, backward) = match (fw, bw, lanes) {
        (Some(f), Some(b), _) => (f, b),
        (Some(f), None, Some(n)) if n > f => (f, n - f),
        (None, Some(b), Some(n)) if n > b => (n - b, b),
        (Some(f), None, _) => (f, 1),
        (None, Some(b), _) => (1, b),
        (None, None, Some(1)) => {
            return LaneCounts {
                forward: 1,
                backward: 1,
                shared: true,
            }
        }
        (None, None, Some(n)) => (n - n / 2, n / 2),
        (None, None, None) => (1, 1),
    };
    LaneCounts {
        forward,
        backward,
        shared: false,
    }
}

/// The lane width (metres) from a way's `width` tag divided by the lane count, when present and
/// plausible (2 to 5 m).
fn tagged_lane_width(tags: &Tags, lanes: u32) -> Option<f64> {
    tag(tags, "width")
        .and_then(|v| v.trim().trim_end_matches('m').trim().parse::<f64>().ok())
        .map(|w| w / lanes.max(1) as f64)
        .filter(|w| (2.0..=5.0).contains(w))
}

/// The lane width (metres) of a way: `width` divided by the lane count when plausible, else the
/// class default.
pub fn lane_width(class: &str, tags: &Tags, lanes: u32) -> f64 {
    tagged_lane_width(tags, lanes).unwrap_or_else(|| default_lane_width(class))
}

/// The polyline shifted sideways by `offset_m` (positive to the left of its direction), with
/// mitred corners (the mitre limited to twice the offset on sharp turns).
pub fn offset_polyline(points: &[[f64; 2]], offset_m: f64) -> Vec<[f64; 2]> {
    if offset_m == 0.0 || points.len() < 2 {
        return points.to_vec();
    }
    let normals: Vec<[f64; 2]> = points
        .windows(2)
        .map(|w| {
            let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
            let len = (dx * dx + dy * dy).sqrt();
            [-dy / len, dx / len]
        })
        .collect();
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let before = normals[i.saturating_sub(1)];
            let after = normals[i.min(normals.len() - 1)];
            let sum = [before[0] + after[0], before[1] + after[1]];
            let len = (sum[0] * sum[0] + sum[1] * sum[1]).sqrt();
            let n = if len > 1e-9 {
                [sum[0] / len, sum[1] / len]
            } else {
                after
            };
            let cos_half = (n[0] * after[0] + n[1] * after[1]).max(0.5);
            let d = offset_m / cos_half;
            [p[0] + n[0] * d, p[1] + n[1] * d]
        })
        .collect()
}

/// The longest step between two consecutive nodes of a road (metres): far beyond any real road
/// segment; a longer one is a broken coordinate, and resampling it would turn a few bytes of
/// input into millions of lane points.
pub const MAX_NODE_GAP_M: f64 = 5000.0;

/// How far from its map plane's origin a road may lie (metres). A tangent plane's scale along
/// the radius is `cos(d / R)`: off by 0.11 % (1.1 m per km driven) at 300 km. With an origin of
/// `0,0`, 5400 km away, KITTI 04's roads compiled without a word into 21 % fewer lane-km (40.9
/// against 51.9). One plane serves a region of a few hundred kilometres (docs/fleet.md).
pub const MAX_PLANE_RADIUS_M: f64 = 300_000.0;

/// True when no two consecutive points of `line` are more than [`MAX_NODE_GAP_M`] apart and
/// none lies more than [`MAX_PLANE_RADIUS_M`] from the plane's origin.
pub fn is_plausible_line(line: &[[f64; 2]]) -> bool {
    let steps = line.windows(2).all(|w| {
        let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
        (dx * dx + dy * dy).sqrt() <= MAX_NODE_GAP_M
    });
    steps && line.iter().all(|p| p[0].hypot(p[1]) <= MAX_PLANE_RADIUS_M)
}

/// The projected way line (metres), without repeated points; `None` if it has fewer than two
/// distinct points or is not [`is_plausible_line`]. Counts missing
/// node references into `report`.
fn way_line(
    nodes: &impl NodePositions,
    way: &Way,
    plane: &MapPlane,
    report: &mut DeriveReport,
) -> Option<Vec<[f64; 2]>> {
    let mut line: Vec<[f64; 2]> = Vec::with_capacity(way.nodes.len());
    for id in &way.nodes {
        match nodes.position(*id) {
            Some((lat, lon)) => {
                let p = plane.project(lat, lon);
                if line.last() != Some(&p) {
                    line.push(p);
                }
            }
            None => report.missing_node_refs += 1,
        }
    }
    (line.len() >= 2 && is_plausible_line(&line)).then_some(line)
}

/// Derives lane centerlines from the drivable ways of `osm`, projected with `plane`.
/// Lane ids are `way_id * 32 + lane number` (lane numbers from the left edge of the road).
pub fn derive_lanes(
    osm: &OsmData,
    plane: &MapPlane,
    opts: &LaneOptions,
) -> (Vec<Lane>, DeriveReport) {
    let mut report = DeriveReport::default();
    let mut lanes = Vec::new();
    for way in &osm.ways {
        derive_way_lanes(way, osm, plane, opts, &mut report, &mut lanes);
    }
    (lanes, report)
}

/// The roads of the OSM inputs before the one being derived, by OSM's shared ids
/// ([`is_shared_id`]): a way that several inputs hold (extracts overlap) has its lanes from the
/// first. Both compiles, in memory and streamed, skip by it.
#[derive(Clone, Debug, Default)]
pub struct EarlierRoads {
    /// Ascending, each once.
    ids: Vec<i64>,
}

impl EarlierRoads {
    /// Whether an input before holds `way` as a road, so that its lanes came from there
    /// (counted into `report`).
    pub fn took(&self, way: &Way, report: &mut DeriveReport) -> bool {
        let took = self.ids.binary_search(&way.id).is_ok();
        report.ways_in_earlier_input += usize::from(took);
        took
    }

    /// The id the inputs after must not derive again: `way`'s, when it is a road under a shared
    /// id.
    pub fn id_of(way: &Way, opts: &LaneOptions) -> Option<i64> {
        (is_shared_id(way.id) && road_class(way, opts).is_some()).then_some(way.id)
    }

    /// Adds an input's roads (ids from [`EarlierRoads::id_of`]).
    pub fn add(&mut self, ids: impl IntoIterator<Item = i64>) {
        self.ids.extend(ids);
        self.ids.sort_unstable();
        self.ids.dedup();
    }
}

/// The class of `way` when it is a road lanes are derived from: a `highway` of a selected
/// class, not an area.
pub fn road_class(way: &Way, opts: &LaneOptions) -> Option<RoadClass> {
    tag(&way.tags, "highway")
        .and_then(RoadClass::from_osm)
        .filter(|&c| opts.classes.contains(c) && tag(&way.tags, "area") != Some("yes"))
}

/// Appends the lane centerlines of `way` (none when it is not drivable or has no usable
/// geometry) to `lanes`, its nodes placed by `nodes` and projected with `plane`; counts what it
/// did into `report`. Lanes come in the order of their lane numbers.
pub fn derive_way_lanes(
    way: &Way,
    nodes: &impl NodePositions,
    plane: &MapPlane,
    opts: &LaneOptions,
    report: &mut DeriveReport,
    lanes: &mut Vec<Lane>,
) {
    let Some(road_class) = road_class(way, opts) else {
        report.ways_not_drivable += 1;
        return;
    };
    let class = road_class.name();
    let Some(mut line) = way_line(nodes, way, plane, report) else {
        report.ways_without_geometry += 1;
        return;
    };
    if matches!(tag(&way.tags, "oneway"), Some("-1" | "reverse")) {
        line.reverse();
    }
    report.ways_used += 1;
    let counts = lane_counts(class, &way.tags);
    let id = |k: u32| (way.id.unsigned_abs() << 5) | u64::from(k & 31);
    let lanes_tagged = ["lanes", "lanes:forward", "lanes:backward"]
        .iter()
        .any(|key| tag(&way.tags, key).is_some());
    let mut tags_flags = 0;
    if lanes_tagged {
        tags_flags |= LaneInfo::LANES_TAGGED;
    }
    if counts.shared {
        let forward = resample(&line, opts.spacing_m);
        let mut reversed = line.clone();
        reversed.reverse();
        let flags = tags_flags | LaneInfo::SHARED;
        lanes.push(Lane {
            id: id(0),
            info: LaneInfo::new(road_class, flags),
            points: forward,
        });
        lanes.push(Lane {
            id: id(1),
            info: LaneInfo::new(road_class, flags | LaneInfo::BACKWARD),
            points: resample(&reversed, opts.spacing_m),
        });
        report.lanes += 2;
        return;
    }
    let total = counts.forward + counts.backward;
    let width = lane_width(class, &way.tags, total);
    if tagged_lane_width(&way.tags, total).is_some() {
        tags_flags |= LaneInfo::WIDTH_TAGGED;
    }
    let unmarked = tag(&way.tags, "lanes").is_none()
        && counts.forward > 0
        && counts.backward > 0
        && matches!(class, "residential" | "unclassified" | "living_street");
    if unmarked {
        tags_flags |= LaneInfo::UNMARKED;
    }
    let scale = if unmarked {
        opts.unmarked_offset_scale
    } else {
        1.0
    };
    // Lanes numbered from the road's left edge (in the way's direction). Right-hand
    // traffic puts the backward lanes on the left, left-hand traffic the forward ones.
    for k in 0..total {
        let forward = match opts.traffic {
            Traffic::Right => k >= counts.backward,
            Traffic::Left => k < counts.forward,
        };
        let offset = (total as f64 / 2.0 - k as f64 - 0.5) * width * scale;
        let mut centre = offset_polyline(&line, offset);
        let mut flags = tags_flags;
        if !forward {
            centre.reverse();
            flags |= LaneInfo::BACKWARD;
        }
        lanes.push(Lane {
            id: id(k),
            info: LaneInfo::new(road_class, flags),
            points: resample(&centre, opts.spacing_m),
        });
        report.lanes += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::osm::read_xml;
    use lanealign_core::geo::Projection;
    use std::path::Path;

    fn tags(pairs: &[(&str, &str)]) -> Tags {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn lane_counts_follow_the_tags() {
        let c = |class: &str, t: &[(&str, &str)]| {
            let l = lane_counts(class, &tags(t));
            (l.forward, l.backward, l.shared)
        };
        assert_eq!(c("residential", &[]), (1, 1, false));
        assert_eq!(c("residential", &[("lanes", "1")]), (1, 1, true));
        assert_eq!(c("primary", &[("lanes", "4")]), (2, 2, false));
        assert_eq!(
            c("primary", &[("lanes", "3"), ("lanes:forward", "2")]),
            (2, 1, false)
        );
        assert_eq!(
            c("primary", &[("oneway", "yes"), ("lanes", "3")]),
            (3, 0, false)
        );
        assert_eq!(c("motorway", &[]), (2, 0, false));
        assert_eq!(c("tertiary", &[("junction", "roundabout")]), (1, 0, false));
        assert_eq!(c("secondary", &[("oneway", "-1")]), (1, 0, false));
        assert_eq!(
            c("motorway", &[("oneway", "no"), ("lanes", "4")]),
            (2, 2, false)
        );
    }

    fn straight_way(extra: &str) -> OsmData {
        let xml = format!(
            r#"<osm><node id="1" lat="49.0" lon="8.4"/><node id="2" lat="49.0" lon="8.401"/>
               <node id="3" lat="49.0" lon="8.402"/>
               <way id="7"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="99"/>
               <tag k="highway" v="primary"/>{extra}</way>
               <way id="8"><nd ref="1"/><tag k="highway" v="primary"/></way></osm>"#
        );
        read_xml(xml.as_bytes(), Path::new("w.osm")).unwrap()
    }

    #[test]
    fn two_way_lanes_sit_right_of_the_way_in_their_direction() {
        let osm = straight_way(r#"<tag k="lanes" v="2"/><tag k="width" v="7"/>"#);
        let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        let (lanes, report) = derive_lanes(&osm, &plane, &LaneOptions::default());
        assert_eq!(report.ways_used, 1);
        assert_eq!(report.ways_without_geometry, 1, "way 8 has one node");
        assert_eq!(report.missing_node_refs, 1, "node 99 is missing");
        assert_eq!(lanes.len(), 2);
        // The way runs east. Lane 0 is the westbound lane on the north side (y = +1.75 m).
        let (west, east) = (&lanes[0].points, &lanes[1].points);
        assert!(west[0][0] > west[west.len() - 1][0]);
        assert!((west[0][1] - 1.75).abs() < 0.01, "{:?}", west[0]);
        assert!(east[0][0] < east[east.len() - 1][0]);
        assert!((east[0][1] + 1.75).abs() < 0.01, "{:?}", east[0]);
        // Resampled at 3 m or more.
        assert!(east.windows(2).all(|w| (w[1][0] - w[0][0]).abs() >= 3.0));
    }

    #[test]
    fn unmarked_two_way_streets_have_their_lanes_closer_to_the_way_line() {
        let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        // The eastbound lane's offset (metres, + north) of a way running east.
        let eastbound = |class: &str, extra: &str, opts: &LaneOptions| {
            let xml = format!(
                r#"<osm><node id="1" lat="49.0" lon="8.4"/><node id="2" lat="49.0" lon="8.401"/>
                   <way id="7"><nd ref="1"/><nd ref="2"/><tag k="highway" v="{class}"/>{extra}</way>
                   </osm>"#
            );
            let osm = read_xml(xml.as_bytes(), Path::new("w.osm")).unwrap();
            let (lanes, _) = derive_lanes(&osm, &plane, opts);
            let lane = lanes.iter().find(|l| l.points[0][0] < l.points[1][0]);
            lane.unwrap().points[0][1]
        };
        let (default, paper) = (LaneOptions::default(), LaneOptions::paper());
        // Residential, no lanes tag: half of the nominal 2.75 / 2 m.
        assert!((eastbound("residential", "", &default) + 0.6875).abs() < 0.01);
        assert!((eastbound("residential", "", &paper) + 1.375).abs() < 0.01);
        // Marked lanes, other classes and one-way streets keep the nominal offset.
        let two = r#"<tag k="lanes" v="2"/>"#;
        assert!((eastbound("residential", two, &default) + 1.375).abs() < 0.01);
        assert!((eastbound("primary", "", &default) + 1.625).abs() < 0.01);
        let oneway = r#"<tag k="oneway" v="yes"/>"#;
        assert!(eastbound("residential", oneway, &default).abs() < 0.01);
    }

    #[test]
    fn shared_single_lane_runs_both_ways_on_the_way_line() {
        let osm = straight_way(r#"<tag k="lanes" v="1"/>"#);
        let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        let (lanes, _) = derive_lanes(&osm, &plane, &LaneOptions::default());
        assert_eq!(lanes.len(), 2);
        assert!(lanes
            .iter()
            .all(|l| l.points.iter().all(|p| p[1].abs() < 0.01)));
        assert!(lanes[0].points[0][0] < lanes[1].points[0][0]);
    }

    #[test]
    fn left_hand_traffic_mirrors_the_sides() {
        let osm = straight_way("");
        let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
        let opts = LaneOptions {
            traffic: Traffic::Left,
            ..LaneOptions::default()
        };
        let (lanes, _) = derive_lanes(&osm, &plane, &opts);
        // The eastbound lane is now on the north (left) side.
        let east = lanes
            .iter()
            .find(|l| l.points[0][0] < l.points[1][0])
            .unwrap();
        assert!(east.points[0][1] > 0.0);
    }

    #[test]
    fn offset_keeps_distance_around_a_corner() {
        let line = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]];
        let off = offset_polyline(&line, -2.0);
        assert_eq!(off[0], [0.0, -2.0]);
        assert!((off[1][0] - 12.0).abs() < 1e-9 && (off[1][1] + 2.0).abs() < 1e-9);
        assert_eq!(off[2], [12.0, 10.0]);
    }
}
