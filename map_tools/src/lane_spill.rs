//! Derived lanes on disk while a grid compiles, sorted by the block of cells they reach: an
//! external merge sort (written by hand: the crates for it sort serde values, and this needs
//! the block and the lane's place in the map as the key and nothing more).
//!
//! A block is a square of `block_cells` x `block_cells` grid cells. Lanes arrive in the whole
//! map's order and are numbered as they come; a lane is recorded once per block it reaches.
//! Records gather in a buffer of [`RUN_BYTES`]; a full buffer is sorted by (block, lane number)
//! and written as a run to an unnamed scratch file. Reading merges the runs and hands out one
//! block's lanes at a time. Memory holds one buffer, one record per run and the block handed out,
//! whatever the size of the map.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, Write};
use std::path::{Path, PathBuf};

use lanealign_core::grid::{cells_near, MapSummary};
use lanealign_core::lane_geometry::{LaneInfo, RoadClass};
use lanealign_core::lane_map::{polyline_length_m, Lane, MAX_POINTS};

/// A block's index: it holds cells `[x b, (x + 1) b) x [y b, (y + 1) b)` (`b` cells a side).
pub type BlockKey = [i32; 2];

/// Bytes of records gathered before they are sorted and written as a run.
pub const RUN_BYTES: usize = 32 << 20;

/// Scratch files that failed.
#[derive(Debug, thiserror::Error)]
pub enum SpillError {
    /// A scratch file could not be written or read.
    #[error("the scratch file of derived lanes: {0}")]
    Io(#[from] std::io::Error),
    /// A record read back is not what was written (a scratch file changed under the compile).
    #[error("a lane record in the scratch files is damaged")]
    Damaged,
    /// More lanes or points than a lane map holds.
    #[error("the map has more than {MAX_POINTS} lane points")]
    TooLarge,
}

/// Lanes being written, in the whole map's order; [`finish`](LaneSpill::finish) sorts them by
/// block.
pub struct LaneSpill {
    dir: PathBuf,
    runs: Vec<Vec<File>>,
    buffer: Vec<u8>,
    index: Vec<(BlockKey, u32, usize)>,
    lanes: u32,
    summary: MapSummary,
    length_m: f64,
    cell_size_m: f64,
    margin_m: f64,
    block_cells: i32,
    blocks: Vec<BlockKey>,
    record: Vec<u8>,
}

/// Bytes of a record before its points: block x and y, lane number (32-bit), lane id (64-bit),
/// class code, flags (8-bit), point count (32-bit); little-endian. Then x and y of each point
/// (64-bit floats, metres).
const HEADER: usize = 4 + 4 + 4 + 8 + 1 + 1 + 4;

impl LaneSpill {
    /// An empty spill whose scratch files live in folder `dir`, for cells of `cell_size_m`
    /// holding lanes within `margin_m`, cut in blocks of `block_cells` a side.
    pub fn new_in(dir: &Path, cell_size_m: f64, margin_m: f64, block_cells: i32) -> LaneSpill {
        LaneSpill {
            dir: dir.to_path_buf(),
            runs: Vec::new(),
            buffer: Vec::new(),
            index: Vec::new(),
            lanes: 0,
            summary: MapSummary::empty(),
            length_m: 0.0,
            cell_size_m,
            margin_m,
            block_cells: block_cells.max(1),
            blocks: Vec::new(),
            record: Vec::new(),
        }
    }

    /// Adds the next lane of the whole map's order; a lane without points is no lane (as in a
    /// lane map) and is skipped.
    pub fn push(&mut self, lane: &Lane) -> Result<(), SpillError> {
        if lane.points.is_empty() {
            return Ok(());
        }
        if self.summary.points + lane.points.len() as u64 > MAX_POINTS as u64 {
            return Err(SpillError::TooLarge);
        }
        let ordinal = self.lanes;
        self.lanes += 1;
        self.record.clear();
        self.record.extend_from_slice(&ordinal.to_le_bytes());
        self.record.extend_from_slice(&lane.id.to_le_bytes());
        self.record.push(lane.info.class as u8);
        self.record.push(lane.info.flags);
        self.record
            .extend_from_slice(&(lane.points.len() as u32).to_le_bytes());
        for p in &lane.points {
            self.record.extend_from_slice(&p[0].to_le_bytes());
            self.record.extend_from_slice(&p[1].to_le_bytes());
        }
        self.blocks.clear();
        let b = self.block_cells;
        for p in &lane.points {
            let [[x0, x1], [y0, y1]] = cells_near(*p, self.cell_size_m, self.margin_m);
            for bx in x0.div_euclid(b)..=x1.div_euclid(b) {
                for by in y0.div_euclid(b)..=y1.div_euclid(b) {
                    self.blocks.push([bx, by]);
                }
            }
        }
        self.blocks.sort_unstable();
        self.blocks.dedup();
        for &block in &self.blocks {
            self.index.push((block, ordinal, self.buffer.len()));
            self.buffer.extend_from_slice(&block[0].to_le_bytes());
            self.buffer.extend_from_slice(&block[1].to_le_bytes());
            self.buffer.extend_from_slice(&self.record);
        }
        self.summary.add(&lane.points);
        self.length_m += polyline_length_m(&lane.points);
        if self.buffer.len() >= RUN_BYTES {
            self.write_run()?;
        }
        Ok(())
    }

