#![no_main]
//! The `pbf` harness of `lanealign_fuzzing::targets` under libFuzzer.

use lanealign_fuzzing::targets::Target;
use libfuzzer_sys::fuzz_target;

fuzz_target!(
    init: lanealign_fuzzing::let_osmpbf_panics_unwind(),
    |data: &[u8]| {
        let mut input = data.to_vec();
        Target::Pbf.prepare(&mut input, data.len() as u64);
        let _ = Target::Pbf.run(&input);
    }
);
