//! OSM PBF (`.osm.pbf`) reading with the `osmpbf` crate, decoding blocks on all cores.

use std::io::Read;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};

use lanealign_core::input::open_regular;
use osmpbf::{Blob, BlobDecode, BlobReader, Element, RelMemberType};
use rayon::iter::{ParallelBridge, ParallelIterator};

use crate::osm::{Member, OsmData, Relation, Way};

/// A PBF file that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct PbfError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

/// Nanodegrees quantised to OSM's 1e-7 degrees, as the XML reader does (PBF files written with a
/// finer granularity than the default are rounded the same way).
fn quantise(nano: i64) -> i64 {
    (nano as f64 / 100.0).round() as i64 * 100
}

/// A node's coordinates in nanodegrees, quantised; `Err` names the node when they are outside
/// WGS84 (latitude within ±90°, longitude within ±180°).
fn node_position(id: i64, nano_lat: i64, nano_lon: i64) -> Result<(i64, i64), String> {
    if nano_lat.abs() > 90_000_000_000 || nano_lon.abs() > 180_000_000_000 {
        return Err(format!(
            "node {id}: coordinates out of range ({}, {})",
            nano_lat as f64 / 1e9,
            nano_lon as f64 / 1e9
        ));
    }
    Ok((quantise(nano_lat), quantise(nano_lon)))
}

fn add_element(d: &mut OsmData, e: Element<'_>) -> Result<(), String> {
    match e {
        Element::Way(w) => d.ways.push(way_of(&w)),
        Element::Relation(r) => d.relations.push(relation_of(&r)),
        node => {
            if let Some(n) = node_of(&node) {
                let (id, at) = n?;
                d.add_node(id, at)
                    .map_err(|first| crate::osm::node_twice(id, first, at))?;
            }
        }
    }
    Ok(())
}

/// A node's id and `(lat, lon)` (nanodegrees, quantised).
pub(crate) type NodeAt = (i64, (i64, i64));

/// A node element's id and position (`Err` outside WGS84); `None` for a way or relation.
pub(crate) fn node_of(e: &Element<'_>) -> Option<Result<NodeAt, String>> {
    let (id, lat, lon) = match e {
        Element::Node(n) => (n.id(), n.nano_lat(), n.nano_lon()),
        Element::DenseNode(n) => (n.id(), n.nano_lat(), n.nano_lon()),
        Element::Way(_) | Element::Relation(_) => return None,
    };
    Some(node_position(id, lat, lon).map(|at| (id, at)))
}

fn tags_of<'a>(tags: impl Iterator<Item = (&'a str, &'a str)>) -> Vec<(String, String)> {
    tags.map(|(k, v)| (k.to_string(), v.to_string())).collect()
}

/// A way element as the readers keep it.
pub(crate) fn way_of(w: &osmpbf::Way<'_>) -> Way {
    Way {
        id: w.id(),
        nodes: w.refs().collect(),
        tags: tags_of(w.tags()),
    }
}

/// A relation element as the readers keep it (osmpbf panics on some malformed members: callers
/// decode within [`for_each_element`], which turns that into an error).
pub(crate) fn relation_of(r: &osmpbf::Relation<'_>) -> Relation {
    Relation {
        id: r.id(),
        members: r
            .members()
            .map(|m| Member {
                kind: match m.member_type {
                    RelMemberType::Node => "node",
                    RelMemberType::Way => "way",
                    RelMemberType::Relation => "relation",
                }
                .to_string(),
                id: m.member_id,
                role: m.role().unwrap_or_default().to_string(),
            })
            .collect(),
        tags: tags_of(r.tags()),
    }
}

/// The elements of one blob.
fn decode_block(blob: &Blob) -> Result<OsmData, String> {
    let mut block_data = OsmData::default();
    for_each_element(blob, |e| add_element(&mut block_data, e))?;
    Ok(block_data)
}

/// Calls `visit` with every element of one blob (none for a header blob). osmpbf 0.3.8 panics
/// on some malformed blocks (an unknown relation member type unwraps a protobuf enum, found by
/// fuzzing): such a block is an error like any other.
pub(crate) fn for_each_element(
    blob: &Blob,
    mut visit: impl FnMut(Element<'_>) -> Result<(), String>,
) -> Result<(), String> {
    std::panic::catch_unwind(AssertUnwindSafe(|| {
        if let BlobDecode::OsmData(block) = blob.decode().map_err(|e| e.to_string())? {
            for e in block.elements() {
                visit(e)?;
            }
        }
        Ok(())
    }))
    .unwrap_or_else(|payload| {
        let why = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("no message");
        Err(format!(
            "a malformed data block (the PBF decoder failed: {why})"
        ))
    })
}

/// Calls `visit` with every blob of the PBF file at `path` (a regular file) and its place in the
/// file (0 for the first), on every core, in no particular order; the first error stops the
/// walk.
pub(crate) fn for_each_blob(
    path: &Path,
    visit: impl Fn(u64, &Blob) -> Result<(), String> + Sync,
) -> Result<(), PbfError> {
    let err = |message: String| PbfError {
        path: path.to_path_buf(),
        message,
    };
    let file = open_regular(path).map_err(|e| err(e.to_string()))?;
    BlobReader::new(std::io::BufReader::new(file))
        .zip(0u64..)
        .par_bridge()
        .try_for_each(|(blob, k)| visit(k, &blob.map_err(|e| e.to_string())?))
        .map_err(err)
}

/// Reads a PBF file (regular files only); ways and relations come out ordered by id (see
/// [`OsmData::sort`]).
pub fn read_pbf_file(path: &Path) -> Result<OsmData, PbfError> {
    let file = open_regular(path).map_err(|e| PbfError {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    read_pbf(std::io::BufReader::new(file), path)
}

/// Reads PBF from any reader; `path` names the source in errors.
pub fn read_pbf<R: Read + Send>(input: R, path: &Path) -> Result<OsmData, PbfError> {
    let err = |message: String| PbfError {
        path: path.to_path_buf(),
        message,
    };
    let blobs = BlobReader::new(input);
    let mut data = blobs
        .par_bridge()
        .map(|blob| decode_block(&blob.map_err(|e| e.to_string())?))
        .try_reduce(OsmData::default, |mut a, b| {
            a.merge(b)?;
            Ok(a)
        })
        .map_err(err)?;
    data.sort();
    Ok(data)
}
