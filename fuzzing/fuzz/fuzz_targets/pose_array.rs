#![no_main]
//! The `pose_array` harness of `lanealign_fuzzing::targets` under libFuzzer.

use lanealign_fuzzing::targets::Target;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut input = data.to_vec();
    Target::PoseArray.prepare(&mut input, data.len() as u64);
    let _ = Target::PoseArray.run(&input);
});
