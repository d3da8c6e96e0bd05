//! The harnesses that correct reach the corrector's alignments on their seeds: a harness whose
//! seeds only warm the corrector up never hands a mutant to the matching, the ICP, the
//! covariance or a correction applied (the presets' window of 150 poses never filled on the
//! seed lanes until the harnesses took a window of their own).

use std::sync::Arc;

use lanealign_core::corrector::{MatchMode, Status};
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{Placement, SourceCorrector};
use lanealign_fuzzing::seeds;
use lanealign_fuzzing::targets::{
    drive_twins, harness_params, serve, snapshot_setup, wire_setup, Target,
};
use lanealign_wire::payload::StatusCode;

fn accepted(statuses: &[StatusCode]) -> usize {
    statuses
        .iter()
        .filter(|s| **s == StatusCode::Accepted)
        .count()
}

#[test]
fn the_wire_seed_is_aligned_in_both_sessions() {
    let answered = serve(&seeds::wire_stream(), &wire_setup());
    // Session 1: 40 poses, then one after its goodbye; session 2 starts afresh at the 13th.
    assert_eq!(accepted(&answered[&1]), 21, "{:?}", answered[&1]);
    assert_eq!(accepted(&answered[&2]), 9, "{:?}", answered[&2]);
}

#[test]
fn the_journal_seed_is_aligned_while_it_is_on_the_lanes() {
    let setup = snapshot_setup();
    assert!(setup.params.scale_sigma > 0.0 && setup.params.watch_stalls);
    let answered = serve(&seeds::long_stream(), &setup);
    let n = accepted(&answered[&1]);
    assert!((20..=100).contains(&n), "{n} accepted of 600");
}

#[test]
fn the_drive_is_aligned_with_either_method_and_preset() {
    let map = Arc::new(seeds::lane_map());
    let placement = Placement {
        convention: AxisConvention::Flu,
        anchored_from_odom: Se2::IDENTITY,
        smoothing: None,
    };
    for preset in [Preset::KissIcp, Preset::OrbSlam3] {
        for method in [Method::Robust, Method::Paper] {
            let mut corrector = SourceCorrector::new(
                map.clone(),
                harness_params(preset, method),
                MatchMode::Fast,
                placement,
            );
            let n = seeds::drive(40)
                .iter()
                .filter(|pose| matches!(corrector.correct(pose).0.status, Status::Accepted { .. }))
                .count();
            assert_eq!(n, 21, "{preset:?} {method:?}");
        }
    }
}

#[test]
fn the_map_readers_seeds_are_aligned_along_their_first_lane() {
    for target in [
        Target::Tile,
        Target::OsmXml,
        Target::Lanelet2,
        Target::Pbf,
        Target::LaneCsv,
    ] {
        for (k, seed) in target.seeds().iter().enumerate() {
            let map = target.read_map(seed).expect("a seed is read");
            // 30 poses: the window fills at the 20th, and every pose from there is aligned.
            let n = drive_twins(&Arc::new(map));
            assert_eq!(n, 11, "{} seed {k}", target.name());
        }
    }
}
