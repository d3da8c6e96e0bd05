//! Conformance: on the paper pipeline's own lane maps, the paper's algorithm reproduces the
//! reference implementation's counts and errors per sequence (`reference/results.csv`).
//!
//! SPEC section 2 takes "the N nearest lane points, equal distances ordered by point index".
//! The reference maps hold hundreds of duplicate points (lane joints), so a tie often straddles
//! the N-th place, and which tied point makes the cut is not fixed by the spec: lanealign keeps
//! the lowest indices; the reference kept whatever its KD-tree's traversal found first. Runs
//! whose outcome depends on that choice are chaotic in it. So every run must either match the
//! reference exactly, or be shown to be tie-sensitive: re-run with the lanes in reverse order
//! (which changes nothing but the order of tied points), its counts change.

use std::path::Path;
use std::sync::Arc;

use lanealign_core::corrector::MatchMode;
use lanealign_core::lane_csv;
use lanealign_core::lane_map::{Lane, LaneMap};
use lanealign_core::metrics::{ape_2d, Ape2d};
use lanealign_core::params::Preset;
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
    lanes: &[Lane],
    preset: Preset,
    odom: &[Pose3],
    gt: &[Pose3],
) -> ((usize, usize, usize), Ape2d) {
    let cam = AxisConvention::KittiCamera;
    let map = Arc::new(LaneMap::new(lanes).expect("map"));
    let out = correct_trajectory(
        map,
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

#[test]
fn paper_method_reproduces_the_reference_on_reference_lanes() {
    let Some(data) = shared_data() else { return };
    let refs = references(&data);
    assert_eq!(refs.len(), 40);
    let (mut exact, mut tie_sensitive, mut failures) = (0, Vec::new(), Vec::new());
    println!("odometry  preset     seq  attempts accepted resets (reference)      ape_mean (reference)  rmse  lat_rmse  max");
    for r in &refs {
        let lanes = lane_csv::read(&data.join(format!("reference/lanes/lanes_{}.csv", r.seq)))
            .expect("lanes");
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
        let (c, m) = run(&lanes, preset, &odom.poses, &gt.poses);
        let v = &r.values;
        let want = (v[7] as usize, v[8] as usize, v[9] as usize);
        println!(
            "{:9} {:10} {}  {:5} {:5} {:3}  ({:5} {:5} {:3})  {:8.4} ({:8.4}) {:7.4} {:7.4} {:8.4}",
            r.odometry,
            r.preset,
            r.seq,
            c.0,
            c.1,
            c.2,
            want.0,
            want.1,
            want.2,
            m.mean_m,
            v[2],
            m.rmse_m,
            m.lateral_rmse_m,
            m.max_m
        );
        let close = |a: f64, b: f64| (a - b).abs() <= 0.01;
        let matches = c == want
            && close(m.mean_m, v[2])
            && close(m.rmse_m, v[3])
            && close(m.lateral_rmse_m, v[4])
            && close(m.max_m, v[6]);
        let name = format!("{} {} {}", r.odometry, r.preset, r.seq);
        if matches {
            exact += 1;
            continue;
        }
        let mut reversed = lanes.clone();
        reversed.reverse();
        let (c_rev, m_rev) = run(&reversed, preset, &odom.poses, &gt.poses);
        if c_rev != c || m_rev.mean_m != m.mean_m {
            println!(
                "    tie-sensitive: reversed lane order gives {c_rev:?}, APE {:.4}",
                m_rev.mean_m
            );
            tie_sensitive.push(name);
        } else {
            failures.push(name);
        }
    }
    println!("{exact} runs match the reference exactly; tie-sensitive: {tie_sensitive:?}");
    assert!(
        failures.is_empty(),
        "runs that differ from the reference although the tie order does not matter: {failures:?}"
    );
    assert!(exact >= 33, "only {exact} of 40 runs match exactly");
}