    /// Sorts the buffer's records by (block, lane number) and writes them as a run.
    fn write_run(&mut self) -> Result<(), SpillError> {
        self.index
            .sort_unstable_by_key(|&(block, ordinal, _)| (block, ordinal));
        let mut run = BufWriter::with_capacity(1 << 20, tempfile::tempfile_in(&self.dir)?);
        for &(_, _, start) in &self.index {
            let n = u32::from_le_bytes(record_field(&self.buffer[start..], 22)) as usize;
            run.write_all(&self.buffer[start..start + HEADER + 16 * n])?;
        }
        self.buffer.clear();
        self.index.clear();
        self.add_run(0, finished(run)?)
    }

    /// Adds a run at `level`; [`FAN_IN`] runs of one level are merged into one of the next, so
    /// that no merge reads from more than [`FAN_IN`] files a level.
    fn add_run(&mut self, level: usize, run: File) -> Result<(), SpillError> {
        if self.runs.len() <= level {
            self.runs.resize_with(level + 1, Vec::new);
        }
        self.runs[level].push(run);
        if self.runs[level].len() < FAN_IN {
            return Ok(());
        }
        let mut merge = Merge::new(std::mem::take(&mut self.runs[level]))?;
        let mut merged = BufWriter::with_capacity(1 << 20, tempfile::tempfile_in(&self.dir)?);
        while let Some(record) = merge.next()? {
            merged.write_all(&record.bytes)?;
        }
        self.add_run(level + 1, finished(merged)?)
    }

    /// Every lane pushed: the lanes by block.
    pub fn finish(mut self) -> Result<SpilledLanes, SpillError> {
        if !self.index.is_empty() {
            self.write_run()?;
        }
        Ok(SpilledLanes {
            merge: Merge::new(self.runs.into_iter().flatten().collect())?,
            summary: self.summary,
            length_m: self.length_m,
            block_cells: self.block_cells,
        })
    }
}

/// Runs merged at once at most: the merge holds a read buffer of `READ_BYTES` per run.
pub const FAN_IN: usize = 64;
const READ_BYTES: usize = 64 << 10;

/// A written run, rewound for reading.
fn finished(run: BufWriter<File>) -> Result<File, SpillError> {
    let mut file = run.into_inner().map_err(|e| e.into_error())?;
    file.rewind()?;
    Ok(file)
}

/// Four bytes of a record at `at`.
fn record_field(record: &[u8], at: usize) -> [u8; 4] {
    let mut field = [0; 4];
    field.copy_from_slice(&record[at..at + 4]);
    field
}

/// One record as a run holds it, with its sort key.
struct Record {
    block: BlockKey,
    ordinal: u32,
    bytes: Vec<u8>,
}

/// The next record of a run, `None` at its end.
fn read_record(reader: &mut impl Read) -> Result<Option<Record>, SpillError> {
    let mut bytes = vec![0u8; HEADER];
    let mut got = 0;
    while got < HEADER {
        match reader.read(&mut bytes[got..])? {
            0 if got == 0 => return Ok(None),
            0 => return Err(SpillError::Damaged),
            n => got += n,
        }
    }
    let n = u32::from_le_bytes(record_field(&bytes, 22)) as usize;
    if n > MAX_POINTS {
        return Err(SpillError::Damaged);
    }
    bytes.resize(HEADER + 16 * n, 0);
    reader.read_exact(&mut bytes[HEADER..])?;
    Ok(Some(Record {
        block: [
            i32::from_le_bytes(record_field(&bytes, 0)),
            i32::from_le_bytes(record_field(&bytes, 4)),
        ],
        ordinal: u32::from_le_bytes(record_field(&bytes, 8)),
        bytes,
    }))
}

/// The lane a record holds.
fn lane_of(record: &Record) -> Result<Lane, SpillError> {
    let b = &record.bytes;
    let mut id = [0u8; 8];
    id.copy_from_slice(&b[12..20]);
    let class = RoadClass::from_code(b[20]).ok_or(SpillError::Damaged)?;
    let points = b[HEADER..]
        .chunks_exact(16)
        .map(|c| {
            let (mut x, mut y) = ([0u8; 8], [0u8; 8]);
            x.copy_from_slice(&c[..8]);
            y.copy_from_slice(&c[8..]);
            [f64::from_le_bytes(x), f64::from_le_bytes(y)]
        })
        .collect();
    Ok(Lane {
        id: u64::from_le_bytes(id),
        info: LaneInfo::new(class, b[21]),
        points,
    })
}

/// Runs read together in (block, lane number) order.
struct Merge {
    runs: Vec<(BufReader<File>, Option<Record>)>,
    heads: BinaryHeap<Reverse<(BlockKey, u32, usize)>>,
}

impl Merge {
    fn new(files: Vec<File>) -> Result<Merge, SpillError> {
        let mut merge = Merge {
            runs: Vec::with_capacity(files.len()),
            heads: BinaryHeap::new(),
        };
        for file in files {
            let mut reader = BufReader::with_capacity(READ_BYTES, file);
            let head = read_record(&mut reader)?;
            if let Some(r) = &head {
                merge
                    .heads
                    .push(Reverse((r.block, r.ordinal, merge.runs.len())));
            }
            merge.runs.push((reader, head));
        }
        Ok(merge)
    }

