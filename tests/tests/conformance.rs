//! Conformance: on the paper pipeline's own lane maps, the paper's method reproduces the
//! reference implementation's counts and errors per sequence (`reference/results.csv`).
//!
//! A run is *undetermined* when at some matching step the algorithm (docs/algorithm.md) does not
//! fix a match, in one of two ways (docs/conformance.md):
//!
//! - a tie: "the N nearest lane points, equal distances ordered by point index" does not say
//!   which points are kept when more share the N-th distance than fit; lanealign keeps the
//!   lowest indices, the reference whichever its KD-tree met first. Undetermined when two
//!   admissible choices of the tied points give different matches.
//! - rounding: two window poses that coincide in exact arithmetic (a car standing still, with a
//!   correction accepted in between) differ by rounding noise, 1e-15 m; the algorithm gives
//!   coinciding poses no direction, but the noise has one, and it decides whether they match.
//!
//! Every determined run must match the reference: counts equal, mean, RMSE, lateral RMSE and
//! largest error within 0.01 m. An undetermined run may differ, by at most 0.06 m in its mean
//! error (the figure the reference reports). Both kinds of step are found here, by checking
//! every matching step's window exactly.

use std::path::Path;
use std::sync::Arc;

use lanealign_core::corrector::{Corrector, MatchMode};
use lanealign_core::lane_csv;
use lanealign_core::lane_map::{Candidate, Lane, LaneMap};
use lanealign_core::matching::{trajectory_direction, try_candidate};
use lanealign_core::metrics::{ape_2d, Ape2d};
use lanealign_core::params::{Params, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{correct_trajectory, counts, Placement};
use lanealign_core::trajectory::{read, Format};
use lanealign_tests::shared_data;

struct Reference {
    odometry: String,
    preset: String,
    seq: String,
    /// poses, raw, ape_mean, rmse, lateral, heading, max, attempts, accepted, resets
    values: Vec<f64>,
}

fn references(data: &Path) -> Vec<Reference> {
    let text = std::fs::read_to_string(data.join("reference/results.csv")).expect("results.csv");
    text.lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            Reference {
                odometry: f[0].to_string(),
                preset: f[1].to_string(),
                seq: f[2].to_string(),
                values: f[3..].iter().map(|v| v.parse().expect("number")).collect(),
            }
        })
        .collect()
}

fn run(
    map: &Arc<LaneMap>,
    preset: Preset,
    odom: &[Pose3],
    gt: &[Pose3],
) -> ((usize, usize, usize), Ape2d) {
    let cam = AxisConvention::KittiCamera;
    let out = correct_trajectory(
        map.clone(),
        preset.params(),
        MatchMode::Fast,
        Placement {
            convention: cam,
            anchored_from_odom: Se2::IDENTITY,
            smoothing: None,
        },
        odom,
    );
    let est: Vec<Pose3> = out.iter().map(|c| cam.to_planar(&c.pose)).collect();
    let gt: Vec<Pose3> = gt.iter().map(|p| cam.to_planar(p)).collect();
    let c = counts(&out);
    (
        (c.attempts, c.accepted, c.resets),
        ape_2d(&gt, &est).expect("paired"),
    )
}

/// True when the match of the pose at `x` moving along `dir` depends on which of the points at
/// its `n`-th nearest distance are kept: more points share that distance than fit, and two
/// admissible choices of them give different matches.
fn tie_decides(map: &LaneMap, x: [f64; 2], dir: [f64; 2], params: &Params) -> bool {
    let n = params.neighbours;
    let tau = params.min_direction_cos;
    let mut nearest: Vec<Candidate> = Vec::new();
    map.nearest(x, n, &mut nearest);
    if nearest.len() < n {
        return false;
    }
    let cut = nearest[n - 1].0;
    let closer: Vec<u32> = nearest.iter().filter(|c| c.0 < cut).map(|c| c.1).collect();
    if closer
        .iter()
        .any(|&j| try_candidate(map, j, x, dir, tau).is_some())
    {
        return false; // decided before the tie
    }
    let room = n - closer.len();
    let mut wide = Vec::new();
    map.nearest(x, n + 256, &mut wide);
    let tied: Vec<Option<[f64; 2]>> = wide
        .iter()
        .filter(|c| c.0 == cut)
        .map(|c| try_candidate(map, c.1, x, dir, tau))
        .collect();
    if tied.len() <= room {
        return false;
    }
    // The answer for a choice of `room` tied points is the first passing one in index order,
    // or none. Tied point `t` can be the answer when enough points can fill the choice without
    // preceding it as a passing candidate: failing points before it, any points after it.
    let mut answers: Vec<Option<[f64; 2]>> = Vec::new();
    let mut failing_before = 0;
    for (t, answer) in tied.iter().enumerate() {
        match answer {
            Some(q) if failing_before + (tied.len() - t - 1) >= room - 1 => {
                answers.push(Some(*q));
            }
            Some(_) => {}
            None => failing_before += 1,
        }
    }
    if tied.iter().filter(|a| a.is_none()).count() >= room {
        answers.push(None);
    }
    answers.dedup();
    answers.len() > 1
}

