#![no_main]
//! The `journal` harness of `lanealign_fuzzing::targets` under libFuzzer.

use lanealign_fuzzing::targets::Target;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = Target::Journal.run(data);
});
