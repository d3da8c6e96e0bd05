//! The streaming grid compile (PBF inputs: nodes and lanes on disk, cells cut a block at a time)
//! writes, byte for byte, the grid cut from the map compiled in memory; inputs that cannot
//! stream are read in memory and say why; a way twice in one input is refused; overlapping
//! extracts merge into the map of the area they cover.

use std::path::{Path, PathBuf};
use std::process::Command;

use lanealign_map::compile::{compile, CompileError, CompileOptions};
use lanealign_map::grid_compile::{compile_grid, GridOptions, Reading};
use lanealign_tests::shared_data;

fn osmium_installed() -> bool {
    let there = Command::new("osmium").arg("--version").output().is_ok();
    if !there {
        eprintln!("SKIPPED: osmium (Debian package osmium-tool) is not installed");
    }
    there
}

/// `xml` converted to PBF by osmium (which keeps the elements' order) at `pbf`.
fn to_pbf(xml: &Path, pbf: &Path) {
    let status = Command::new("osmium")
        .args(["cat", "--overwrite", "-o"])
        .arg(pbf)
        .arg(xml)
        .status()
        .unwrap();
    assert!(status.success(), "osmium cat {}", xml.display());
}

/// Every file under `dir`, relative to it, with its bytes, in name order.
fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let bytes = std::fs::read(&path).unwrap();
                out.push((path.strip_prefix(dir).unwrap().to_path_buf(), bytes));
            }
        }
    }
    out.sort();
    out
}

/// The grid `compile_grid` writes from `inputs`, and the one cut from `compile`'s map.
fn both_grids(inputs: &[PathBuf], cell_size_m: f64, out: &Path) -> (Reading, PathBuf, PathBuf) {
    let options = CompileOptions::default();
    let grid = GridOptions {
        cell_size_m,
        margin_m: 50.0,
        sign: None,
        map_version: 20_261_207,
    };
    let streamed = out.join("streamed");
    let done = compile_grid(inputs, &options, &streamed, &grid).unwrap();
    let in_memory = out.join("in_memory");
    let compiled = compile(inputs, &options).unwrap();
    compiled
        .write_grid(&in_memory, 3.0, cell_size_m, 50.0, None, grid.map_version)
        .unwrap();
    (done.reading, streamed, in_memory)
}

#[test]
fn a_streamed_pbf_grid_equals_the_grid_of_the_map_in_memory() {
    let Some(data) = shared_data() else { return };
    if !osmium_installed() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let pbf = |seq: &str| {
        let path = dir.path().join(format!("{seq}.osm.pbf"));
        to_pbf(&data.join(format!("osm/kitti_{seq}.osm")), &path);
        path
    };
    let (p00, p05, p09) = (pbf("00"), pbf("05"), pbf("09"));
    // 50 m cells put 40 cells a side in a block (several blocks a drive), 200 m cells 10; two
    // inputs check the map's order across inputs.
    let cases = [
        (vec![p00.clone()], 200.0),
        (vec![p05.clone()], 50.0),
        (vec![p09, p00, p05], 200.0),
    ];
    for (k, (inputs, cell)) in cases.iter().enumerate() {
        let out = dir.path().join(format!("case{k}"));
        let (reading, streamed, in_memory) = both_grids(inputs, *cell, &out);
        assert_eq!(reading, Reading::Streamed, "case {k}");
        let grid = lanealign_core::grid::Grid::open(&streamed).unwrap();
        let first = grid.cells().next().unwrap();
        assert_eq!(grid.info().map_version, 20_261_207, "case {k}");
        assert!(
            grid.load_cell(first).is_ok(),
            "case {k}: a cell of the version"
        );
        let (a, b) = (files(&streamed), files(&in_memory));
        assert!(a.len() > 10, "case {k}: {} files", a.len());
        assert_eq!(
            a.iter().map(|f| &f.0).collect::<Vec<_>>(),
            b.iter().map(|f| &f.0).collect::<Vec<_>>(),
            "case {k}: the same files"
        );
        for ((name, x), (_, y)) in a.iter().zip(&b) {
            assert!(x == y, "case {k}: {} differs", name.display());
        }
    }
}

