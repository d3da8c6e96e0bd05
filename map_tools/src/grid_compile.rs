//! Compiling road data into a grid, with memory bounded by a block of cells when every input is
//! PBF (`lanealign-map compile --grid`).
//!
//! PBF inputs stream in two passes, each decoding blocks on every core and putting their results
//! back in file order: the first appends node locations to a store on disk ([`NodeStore`]) and
//! finds the plane's origin; the second derives each way's lanes as it passes and hands them, in
//! the whole map's order, to an external sort by block of cells ([`LaneSpill`]). Then the sorted
//! lanes are read back a block at a time and the block's cells cut and written on every core.
//! Nothing holds the input, its nodes or the whole map: memory holds the sort's buffer and a few
//! blocks. The grid equals, byte for byte, the one cut from the map compiled in memory (tested).
//! Inputs that cannot stream are read in memory, and the result says why: XML (small by nature),
//! Lanelet2 maps (lanes from relations), and PBF whose nodes or ways are not sorted by id.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};

use lanealign_core::geo::MapPlane;
use lanealign_core::grid::{
    self, partition_lanes, CellEntry, CellKey, GridSpec, Manifest, OrderedLane,
};
use lanealign_core::lane_geometry::LaneGeometry;
use lanealign_core::lane_map::Lane;
use lanealign_core::tile::SigningKey;
use osmpbf::Element;

use crate::compile::{compile, is_pbf, CompileError, CompileOptions, InputReport, NodeBounds};
use crate::lane_spill::{BlockKey, BlockLanes, LaneSpill, SpillError, SpilledLanes};
use crate::node_store::{NodeStore, NodeStoreError, NodeWriter};
use crate::osm::{tag, MergedNodes};
use crate::osm_lanes::{derive_way_lanes, DeriveReport, EarlierRoads};
use crate::pbf::{for_each_blob, for_each_element, node_of, relation_of, way_of};

/// The grid to cut.
pub struct GridOptions<'a> {
    /// Side of a cell's square (metres).
    pub cell_size_m: f64,
    /// How far beyond its square a cell holds lane points (metres).
    pub margin_m: f64,
    /// Sign every cell, and the manifest, with this key.
    pub sign: Option<&'a SigningKey>,
    /// The builder's number for this build of the map, in the manifest and every cell (0: none).
    pub map_version: u64,
}

/// A compiled grid and what went into it.
pub struct GridCompiled {
    /// Its manifest (as written).
    pub manifest: Manifest,
    /// The plane of its lanes.
    pub plane: MapPlane,
    /// How the lanes were derived.
    pub geometry: LaneGeometry,
    /// What each input contributed, in input order.
    pub reports: Vec<InputReport>,
    /// Total lane length (metres).
    pub lane_length_m: f64,
    /// How the inputs were read.
    pub reading: Reading,
}

/// How a grid's inputs were read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Reading {
    /// Streamed: nodes and lanes on disk, memory bounded by a block of cells.
    Streamed,
    /// Read into memory, for the reason given (a person reads it).
    InMemory(String),
}

/// Side of a block of cells (metres) the streaming compiler aims at: memory follows the lanes
/// of one block per core.
const BLOCK_M: f64 = 2000.0;

/// Compiles `inputs` into a grid in folder `output` (see the module's documentation for which
/// inputs stream).
pub fn compile_grid(
    inputs: &[PathBuf],
    options: &CompileOptions,
    output: &Path,
    grid: &GridOptions,
) -> Result<GridCompiled, CompileError> {
    let reason = if inputs.iter().all(|p| is_pbf(p)) {
        match stream(inputs, options, output, grid)? {
            Ok(done) => return Ok(done),
            Err(reason) => reason,
        }
    } else {
        "an input is not PBF (XML is read in memory)".to_string()
    };
    let compiled = compile(inputs, options)?;
    let manifest = compiled.write_grid(
        output,
        options.lanes.spacing_m,
        grid.cell_size_m,
        grid.margin_m,
        grid.sign,
        grid.map_version,
    )?;
    Ok(GridCompiled {
        manifest,
        plane: compiled.plane,
        geometry: compiled.geometry,
        lane_length_m: compiled.map.lane_length_m(),
        reports: compiled.reports,
        reading: Reading::InMemory(reason),
    })
}

