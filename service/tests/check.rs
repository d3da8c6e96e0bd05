//! `lanealignd check`: a good configuration passes; bad ones fail naming what is wrong, with
//! exactly the rules the daemon applies. (These tests also make `cargo test` build `lanealignd`,
//! which the end-to-end tests start as a process.)

use std::path::Path;
use std::process::{Command, Output};

use lanealign_core::geo::{MapPlane, Projection};
use lanealign_core::lane_geometry::LaneGeometry;
use lanealign_core::lane_map::{Lane, LaneMap};

/// `lanealignd check --config CONFIG`, with the state folder (read, never written, by `check`)
/// beside the configuration unless it names one: never the user's own.
fn check(config: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lanealignd"))
        .env("LANEALIGN_STATE_DIR", config.parent().unwrap())
        .arg("check")
        .arg("--config")
        .arg(config)
        .output()
        .expect("run lanealignd")
}

/// A one-lane tile derived with unmarked-street offset scale `scale`.
fn write_tile(path: &Path, scale: f64) {
    let lanes = vec![Lane::new(
        1,
        (0..10).map(|i| [i as f64 * 3.0, 0.0]).collect(),
    )];
    let map = LaneMap::new(&lanes).unwrap();
    let geometry = LaneGeometry {
        unmarked_offset_scale: Some(scale),
        ..LaneGeometry::default()
    };
    let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
    lanealign_core::tile::write(path, &map, &plane, 3.0, &geometry).unwrap();
}

/// `map` (in the plane of [`write_tile`]'s tile) as a grid of 50 m cells in folder `dir`,
/// signed with `sign`, built as `map_version`.
fn write_grid(
    dir: &Path,
    map: &LaneMap,
    sign: Option<&lanealign_core::tile::SigningKey>,
    map_version: u64,
) {
    let spec = lanealign_core::grid::GridSpec {
        plane: &MapPlane::new(Projection::Tangent, 49.0, 8.4),
        spacing_m: 3.0,
        geometry: &LaneGeometry::default(),
        cell_size_m: 50.0,
        margin_m: 10.0,
        sign,
        map_version,
    };
    lanealign_core::grid::write(dir, map, &spec, 1).unwrap();
}

const CONFIG: &str = r#"
tile = "t.tile"
[[source]]
name = "wheel"
anchor = { lat = 49.0, lon = 8.4, yaw_deg = 0 }
corrector = { preset = "orb-slam3" }
"#;

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).to_string()
}

#[test]
fn a_good_config_and_tile_pass() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(&dir.path().join("t.tile"), 0.5);
    write_tile(&dir.path().join("paper.tile"), 1.0);
    let config = dir.path().join("d.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = check(&config);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("ok: 1 sources"));
    assert!(!stderr(&out).contains("WARN"), "{}", stderr(&out));
    // The paper's method, smoothed, on a tile of the paper's lane geometry.
    let paper = CONFIG.replace("t.tile", "paper.tile").replace(
        "preset = \"orb-slam3\"",
        "preset = \"orb-slam3\", method = \"paper\", smooth = true",
    );
    std::fs::write(&config, paper).unwrap();
    let out = check(&config);
    assert!(out.status.success(), "{}", stderr(&out));
}

/// A configuration named by its bare file name (`--config d.toml`, run in its folder) whose
/// relative `state_dir` does not exist yet passes, as it does named `./d.toml` or by its whole
/// path: until 2026-12-07 the state folder's nearest existing ancestor was looked for up to
/// `""`, which does not exist as a path, and `check` and the start refused with `st/default: not
/// a directory`.
#[test]
fn a_relative_state_dir_beside_a_bare_config_name_passes() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(&dir.path().join("t.tile"), 0.5);
    std::fs::write(
        dir.path().join("d.toml"),
        format!("state_dir = \"state\"\n{CONFIG}"),
    )
    .unwrap();
    for name in ["d.toml", "./d.toml"] {
        let out = Command::new(env!("CARGO_BIN_EXE_lanealignd"))
            .args(["check", "--config", name])
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(out.status.success(), "{name}: {}", stderr(&out));
    }
    assert!(!dir.path().join("state").exists(), "check makes nothing");
}

