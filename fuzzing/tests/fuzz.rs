//! Every harness on 10^5 mutants of its seeds (`pbf_grid`, which writes files, on 10^4, and
//! `journal`, which writes a session's journal and restores it, on 2.5 x 10^3;
//! `LANEALIGN_FUZZ_CASES` changes the count), from a
//! fixed seed per target: reproducible, on stable Rust. A panic fails the test naming the case
//! and writes the input to `target/fuzz-failures/` to reproduce it; a case slower than a second
//! fails as a hang.

use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use lanealign_fuzzing::mutate::mutate;
use lanealign_fuzzing::targets::Target;
use rand::rngs::SmallRng;
use rand::{Rng, RngExt, SeedableRng};

fn cases() -> usize {
    std::env::var("LANEALIGN_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000)
}

/// The panic's message.
fn message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_default()
}

/// The harnesses run in the build that ships (CI tests in release), and an integer overflow they
/// reach must fail them instead of wrapping round: the workspace's release profile checks
/// overflow, as the dev profile does (Cargo.toml).
#[test]
fn integer_overflow_panics_in_this_build() {
    let largest = std::hint::black_box(u64::MAX);
    let sum = std::panic::catch_unwind(|| largest + 1);
    assert!(
        sum.is_err(),
        "u64::MAX + 1 gave {sum:?}: this build wraps round on overflow (set overflow-checks)"
    );
}

fn fuzz(target: Target) {
    // Panics are this test's findings, reported below (on standard error, which the harness
    // shows for a failed test) with their input: the default hook would also print every panic
    // a reader catches and turns into an error (osmpbf's, in rayon's threads).
    std::panic::set_hook(Box::new(|_| {}));
    let seeds = target.seeds();
    for seed in &seeds {
        assert!(
            target.run(seed).is_ok(),
            "{}: a seed must be accepted",
            target.name()
        );
    }
    let mut rng = SmallRng::seed_from_u64(0x1a2e_a119 ^ target as u64);
    let (mut accepted, mut slowest) = (0usize, Duration::ZERO);
    let started = Instant::now();
    // Each pbf_grid case writes two grids to disk (about 3 ms): a tenth of the cases. Each
    // journal case journals a session and restores it (a few ms for the seed past a segment):
    // a fortieth.
    let n = match target {
        Target::PbfGrid => cases() / 10,
        Target::Journal => cases() / 40,
        _ => cases(),
    };
    for case in 0..n {
        let seed = &seeds[rng.random_range(0..seeds.len())];
        let other = &seeds[rng.random_range(0..seeds.len())];
        let mut input = mutate(&mut rng, seed, target.dictionary(), other);
        target.prepare(&mut input, rng.next_u64());
        let t = Instant::now();
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| target.run(&input)));
        let took = t.elapsed();
        slowest = slowest.max(took);
        let failure = match outcome {
            Ok(result) => {
                accepted += usize::from(result.is_ok());
                (took > Duration::from_secs(1)).then(|| format!("took {took:?}"))
            }
            Err(payload) => Some(format!("panicked: {}", message(payload.as_ref()))),
        };
        if let Some(what) = failure {
            let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/fuzz-failures");
            let file = dir.join(format!("{}-{case}.bin", target.name()));
            let _ = std::fs::create_dir_all(&dir);
            let _ = std::fs::write(&file, &input);
            eprintln!(
                "{} case {case} {what}; input in {}",
                target.name(),
                file.display()
            );
            panic!("{} case {case} failed", target.name());
        }
    }
    eprintln!(
        "{}: {n} cases in {:.1} s, {accepted} accepted, slowest {slowest:?}",
        target.name(),
        started.elapsed().as_secs_f64()
    );
    // The wire and journal harnesses answer every stream with a pose (their findings are broken
    // invariants); every reader must both accept and refuse some mutants, or the mutants do not
    // reach its logic.
    let answers_all = matches!(target, Target::Wire | Target::Journal);
    let reaches_both = accepted > 0 && accepted < n;
    if !(answers_all || reaches_both) {
        eprintln!("{}: {accepted} of {n} mutants accepted", target.name());
        panic!("{}: mutants must reach both answers", target.name());
    }
}

#[test]
fn tile() {
    fuzz(Target::Tile);
}

#[test]
fn grid_cell() {
    fuzz(Target::GridCell);
}

#[test]
fn grid_manifest() {
    fuzz(Target::GridManifest);
}

#[test]
fn osm_xml() {
    fuzz(Target::OsmXml);
}

#[test]
fn pbf() {
    fuzz(Target::Pbf);
}

#[test]
fn pbf_grid() {
    fuzz(Target::PbfGrid);
}

#[test]
fn lanelet2() {
    fuzz(Target::Lanelet2);
}

#[test]
fn kitti() {
    fuzz(Target::Kitti);
}

#[test]
fn tum() {
    fuzz(Target::Tum);
}

#[test]
fn lane_csv() {
    fuzz(Target::LaneCsv);
}

#[test]
fn daemon_toml() {
    fuzz(Target::DaemonToml);
}

#[test]
fn wire() {
    fuzz(Target::Wire);
}

#[test]
fn snapshot() {
    fuzz(Target::Snapshot);
}

#[test]
fn journal() {
    fuzz(Target::Journal);
}

#[test]
fn pose_array() {
    fuzz(Target::PoseArray);
}
