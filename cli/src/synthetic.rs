//! A synthetic town for running lanealign with no data at all: a grid of two-way streets with
//! right-hand lanes, a route looping through it, the true poses along the route and a drifting
//! odometry run of them; and, from any true run, an odometry whose heading drifts as much as
//! asked ([`heading_drifted`]). Everything is generated from a fixed seed.

use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::lane_geometry::{LaneGeometry, RoadClasses, Traffic};
use std::path::Path;

use lanealign_core::lane_map::{Lane, LaneMap};
use lanealign_core::pose::{apply_planar_correction, AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::tile::{self, TileError};

/// Street spacing (metres) and count per axis.
const BLOCK_M: f64 = 120.0;
const STREETS: usize = 6;
/// Lane centre offset from the street axis (metres).
const LANE_OFFSET_M: f64 = 1.75;
/// Lane point spacing (metres).
const SPACING_M: f64 = 3.0;

/// The generator the synthetic data is made with. The tests use it too (kill moments), so that
/// the project has one generator for data made from a seed.
pub use lanealign_core::rng::Lcg;

fn line(from: [f64; 2], to: [f64; 2]) -> Vec<[f64; 2]> {
    let len = (to[0] - from[0]).hypot(to[1] - from[1]);
    let n = (len / SPACING_M).floor() as usize;
    (0..=n)
        .map(|i| {
            let t = i as f64 * SPACING_M / len;
            [
                from[0] + t * (to[0] - from[0]),
                from[1] + t * (to[1] - from[1]),
            ]
        })
        .collect()
}

/// The town's lanes (metres, map plane): each street has one lane per direction, each lane a
/// block long, offset to the right of its direction of travel.
pub fn town_lanes() -> Vec<Lane> {
    city_lanes(STREETS)
}

/// The lanes of a city of `streets` x `streets` streets laid out as the town's (about
/// 160 `streets`^2 lane points: 80 streets make a region of 9.5 km x 9.5 km and a million points).
pub fn city_lanes(streets: usize) -> Vec<Lane> {
    let mut lanes = Vec::new();
    let mut id = 0;
    let mut push = |from: [f64; 2], to: [f64; 2]| {
        let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
        let len = dx.hypot(dy);
        let right = [dy / len * LANE_OFFSET_M, -dx / len * LANE_OFFSET_M];
        let shifted = |p: [f64; 2]| [p[0] + right[0], p[1] + right[1]];
        id += 1;
        lanes.push(Lane::new(id, line(shifted(from), shifted(to))));
    };
    for k in 0..streets {
        let c = k as f64 * BLOCK_M;
        for b in 0..streets.saturating_sub(1) {
            let (s, e) = (b as f64 * BLOCK_M, (b + 1) as f64 * BLOCK_M);
            push([s, c], [e, c]);
            push([e, c], [s, c]);
            push([c, s], [c, e]);
            push([c, e], [c, s]);
        }
    }
    lanes
}

/// Where the town lies: an East-North tangent plane at 49 N, 8.4 E (metres).
pub fn town_plane() -> MapPlane {
    MapPlane::new(Projection::Tangent, 49.0, 8.4)
}

/// The anchor of the town's odometry: its frame is the map plane itself.
pub fn town_anchor() -> Anchor {
    Anchor::new(49.0, 8.4, 0.0, 0.0, 0.0).expect("constant, valid anchor")
}

/// What a tile of the town records about its lanes: drawn directly, not derived from OSM ways.
pub fn town_geometry() -> LaneGeometry {
    LaneGeometry {
        traffic: Traffic::Right,
        classes: RoadClasses::EMPTY,
        unmarked_offset_scale: None,
    }
}

/// Writes the town's tile to `path`.
pub fn write_town_tile(path: &Path) -> Result<(), TileError> {
    let map = LaneMap::new(&town_lanes()).map_err(|source| TileError::Map {
        path: path.to_path_buf(),
        source,
    })?;
    tile::write(path, &map, &town_plane(), SPACING_M, &town_geometry())
}

/// The route's corners (street intersections), driven in order and then back to the start.
const ROUTE: [(usize, usize); 8] = [
    (0, 0),
    (4, 0),
    (4, 2),
    (2, 2),
    (2, 5),
    (5, 5),
    (5, 1),
    (0, 1),
];

/// The most laps [`drive`] drives: 11.5 million poses (a lap is 2880), above the 10^7 a soak's
/// source sends at most, in 1.1 GB each for the truth and the odometry.
pub const MAX_LAPS: usize = 4000;

/// True poses (flu, map plane) every metre along the route, `laps` times (1 to [`MAX_LAPS`]),
/// driving in the right lane; and an odometry run of them with a heading drift, a scale error
/// and noise from `seed`, starting at the true start pose.
pub fn drive(laps: usize, seed: u64) -> (Vec<Pose3>, Vec<Pose3>) {
    assert!(
        (1..=MAX_LAPS).contains(&laps),
        "{laps} laps: the town is driven 1 to {MAX_LAPS} times"
    );
    let route: Vec<(usize, usize)> = (0..laps)
        .flat_map(|_| ROUTE)
        .chain(std::iter::once(ROUTE[0]))
        .collect();
    drive_route(&route, seed)
}

/// At least `poses` true poses and their odometry run (see [`drive`]): as many laps as that
/// takes, driven in one go, so that the odometry drifts on from lap to lap as a vehicle's would
/// (a run replayed in a loop jumps back to its start at every loop instead, and its corrector
/// then finds itself hundreds of metres off).
pub fn drive_at_least(poses: usize, seed: u64) -> (Vec<Pose3>, Vec<Pose3>) {
    let lap = drive(1, seed).0.len().max(1);
    drive(poses.div_ceil(lap).max(1), seed)
}

/// A drive across a city of `streets` streets (see [`city_lanes`]): from its south-west
/// corner to its north-east one in steps of three blocks east and three north, as
/// [`drive`] drives the town.
pub fn drive_across(streets: usize, seed: u64) -> (Vec<Pose3>, Vec<Pose3>) {
    let last = streets.saturating_sub(1);
    let mut route = vec![(0, 0)];
    let (mut i, mut j) = (0, 0);
    while i < last || j < last {
        i = (i + 3).min(last);
        route.push((i, j));
        j = (j + 3).min(last);
        route.push((i, j));
    }
    drive_route(&route, seed)
}

/// True poses every metre along `route` (street intersections, driven in order in the right
/// lane) and an odometry run of them (see [`drive`]).
fn drive_route(route: &[(usize, usize)], seed: u64) -> (Vec<Pose3>, Vec<Pose3>) {
    let corner = |(i, j): (usize, usize)| [i as f64 * BLOCK_M, j as f64 * BLOCK_M];
    let mut truth = Vec::new();
    for w in route.windows(2) {
        let (a, b) = (corner(w[0]), corner(w[1]));
        if a == b {
            continue;
        }
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = dx.hypot(dy);
        let yaw = dy.atan2(dx);
        let right = [dy / len * LANE_OFFSET_M, -dx / len * LANE_OFFSET_M];
        for i in 0..len as usize {
            let t = i as f64 / len;
            truth.push(Pose3::planar(
                a[0] + t * dx + right[0],
                a[1] + t * dy + right[1],
                yaw,
                0.0,
            ));
        }
    }
    let mut rng = Lcg(seed);
    let yaw_of = |p: &Pose3| p.planar_heading();
    let [x0, y0] = truth[0].planar_position();
    let (mut x, mut y, mut yaw) = (x0, y0, yaw_of(&truth[0]));
    let mut odometry = vec![truth[0]];
    for w in truth.windows(2) {
        let ([ax, ay], [bx, by]) = (w[0].planar_position(), w[1].planar_position());
        let (dx, dy) = (bx - ax, by - ay);
        let (s0, c0) = yaw_of(&w[0]).sin_cos();
        // The step in the vehicle frame, measured with 1 % scale error and noise.
        let forward = (c0 * dx + s0 * dy) * 1.01 + 0.01 * rng.normal();
        let left = -s0 * dx + c0 * dy + 0.005 * rng.normal();
        let turn = yaw_of(&w[1]) - yaw_of(&w[0]);
        let turn = (turn + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
            - std::f64::consts::PI;
        // Gyro bias: 0.0015 degrees per metre (about 4 degrees a lap), and noise.
        yaw += turn + 0.0015f64.to_radians() + 0.0002 * rng.normal();
        let (s, c) = yaw.sin_cos();
        x += c * forward - s * left;
        y += s * forward + c * left;
        odometry.push(Pose3::planar(x, y, yaw, 0.0));
    }
    (truth, odometry)
}

/// An odometry run made from `truth` (poses in `convention`): the truth's planar steps, with the
/// heading turned after each by a normal amount of standard deviation `deg_per_sqrt_100m`
/// degrees times the square root of the step's length over 100 m (a random walk of the heading
/// per distance, as the presets' `yaw_drift_var_per_m` models it). Step lengths are exact;
/// height, roll and pitch are the truth's. The same on every machine for one `seed`.
pub fn heading_drifted(
    truth: &[Pose3],
    convention: AxisConvention,
    deg_per_sqrt_100m: f64,
    seed: u64,
) -> Vec<Pose3> {
    let planar: Vec<Pose3> = truth.iter().map(|p| convention.to_planar(p)).collect();
    let Some(first) = planar.first() else {
        return Vec::new();
    };
    let mut rng = Lcg(seed);
    let mut truth_before = first.to_se2();
    let mut odom = truth_before;
    let mut out = vec![truth[0]];
    for pose in &planar[1..] {
        let truth_now = pose.to_se2();
        let step = truth_before.inverse() * truth_now;
        let [dx, dy] = step.translation();
        let turn = deg_per_sqrt_100m.to_radians() * (dx.hypot(dy) / 100.0).sqrt() * rng.normal();
        odom = (odom * step * Se2::new(turn, 0.0, 0.0)).normalized();
        let odom_from_truth = odom * truth_now.inverse();
        out.push(convention.from_planar(&apply_planar_correction(&odom_from_truth, pose)));
        truth_before = truth_now;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use lanealign_core::corrector::MatchMode;
    use lanealign_core::lane_map::LaneMap;
    use lanealign_core::metrics::ape_2d;
    use lanealign_core::params::{Method, Preset};
    use lanealign_core::source_corrector::{correct_trajectory, counts, Placement};
    use std::sync::Arc;

    #[test]
    fn a_long_drive_drifts_on_from_lap_to_lap_without_jumping_back() {
        let (truth, odometry) = drive_at_least(20_000, 7);
        assert!(odometry.len() >= 20_000, "{}", odometry.len());
        assert_eq!(truth.len(), odometry.len());
        let step = |w: &[Pose3]| {
            let ([ax, ay], [bx, by]) = (w[0].planar_position(), w[1].planar_position());
            (bx - ax).hypot(by - ay)
        };
        let longest = odometry.windows(2).map(step).fold(0.0, f64::max);
        // Steps of a metre, a few at the corners, where the lane offset turns with the street.
        assert!(longest < 5.0, "an odometry step of {longest} m");
        // It drifts on: the last lap's odometry is farther from the truth than the first's.
        let off = |k: usize| {
            let ([ax, ay], [bx, by]) = (truth[k].planar_position(), odometry[k].planar_position());
            (bx - ax).hypot(by - ay)
        };
        assert!(off(odometry.len() - 1) > off(drive(1, 7).0.len() - 1));
    }

    #[test]
    fn the_town_drive_drifts_and_lanealign_removes_most_of_it() {
        let (truth, odometry) = drive(3, 42);
        let map = Arc::new(LaneMap::new(&town_lanes()).unwrap());
        let placement = Placement {
            convention: AxisConvention::Flu,
            anchored_from_odom: Se2::IDENTITY,
            smoothing: None,
        };
        let raw = ape_2d(&truth, &odometry).unwrap();
        assert!(raw.mean_m > 5.0, "the odometry must drift: {}", raw.mean_m);
        for method in Method::ALL {
            let params = method.params(Preset::KissIcp);
            let run =
                correct_trajectory(map.clone(), params, MatchMode::Fast, placement, &odometry);
            let corrected: Vec<_> = run.iter().map(|c| c.pose).collect();
            let fixed = ape_2d(&truth, &corrected).unwrap();
            let c = counts(&run);
            let (attempts, accepted) = (c.attempts, c.accepted);
            assert!(
                fixed.mean_m < raw.mean_m / 3.0,
                "{}: raw {} corrected {} ({accepted}/{attempts} accepted)",
                method.name(),
                raw.mean_m,
                fixed.mean_m
            );
        }
    }

    #[test]
    fn a_heading_drift_keeps_the_steps_and_walks_the_heading() {
        // KITTI-camera poses of a drive around a 200 m square, one pose a metre.
        let camera = AxisConvention::KittiCamera;
        let truth: Vec<Pose3> = (0..800)
            .map(|i| {
                let (side, along) = (i / 200, (i % 200) as f64);
                let corners = [[0.0, 0.0], [200.0, 0.0], [200.0, 200.0], [0.0, 200.0]];
                let yaw = side as f64 * std::f64::consts::FRAC_PI_2;
                let [x, y] = corners[side];
                let planar = Pose3::planar(x + along * yaw.cos(), y + along * yaw.sin(), yaw, 0.3);
                camera.from_planar(&planar)
            })
            .collect();
        let planar_step = |w: &[Pose3]| {
            let [a, b] = [camera.to_planar(&w[0]), camera.to_planar(&w[1])];
            let ([ax, ay], [bx, by]) = (a.planar_position(), b.planar_position());
            (bx - ax).hypot(by - ay)
        };
        let heading_off = |run: &[Pose3], k: usize| {
            let (a, b) = (camera.to_planar(&run[k]), camera.to_planar(&truth[k]));
            lanealign_core::se2::wrap_angle(a.planar_heading() - b.planar_heading())
        };
        // Without drift it is the truth again.
        let same = heading_drifted(&truth, camera, 0.0, 1);
        for (a, b) in same.iter().zip(&truth) {
            let (a, b) = (a.to_row_major(), b.to_row_major());
            assert!(
                a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9),
                "{a:?} {b:?}"
            );
        }
        // With drift, every step keeps its length and the height stays; the heading's error
        // after 800 m has the spread the walk gives it: 1 degree per square root of 100 m is
        // 2.83 degrees after 800 m (RMS over 200 seeds, within 15 %).
        let mut squares = 0.0;
        for seed in 0..200 {
            let run = heading_drifted(&truth, camera, 1.0, seed);
            assert_eq!(run.len(), truth.len());
            for (w, t) in run.windows(2).zip(truth.windows(2)) {
                assert!((planar_step(w) - planar_step(t)).abs() < 1e-9);
            }
            assert!((camera.to_planar(&run[799]).translation[2] - 0.3).abs() < 1e-9);
            squares += heading_off(&run, 799).to_degrees().powi(2);
        }
        let rms = (squares / 200.0).sqrt();
        assert!(
            (rms / 8.0f64.sqrt() - 1.0).abs() < 0.15,
            "RMS {rms} degrees"
        );
        // One seed, one run.
        assert_eq!(
            heading_drifted(&truth, camera, 1.0, 5),
            heading_drifted(&truth, camera, 1.0, 5)
        );
    }
}