fn lane_error(dir: &Path) -> impl Fn(SpillError) -> CompileError + '_ {
    move |source| CompileError::LaneScratch {
        dir: dir.to_path_buf(),
        source,
    }
}

/// The streaming compile; `Ok(Err(why))` when an input cannot stream (a Lanelet2 map, or nodes
/// not sorted by id), with nothing written but the cells folder.
fn stream(
    inputs: &[PathBuf],
    options: &CompileOptions,
    output: &Path,
    grid: &GridOptions,
) -> Result<Result<GridCompiled, String>, CompileError> {
    let cells_dir = grid::create_cells_dir(output)?;
    let mut stores = Vec::with_capacity(inputs.len());
    let unsorted = |path: &Path, why: &dyn std::fmt::Display| {
        format!(
            "{}: {why} (`osmium sort` sorts it, so that it streams)",
            path.display()
        )
    };
    let mut bounds = NodeBounds::EMPTY;
    for path in inputs {
        let stored = match store_nodes(path, output)? {
            Ok(stored) => stored,
            Err(why) => return Ok(Err(unsorted(path, &why))),
        };
        bounds.join(stored.bounds);
        stores.push(stored);
    }
    let (lat, lon) = crate::compile::plane_origin(options.origin, || bounds.centre())?;
    let plane = MapPlane::new(options.projection, lat, lon);
    let block_cells = (BLOCK_M / grid.cell_size_m).round().clamp(1.0, 64.0) as i32;
    let mut spill = LaneSpill::new_in(output, grid.cell_size_m, grid.margin_m, block_cells);
    let mut reports = Vec::with_capacity(inputs.len());
    let all: Vec<&NodeStore> = stores.iter().map(|s| &s.store).collect();
    let mut earlier_roads = EarlierRoads::default();
    for (k, (path, stored)) in inputs.iter().zip(&stores).enumerate() {
        let input = StreamedInput {
            path,
            nodes: MergedNodes::new(&stored.store, &all),
            with_ways: &stored.with_ways,
            earlier_roads: &earlier_roads,
            keep_roads: k + 1 < inputs.len(),
        };
        match derive_streamed(&input, output, &plane, options, &mut spill)? {
            Derived::Lanes(report, roads) => {
                reports.push(InputReport::Osm(report));
                earlier_roads.add(roads);
            }
            Derived::Lanelet2 => return Ok(Err(format!("{} is a Lanelet2 map", path.display()))),
            Derived::Unsorted(why) => return Ok(Err(unsorted(path, &why))),
        }
    }
    drop(all);
    drop(stores);
    let mut spilled = spill.finish().map_err(lane_error(output))?;
    if spilled.summary.lanes == 0 {
        return Err(CompileError::NoLanes(
            inputs.iter().cloned().zip(reports).collect(),
        ));
    }
    let geometry = options.lanes.geometry();
    let spec = GridSpec {
        plane: &plane,
        spacing_m: options.lanes.spacing_m,
        geometry: &geometry,
        cell_size_m: grid.cell_size_m,
        margin_m: grid.margin_m,
        sign: grid.sign,
        map_version: grid.map_version,
    };
    let entries = cut_blocks(&mut spilled, &cells_dir, &spec, output)?;
    let manifest = grid::write_manifest(output, &spec, &spilled.summary, entries)?;
    Ok(Ok(GridCompiled {
        manifest,
        plane,
        geometry,
        reports,
        lane_length_m: spilled.length_m,
        reading: Reading::Streamed,
    }))
}

