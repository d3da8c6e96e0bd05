//! Grids of tiles on real data: every shared KITTI run corrected against a grid of 200 m cells,
//! loading the cells around it as it drives, equals the run against one tile, bit for bit; and no
//! neighbour query reached beyond the loaded cells.

use std::sync::Arc;

use lanealign_cli::kitti::anchors;
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::Projection;
use lanealign_core::grid::{self, correct_trajectory_on_grid, Grid, GridSpec, LoadPolicy};
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::source_corrector::{correct_trajectory, Placement};
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_map::osm_lanes::LaneOptions;
use lanealign_tests::{shared_data, SEQUENCES};

#[test]
fn every_shared_run_on_a_grid_equals_the_whole_map_bit_for_bit() {
    let Some(data) = shared_data() else { return };
    let anchors = anchors(&data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (mut runs, mut most_cells, mut cells_in_grids) = (0, 0, 0);
    for seq in SEQUENCES {
        let anchor = anchors[seq];
        for method in [Method::Robust, Method::Paper] {
            let options = CompileOptions {
                origin: Some((anchor.lat(), anchor.lon())),
                projection: Projection::Kitti,
                lanes: LaneOptions {
                    unmarked_offset_scale: method.unmarked_offset_scale(),
                    ..LaneOptions::default()
                },
            };
            let osm = data.join(format!("osm/kitti_{seq}.osm"));
            let compiled = compile(std::slice::from_ref(&osm), &options).unwrap();
            let folder = dir.path().join(format!("{seq}_{}", method.name()));
            let spec = GridSpec {
                plane: &compiled.plane,
                spacing_m: 3.0,
                geometry: &compiled.geometry,
                cell_size_m: 200.0,
                margin_m: 50.0,
                sign: None,
                map_version: 0,
            };
            grid::write(&folder, &compiled.map, &spec, 2).unwrap();
            let grid = Arc::new(Grid::open(&folder).unwrap());
            cells_in_grids += grid.cells().count();
            let whole = Arc::new(compiled.map);
            let anchored_from_odom = anchor.anchored_from_odom(&compiled.plane);
            for (run, preset) in [("lidar", Preset::KissIcp), ("stereo_vo", Preset::OrbSlam3)] {
                let odom = read(
                    &data.join(format!("odometry/{run}/{seq}.txt")),
                    Format::Kitti,
                )
                .unwrap();
                let placement = Placement {
                    convention: AxisConvention::KittiCamera,
                    anchored_from_odom,
                    smoothing: None,
                };
                let params = method.params(preset);
                let expected = correct_trajectory(
                    whole.clone(),
                    params,
                    MatchMode::Fast,
                    placement,
                    &odom.poses,
                );
                let (got, loads) = correct_trajectory_on_grid(
                    grid.clone(),
                    LoadPolicy::default(),
                    params,
                    MatchMode::Fast,
                    placement,
                    &odom.poses,
                    None,
                )
                .unwrap();
                let what = format!("{run} {seq} {}", method.name());
                assert_eq!(loads.uncovered_queries, 0, "{what}: {loads:?}");
                assert!(
                    loads.maps > 1,
                    "{what}: the cells around it changed as it drove"
                );
                assert!(got == expected, "{what}: differs from the whole map");
                most_cells = most_cells.max(loads.most_cells);
                runs += 1;
            }
        }
    }
    assert_eq!(runs, 40);
    eprintln!("40 runs equal; at most {most_cells} cells loaded at once, {cells_in_grids} cells in the 20 grids");
}
