//! Tile compile and load costs on the shared maps, and PBF read throughput against osmium.
//!
//! `cargo bench -p lanealign-map --bench tiles -- [--loads N] [--pbf-copies K]`
//!
//! Part 1, per map: compile time, tile bytes, bytes per lane-km, and load time (read + full
//! validation + KD-tree build) over N loads (default 1000), median and p99.
//! Part 2: a large PBF made by tiling KITTI 00's OSM K x K times (default 32) with shifted ids
//! and coordinates (written to a temporary folder, never kept), converted with `osmium cat`; read
//! by lanealign-map and by `osmium fileinfo -e` and `osmium cat -f opl` on the same file, each
//! three times, median wall time. Needs Debian's osmium-tool (skipped without it).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use clap::Parser;

use lanealign_core::tile;
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_map::pbf::read_pbf_file;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn percentile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn maps_table(data: &Path, loads: usize) -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    println!("| map | compile (ms) | lanes | lane-km | tile bytes | bytes per lane-km | load median (us) | load p99 (us) |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut inputs: Vec<PathBuf> = ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"]
        .iter()
        .map(|s| data.join(format!("osm/kitti_{s}.osm")))
        .collect();
    inputs.push(data.join("lanelet2/mapping_example.osm"));
    for input in inputs {
        let start = Instant::now();
        let compiled = compile(std::slice::from_ref(&input), &CompileOptions::default())?;
        let map = &compiled.map;
        let out = dir.path().join("map.tile");
        tile::write_bytes(&out, &compiled.tile_bytes(3.0))?;
        let compile_ms = start.elapsed().as_secs_f64() * 1e3;
        let bytes = std::fs::metadata(&out)?.len();
        let mut times = Vec::with_capacity(loads);
        for _ in 0..loads {
            let t = Instant::now();
            let (loaded, _) = tile::load(&out)?;
            times.push(t.elapsed().as_secs_f64() * 1e6);
            std::hint::black_box(loaded);
        }
        let km = map.lane_length_m() / 1000.0;
        println!(
            "| {} | {compile_ms:.1} | {} | {km:.1} | {bytes} | {:.0} | {:.0} | {:.0} |",
            input
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default(),
            map.lane_count(),
            bytes as f64 / km,
            median(times.clone()),
            percentile(times, 0.99)
        );
    }
    // A synthetic tile of a million points (1000 parallel lanes of 1000 points, 3 m apart): the
    // cost of validating and rebuilding the KD-tree at load for a large city.
    let lanes: Vec<lanealign_core::lane_map::Lane> = (0..1000)
        .map(|k| {
            let points = (0..1000)
                .map(|i| [i as f64 * 3.0, k as f64 * 3.5])
                .collect();
            lanealign_core::lane_map::Lane::new(k, points)
        })
        .collect();
    let map = lanealign_core::lane_map::LaneMap::new(&lanes)?;
    let plane = lanealign_core::geo::MapPlane::new(Default::default(), 49.0, 8.4);
    let out = dir.path().join("million.tile");
    let geometry = lanealign_core::lane_geometry::LaneGeometry::default();
    tile::write(&out, &map, &plane, 3.0, &geometry)?;
    let bytes = std::fs::metadata(&out)?.len();
    let times: Vec<f64> = (0..loads.min(20))
        .map(|_| {
            let t = Instant::now();
            let loaded = tile::load(&out).map(|(m, _)| m.len());
            std::hint::black_box(loaded.ok());
            t.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    let km = map.lane_length_m() / 1000.0;
    println!(
        "| synthetic 10^6 points | - | 1000 | {km:.1} | {bytes} | {:.0} | {:.0} | {:.0} |",
        bytes as f64 / km,
        median(times.clone()),
        percentile(times, 0.99)
    );
    Ok(())
}

/// KITTI 00's OSM repeated `copies` x `copies` times, each copy with ids offset and coordinates
/// shifted by its extent, as one OSM XML document.
fn tiled_osm(source: &Path, copies: usize) -> anyhow::Result<String> {
    let osm = lanealign_map::osm::read_xml_file(source)?;
    let mut out = String::from(
        "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' generator='lanealign bench'>\n",
    );
    let id_step = 1i64 << 40;
    let escape = |s: &str| {
        s.replace('&', "&amp;")
            .replace('\'', "&apos;")
            .replace('<', "&lt;")
            .replace('>', "&gt;")
    };
    let mut nodes: Vec<(&i64, &(i64, i64))> = osm.nodes.iter().collect();
    nodes.sort();
    for k in 0..copies * copies {
        let (dlat, dlon) = ((k / copies) as f64 * 0.03, (k % copies) as f64 * 0.04);
        let offset = k as i64 * id_step;
        for (&id, &(lat, lon)) in &nodes {
            let _ = writeln!(
                out,
                "<node id='{}' lat='{:.7}' lon='{:.7}'/>",
                id + offset,
                lat as f64 / 1e9 + dlat,
                lon as f64 / 1e9 + dlon
            );
        }
    }
    for k in 0..copies * copies {
        let offset = k as i64 * id_step;
        for w in &osm.ways {
            let _ = writeln!(out, "<way id='{}'>", w.id + offset);
            for n in &w.nodes {
                let _ = writeln!(out, "<nd ref='{}'/>", n + offset);
            }
            for (key, v) in &w.tags {
                let _ = writeln!(out, "<tag k='{}' v='{}'/>", escape(key), escape(v));
            }
            out.push_str("</way>\n");
        }
    }
    out.push_str("</osm>\n");
    Ok(out)
}

fn timed(mut command: Command) -> anyhow::Result<f64> {
    let t = Instant::now();
    let status = command
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()?;
    anyhow::ensure!(status.success(), "{command:?} failed");
    Ok(t.elapsed().as_secs_f64())
}

fn pbf_table(data: &Path, copies: usize) -> anyhow::Result<()> {
    if Command::new("osmium").arg("--version").output().is_err() {
        println!("SKIPPED PBF throughput: osmium (Debian package osmium-tool) is not installed");
        return Ok(());
    }
    let dir = tempfile::tempdir()?;
    let xml = dir.path().join("large.osm");
    let pbf = dir.path().join("large.osm.pbf");
    std::fs::write(&xml, tiled_osm(&data.join("osm/kitti_00.osm"), copies)?)?;
    let mut convert = Command::new("osmium");
    convert
        .args(["cat", "--overwrite", "-o"])
        .arg(&pbf)
        .arg(&xml);
    timed(convert)?;
    let mb = std::fs::metadata(&pbf)?.len() as f64 / 1e6;
    let mut ours = Vec::new();
    let mut elements = (0, 0);
    for _ in 0..3 {
        let t = Instant::now();
        let d = read_pbf_file(&pbf)?;
        ours.push(t.elapsed().as_secs_f64());
        elements = (d.nodes.len(), d.ways.len());
    }
    let osmium = |args: &[&str]| -> anyhow::Result<f64> {
        let mut runs = Vec::new();
        for _ in 0..3 {
            let mut c = Command::new("osmium");
            c.args(args).arg(&pbf);
            runs.push(timed(c)?);
        }
        Ok(median(runs))
    };
    let fileinfo = osmium(&["fileinfo", "-e"])?;
    let opl = osmium(&["cat", "-f", "opl", "-o", "/dev/null", "--overwrite"])?;
    let ours = median(ours);
    println!("\nPBF: KITTI 00 tiled {copies}x{copies}: {mb:.1} MB, {} nodes, {} ways; median of 3 runs, 2 cores", elements.0, elements.1);
    println!("| reader | what it does | wall time (s) | MB/s | ratio to lanealign |");
    println!("|---|---|---|---|---|");
    println!("| lanealign-map read_pbf_file | decode all blocks, keep nodes, ways, tags | {ours:.3} | {:.0} | 1.00 |", mb / ours);
    println!("| osmium fileinfo -e | decode all blocks, count and checksum | {fileinfo:.3} | {:.0} | {:.2} |", mb / fileinfo, fileinfo / ours);
    println!(
        "| osmium cat -f opl | decode all blocks, write OPL text | {opl:.3} | {:.0} | {:.2} |",
        mb / opl,
        opl / ours
    );
    Ok(())
}

#[derive(Parser)]
struct Args {
    /// Loads of each tile, for the load time's median and p99.
    #[arg(long, default_value_t = 1000)]
    loads: usize,
    /// The PBF is KITTI 00's OSM tiled this many times in each direction.
    #[arg(long, default_value_t = 32)]
    pbf_copies: usize,
    /// Cargo passes this to every bench.
    #[arg(long, hide = true)]
    bench: bool,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let data = data_dir();
    if !data.join("osm/kitti_00.osm").is_file() {
        println!("SKIPPED: no shared data at {}", data.display());
        return Ok(());
    }
    maps_table(&data, args.loads)?;
    pbf_table(&data, args.pbf_copies)
}