#[test]
fn inputs_that_cannot_stream_are_read_in_memory_and_say_why() {
    let Some(data) = shared_data() else { return };
    if !osmium_installed() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let lanelet = dir.path().join("lanelet.osm.pbf");
    to_pbf(&data.join("lanelet2/mapping_example.osm"), &lanelet);
    let (reading, streamed, in_memory) =
        both_grids(std::slice::from_ref(&lanelet), 100.0, &dir.path().join("l"));
    assert!(
        matches!(&reading, Reading::InMemory(why) if why.contains("Lanelet2")),
        "{reading:?}"
    );
    assert_eq!(files(&streamed), files(&in_memory));

    // Nodes out of id order (osmium keeps the order it reads).
    let unsorted_xml = dir.path().join("unsorted.osm");
    std::fs::write(
        &unsorted_xml,
        "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6'>\n\
         <node id='2' lat='49.0001' lon='8.4'/>\n<node id='1' lat='49.0' lon='8.4'/>\n\
         <node id='3' lat='49.0002' lon='8.4'/>\n\
         <way id='7'><nd ref='1'/><nd ref='2'/><nd ref='3'/><tag k='highway' v='primary'/></way>\n\
         </osm>\n",
    )
    .unwrap();
    let unsorted = dir.path().join("unsorted.osm.pbf");
    to_pbf(&unsorted_xml, &unsorted);
    let (reading, streamed, in_memory) = both_grids(
        std::slice::from_ref(&unsorted),
        100.0,
        &dir.path().join("u"),
    );
    assert!(
        matches!(&reading, Reading::InMemory(why) if why.contains("not sorted by id") && why.contains("osmium sort")),
        "{reading:?}"
    );
    assert_eq!(files(&streamed), files(&in_memory));
}

/// A way twice in one input is refused, streamed or read in memory (which gave its lanes twice);
/// so is a node at two places (which took one of the two as the blocks' decoding happened to end).
#[test]
fn a_way_or_a_node_twice_in_one_input_is_refused() {
    if !osmium_installed() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let xml = dir.path().join("twice.osm");
    let way = "<way id='7'><nd ref='1'/><nd ref='2'/><tag k='highway' v='primary'/></way>\n";
    std::fs::write(
        &xml,
        format!(
            "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6'>\n\
             <node id='1' lat='49.0' lon='8.4'/>\n<node id='2' lat='49.0005' lon='8.4'/>\n\
             {way}{way}</osm>\n"
        ),
    )
    .unwrap();
    let pbf = dir.path().join("twice.osm.pbf");
    to_pbf(&xml, &pbf);
    let grid = GridOptions {
        cell_size_m: 100.0,
        margin_m: 50.0,
        sign: None,
        map_version: 0,
    };
    let out = dir.path().join("grid");
    let err = compile_grid(&[pbf], &CompileOptions::default(), &out, &grid)
        .err()
        .expect("a way twice is refused");
    assert!(
        matches!(err, CompileError::DuplicateWay { way: 7, .. }),
        "{err}"
    );
    assert!(
        !out.join("manifest.toml").exists(),
        "no manifest for a failed compile"
    );
    let err = compile(std::slice::from_ref(&xml), &CompileOptions::default())
        .err()
        .expect("in memory too");
    assert!(
        matches!(err, CompileError::DuplicateWay { way: 7, .. }),
        "{err}"
    );

    let moved = dir.path().join("moved.osm");
    std::fs::write(
        &moved,
        format!(
            "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6'>\n\
             <node id='1' lat='49.0' lon='8.4'/>\n<node id='2' lat='49.0005' lon='8.4'/>\n\
             <node id='2' lat='49.0006' lon='8.4'/>\n{way}</osm>\n"
        ),
    )
    .unwrap();
    let pbf = dir.path().join("moved.osm.pbf");
    to_pbf(&moved, &pbf);
    for (input, said) in [
        (&moved, "moved.osm: at byte 134: "),
        (&pbf, "moved.osm.pbf: "),
    ] {
        let said = format!(
            "{said}node 2 appears twice, at (49.0005, 8.4) and at (49.0006, 8.4) (an OSM file \
             holds each node once)"
        );
        let err = compile(std::slice::from_ref(input), &CompileOptions::default())
            .err()
            .expect("a node at two places is refused");
        assert!(err.to_string().contains(&said), "{err}");
    }
    let err = compile_grid(&[pbf], &CompileOptions::default(), &out, &grid)
        .err()
        .expect("streamed too");
    assert!(err.to_string().contains("node 2 appears twice"), "{err}");
}

