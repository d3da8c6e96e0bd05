//! Compiling a large PBF into a grid, side by side with `osmium cat` reading the same file, in
//! one run: wall time and peak memory of each, for inputs of growing size.
//!
//! `cargo bench -p lanealign-map --bench grid_compile -- [--copies 32,64,128] [--cell M]
//! [--in-memory] [--check] [--keep DIR]` (`-- --help` lists them)
//!
//! For each K in `--copies`: KITTI 00's OSM repeated K x K times (ids renumbered densely, as a
//! renumbered extract has them; each copy shifted by its extent), written as OPL into `osmium
//! cat`, which writes a sorted PBF (in a temporary folder, or kept in `--keep DIR` as
//! `kitti00_xK.osm.pbf`). Then, each under
//! `/usr/bin/time`: `osmium cat -f opl -o /dev/null` (decode every block, write every element as
//! text) and `lanealign-map compile --grid M` (default 1000 m cells). `--in-memory` adds
//! `lanealign-map compile` to one tile, which reads the whole input into memory (the compile
//! before the grid streamed), for comparison on sizes this machine can hold; `--check` compiles
//! the same grid in memory with the library and compares every file byte for byte. Needs
//! Debian's osmium-tool and GNU time (skipped without them).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use clap::Parser;

use lanealign_map::compile::{compile, CompileOptions};
use lanealign_map::osm::{read_xml_file, OsmData};

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

/// A tag key or value in OPL: every character but ASCII letters, digits and `_:.-` as
/// `%<hex code point>%`.
fn opl_escape(out: &mut String, s: &str) {
    for c in s.chars() {
        if c.is_ascii_alphanumeric() || "_:.-".contains(c) {
            out.push(c);
        } else {
            let _ = write!(out, "%{:x}%", c as u32);
        }
    }
}

/// Writes `osm` repeated `copies` x `copies` times as OPL into `out`: every copy's nodes, then
/// every copy's ways, ids ascending (renumbered densely), copy `(r, c)` shifted by `r` x 0.03
/// degrees of latitude and `c` x 0.04 of longitude (KITTI 00's extent).
fn write_tiled_opl(
    osm: &OsmData,
    copies: usize,
    out: &mut impl std::io::Write,
) -> std::io::Result<(u64, u64)> {
    let mut nodes: Vec<(i64, (i64, i64))> = osm.nodes.iter().map(|(&id, &at)| (id, at)).collect();
    nodes.sort_unstable();
    let rank: std::collections::HashMap<i64, i64> = nodes
        .iter()
        .enumerate()
        .map(|(k, &(id, _))| (id, k as i64 + 1))
        .collect();
    let (n_nodes, n_ways) = (nodes.len() as i64, osm.ways.len() as i64);
    let mut line = String::new();
    for k in 0..copies * copies {
        let (dlat, dlon) = ((k / copies) as f64 * 0.03, (k % copies) as f64 * 0.04);
        for (r, &(_, (lat, lon))) in nodes.iter().enumerate() {
            line.clear();
            let _ = writeln!(
                line,
                "n{} x{:.7} y{:.7}",
                k as i64 * n_nodes + r as i64 + 1,
                lon as f64 / 1e9 + dlon,
                lat as f64 / 1e9 + dlat
            );
            out.write_all(line.as_bytes())?;
        }
    }
    for k in 0..copies * copies {
        for (r, w) in osm.ways.iter().enumerate() {
            line.clear();
            let _ = write!(line, "w{} T", k as i64 * n_ways + r as i64 + 1);
            for (i, (key, value)) in w.tags.iter().enumerate() {
                if i > 0 {
                    line.push(',');
                }
                opl_escape(&mut line, key);
                line.push('=');
                opl_escape(&mut line, value);
            }
            line.push_str(" N");
            let refs = w.nodes.iter().filter_map(|id| rank.get(id));
            for (i, r) in refs.enumerate() {
                if i > 0 {
                    line.push(',');
                }
                let _ = write!(line, "n{}", k as i64 * n_nodes + r);
            }
            line.push('\n');
            out.write_all(line.as_bytes())?;
        }
    }
    let copies = (copies * copies) as u64;
    Ok((copies * n_nodes as u64, copies * n_ways as u64))
}

