//! Node locations on disk, for compiling inputs larger than memory. Written by hand: the
//! stores that keep node locations for OSM tools (osmium's indexes) are C++, and the one this
//! needs is a sorted file and a small index.
//!
//! Nodes arrive in ascending id order (as every sorted PBF holds them: planet files, Geofabrik
//! extracts, `osmium sort` output) and are appended as 16-byte records: id (64-bit), latitude
//! and longitude in 1e-7 degrees (32-bit; OSM's own precision, so a position reads back exactly
//! as the in-memory reader holds it), little-endian. Memory holds the first id of every chunk of
//! [`CHUNK`] records (half a byte per node); a lookup reads one chunk (4 KiB).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;

use crate::osm::NodePositions;

/// Records per chunk: a lookup reads `16 CHUNK` bytes.
pub const CHUNK: usize = 256;
const RECORD: usize = 16;

/// Why nodes could not be stored.
#[derive(Debug, thiserror::Error)]
pub enum NodeStoreError {
    /// The scratch file could not be written.
    #[error("the scratch file of node locations: {0}")]
    Io(#[from] std::io::Error),
    /// A node's id is not above the one before it: the input is not sorted by id.
    #[error("node {id} follows node {previous}: the nodes are not sorted by id")]
    Unsorted {
        /// The node's id.
        id: i64,
        /// The id before it.
        previous: i64,
    },
}

/// Nodes being written, in ascending id order.
pub struct NodeWriter {
    file: BufWriter<File>,
    firsts: Vec<i64>,
    count: usize,
    last: Option<i64>,
}

impl NodeWriter {
    /// An empty store whose unnamed file (removed by the system when the store is dropped or
    /// the process dies) lives in folder `dir`.
    pub fn new_in(dir: &Path) -> Result<NodeWriter, NodeStoreError> {
        Ok(NodeWriter {
            file: BufWriter::with_capacity(1 << 20, tempfile::tempfile_in(dir)?),
            firsts: Vec::new(),
            count: 0,
            last: None,
        })
    }

    /// Appends `nodes`: `(id, lat, lon)` with coordinates in nanodegrees, multiples of 100
    /// (quantised as the readers do), every id above the last one appended.
    pub fn append(&mut self, nodes: &[(i64, i64, i64)]) -> Result<(), NodeStoreError> {
        for &(id, lat, lon) in nodes {
            if let Some(previous) = self.last.filter(|&p| id <= p) {
                return Err(NodeStoreError::Unsorted { id, previous });
            }
            if self.count.is_multiple_of(CHUNK) {
                self.firsts.push(id);
            }
            let mut record = [0u8; RECORD];
            record[..8].copy_from_slice(&id.to_le_bytes());
            record[8..12].copy_from_slice(&((lat / 100) as i32).to_le_bytes());
            record[12..].copy_from_slice(&((lon / 100) as i32).to_le_bytes());
            self.file.write_all(&record)?;
            self.count += 1;
            self.last = Some(id);
        }
        Ok(())
    }

    /// Every node appended: the store to look them up in.
    pub fn finish(self) -> Result<NodeStore, NodeStoreError> {
        let file = self.file.into_inner().map_err(|e| e.into_error())?;
        Ok(NodeStore {
            file,
            firsts: self.firsts,
            count: self.count,
        })
    }
}

/// Node locations by id, on disk.
pub struct NodeStore {
    file: File,
    firsts: Vec<i64>,
    count: usize,
}

impl NodeStore {
    /// Node `id`'s `(lat, lon)` in nanodegrees, `None` when the input had no such node (or the
    /// scratch file cannot be read, which the next write would have reported).
    pub fn get(&self, id: i64) -> Option<(i64, i64)> {
        let chunk = self
            .firsts
            .partition_point(|&first| first <= id)
            .checked_sub(1)?;
        let records = CHUNK.min(self.count - chunk * CHUNK);
        let mut bytes = [0u8; CHUNK * RECORD];
        let bytes = &mut bytes[..records * RECORD];
        self.file
            .read_exact_at(bytes, (chunk * CHUNK * RECORD) as u64)
            .ok()?;
        let id_of = |k: usize| {
            let at = k * RECORD;
            i64::from_le_bytes(bytes[at..at + 8].try_into().unwrap_or_default())
        };
        let (mut lo, mut hi) = (0, records);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if id_of(mid) < id {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        (lo < records && id_of(lo) == id).then(|| {
            let at = lo * RECORD + 8;
            let coordinate =
                |b: &[u8]| i64::from(i32::from_le_bytes(b.try_into().unwrap_or_default())) * 100;
            (
                coordinate(&bytes[at..at + 4]),
                coordinate(&bytes[at + 4..at + 8]),
            )
        })
    }
}

impl NodePositions for NodeStore {
    fn position(&self, id: i64) -> Option<(f64, f64)> {
        self.get(id)
            .map(|(lat, lon)| (lat as f64 / 1e9, lon as f64 / 1e9))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_read_back_exactly_and_absent_ids_are_absent() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = NodeWriter::new_in(dir.path()).unwrap();
        let mut nodes = vec![
            (i64::MIN, -90_000_000_000, -180_000_000_000),
            (-7, 100, 200),
            (0, 0, 0),
            (i64::MAX, 90_000_000_000, 180_000_000_000),
        ];
        // Enough nodes for several chunks, with gaps.
        nodes.extend(
            (0..1000).map(|k| (3 * k + 5, 49_012_345_600 + k * 100, 8_401_234_500 - k * 100)),
        );
        nodes.sort_unstable();
        for part in nodes.chunks(300) {
            writer.append(part).unwrap();
        }
        let store = writer.finish().unwrap();
        for &(id, lat, lon) in &nodes {
            assert_eq!(store.get(id), Some((lat, lon)), "node {id}");
        }
        for id in [1, 4, 6, 7, 3004, 3005, i64::MAX - 1, -8, -1] {
            assert_eq!(store.get(id), None, "node {id} was never stored");
        }
    }

    #[test]
    fn an_unsorted_or_repeated_id_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = NodeWriter::new_in(dir.path()).unwrap();
        writer.append(&[(10, 0, 0), (12, 0, 0)]).unwrap();
        for id in [12, 11] {
            let err = writer.append(&[(id, 0, 0)]).unwrap_err();
            assert!(
                matches!(err, NodeStoreError::Unsorted { previous: 12, .. }),
                "{err}"
            );
        }
    }
}