/// Why a matching step is undetermined.
#[derive(Debug)]
enum Undetermined {
    /// A tie at the N-th distance decides a match.
    Tie,
    /// Two poses that coincide up to rounding noise (closer than 1e-9 m, not equal) give one
    /// of them a direction.
    Rounding,
}

/// The first matching step that is undetermined, and why (the paper's method: the window
/// during matching is the previous window plus the new pose, cut to `max_window`).
fn first_undetermined_step(
    map: &Arc<LaneMap>,
    preset: Preset,
    odom: &[Pose3],
) -> Option<(usize, Undetermined)> {
    let params = preset.params();
    let mut corrector = Corrector::new(map.clone(), params);
    let cam = AxisConvention::KittiCamera;
    for (k, pose) in odom.iter().enumerate() {
        let p = cam.to_planar(pose).planar_position();
        let mut window = corrector.window().to_vec();
        window.push(corrector.map_from_anchored().apply(p));
        let excess = window.len().saturating_sub(params.max_window);
        window.drain(..excess);
        if !corrector.push(p).status.attempted() {
            continue;
        }
        for i in 0..window.len() {
            let next = if i + 1 < window.len() {
                i + 1
            } else {
                i.saturating_sub(1)
            };
            let (a, b) = (window[i], window[next]);
            let step = (b[0] - a[0]).hypot(b[1] - a[1]);
            if step > 0.0 && step < 1e-9 {
                return Some((k, Undetermined::Rounding));
            }
            let dir = trajectory_direction(&window, i);
            if dir != [0.0, 0.0] && tie_decides(map, window[i], dir, &params) {
                return Some((k, Undetermined::Tie));
            }
        }
    }
    None
}

#[test]
fn paper_method_reproduces_the_reference_on_reference_lanes() {
    let Some(data) = shared_data() else { return };
    let refs = references(&data);
    assert_eq!(refs.len(), 40);
    let (mut exact, mut undetermined, mut failures) = (0, Vec::new(), Vec::new());
    let mut largest = 0.0f64;
    println!("odometry  preset     seq  attempts accepted resets (reference)      ape_mean (reference)  rmse  lat_rmse  max (reference)");
    for r in &refs {
        let lanes: Vec<Lane> =
            lane_csv::read(&data.join(format!("reference/lanes/lanes_{}.csv", r.seq)))
                .expect("lanes");
        let map = Arc::new(LaneMap::new(&lanes).expect("map"));
        let gt = read(
            &data.join(format!("kitti/poses/{}.txt", r.seq)),
            Format::Kitti,
        )
        .unwrap();
        let odom = read(
            &data.join(format!("odometry/{}/{}.txt", r.odometry, r.seq)),
            Format::Kitti,
        )
        .unwrap();
        let preset: Preset = r.preset.parse().unwrap();
        let (c, m) = run(&map, preset, &odom.poses, &gt.poses);
        let v = &r.values;
        let want = (v[7] as usize, v[8] as usize, v[9] as usize);
        println!(
            "{:9} {:10} {}  {:5} {:5} {:3}  ({:5} {:5} {:3})  {:8.4} ({:8.4}) {:7.4} {:7.4} {:8.4} ({:8.4})",
            r.odometry, r.preset, r.seq, c.0, c.1, c.2, want.0, want.1, want.2, m.mean_m, v[2],
            m.rmse_m, m.lateral_rmse_m, m.max_m, v[6]
        );
        let error = [
            (m.mean_m - v[2]).abs(),
            (m.rmse_m - v[3]).abs(),
            (m.lateral_rmse_m - v[4]).abs(),
            (m.max_m - v[6]).abs(),
        ]
        .into_iter()
        .fold(0.0, f64::max);
        let name = format!("{} {} {}", r.odometry, r.preset, r.seq);
        if c == want && error <= 0.01 {
            exact += 1;
            continue;
        }
        let mean_error = (m.mean_m - v[2]).abs();
        match first_undetermined_step(&map, preset, &odom.poses) {
            Some((step, why)) if mean_error <= 0.06 => {
                println!("    undetermined from step {step} ({why:?}); mean error differs by {mean_error:.4} m, the largest error by {:.4} m", (m.max_m - v[6]).abs());
                largest = largest.max(mean_error);
                undetermined.push(name);
            }
            step => failures.push(format!(
                "{name} (mean error differs by {mean_error:.4} m; undetermined from {step:?})"
            )),
        }
    }
    println!(
        "{exact} of 40 runs match the reference; {} undetermined runs differ by at most {largest:.4} m in mean error: {undetermined:?}",
        undetermined.len()
    );
    assert!(
        failures.is_empty(),
        "runs that differ although the algorithm determines them, or by more than 0.06 m: {failures:?}"
    );
}