/// `input` cut by osmium to the box `west,south,east,north` (degrees) with `strategy`, in the
/// format `out`'s name says.
fn extract(input: &Path, bbox: &str, strategy: &str, out: &Path) {
    let status = Command::new("osmium")
        .args(["extract", "--overwrite", "-s", strategy, "-b", bbox, "-o"])
        .arg(out)
        .arg(input)
        .status()
        .unwrap();
    assert!(status.success(), "osmium extract {}", input.display());
}

/// Every lane of a compiled map, by id: its id, class and points.
fn lanes_by_id(inputs: &[PathBuf]) -> Vec<(u64, String, Vec<[f64; 2]>)> {
    let compiled = compile(inputs, &CompileOptions::default()).unwrap();
    let mut lanes: Vec<_> = compiled
        .map
        .lanes()
        .map(|(id, info, points)| (id, format!("{info:?}"), points.to_vec()))
        .collect();
    lanes.sort_by_key(|lane| lane.0);
    lanes
}

/// Two extracts that overlap (as neighbouring regions' do) compile into the map of the area
/// they cover: the ways of the overlap once (they gave their lanes twice), and a way an extract
/// cut at its border whole, from the nodes the other extract holds. Streamed, the same grid.
#[test]
fn overlapping_extracts_merge_into_the_map_of_the_whole() {
    let Some(data) = shared_data() else { return };
    if !osmium_installed() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let whole = data.join("osm/kitti_00.osm");
    // KITTI 00's roads span longitudes 8.383-8.409; the two boxes share 8.395-8.397.
    let (west, east) = ("8.38,48.97,8.397,48.995", "8.395,48.97,8.41,48.995");
    let expected = lanes_by_id(std::slice::from_ref(&whole));
    for strategy in ["simple", "complete_ways"] {
        let cut = |bbox, name: &str| {
            let path = dir.path().join(format!("{strategy}_{name}"));
            extract(&whole, bbox, strategy, &path);
            path
        };
        let halves = [cut(west, "w.osm"), cut(east, "e.osm")];
        let merged = lanes_by_id(&halves);
        assert_eq!(merged.len(), expected.len(), "{strategy}: lanes");
        assert!(merged == expected, "{strategy}: the lanes of the whole");
        // The west half alone lacks what lies beyond its border (with `simple`, the parts of
        // the ways that cross it): the east half adds to it.
        assert!(
            lanes_by_id(&halves[..1]).len() < expected.len(),
            "{strategy}"
        );

        let pbfs = [cut(west, "w.osm.pbf"), cut(east, "e.osm.pbf")];
        let out = dir.path().join(format!("{strategy}_grid"));
        let (reading, streamed, in_memory) = both_grids(&pbfs, 200.0, &out);
        assert_eq!(reading, Reading::Streamed, "{strategy}");
        assert!(
            files(&streamed) == files(&in_memory),
            "{strategy}: the grids"
        );
    }

    // Files an editor made number their new objects -1, -2, ... each: their ways and nodes are
    // their own, streamed as in memory.
    let drawn: Vec<PathBuf> = ["49.00", "49.02"]
        .iter()
        .enumerate()
        .map(|(k, lat)| {
            let xml = dir.path().join(format!("drawn{k}.osm"));
            std::fs::write(
                &xml,
                format!(
                    "<osm version='0.6'>\n<node id='-2' lat='{lat}9' lon='8.41'/>\n\
                     <node id='-1' lat='{lat}0' lon='8.41'/>\n<way id='-1'><nd ref='-1'/>\
                     <nd ref='-2'/><tag k='highway' v='residential'/></way>\n</osm>\n"
                ),
            )
            .unwrap();
            let pbf = dir.path().join(format!("drawn{k}.osm.pbf"));
            to_pbf(&xml, &pbf);
            pbf
        })
        .collect();
    assert_eq!(lanes_by_id(&drawn).len(), 4, "two lanes from each file");
    let (reading, streamed, in_memory) = both_grids(&drawn, 200.0, &dir.path().join("drawn"));
    assert_eq!(reading, Reading::Streamed);
    assert!(files(&streamed) == files(&in_memory), "the drawn grids");
}
