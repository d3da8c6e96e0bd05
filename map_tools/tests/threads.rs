//! `compile` leaves no thread behind: its reading spinner's thread ends with the reading. Alone
//! in its own test binary, so that no other test's threads come and go while it counts.

use std::path::PathBuf;

use lanealign_map::compile::{compile, CompileOptions};

const ONE_ROAD: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="test">
 <node id="1" lat="49.0000000" lon="8.4000000"/>
 <node id="2" lat="49.0010000" lon="8.4005000"/>
 <way id="10">
  <nd ref="1"/><nd ref="2"/>
  <tag k="highway" v="residential"/>
 </way>
</osm>
"#;

/// The threads of this process, as Linux lists them.
fn threads() -> usize {
    std::fs::read_dir("/proc/self/task")
        .expect("Linux lists a process's threads in /proc/self/task")
        .count()
}

#[test]
fn compiling_leaves_no_thread_behind() {
    let osm = std::env::temp_dir().join(format!("lanealign-threads-{}.osm", std::process::id()));
    std::fs::write(&osm, ONE_ROAD).unwrap();
    let inputs: Vec<PathBuf> = vec![osm.clone()];
    let before = threads();
    for _ in 0..20 {
        let compiled = compile(&inputs, &CompileOptions::default()).unwrap();
        assert!(compiled.map.lane_count() > 0);
    }
    let after = threads();
    std::fs::remove_file(&osm).unwrap();
    assert_eq!(after, before, "threads before and after 20 compiles");
}
