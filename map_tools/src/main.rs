//! `lanealign-map`: compile road data into a lane tile, and inspect tiles.

use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, bail, Context};
use clap::{Parser, Subcommand};
use lanealign_core::geo::{check_lat_lon, Projection};
use lanealign_core::grid;
use lanealign_core::lane_geometry::{LaneInfo, RoadClass, RoadClasses, Traffic};
use lanealign_core::params::UNMARKED_OFFSET_SCALE;
use lanealign_core::tile;
use lanealign_map::compile::{compile, CompileOptions, InputReport};
use lanealign_map::grid_compile::{compile_grid, GridOptions, Reading};
use lanealign_map::keys::{self, read_secret_key};
use lanealign_map::osm_lanes::LaneOptions;

#[derive(Parser)]
#[command(
    name = "lanealign-map",
    version,
    about = "Compile OSM / Lanelet2 road data into lane tiles, and inspect tiles"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Compile .osm, .osm.pbf and Lanelet2 .osm inputs into one tile, or with --grid into a
    /// folder of tiles (a grid: square cells loaded on demand, and a manifest).
    Compile {
        /// Inputs, merged in order (a way several OSM inputs hold, as overlapping extracts do,
        /// comes from the first; its nodes from any)
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Origin of the map plane, LAT,LON in degrees (default: the centre of the data).
        #[arg(long, allow_hyphen_values = true)]
        origin: Option<String>,
        /// Map plane projection: tangent (true scale) or kitti (spherical, as KITTI's GPS).
        #[arg(long, default_value = "tangent")]
        projection: Projection,
        /// Minimum spacing of lane points, metres.
        #[arg(long, default_value_t = 3.0)]
        spacing: f64,
        /// Traffic side: right or left.
        #[arg(long, default_value = "right")]
        traffic: Traffic,
        /// Lanes of unmarked two-way streets (residential, unclassified, living_street without a
        /// lanes tag) at this fraction of their nominal offset from the way line: 0.5 is
        /// lanealign's lane geometry (the robust method's), 1 the paper's (`--method paper`).
        #[arg(long, default_value_t = UNMARKED_OFFSET_SCALE)]
        unmarked_offset_scale: f64,
        /// Comma-separated highway classes to derive lanes from (default: motorway to
        /// living_street and their links; add service to include it).
        #[arg(long)]
        classes: Option<String>,
        /// Sign the tile (with --grid: every cell and the manifest) with the secret key in this
        /// file (from `lanealign-map keygen`).
        #[arg(long, value_name = "KEY_FILE")]
        sign: Option<PathBuf>,
        /// The build's number for this map (0 to 2^63 - 1; the tile, or the grid's manifest and
        /// every cell, carry it, under the signature): a daemon with `min_map_version` refuses
        /// older maps, and SIGHUP never replaces a map with an older one. Give each map build a
        /// larger number than the last (a build counter, or a date such as 20261207).
        #[arg(long, value_name = "N", default_value_t = 0)]
        map_version: u64,
        /// Write a grid of square cells this many metres wide into the folder OUTPUT instead of
        /// one tile (`manifest.toml` and `cells/X_Y.tile`).
        #[arg(long, value_name = "SIZE_M")]
        grid: Option<f64>,
        /// With --grid: every cell also holds the lanes within this many metres of its square,
        /// so that a query near a border needs no neighbouring cell.
        #[arg(long, value_name = "METRES", default_value_t = 50.0, requires = "grid")]
        margin: f64,
        /// The tile (or with --grid the folder) to write.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Make a key pair for signing tiles: the secret key (64 hex digits, file mode 0600) goes to
    /// OUTPUT, the public key to OUTPUT.pub and standard output (for `trusted_tile_keys`).
    Keygen {
        /// The secret key file to write (refused if it exists).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Print a tile's (or a grid's) header, counts, lane geometry and validity; optionally
    /// export a tile's lanes as GeoJSON.
    Inspect {
        /// The tile, or a grid's folder.
        tile: PathBuf,
        /// Write the lane centerlines (WGS84, in driving direction) as GeoJSON.
        #[arg(long)]
        geojson: Option<PathBuf>,
        /// Exit 1 unless the map is signed by one of these public keys (64 hex digits, or a file
        /// holding them such as keygen's KEY.pub; repeatable): a tile, or a grid's manifest and
        /// every cell. What a map build checks before it ships a map to trusted_tile_keys.
        #[arg(long, value_name = "PUBLIC_KEY")]
        trusted: Vec<String>,
        /// Print what was checked as one JSON object (for a map build's scripts: `map_version`,
        /// `checksum`, `signer`, a grid's `cell_signers`, ...) instead of text.
        #[arg(long, conflicts_with = "geojson")]
        json: bool,
    },
}

/// Refuses `signer` (of `what`) when it is not among `trusted`; any signer, or none, when no key
/// is given.
fn require_trusted(
    trusted: &[[u8; 32]],
    signer: Option<[u8; 32]>,
    what: &std::path::Path,
) -> anyhow::Result<()> {
    if trusted.is_empty() || signer.is_some_and(|s| trusted.contains(&s)) {
        return Ok(());
    }
    match signer {
        Some(key) => bail!(
            "{}: signed by {}, which is not among the --trusted keys",
            what.display(),
            tile::key_hex(&key)
        ),
        None => bail!(
            "{}: not signed, and --trusted asks for a signature by one of its keys",
            what.display()
        ),
    }
}

/// What `inspect` says of a map's version: the number, or that the build gave none.
fn map_version_text(map_version: u64) -> String {
    match map_version {
        0 => "0 (none given: compile --map-version N)".into(),
        n => n.to_string(),
    }
}

/// What `inspect` says of a map's signature: `by KEY (signature valid)`, or `no`.
fn signature_state(signer: Option<[u8; 32]>) -> String {
    signer.map_or_else(
        || "no".into(),
        |key| format!("by {} (signature valid)", tile::key_hex(&key)),
    )
}

/// The public keys `--trusted` gives.
fn trusted_keys(given: &[String]) -> anyhow::Result<Vec<[u8; 32]>> {
    let keys = given.iter().map(|k| keys::read_public_key(k));
    keys.collect::<Result<_, _>>().context("--trusted")
}

/// What each input contributed, one line per input on standard error.
fn print_reports(inputs: &[PathBuf], reports: &[InputReport]) {
    for (path, report) in inputs.iter().zip(reports) {
        eprintln!("{}: {report}", path.display());
    }
}

fn parse_origin(s: &str) -> anyhow::Result<(f64, f64)> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--origin '{s}': expected LAT,LON"))?;
    let [lat, lon] = v[..] else {
        bail!("--origin '{s}': expected LAT,LON in degrees");
    };
    check_lat_lon(lat, lon).with_context(|| format!("--origin '{s}'"))?;
    Ok((lat, lon))
}

