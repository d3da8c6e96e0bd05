//! OSM PBF (`.osm.pbf`) reading with the `osmpbf` crate, decoding blocks on all cores.

use std::path::{Path, PathBuf};

use osmpbf::{BlobDecode, BlobReader, Element, RelMemberType};
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

fn add_element(d: &mut OsmData, e: Element<'_>) {
    let tags = |it: &mut dyn Iterator<Item = (&str, &str)>| -> Vec<(String, String)> {
        it.map(|(k, v)| (k.to_string(), v.to_string())).collect()
    };
    match e {
        Element::Node(n) => {
            d.nodes
                .insert(n.id(), (quantise(n.nano_lat()), quantise(n.nano_lon())));
        }
        Element::DenseNode(n) => {
            d.nodes
                .insert(n.id(), (quantise(n.nano_lat()), quantise(n.nano_lon())));
        }
        Element::Way(w) => d.ways.push(Way {
            id: w.id(),
            nodes: w.refs().collect(),
            tags: tags(&mut w.tags()),
        }),
        Element::Relation(r) => d.relations.push(Relation {
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
            tags: tags(&mut r.tags()),
        }),
    }
}

/// Reads a PBF file; ways and relations come out ordered by id (see [`OsmData::sort`]).
pub fn read_pbf_file(path: &Path) -> Result<OsmData, PbfError> {
    let err = |e: osmpbf::Error| PbfError {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let blobs = BlobReader::from_path(path).map_err(err)?;
    let mut data = blobs
        .par_bridge()
        .map(|blob| {
            let mut block_data = OsmData::default();
            if let BlobDecode::OsmData(block) = blob?.decode()? {
                for e in block.elements() {
                    add_element(&mut block_data, e);
                }
            }
            Ok(block_data)
        })
        .try_reduce(OsmData::default, |mut a, b| {
            a.merge(b);
            Ok(a)
        })
        .map_err(err)?;
    data.sort();
    Ok(data)
}