#[test]
fn bad_configs_and_tiles_fail_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(&dir.path().join("t.tile"), 0.5);
    let config = dir.path().join("d.toml");
    let cases = [
        (
            CONFIG.replace("corrector = { preset = \"orb-slam3\" }\n", ""),
            "missing field `corrector`",
        ),
        (
            CONFIG.replace("yaw_deg = 0", "yaw_deg = 0, height = 3"),
            "height",
        ),
        (CONFIG.replace("orb-slam3", "orbslam"), "orb-slam3"),
        (
            CONFIG.replace("t.tile", "missing.tile"),
            "lanealign-map compile INPUT.osm",
        ),
        (
            CONFIG.replace(
                "preset = \"orb-slam3\"",
                "preset = \"orb-slam3\", method = \"best\"",
            ),
            "unknown variant `best`",
        ),
        // The paper's method on a tile of lanealign's geometry: refused, with the fix.
        (
            CONFIG.replace(
                "preset = \"orb-slam3\"",
                "preset = \"orb-slam3\", method = \"paper\"",
            ),
            "--unmarked-offset-scale 1",
        ),
        (
            CONFIG.replace(
                "name = \"wheel\"",
                &format!("name = \"{}\"", "w".repeat(300)),
            ),
            "longer than 64",
        ),
        (
            format!("metrics_interval_s = 1e300\n{CONFIG}"),
            "metrics_interval_s",
        ),
        // A state folder the daemon could not make: `check` said ok, and the start failed.
        (
            format!("state_dir = \"t.tile/state\"\n{CONFIG}"),
            "state_dir holds the sessions' journals",
        ),
    ];
    for (text, what) in cases {
        std::fs::write(&config, text).unwrap();
        let out = check(&config);
        assert!(!out.status.success(), "{what}: must fail");
        assert!(stderr(&out).contains(what), "{what}: {}", stderr(&out));
    }
    // A damaged tile is refused with the reason.
    std::fs::write(&config, CONFIG).unwrap();
    let tile = dir.path().join("t.tile");
    let mut bytes = std::fs::read(&tile).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(&tile, bytes).unwrap();
    let err = stderr(&check(&config));
    assert!(err.contains("checksum mismatch"), "{err}");
    // The configuration file itself: a folder, too long, not text, absent. Until 2026-12-07 the
    // first two said `(file): not a regular file of at most 1048576 bytes` alike.
    let long = dir.path().join("long.toml");
    std::fs::write(&long, " ".repeat(1 << 21)).unwrap();
    let binary = dir.path().join("binary.toml");
    std::fs::write(&binary, b"\xff\xfe").unwrap();
    for (path, what) in [
        (dir.path().to_path_buf(), "not a regular file (a folder"),
        (long, "2097152 bytes, more than the 1048576 bytes"),
        (binary, "invalid utf-8"),
        (dir.path().join("absent.toml"), "No such file"),
    ] {
        let err = stderr(&check(&path));
        let said = format!("error: {}: {what}", path.display());
        assert!(err.contains(&said), "{said}: {err}");
    }
}

#[test]
fn trusted_keys_admit_only_tiles_their_holders_signed() {
    use lanealign_core::tile::{key_hex, sign, SigningKey};
    let dir = tempfile::tempdir().unwrap();
    let unsigned = dir.path().join("t.tile");
    write_tile(&unsigned, 0.5);
    let builder = SigningKey::from_bytes(&[3; 32]);
    let stranger = SigningKey::from_bytes(&[4; 32]);
    for (name, key) in [("ours.tile", &builder), ("theirs.tile", &stranger)] {
        let mut bytes = std::fs::read(&unsigned).unwrap();
        sign(&mut bytes, key);
        std::fs::write(dir.path().join(name), bytes).unwrap();
    }
    let trusted = key_hex(&builder.verifying_key().to_bytes());
    let config = dir.path().join("d.toml");
    let with_keys = |tile: &str, keys: &str| {
        std::fs::write(
            &config,
            format!(
                "trusted_tile_keys = [{keys}]\n{}",
                CONFIG.replace("t.tile", tile)
            ),
        )
        .unwrap();
        check(&config)
    };
    let out = with_keys("ours.tile", &format!("\"{trusted}\""));
    assert!(out.status.success(), "{}", stderr(&out));
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        said.contains(&format!("; signed by {trusted}; map version 0)")),
        "{said}"
    );
    // Without trusted keys, any valid tile loads, signed or not.
    assert!(with_keys("theirs.tile", "").status.success());
    assert!(with_keys("t.tile", "").status.success());
    for (tile, why) in [
        ("t.tile", "is not signed"),
        ("theirs.tile", "which is not trusted"),
    ] {
        let out = with_keys(tile, &format!("\"{trusted}\""));
        assert!(!out.status.success(), "{tile} must be refused");
        assert!(stderr(&out).contains(why), "{}", stderr(&out));
    }
    let out = with_keys("ours.tile", "\"abc\"");
    assert!(
        stderr(&out).contains("not a public key"),
        "{}",
        stderr(&out)
    );
}

