#![no_main]
//! The `grid_manifest` harness of `lanealign_fuzzing::targets` under libFuzzer.

use lanealign_fuzzing::targets::Target;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut input = data.to_vec();
    Target::GridManifest.prepare(&mut input, data.len() as u64);
    let _ = Target::GridManifest.run(&input);
});