/// Runs `program args` under GNU time: wall time (s) and peak resident memory (MiB).
fn measured(program: &str, args: &[&str]) -> anyhow::Result<(f64, f64)> {
    let out = Command::new("/usr/bin/time")
        .args(["-f", "%e %M", program])
        .args(args)
        .stdout(Stdio::null())
        .output()?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    anyhow::ensure!(out.status.success(), "{program} {args:?} failed:\n{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    let mut fields = last.split_whitespace().map(str::parse::<f64>);
    match (fields.next(), fields.next()) {
        (Some(Ok(wall)), Some(Ok(kib))) => Ok((wall, kib / 1024.0)),
        _ => anyhow::bail!("unexpected output of /usr/bin/time: {last}"),
    }
}

fn size_on_disk(dir: &Path) -> anyhow::Result<u64> {
    let out = Command::new("du").args(["-sb"]).arg(dir).output()?;
    let text = String::from_utf8_lossy(&out.stdout);
    Ok(text.split_whitespace().next().unwrap_or("0").parse()?)
}

/// Whether folders `a` and `b` hold the same files with the same bytes.
fn same_files(a: &Path, b: &Path) -> anyhow::Result<bool> {
    let mut names = Vec::new();
    for dir in [a, b] {
        let mut here = Vec::new();
        for sub in ["", "cells"] {
            for entry in std::fs::read_dir(dir.join(sub))? {
                let entry = entry?;
                if entry.file_type()?.is_file() {
                    here.push(Path::new(sub).join(entry.file_name()));
                }
            }
        }
        here.sort();
        names.push(here);
    }
    if names[0] != names[1] {
        return Ok(false);
    }
    for name in &names[0] {
        if std::fs::read(a.join(name))? != std::fs::read(b.join(name))? {
            return Ok(false);
        }
    }
    Ok(true)
}

#[derive(Parser)]
struct Args {
    /// Each K: KITTI 00's OSM repeated K x K times, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "32,64,128")]
    copies: Vec<usize>,
    /// Cell size of the grids (metres).
    #[arg(long, default_value_t = 1000.0)]
    cell: f64,
    /// Also compile in memory (the compile before the grid streamed), for comparison.
    #[arg(long)]
    in_memory: bool,
    /// Check each streamed grid against the in-memory one, file for file.
    #[arg(long)]
    check: bool,
    /// Keep the generated PBF files in this folder (`kitti00_xK.osm.pbf`) instead of a temporary one.
    #[arg(long)]
    keep: Option<PathBuf>,
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
    for tool in ["osmium", "/usr/bin/time"] {
        if Command::new(tool).arg("--version").output().is_err() {
            println!("SKIPPED: {tool} is not installed (Debian packages osmium-tool, time)");
            return Ok(());
        }
    }
    let Args {
        copies,
        cell,
        in_memory,
        check,
        keep,
        ..
    } = args;
    let compiler = env!("CARGO_BIN_EXE_lanealign-map");
    let osm = read_xml_file(&data.join("osm/kitti_00.osm"))?;
    let dir = tempfile::tempdir()?;
    println!("Grid compile of KITTI 00's OSM repeated K x K times, {cell} m cells; one run each, this machine ({} cores)", std::thread::available_parallelism().map_or(1, |n| n.get()));
    println!("| K | PBF (MB) | nodes | ways | command | wall (s) | peak memory (MiB) | output |");
    println!("|---:|---:|---:|---:|---|---:|---:|---|");
    for k in copies {
        let pbf = match &keep {
            Some(folder) => folder.join(format!("kitti00_x{k}.osm.pbf")),
            None => dir.path().join("large.osm.pbf"),
        };
        let pbf_arg = pbf.to_string_lossy().into_owned();
        let mut osmium = Command::new("osmium")
            .args(["cat", "-F", "opl", "--overwrite", "-o", &pbf_arg])
            .stdin(Stdio::piped())
            .spawn()?;
        let mut stdin = std::io::BufWriter::with_capacity(
            1 << 20,
            osmium
                .stdin
                .take()
                .ok_or_else(|| anyhow::anyhow!("no stdin"))?,
        );
        let (nodes, ways) = write_tiled_opl(&osm, k, &mut stdin)?;
        stdin.flush()?;
        drop(stdin);
        anyhow::ensure!(osmium.wait()?.success(), "osmium could not write the PBF");
        let mb = std::fs::metadata(&pbf)?.len() as f64 / 1e6;
        let row = |command: &str, (wall, mib): (f64, f64), output: &str| {
            println!("| {k} | {mb:.1} | {nodes} | {ways} | {command} | {wall:.1} | {mib:.0} | {output} |");
        };
        row(
            "`osmium cat -f opl -o /dev/null`",
            measured(
                "osmium",
                &[
                    "cat",
                    "-f",
                    "opl",
                    "-o",
                    "/dev/null",
                    "--overwrite",
                    &pbf_arg,
                ],
            )?,
            "every element as text",
        );
        let grid = dir.path().join("grid");
        let cell_arg = cell.to_string();
        let grid_arg = grid.to_string_lossy().into_owned();
        let run = measured(
            compiler,
            &["compile", &pbf_arg, "--grid", &cell_arg, "-o", &grid_arg],
        )?;
        let cells = std::fs::read_dir(grid.join("cells"))?.count();
        row(
            &format!("`lanealign-map compile --grid {cell}`"),
            run,
            &format!("{cells} cells, {:.0} MB", size_on_disk(&grid)? as f64 / 1e6),
        );
        if check {
            let options = CompileOptions::default();
            let compiled = compile(std::slice::from_ref(&pbf), &options)?;
            let reference = dir.path().join("reference");
            compiled.write_grid(&reference, 3.0, cell, 50.0, None, 0)?;
            let same = same_files(&grid, &reference)?;
            println!("| {k} | | | | streamed grid equal to the in-memory grid, byte for byte | | | {same} |");
            anyhow::ensure!(same, "the streamed grid differs from the in-memory grid");
            std::fs::remove_dir_all(&reference)?;
        }
        std::fs::remove_dir_all(&grid)?;
        if in_memory {
            let tile = dir.path().join("one.tile");
            let tile_arg = tile.to_string_lossy().into_owned();
            let run = measured(compiler, &["compile", &pbf_arg, "-o", &tile_arg])?;
            row(
                "`lanealign-map compile` (one tile, in memory)",
                run,
                &format!("{:.0} MB", std::fs::metadata(&tile)?.len() as f64 / 1e6),
            );
            std::fs::remove_file(&tile)?;
        }
    }
    Ok(())
}