/// With trusted keys, a grid's manifest must carry a trusted signature as well as its cells:
/// which cells make the grid is the manifest's word. Signed cells under an unsigned manifest
/// (a grid compiled before manifests were signed, or one whose manifest was edited and its
/// signature lines removed) are refused, and so are a stranger's cells under a manifest a
/// trusted key signed.
#[test]
fn trusted_keys_admit_only_grids_whose_manifest_their_holders_signed() {
    use lanealign_core::grid;
    use lanealign_core::tile::{key_hex, SigningKey};
    let dir = tempfile::tempdir().unwrap();
    let lanes: Vec<Lane> = (0..3)
        .map(|k| {
            Lane::new(
                k,
                (0..40).map(|i| [i as f64 * 3.0, k as f64 * 40.0]).collect(),
            )
        })
        .collect();
    let map = LaneMap::new(&lanes).unwrap();
    let (builder, stranger) = (
        SigningKey::from_bytes(&[3; 32]),
        SigningKey::from_bytes(&[4; 32]),
    );
    for (name, key) in [
        ("ours", Some(&builder)),
        ("theirs", Some(&stranger)),
        ("none", None),
    ] {
        write_grid(&dir.path().join(name), &map, key, 0);
    }
    // Our cells under our manifest without its signature lines ("bare"), and the stranger's
    // cells under their manifest signed again by us ("mixed").
    let copy_of = |from: &str, to: &str, sign: Option<&SigningKey>| {
        let (from, to) = (dir.path().join(from), dir.path().join(to));
        std::fs::create_dir_all(to.join("cells")).unwrap();
        for entry in std::fs::read_dir(from.join("cells")).unwrap() {
            let entry = entry.unwrap();
            std::fs::copy(entry.path(), to.join("cells").join(entry.file_name())).unwrap();
        }
        let signed = std::fs::read_to_string(from.join("manifest.toml")).unwrap();
        let body = &signed[signed.find("format = ").unwrap()..];
        let text = sign.map_or(body.to_string(), |key| grid::signature::sign(body, key));
        std::fs::write(to.join("manifest.toml"), text).unwrap();
        to
    };
    let bare = copy_of("ours", "bare", None);
    copy_of("theirs", "mixed", Some(&builder));
    let trusted = key_hex(&builder.verifying_key().to_bytes());
    let config = dir.path().join("d.toml");
    let with_keys = |grid: &str, keys: &str| {
        let text = CONFIG.replace("t.tile", grid);
        std::fs::write(&config, format!("trusted_tile_keys = [{keys}]\n{text}")).unwrap();
        check(&config)
    };
    let keys = format!("\"{trusted}\"");
    let out = with_keys("ours", &keys);
    assert!(out.status.success(), "{}", stderr(&out));
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        said.contains(&format!("; signed by {trusted}; map version 0)")),
        "{said}"
    );
    let said = String::from_utf8_lossy(&with_keys("none", "").stdout).to_string();
    assert!(said.contains("; unsigned; map version 0)"), "{said}");
    for grid in ["theirs", "none", "bare", "mixed"] {
        assert!(with_keys(grid, "").status.success(), "{grid}, no keys");
    }
    for (grid, why) in [
        ("theirs", "which is not trusted"),
        ("none", "is not signed"),
        (
            "bare",
            "manifest {bare} is not signed: compile it with `lanealign-map compile --grid",
        ),
        ("mixed", "not signed by a key in trusted_tile_keys"),
    ] {
        let out = with_keys(grid, &keys);
        assert!(!out.status.success(), "{grid} must be refused");
        let why = why.replace("{bare}", &bare.display().to_string());
        assert!(stderr(&out).contains(&why), "{grid}: {}", stderr(&out));
    }
}