/// The first pass over one PBF input: its nodes into a store in `dir` (in file order, whatever
/// order the cores decode blocks in), their bounds (empty when it has none), and which blobs hold
/// ways. `Ok(Err(_))` when the nodes are not sorted by id.
fn store_nodes(
    path: &Path,
    dir: &Path,
) -> Result<Result<StoredNodes, NodeStoreError>, CompileError> {
    let writer = NodeWriter::new_in(dir).map_err(|e| node_error(dir, e))?;
    let order = Mutex::new(InOrder {
        writer,
        blobs: InFileOrder::default(),
        bounds: NodeBounds::EMPTY,
        unsorted: None,
        with_ways: Vec::new(),
    });
    let walked = for_each_blob(path, |k, blob| {
        let mut nodes = Vec::new();
        let mut ways = false;
        for_each_element(blob, |e| {
            match node_of(&e) {
                Some(node) => {
                    let (id, (lat, lon)) = node?;
                    nodes.push((id, lat, lon));
                }
                None => ways = true,
            }
            Ok(())
        })?;
        let mut order = order.lock().unwrap_or_else(PoisonError::into_inner);
        if ways {
            order.with_ways.push(k);
        }
        order.blobs.insert(k, nodes);
        order.write_ready().map_err(|e| e.to_string())?;
        match &order.unsorted {
            None => Ok(()),
            Some(e) => Err(e.to_string()),
        }
    });
    let mut order = order.into_inner().unwrap_or_else(PoisonError::into_inner);
    if let Some(unsorted) = order.unsorted {
        return Ok(Err(unsorted));
    }
    walked?;
    order.with_ways.sort_unstable();
    let store = order.writer.finish().map_err(|e| node_error(dir, e))?;
    Ok(Ok(StoredNodes {
        store,
        bounds: order.bounds,
        with_ways: order.with_ways,
    }))
}

/// What the first pass over one input keeps.
struct StoredNodes {
    /// Its nodes.
    store: NodeStore,
    /// Their bounds `[min lat, min lon, max lat, max lon]` (nanodegrees).
    bounds: NodeBounds,
    /// The blobs (by place in the file) that hold ways or relations, ascending: the second pass
    /// decodes only these.
    with_ways: Vec<u64>,
}

fn node_error(dir: &Path, source: NodeStoreError) -> CompileError {
    CompileError::NodeScratch {
        dir: dir.to_path_buf(),
        source,
    }
}

/// What the cores made of each blob, handed back in the blobs' file order.
struct InFileOrder<T> {
    next: u64,
    waiting: BTreeMap<u64, T>,
}

impl<T> Default for InFileOrder<T> {
    fn default() -> Self {
        InFileOrder {
            next: 0,
            waiting: BTreeMap::new(),
        }
    }
}

impl<T> InFileOrder<T> {
    /// What the cores made of blob `k` (0 for the file's first).
    fn insert(&mut self, k: u64, made: T) {
        self.waiting.insert(k, made);
    }

    /// The next blob's, once every blob before it has been handed back.
    fn next_ready(&mut self) -> Option<T> {
        let made = self.waiting.remove(&self.next)?;
        self.next += 1;
        Some(made)
    }
}

/// Blocks of nodes put back in file order for the store.
struct InOrder {
    writer: NodeWriter,
    blobs: InFileOrder<Vec<(i64, i64, i64)>>,
    bounds: NodeBounds,
    unsorted: Option<NodeStoreError>,
    with_ways: Vec<u64>,
}

impl InOrder {
    /// Appends every waiting block that is next in the file; after nodes out of order, only
    /// drops them.
    fn write_ready(&mut self) -> Result<(), NodeStoreError> {
        while let Some(nodes) = self.blobs.next_ready() {
            if self.unsorted.is_some() {
                continue;
            }
            for &(_, lat, lon) in &nodes {
                self.bounds.add(lat, lon);
            }
            match self.writer.append(&nodes) {
                Err(e @ NodeStoreError::Unsorted { .. }) => self.unsorted = Some(e),
                other => other?,
            }
        }
        Ok(())
    }
}

/// What the second pass over one input made.
enum Derived {
    /// Its lanes are in the spill, with what derivation did and its roads' ids (none for the
    /// last input).
    Lanes(DeriveReport, Vec<i64>),
    /// It is a Lanelet2 map (lanes come from relations, read in memory).
    Lanelet2,
    /// Its ways are not sorted by id (so the map's order cannot be kept as they stream).
    Unsorted(String),
}