/// GeoJSON properties of one lane: where it came from and how it runs.
fn lane_properties(id: u64, info: LaneInfo, points: usize) -> serde_json::Value {
    let direction = if info.has(LaneInfo::BACKWARD) {
        "backward"
    } else {
        "forward"
    };
    let mut p = serde_json::json!({
        "lane_id": id,
        "road_class": info.class.name(),
        "direction": direction,
        "lanes_tagged": info.has(LaneInfo::LANES_TAGGED),
        "unmarked": info.has(LaneInfo::UNMARKED),
        "points": points,
    });
    match info.class {
        RoadClass::Lanelet => p["lanelet_id"] = serde_json::json!(id >> 1),
        RoadClass::Unknown => {}
        _ => {
            p["osm_way_id"] = serde_json::json!(id >> 5);
            p["lane_index"] = serde_json::json!(id & 31);
        }
    }
    p
}

/// What `inspect --json` prints of any map: where it lies, how it was built, and by whom.
fn map_json(
    kind: &str,
    path: &std::path::Path,
    info: &tile::TileInfo,
    trusted: &[[u8; 32]],
) -> serde_json::Value {
    let g = &info.geometry;
    serde_json::json!({
        "kind": kind,
        "path": path.display().to_string(),
        "map_version": info.map_version,
        "checksum": format!("{:016x}", info.checksum),
        "signer": info.signer.map(|k| tile::key_hex(&k)),
        "trusted": (!trusted.is_empty()).then_some(true),
        "projection": info.plane.projection.name(),
        "origin_lat": info.plane.origin_lat,
        "origin_lon": info.plane.origin_lon,
        "spacing_m": info.spacing_m,
        "traffic": g.traffic.name(),
        "road_classes": g.classes.iter().map(|c| c.name()).collect::<Vec<_>>(),
        "unmarked_offset_scale": g.unmarked_offset_scale,
        "lanes": info.lanes,
        "points": info.points,
        "bounds_m": info.bounds,
    })
}