/// `min_map_version` refuses a tile or a grid older than it (an older map put in the
/// configured place: a signature says who built a map, the version which build), and `check`
/// says which version it found.
#[test]
fn min_map_version_refuses_older_maps() {
    use lanealign_core::tile;
    let dir = tempfile::tempdir().unwrap();
    let lanes = vec![Lane::new(
        1,
        (0..10).map(|i| [i as f64 * 3.0, 0.0]).collect(),
    )];
    let map = LaneMap::new(&lanes).unwrap();
    let plane = MapPlane::new(Projection::Tangent, 49.0, 8.4);
    for version in [4, 5, 6] {
        let mut bytes = tile::encode(&map, &plane, 3.0, &LaneGeometry::default());
        tile::set_map_version(&mut bytes, version).unwrap();
        tile::write_bytes(&dir.path().join(format!("v{version}.tile")), &bytes).unwrap();
        write_grid(&dir.path().join(format!("g{version}")), &map, None, version);
    }
    let config = dir.path().join("d.toml");
    let with_floor = |map: &str, floor: &str| {
        let text = CONFIG.replace("t.tile", map);
        std::fs::write(&config, format!("{floor}\n{text}")).unwrap();
        check(&config)
    };
    for map in ["v4.tile", "g4"] {
        let out = with_floor(map, "");
        assert!(out.status.success(), "{map}: no floor: {}", stderr(&out));
        let said = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(said.contains("; unsigned; map version 4)"), "{said}");
    }
    for (map, what) in [("v4.tile", "tile"), ("g4", "grid's manifest")] {
        let out = with_floor(map, "min_map_version = 5");
        assert!(!out.status.success(), "{map} must be refused");
        let why = format!(
            "min_map_version: {what} {} is map version 4, older than the oldest this daemon serves (5)",
            dir.path().join(map).display()
        );
        assert!(stderr(&out).contains(&why), "{map}: {}", stderr(&out));
    }
    for map in ["v5.tile", "v6.tile", "g5", "g6"] {
        let out = with_floor(map, "min_map_version = 5");
        assert!(out.status.success(), "{map}: {}", stderr(&out));
    }
    // The newest version a daemon of the namespace served (recorded in its state folder) is a
    // floor too, whatever the configuration's.
    let record = dir.path().join("default").join("served_map_version");
    std::fs::create_dir_all(record.parent().unwrap()).unwrap();
    std::fs::write(&record, "5\n").unwrap();
    for map in ["v4.tile", "g4"] {
        let out = with_floor(map, "");
        let why = format!(
            "map version 4 is older than 5, the newest this namespace's daemon has served (recorded in {})",
            record.display()
        );
        assert!(stderr(&out).contains(&why), "{map}: {}", stderr(&out));
        assert!(!out.status.success(), "{map} must be refused");
    }
    for map in ["v6.tile", "g6"] {
        let out = with_floor(map, "");
        let said = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            said.contains("map version 6, newest served here 5)"),
            "{said}"
        );
    }
    assert_eq!(
        std::fs::read_to_string(&record).unwrap(),
        "5\n",
        "check writes nothing"
    );
    std::fs::write(&record, "five\n").unwrap();
    let out = with_floor("v6.tile", "");
    assert!(!out.status.success(), "a damaged record is refused");
    assert!(stderr(&out).contains("is damaged"), "{}", stderr(&out));
    for (floor, why) in [
        ("min_map_version = -1", "min_map_version"),
        ("min_map_version = \"5\"", "min_map_version"),
    ] {
        let out = with_floor("v6.tile", floor);
        assert!(!out.status.success(), "{floor} must be refused");
        assert!(stderr(&out).contains(why), "{floor}: {}", stderr(&out));
    }
}

/// A daemon serves 1 to 256 sources: with 3000 it had started 464 workers after 90 s, not ready
/// and deaf to SIGTERM until it would be.
#[test]
fn a_daemon_serves_one_to_256_sources() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(&dir.path().join("t.tile"), 0.5);
    let config = dir.path().join("d.toml");
    let (head, source) = CONFIG.split_at(CONFIG.find("[[source]]").unwrap());
    let with = |n: usize| {
        let sources: String = match n {
            0 => "source = []\n".into(),
            _ => (0..n)
                .map(|k| source.replace("name = \"wheel\"", &format!("name = \"s{k}\"")))
                .collect(),
        };
        std::fs::write(&config, format!("{head}{sources}")).unwrap();
        check(&config)
    };
    let out = with(256);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("ok: 256 sources"));
    for (n, says) in [
        (0, "0 [[source]] tables: 1 to 256 are served"),
        (257, "257 [[source]] tables: 1 to 256 are served"),
    ] {
        let out = with(n);
        assert!(!out.status.success(), "{n} sources passed");
        assert!(stderr(&out).contains(says), "{n}: {}", stderr(&out));
    }
}

/// A source anchored where no lane of the tile is near (Berlin, for a tile at Karlsruhe; or
/// latitude and longitude swapped) is told at `check` and at start, as `correct` tells a run's
/// first pose: `check` said ok, and the worker told it only once a session's first 100
/// alignments had been refused.
#[test]
fn a_source_anchored_far_from_every_lane_is_told() {
    let dir = tempfile::tempdir().unwrap();
    write_tile(&dir.path().join("t.tile"), 0.5);
    let config = dir.path().join("d.toml");
    for (anchor, km) in [
        ("lat = 52.52, lon = 13.40", "526"),
        ("lat = 49.01, lon = 8.4", "1.1"),
    ] {
        std::fs::write(&config, CONFIG.replace("lat = 49.0, lon = 8.4", anchor)).unwrap();
        let out = check(&config);
        let err = stderr(&out);
        assert!(out.status.success(), "{err}");
        assert!(
            err.contains("WARN")
                && err.contains(&format!(
                    "source wheel: its anchor places the odometry frame's origin {km}"
                ))
                && err.contains("km from the nearest lane: check its anchor"),
            "{anchor}: {err}"
        );
    }
    // 900 m away: near enough.
    std::fs::write(
        &config,
        CONFIG.replace("lat = 49.0, lon = 8.4", "lat = 49.0081, lon = 8.4"),
    )
    .unwrap();
    let out = check(&config);
    assert!(!stderr(&out).contains("WARN"), "{}", stderr(&out));
}