/// The ways of one blob with lanes, in file order, its roads' ids, and what derivation did.
type BlobLanes = (Vec<(i64, Vec<Lane>)>, Vec<i64>, DeriveReport);

/// One input of the second pass.
struct StreamedInput<'a> {
    /// The file.
    path: &'a Path,
    /// Its nodes, then those of the other inputs.
    nodes: MergedNodes<'a, NodeStore>,
    /// Its blobs that hold ways or relations (from the first pass), ascending.
    with_ways: &'a [u64],
    /// The roads of the inputs before it.
    earlier_roads: &'a EarlierRoads,
    /// Whether inputs follow, which need its roads' ids.
    keep_roads: bool,
}

/// The second pass over one input: every way's lanes, derived on every core, into `spill` in
/// the whole map's order (ways by id, as the in-memory compile orders them); scratch files in
/// `dir`.
fn derive_streamed(
    input: &StreamedInput<'_>,
    dir: &Path,
    plane: &MapPlane,
    options: &CompileOptions,
    spill: &mut LaneSpill,
) -> Result<Derived, CompileError> {
    let order = Mutex::new(WaysInOrder {
        spill,
        blobs: InFileOrder::default(),
        last_way: None,
        roads: Vec::new(),
        report: DeriveReport::default(),
        stop: None,
    });
    let walked = for_each_blob(input.path, |k, blob| {
        let mut report = DeriveReport::default();
        if input.with_ways.binary_search(&k).is_err() {
            let mut order = order.lock().unwrap_or_else(PoisonError::into_inner);
            order.blobs.insert(k, (Vec::new(), Vec::new(), report));
            order.write_ready();
            return Ok(());
        }
        let mut ways = Vec::new();
        let mut roads = Vec::new();
        let mut lanes = Vec::new();
        for_each_element(blob, |e| {
            match e {
                Element::Way(w) => {
                    let way = way_of(&w);
                    if input.keep_roads {
                        roads.extend(EarlierRoads::id_of(&way, &options.lanes));
                    }
                    if input.earlier_roads.took(&way, &mut report) {
                        return Ok(());
                    }
                    derive_way_lanes(
                        &way,
                        &input.nodes,
                        plane,
                        &options.lanes,
                        &mut report,
                        &mut lanes,
                    );
                    if !lanes.is_empty() {
                        ways.push((way.id, std::mem::take(&mut lanes)));
                    }
                }
                // Read whole, as the in-memory reader does, so that a malformed member is
                // refused here too.
                Element::Relation(r) => {
                    if tag(&relation_of(&r).tags, "type") == Some("lanelet") {
                        return Err(LANELET2.into());
                    }
                }
                Element::Node(_) | Element::DenseNode(_) => {}
            }
            Ok(())
        })
        .map_err(|e| {
            if e == LANELET2 {
                order.lock().unwrap_or_else(PoisonError::into_inner).stop = Some(Stop::Lanelet2);
            }
            e
        })?;
        let mut order = order.lock().unwrap_or_else(PoisonError::into_inner);
        order.blobs.insert(k, (ways, roads, report));
        order.write_ready();
        match &order.stop {
            None => Ok(()),
            Some(stop) => Err(stop.to_string()),
        }
    });
    let order = order.into_inner().unwrap_or_else(PoisonError::into_inner);
    match order.stop {
        Some(Stop::Lanelet2) => return Ok(Derived::Lanelet2),
        Some(Stop::Unsorted(why)) => return Ok(Derived::Unsorted(why)),
        Some(Stop::Duplicate(way)) => {
            return Err(CompileError::DuplicateWay {
                path: input.path.to_path_buf(),
                way,
            })
        }
        Some(Stop::Spill(e)) => return Err(lane_error(dir)(e)),
        None => walked?,
    }
    Ok(Derived::Lanes(order.report, order.roads))
}

/// The message that stops the walk at a Lanelet2 relation.
const LANELET2: &str = "a Lanelet2 map";

/// Why the second pass stopped early.
#[derive(Debug)]
enum Stop {
    Lanelet2,
    Unsorted(String),
    Duplicate(i64),
    Spill(SpillError),
}

