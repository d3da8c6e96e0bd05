//! Conformance: on the paper pipeline's own lane maps, the paper's algorithm reproduces the
//! reference implementation's counts and errors per sequence (`reference/results.csv`).

use std::path::Path;
use std::sync::Arc;

use lanealign_core::lane_csv;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::ape_2d;
use lanealign_core::offline::{correct, counts};
use lanealign_core::params::Preset;
use lanealign_core::pose::AxisConvention;
use lanealign_core::trajectory::{read, Format};
use lanealign_tests::shared_data;

struct Reference {
    odometry: String,
    preset: String,
    seq: String,
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

#[test]
fn paper_method_reproduces_the_reference_on_reference_lanes() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let mut failures = Vec::new();
    let refs = references(&data);
    assert_eq!(refs.len(), 40);
    let mut maps = std::collections::HashMap::new();
    println!("odometry  preset     seq  attempts accepted resets  ape_mean  (ref)    rmse    lat_rmse  max");
    for r in &refs {
        let map = maps
            .entry(r.seq.clone())
            .or_insert_with(|| {
                let lanes =
                    lane_csv::read(&data.join(format!("reference/lanes/lanes_{}.csv", r.seq)))
                        .expect("lanes");
                Arc::new(LaneMap::new(&lanes).expect("map"))
            })
            .clone();
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
        let params = r.preset.parse::<Preset>().unwrap().params();
        let run = correct(map, params, cam, &odom.poses);
        let (attempts, accepted, resets) = counts(&run);
        let planar = |poses: &mut dyn Iterator<Item = &[[f64; 4]; 3]>| -> Vec<[[f64; 4]; 3]> {
            poses.map(|p| cam.to_planar(p)).collect()
        };
        let gt_p = planar(&mut gt.poses.iter());
        let est_p = planar(&mut run.iter().map(|c| &c.pose));
        let m = ape_2d(&gt_p, &est_p).unwrap();
        let v = &r.values;
        // poses, raw, ape_mean, rmse, lateral, heading, max, attempts, accepted, resets
        println!(
            "{:9} {:10} {}  {:8} {:8} {:6}  {:8.4} ({:8.4}) {:8.4} {:8.4} {:8.4}",
            r.odometry,
            r.preset,
            r.seq,
            attempts,
            accepted,
            resets,
            m.mean_m,
            v[2],
            m.rmse_m,
            m.lateral_rmse_m,
            m.max_m
        );
        let counts_ok =
            (attempts, accepted, resets) == (v[7] as usize, v[8] as usize, v[9] as usize);
        let close = |a: f64, b: f64| (a - b).abs() <= 0.01;
        let metrics_ok = close(m.mean_m, v[2])
            && close(m.rmse_m, v[3])
            && close(m.lateral_rmse_m, v[4])
            && close(m.max_m, v[6]);
        if !(counts_ok && metrics_ok) {
            failures.push(format!("{} {} {}", r.odometry, r.preset, r.seq));
        }
    }
    assert!(
        failures.is_empty(),
        "runs that differ from the reference: {failures:?}"
    );
}