    /// The block of the next record.
    fn next_block(&self) -> Option<BlockKey> {
        self.heads.peek().map(|Reverse((block, _, _))| *block)
    }

    /// The next record, `None` after the last.
    fn next(&mut self) -> Result<Option<Record>, SpillError> {
        let Some(Reverse((_, _, k))) = self.heads.pop() else {
            return Ok(None);
        };
        let (reader, head) = &mut self.runs[k];
        let next = read_record(reader)?;
        if let Some(r) = &next {
            self.heads.push(Reverse((r.block, r.ordinal, k)));
        }
        Ok(std::mem::replace(head, next))
    }
}

/// Every lane on disk in sorted runs, handed out one block at a time.
pub struct SpilledLanes {
    merge: Merge,
    /// Lanes, points and bounds of the whole map.
    pub summary: MapSummary,
    /// Total lane length (metres).
    pub length_m: f64,
    block_cells: i32,
}

/// One block's lanes, each with its number in the whole map's order, in that order.
pub type BlockLanes = (BlockKey, Vec<(u32, Lane)>);

impl SpilledLanes {
    /// The next block (in `(x, y)` order) and the lanes that reach it; `None` after the last.
    pub fn next_block(&mut self) -> Result<Option<BlockLanes>, SpillError> {
        let Some(block) = self.merge.next_block() else {
            return Ok(None);
        };
        let mut lanes = Vec::new();
        while self.merge.next_block() == Some(block) {
            if let Some(record) = self.merge.next()? {
                lanes.push((record.ordinal, lane_of(&record)?));
            }
        }
        Ok(Some((block, lanes)))
    }

    /// Cells a side of a block.
    pub fn block_cells(&self) -> i32 {
        self.block_cells
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn lane(id: u64, points: &[[f64; 2]]) -> Lane {
        Lane::new(id, points.to_vec())
    }

    #[test]
    fn blocks_come_out_in_order_with_their_lanes_in_map_order_across_runs() {
        let dir = tempfile::tempdir().unwrap();
        // 100 m cells, no margin, 2 cells a block: blocks are 200 m squares.
        let mut spill = LaneSpill::new_in(dir.path(), 100.0, 0.0, 2);
        let lanes = [
            lane(7, &[[10.0, 10.0], [450.0, 10.0]]),
            lane(3, &[]),
            lane(9, &[[250.0, 10.0]]),
            lane(1, &[[-10.0, 10.0], [10.0, 10.0]]),
        ];
        // A run per lane, and more runs than one merge reads: the merges do the sorting.
        let pushed: Vec<&Lane> = lanes.iter().cycle().take(4 * FAN_IN + 3).collect();
        for l in &pushed {
            spill.push(l).unwrap();
            spill.write_run().unwrap();
        }
        let mut spilled = spill.finish().unwrap();
        let mut got = Vec::new();
        while let Some((block, lanes)) = spilled.next_block().unwrap() {
            let lanes = lanes.iter().map(|(o, l)| (*o, l.id)).collect::<Vec<_>>();
            got.push((block, lanes));
        }
        // Lane 7 reaches blocks x -1 to 2 (its points are 10 m and 450 m east, each reaching
        // into the cell before its own), 9 blocks 0 and 1, lane 1 blocks -1 and 0; all y -1, 0.
        let blocks_of = |id: u64| -> Vec<BlockKey> {
            let xs: &[i32] = match id {
                7 => &[-1, 0, 1, 2],
                9 => &[0, 1],
                _ => &[-1, 0],
            };
            xs.iter().flat_map(|&x| [[x, -1], [x, 0]]).collect()
        };
        let mut expected: BTreeMap<BlockKey, Vec<(u32, u64)>> = BTreeMap::new();
        let mut ordinal = 0;
        for l in pushed.iter().filter(|l| !l.points.is_empty()) {
            for block in blocks_of(l.id) {
                expected.entry(block).or_default().push((ordinal, l.id));
            }
            ordinal += 1;
        }
        assert_eq!(
            spilled.summary.lanes,
            u64::from(ordinal),
            "empty lanes are no lanes"
        );
        assert_eq!(got, expected.into_iter().collect::<Vec<_>>());
    }
}