/// Prints a grid's manifest and checks every cell against it.
fn inspect_grid(path: &std::path::Path, trusted: &[[u8; 32]], json: bool) -> anyhow::Result<()> {
    let grid = grid::Grid::open(path)?;
    require_trusted(trusted, grid.signer(), &path.join(grid::MANIFEST))?;
    let m = grid.manifest();
    let (mut points, mut bytes, mut signers) = (0u64, 0u64, std::collections::BTreeSet::new());
    for key in grid.cells() {
        let cell = grid.load_cell(key)?;
        require_trusted(trusted, cell.signer(), &grid.cell_path(key))?;
        points += cell.points() as u64;
        signers.insert(cell.signer().map(|k| tile::key_hex(&k)));
    }
    for c in &m.cells {
        bytes += c.bytes;
    }
    if json {
        let mut doc = map_json("grid", path, &grid.info(), trusted);
        doc["format_version"] = serde_json::json!(m.format);
        doc["bytes"] = serde_json::json!(bytes);
        doc["cells"] = serde_json::json!(m.cells.len());
        doc["cell_size_m"] = serde_json::json!(m.cell_size_m);
        doc["margin_m"] = serde_json::json!(m.margin_m);
        doc["points_in_cells"] = serde_json::json!(points);
        doc["cell_signers"] = serde_json::json!(signers);
        println!("{doc}");
        return Ok(());
    }
    println!("grid        {}", path.display());
    println!(
        "cells       {} of {} m, margin {} m ({} lane points in cells, {} bytes)",
        m.cells.len(),
        m.cell_size_m,
        m.margin_m,
        points,
        bytes
    );
    println!(
        "origin      {:.9}, {:.9} ({} projection)",
        m.origin_lat, m.origin_lon, m.projection
    );
    println!("map version {}", map_version_text(m.map_version));
    println!("spacing     {} m", m.spacing_m);
    println!("geometry    {}", grid.geometry());
    println!("lanes       {}", m.lanes);
    println!("points      {}", m.points);
    println!(
        "bounds      x {:.1}..{:.1} m, y {:.1}..{:.1} m",
        m.bounds[0], m.bounds[2], m.bounds[1], m.bounds[3]
    );
    println!(
        "checksum    {:016x} (the manifest's); every cell valid and as the manifest says",
        grid.checksum()
    );
    let signed: Vec<String> = signers
        .into_iter()
        .map(|s| s.map_or_else(|| "no".into(), |key| format!("by {key}")))
        .collect();
    println!(
        "signed      manifest {}; cells {}",
        signature_state(grid.signer()),
        signed.join(", ")
    );
    if !trusted.is_empty() {
        println!("trusted     yes: the manifest and every cell signed by --trusted keys");
    }
    Ok(())
}

