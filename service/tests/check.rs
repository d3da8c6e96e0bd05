//! `lanealignd check`: a good configuration passes; bad ones fail naming what is wrong.
//! (These tests also make `cargo test` build `lanealignd`, which the client's end-to-end tests
//! start as a process.)

use std::path::Path;
use std::process::{Command, Output};

use lanealign_core::geo::{MapPlane, Projection};
use lanealign_core::lane_map::{Lane, LaneMap};

fn check(config: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lanealignd"))
        .arg("check")
        .arg("--config")
        .arg(config)
        .output()
        .expect("run lanealignd")
}

fn write_tile(dir: &Path) {
    let lanes = vec![Lane {
        id: 1,
        points: (0..10).map(|i| [i as f64 * 3.0, 0.0]).collect(),
    }];
    let map = LaneMap::new(&lanes).unwrap();
    lanealign_core::tile::write(
        &dir.join("t.tile"),
        &map,
        &MapPlane::new(Projection::Tangent, 49.0, 8.4),
        3.0,
    )
    .unwrap();
}

const CONFIG: &str = r#"
tile = "t.tile"
[[source]]
name = "wheel"
preset = "orb-slam3"
anchor = { lat = 49.0, lon = 8.4, yaw_deg = 0 }
"#;

#[test]
fn a_good_config_and_tile_pass() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(dir.path());
    let config = dir.path().join("d.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = check(&config);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("ok: 1 sources"));
    // Both methods and smoothing are accepted.
    let paper = CONFIG.replace(
        "preset = \"orb-slam3\"",
        "preset = \"orb-slam3\"\nmethod = \"paper\"\nsmooth = true",
    );
    std::fs::write(&config, paper).unwrap();
    let out = check(&config);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn bad_configs_and_tiles_fail_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(dir.path());
    let config = dir.path().join("d.toml");
    let cases = [
        (
            CONFIG.replace("preset = \"orb-slam3\"\n", ""),
            "missing field `preset`",
        ),
        (
            CONFIG.replace("yaw_deg = 0", "yaw_deg = 0, height = 3"),
            "height",
        ),
        (
            CONFIG.replace("orb-slam3", "orbslam"),
            "source.wheel.preset",
        ),
        (CONFIG.replace("t.tile", "missing.tile"), "missing.tile"),
        (
            CONFIG.replace(
                "preset = \"orb-slam3\"",
                "preset = \"orb-slam3\"\nmethod = \"best\"",
            ),
            "source.wheel.method",
        ),
    ];
    for (text, what) in cases {
        std::fs::write(&config, text).unwrap();
        let out = check(&config);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{what}: must fail");
        assert!(err.contains(what), "{what}: {err}");
    }
    // A damaged tile is refused with the reason.
    std::fs::write(&config, CONFIG).unwrap();
    let tile = dir.path().join("t.tile");
    let mut bytes = std::fs::read(&tile).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(&tile, bytes).unwrap();
    let err = String::from_utf8_lossy(&check(&config).stderr).to_string();
    assert!(err.contains("checksum mismatch"), "{err}");
}