impl std::fmt::Display for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Stop::Lanelet2 => f.write_str(LANELET2),
            Stop::Unsorted(why) => f.write_str(why),
            Stop::Duplicate(way) => write!(f, "way {way} appears twice"),
            Stop::Spill(e) => write!(f, "{e}"),
        }
    }
}

/// Blobs of derived lanes put back in file order for the spill.
struct WaysInOrder<'a> {
    spill: &'a mut LaneSpill,
    blobs: InFileOrder<BlobLanes>,
    last_way: Option<i64>,
    roads: Vec<i64>,
    report: DeriveReport,
    stop: Option<Stop>,
}

impl WaysInOrder<'_> {
    /// Pushes every waiting blob that is next in the file into the spill, checking that ways
    /// ascend by id.
    fn write_ready(&mut self) {
        while let Some((ways, roads, report)) = self.blobs.next_ready() {
            self.report.add(&report);
            if self.stop.is_some() {
                continue;
            }
            self.roads.extend(roads);
            for (way, lanes) in ways {
                match self.last_way {
                    Some(last) if way == last => self.stop = Some(Stop::Duplicate(way)),
                    Some(last) if way < last => {
                        self.stop = Some(Stop::Unsorted(format!(
                            "way {way} follows way {last}: the ways are not sorted by id"
                        )))
                    }
                    _ => {}
                }
                if self.stop.is_some() {
                    break;
                }
                self.last_way = Some(way);
                for lane in &lanes {
                    if let Err(e) = self.spill.push(lane) {
                        self.stop = Some(Stop::Spill(e));
                        return;
                    }
                }
            }
        }
    }
}

/// Cuts the cells of every block `spilled` hands out, on every core, and writes them into
/// `cells_dir`; returns their manifest entries. The blocks are merged from disk on this thread
/// and handed to the cutters through a queue of a block per core, so memory holds a few blocks.
fn cut_blocks(
    spilled: &mut SpilledLanes,
    cells_dir: &Path,
    spec: &GridSpec,
    output: &Path,
) -> Result<Vec<CellEntry>, CompileError> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let (send, receive) = std::sync::mpsc::sync_channel::<BlockLanes>(threads);
    let receive = Mutex::new(receive);
    let block_cells = spilled.block_cells();
    std::thread::scope(|scope| {
        let cutters: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut entries = Vec::new();
                    let mut failed = None;
                    loop {
                        let next = receive
                            .lock()
                            .unwrap_or_else(PoisonError::into_inner)
                            .recv();
                        let Ok((block, lanes)) = next else { break };
                        if failed.is_some() {
                            continue;
                        }
                        match cut_block(block, &lanes, block_cells, cells_dir, spec) {
                            Ok(cut) => entries.extend(cut),
                            Err(e) => failed = Some(e),
                        }
                    }
                    failed.map_or(Ok(entries), Err)
                })
            })
            .collect();
        let fed = (|| {
            while let Some(block) = spilled.next_block().map_err(lane_error(output))? {
                if send.send(block).is_err() {
                    break;
                }
            }
            Ok::<(), CompileError>(())
        })();
        drop(send);
        let mut all = Vec::new();
        for cutter in cutters {
            all.extend(
                cutter
                    .join()
                    .unwrap_or_else(|p| std::panic::resume_unwind(p))?,
            );
        }
        fed.map(|()| all)
    })
}

/// The cells of block `block` (of `block_cells` cells a side) cut from the lanes that reach it,
/// written into `cells_dir`.
fn cut_block(
    block: BlockKey,
    lanes: &[(u32, Lane)],
    block_cells: i32,
    cells_dir: &Path,
    spec: &GridSpec,
) -> Result<Vec<CellEntry>, CompileError> {
    let ordered = lanes
        .iter()
        .map(|(ordinal, lane)| -> OrderedLane { (*ordinal, lane.id, lane.info, &lane.points) });
    let in_block = |key: CellKey| key.map(|k| k.div_euclid(block_cells)) == block;
    let cells = partition_lanes(ordered, spec.cell_size_m, spec.margin_m, in_block)?;
    Ok(grid::write_cells(cells_dir, &cells, spec)?)
}