fn main() -> std::process::ExitCode {
    lanealign_core::report::end_quietly_on_closed_pipe();
    lanealign_core::report::exit_code(run(Cli::parse()))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Compile {
            inputs,
            origin,
            projection,
            spacing,
            traffic,
            unmarked_offset_scale,
            classes,
            sign,
            map_version,
            grid,
            margin,
            output,
        } => {
            tile::check_map_version(map_version).map_err(|e| anyhow!("--map-version: {e}"))?;
            let given: Vec<Option<&std::path::Path>> = inputs
                .iter()
                .map(|p| Some(p.as_path()))
                .chain([sign.as_deref()])
                .collect();
            lanealign_core::input::check_outputs_apart(&[Some(&output)], &given)?;
            let key = sign.as_deref().map(read_secret_key).transpose()?;
            if let Some(warning) = sign.as_deref().and_then(keys::exposure) {
                eprintln!("warning: {warning}");
            }
            lanealign_core::lane_map::check_spacing(spacing)
                .map_err(|e| anyhow!("--spacing: {e}"))?;
            lanealign_core::lane_geometry::check_unmarked_offset_scale(unmarked_offset_scale)
                .map_err(|e| anyhow!("--unmarked-offset-scale: {e}"))?;
            let classes = match classes {
                Some(list) => RoadClasses::parse_list(&list).context("--classes")?,
                None => RoadClasses::DEFAULT,
            };
            let options = CompileOptions {
                origin: origin.as_deref().map(parse_origin).transpose()?,
                projection,
                lanes: LaneOptions {
                    classes,
                    traffic,
                    spacing_m: spacing,
                    unmarked_offset_scale,
                },
            };
            let start = Instant::now();
            match grid {
                Some(cell_size_m) => {
                    let grid = GridOptions {
                        cell_size_m,
                        margin_m: margin,
                        sign: key.as_ref(),
                        map_version,
                    };
                    let done = compile_grid(&inputs, &options, &output, &grid)?;
                    print_reports(&inputs, &done.reports);
                    let (m, plane) = (&done.manifest, &done.plane);
                    let bytes: u64 = m.cells.iter().map(|c| c.bytes).sum();
                    eprintln!(
                        "{}: {} lanes, {} points, {:.1} lane-km, {} cells of {cell_size_m} m (margin {margin} m), {bytes} bytes, origin {:.7},{:.7} ({}); {}; {}; {:.2} s",
                        output.display(), m.lanes, m.points, done.lane_length_m / 1000.0,
                        m.cells.len(), plane.origin_lat, plane.origin_lon, plane.projection.name(),
                        done.geometry,
                        match &done.reading {
                            Reading::Streamed => "streamed (nodes and lanes on disk)".to_string(),
                            Reading::InMemory(why) => format!("read in memory: {why}"),
                        },
                        start.elapsed().as_secs_f64()
                    );
                }
                None => {
                    let compiled = compile(&inputs, &options)?;
                    let bytes = compiled.shipped_tile_bytes(spacing, map_version, key.as_ref())?;
                    tile::write_bytes(&output, &bytes)?;
                    print_reports(&inputs, &compiled.reports);
                    let (map, plane) = (&compiled.map, &compiled.plane);
                    eprintln!(
                        "{}: {} lanes, {} points, {:.1} lane-km, {} bytes, origin {:.7},{:.7} ({}); {}; {:.2} s",
                        output.display(), map.lane_count(), map.len(), map.lane_length_m() / 1000.0,
                        bytes.len(), plane.origin_lat, plane.origin_lon, plane.projection.name(),
                        compiled.geometry, start.elapsed().as_secs_f64()
                    );
                }
            }
        }
        Command::Keygen { output } => {
            let mut seed = [0u8; 32];
            getrandom::fill(&mut seed).map_err(|e| anyhow::anyhow!("no system randomness: {e}"))?;
            let key = tile::SigningKey::from_bytes(&seed);
            let public = tile::key_hex(&key.verifying_key().to_bytes());
            let mut file = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(&output)
                .with_context(|| format!("creating {}", output.display()))?;
            writeln!(file, "{}", tile::key_hex(&seed))
                .with_context(|| format!("writing {}", output.display()))?;
            let mut public_path = output.into_os_string();
            public_path.push(".pub");
            lanealign_core::input::write_atomic(
                std::path::Path::new(&public_path),
                format!("{public}\n").as_bytes(),
            )?;
            println!("{public}");
        }
        Command::Inspect {
            tile: path,
            geojson,
            trusted,
            json,
        } if grid::is_grid(&path) => {
            if geojson.is_some() {
                bail!("--geojson takes a tile; inspect one cell of the grid: {}/cells/X_Y.tile is a cell, not a map", path.display());
            }
            let trusted = trusted_keys(&trusted)?;
            inspect_grid(&path, &trusted, json)?;
        }
        Command::Inspect {
            tile: path,
            geojson,
            trusted,
            json,
        } => {
            lanealign_core::input::check_outputs_apart(&[geojson.as_deref()], &[Some(&path)])?;
            let trusted = trusted_keys(&trusted)?;
            let (map, info) = tile::load(&path)?;
            require_trusted(&trusted, info.signer, &path)?;
            if json {
                let mut doc = map_json("tile", &path, &info, &trusted);
                doc["format_version"] = serde_json::json!(tile::VERSION);
                doc["bytes"] = serde_json::json!(tile::HEADER_LEN as u64 + info.payload_len);
                doc["lane_km"] = serde_json::json!(map.lane_length_m() / 1000.0);
                println!("{doc}");
                return Ok(());
            }
            let p = info.plane;
            println!("tile        {}", path.display());
            println!(
                "format      version {}, little-endian, {} bytes",
                tile::VERSION,
                tile::HEADER_LEN as u64 + info.payload_len
            );
            println!(
                "origin      {:.9}, {:.9} ({} projection)",
                p.origin_lat,
                p.origin_lon,
                p.projection.name()
            );
            println!("map version {}", map_version_text(info.map_version));
            println!("spacing     {} m", info.spacing_m);
            println!("geometry    {}", info.geometry);
            println!("lanes       {}", info.lanes);
            println!("points      {}", info.points);
            println!("lane-km     {:.3}", map.lane_length_m() / 1000.0);
            println!(
                "bounds      x {:.1}..{:.1} m, y {:.1}..{:.1} m",
                info.bounds[0], info.bounds[2], info.bounds[1], info.bounds[3]
            );
            match (
                p.lat_lon_of([info.bounds[0], info.bounds[1]]),
                p.lat_lon_of([info.bounds[2], info.bounds[3]]),
            ) {
                (Some((lat0, lon0)), Some((lat1, lon1))) => {
                    println!("lat/lon     {lat0:.7},{lon0:.7} .. {lat1:.7},{lon1:.7}")
                }
                _ => println!("lat/lon     beyond where the plane maps back to the Earth"),
            }
            println!(
                "checksum    {:016x} ok; every field and array valid",
                info.checksum
            );
            println!("signed      {}", signature_state(info.signer));
            if !trusted.is_empty() {
                println!("trusted     yes: signed by a --trusted key");
            }
            if let Some(out) = geojson {
                let features = map
                    .lanes()
                    .map(|(id, lane_info, pts)| {
                        let coords = pts
                            .iter()
                            .enumerate()
                            .map(|(k, &q)| match p.lat_lon_of(q) {
                                Some((lat, lon)) => Ok([lon, lat]),
                                None => bail!(
                                    "lane {id} point {k} at ({:.1}, {:.1}) m does not map back to a latitude and longitude in the tile's {} plane about {:.7},{:.7}: no GeoJSON written",
                                    q[0],
                                    q[1],
                                    p.projection.name(),
                                    p.origin_lat,
                                    p.origin_lon
                                ),
                            })
                            .collect::<anyhow::Result<Vec<[f64; 2]>>>()?;
                        Ok(serde_json::json!({
                            "type": "Feature",
                            "properties": lane_properties(id, lane_info, pts.len()),
                            "geometry": { "type": "LineString", "coordinates": coords },
                        }))
                    })
                    .collect::<anyhow::Result<Vec<serde_json::Value>>>()?;
                let doc = serde_json::json!({
                    "type": "FeatureCollection",
                    "attribution": "Lane centerlines derived from OpenStreetMap data, (c) OpenStreetMap contributors, ODbL 1.0 (https://www.openstreetmap.org/copyright)",
                    "features": features,
                });
                lanealign_core::input::write_atomic(&out, &serde_json::to_vec(&doc)?)?;
                println!(
                    "geojson     {} ({} lanes, coordinates in driving order)",
                    out.display(),
                    map.lane_count()
                );
            }
        }
    }
    Ok(())
}
