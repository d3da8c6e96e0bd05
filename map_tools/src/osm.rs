//! Streaming reader for OpenStreetMap XML (`.osm`, API 0.6): nodes, ways and relations with
//! their tags. Lanelet2 maps are OSM XML too and are read by the same code.

use std::collections::HashMap;
use std::io::BufRead;
use std::path::{Path, PathBuf};

use quick_xml::events::{BytesStart, Event};
use quick_xml::{Reader, XmlVersion};

/// OSM tags of one element, in file order.
pub type Tags = Vec<(String, String)>;

/// Looks up a tag's value.
pub fn tag<'a>(tags: &'a Tags, key: &str) -> Option<&'a str> {
    tags.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

/// An OSM way: an ordered list of node references with tags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Way {
    /// OSM id.
    pub id: i64,
    /// Node ids in order.
    pub nodes: Vec<i64>,
    /// Tags.
    pub tags: Tags,
}

/// One member of a relation.
#[derive(Clone, Debug, PartialEq)]
pub struct Member {
    /// `node`, `way` or `relation`.
    pub kind: String,
    /// The member's id.
    pub id: i64,
    /// Its role (`left`, `right`, `centerline`, ...).
    pub role: String,
}

/// An OSM relation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Relation {
    /// OSM id.
    pub id: i64,
    /// Members in order.
    pub members: Vec<Member>,
    /// Tags.
    pub tags: Tags,
}

/// The elements of one OSM file.
#[derive(Clone, Debug, Default)]
pub struct OsmData {
    /// Node id to `(lat, lon)` in integer nanodegrees (WGS84), quantised to OSM's own precision
    /// of 1e-7 degrees (about 1 cm), so that XML and PBF readers give bit-identical positions.
    pub nodes: HashMap<i64, (i64, i64)>,
    /// Ways in file order.
    pub ways: Vec<Way>,
    /// Relations in file order.
    pub relations: Vec<Relation>,
}

/// Where nodes are: in memory ([`OsmData`]) or in a store on disk.
pub trait NodePositions {
    /// Node `id`'s `(lat, lon)` in degrees (WGS84), `None` when it is unknown.
    fn position(&self, id: i64) -> Option<(f64, f64)>;
}

/// The node positions of several OSM inputs merged: a way's own input first, then the others in
/// input order, so that a way cut at one extract's border finds its nodes in the extract beside
/// it (OSM's ids are one space: a node id means the same node in every extract). A negative id
/// is an object an editor made and never uploaded (JOSM numbers them -1, -2, ... in each file):
/// it is looked up in its own input only.
pub struct MergedNodes<'a, N> {
    order: Vec<&'a N>,
}

impl<'a, N> MergedNodes<'a, N> {
    /// `own` first, then the rest of `all` (every OSM input, in input order; `own` among them).
    pub fn new(own: &'a N, all: &[&'a N]) -> Self {
        let others = all.iter().copied().filter(|n| !std::ptr::eq(*n, own));
        MergedNodes {
            order: std::iter::once(own).chain(others).collect(),
        }
    }
}

impl<N: NodePositions> NodePositions for MergedNodes<'_, N> {
    fn position(&self, id: i64) -> Option<(f64, f64)> {
        let inputs = if is_shared_id(id) {
            self.order.len()
        } else {
            1
        };
        self.order[..inputs]
            .iter()
            .find_map(|nodes| nodes.position(id))
    }
}

/// Whether an OSM id names one object in every file: a positive id is the OSM database's; a
/// negative one an editor's, local to its file.
pub fn is_shared_id(id: i64) -> bool {
    id > 0
}

impl NodePositions for OsmData {
    fn position(&self, id: i64) -> Option<(f64, f64)> {
        self.position(id)
    }
}

impl OsmData {
    /// A node's `(lat, lon)` in degrees.
    pub fn position(&self, id: i64) -> Option<(f64, f64)> {
        self.nodes
            .get(&id)
            .map(|&(lat, lon)| (lat as f64 / 1e9, lon as f64 / 1e9))
    }

    /// Orders ways and relations by id, so that everything derived from the data is
    /// independent of the order a reader met them in.
    pub fn sort(&mut self) {
        self.ways.sort_by_key(|w| w.id);
        self.relations.sort_by_key(|r| r.id);
    }

    /// Adds node `id` at `(lat, lon)` (nanodegrees). A node met again at the same position is
    /// taken once; at another position it is refused, `Err` holding the first position (the map
    /// would depend on which a reader met last, and a PBF's blocks are met in no fixed order).
    pub fn add_node(&mut self, id: i64, at: (i64, i64)) -> Result<(), (i64, i64)> {
        match self.nodes.insert(id, at) {
            Some(first) if first != at => Err(first),
            _ => Ok(()),
        }
    }

    /// Adds the elements of another part of the same file; `Err` names a node the two place
    /// apart (see [`OsmData::add_node`]).
    pub fn merge(&mut self, other: OsmData) -> Result<(), String> {
        for (id, at) in other.nodes {
            self.add_node(id, at)
                .map_err(|first| node_twice(id, first, at))?;
        }
        self.ways.extend(other.ways);
        self.relations.extend(other.relations);
        Ok(())
    }
}

/// Why a file that places node `id` at `first` and at `again` (nanodegrees) is refused.
pub fn node_twice(id: i64, first: (i64, i64), again: (i64, i64)) -> String {
    format!(
        "node {id} appears twice, at {} and at {} (an OSM file holds each node once)",
        degrees(first),
        degrees(again)
    )
}

/// `(lat, lon)` in nanodegrees, written in degrees.
fn degrees((lat, lon): (i64, i64)) -> String {
    format!("({}, {})", lat as f64 / 1e9, lon as f64 / 1e9)
}

/// Degrees to integer nanodegrees, quantised to OSM's precision of 1e-7 degrees (the unit of
/// its database and of PBF's default granularity).
pub fn nanodegrees(deg: f64) -> i64 {
    (deg * 1e7).round() as i64 * 100
}

/// An OSM file that could not be read.
#[derive(Debug, thiserror::Error)]
pub enum OsmError {
    /// The file could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The XML is malformed.
    #[error("{path}: malformed XML at byte {position}: {message}")]
    Xml {
        /// The file.
        path: PathBuf,
        /// Byte offset of the error.
        position: u64,
        /// The parser's message.
        message: String,
    },
    /// A node given twice at two places ([`node_twice`] says which).
    #[error("{path}: at byte {position}: {problem}")]
    NodeTwice {
        /// The file.
        path: PathBuf,
        /// Byte offset of the second.
        position: u64,
        /// The node and its two places.
        problem: String,
    },
    /// An element lacks a required attribute or has a bad value.
    #[error("{path}: at byte {position}: <{element}> has {problem}")]
    BadElement {
        /// The file.
        path: PathBuf,
        /// Byte offset.
        position: u64,
        /// The element name.
        element: String,
        /// What is wrong.
        problem: String,
    },
    /// The document is XML but not OSM (no `<osm>` root).
    #[error("{path}: not an OSM XML file (root element is <{root}>, expected <osm>)")]
    NotOsm {
        /// The file.
        path: PathBuf,
        /// The root element found.
        root: String,
    },
    /// The document ends before `</osm>`: a truncated download or copy.
    #[error("{path}: the file ends at byte {position} before </osm>: it is truncated, so its ways would be incomplete")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Where it ends.
        position: u64,
    },
    /// One element is larger than any real OSM element.
    #[error("{path}: at byte {position}: an element longer than {MAX_ELEMENT_BYTES} bytes")]
    ElementTooLarge {
        /// The file.
        path: PathBuf,
        /// Where it starts.
        position: u64,
    },
    /// Not a regular file.
    #[error(transparent)]
    Input(#[from] lanealign_core::input::InputError),
}

/// The largest single element (tag) read (bytes): OSM elements are a few hundred bytes.
pub const MAX_ELEMENT_BYTES: usize = 1 << 20;

enum Open {
    None,
    Way(Way),
    Relation(Relation),
    Node,
}

struct ElementReader<'a> {
    path: &'a Path,
    position: u64,
}

impl ElementReader<'_> {
    fn attrs(&self, e: &BytesStart<'_>) -> Result<HashMap<String, String>, OsmError> {
        let element = e.name().as_ref().to_string();
        let mut out = HashMap::new();
        for a in e.attributes() {
            let a =
                a.map_err(|err| self.bad(&element, format!("a malformed attribute ({err})")))?;
            let key = a.key.as_ref().to_string();
            let value = a
                .normalized_value(XmlVersion::Implicit1_0)
                .map_err(|err| {
                    self.bad(&element, format!("a malformed value for '{key}' ({err})"))
                })?
                .into_owned();
            out.insert(key, value);
        }
        Ok(out)
    }

    fn bad(&self, element: &str, problem: String) -> OsmError {
        OsmError::BadElement {
            path: self.path.to_path_buf(),
            position: self.position,
            element: element.to_string(),
            problem,
        }
    }

    fn get<T: std::str::FromStr>(
        &self,
        attrs: &HashMap<String, String>,
        element: &str,
        key: &str,
    ) -> Result<T, OsmError> {
        let raw = attrs
            .get(key)
            .ok_or_else(|| self.bad(element, format!("no '{key}' attribute")))?;
        raw.parse()
            .map_err(|_| self.bad(element, format!("a bad '{key}' value '{raw}'")))
    }
}

/// A reader that hands out at most `left` more bytes: the XML parser buffers a whole element
/// before it returns it, so the budget, renewed for every element, is what bounds its memory.
struct Budget<R> {
    inner: R,
    left: usize,
}

impl<R: BufRead> std::io::Read for Budget<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let available = self.fill_buf()?;
        let n = available.len().min(out.len());
        out[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl<R: BufRead> BufRead for Budget<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        let left = self.left;
        let buffered = self.inner.fill_buf()?;
        Ok(&buffered[..buffered.len().min(left)])
    }

    fn consume(&mut self, n: usize) {
        self.inner.consume(n);
        self.left -= n;
    }
}

/// Reads OSM XML from any buffered reader; `path` names the source in errors. No element may
/// be longer than [`MAX_ELEMENT_BYTES`], so memory stays bounded whatever the input.
pub fn read_xml<R: BufRead>(input: R, path: &Path) -> Result<OsmData, OsmError> {
    let mut reader = Reader::from_reader(Budget {
        inner: input,
        left: 0,
    });
    let mut buf = Vec::new();
    let mut data = OsmData::default();
    let mut open = Open::None;
    let mut saw_root = false;
    let mut closed = false;
    loop {
        let position = reader.buffer_position();
        let er = ElementReader { path, position };
        // One byte beyond the limit tells an element that is too long.
        reader.get_mut().left = MAX_ELEMENT_BYTES + 1;
        let event = reader.read_event_into(&mut buf);
        if reader.get_ref().left == 0 {
            return Err(OsmError::ElementTooLarge {
                path: path.to_path_buf(),
                position,
            });
        }
        let event = event.map_err(|e| OsmError::Xml {
            path: path.to_path_buf(),
            position: reader.error_position(),
            message: e.to_string(),
        })?;
        let (e, is_empty) = match &event {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::End(e) => {
                match e.name().as_ref() {
                    "osm" => closed = true,
                    "way" | "relation" | "node" => match std::mem::replace(&mut open, Open::None) {
                        Open::Way(w) => data.ways.push(w),
                        Open::Relation(r) => data.relations.push(r),
                        Open::Node | Open::None => {}
                    },
                    _ => {}
                }
                buf.clear();
                continue;
            }
            Event::Eof => break,
            _ => {
                buf.clear();
                continue;
            }
        };
        let name = e.name().as_ref().to_string();
        if !saw_root {
            if name != "osm" {
                return Err(OsmError::NotOsm {
                    path: path.to_path_buf(),
                    root: name,
                });
            }
            saw_root = true;
            buf.clear();
            continue;
        }
        match name.as_str() {
            "node" => {
                let a = er.attrs(e)?;
                let id: i64 = er.get(&a, "node", "id")?;
                let lat: f64 = er.get(&a, "node", "lat")?;
                let lon: f64 = er.get(&a, "node", "lon")?;
                if !(lat.is_finite() && lon.is_finite() && lat.abs() <= 90.0 && lon.abs() <= 180.0)
                {
                    return Err(er.bad("node", format!("coordinates out of range ({lat}, {lon})")));
                }
                let at = (nanodegrees(lat), nanodegrees(lon));
                data.add_node(id, at).map_err(|first| OsmError::NodeTwice {
                    path: er.path.to_path_buf(),
                    position: er.position,
                    problem: node_twice(id, first, at),
                })?;
                if !is_empty {
                    open = Open::Node;
                }
            }
            "way" => {
                let a = er.attrs(e)?;
                let way = Way {
                    id: er.get(&a, "way", "id")?,
                    ..Way::default()
                };
                if is_empty {
                    data.ways.push(way);
                } else {
                    open = Open::Way(way);
                }
            }
            "relation" => {
                let a = er.attrs(e)?;
                let rel = Relation {
                    id: er.get(&a, "relation", "id")?,
                    ..Relation::default()
                };
                if is_empty {
                    data.relations.push(rel);
                } else {
                    open = Open::Relation(rel);
                }
            }
            "nd" => {
                if let Open::Way(w) = &mut open {
                    let a = er.attrs(e)?;
                    w.nodes.push(er.get(&a, "nd", "ref")?);
                }
            }
            "member" => {
                if let Open::Relation(r) = &mut open {
                    let a = er.attrs(e)?;
                    r.members.push(Member {
                        kind: er.get(&a, "member", "type")?,
                        id: er.get(&a, "member", "ref")?,
                        role: a.get("role").cloned().unwrap_or_default(),
                    });
                }
            }
            "tag" => {
                let a = er.attrs(e)?;
                let k: String = er.get(&a, "tag", "k")?;
                let v: String = er.get(&a, "tag", "v")?;
                match &mut open {
                    Open::Way(w) => w.tags.push((k, v)),
                    Open::Relation(r) => r.tags.push((k, v)),
                    Open::Node | Open::None => {}
                }
            }
            _ => {}
        }
        buf.clear();
    }
    if !saw_root {
        return Err(OsmError::NotOsm {
            path: path.to_path_buf(),
            root: "(none)".to_string(),
        });
    }
    if !closed {
        return Err(OsmError::Truncated {
            path: path.to_path_buf(),
            position: reader.buffer_position(),
        });
    }
    data.sort();
    Ok(data)
}

/// Reads an OSM XML file (a regular file).
pub fn read_xml_file(path: &Path) -> Result<OsmData, OsmError> {
    let file = lanealign_core::input::open_regular(path)?;
    read_xml(std::io::BufReader::new(file), path)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = r#"<?xml version="1.0"?>
<osm version="0.6">
  <node id="1" lat="49.0" lon="8.4"/>
  <node id="2" lat="49.001" lon="8.4"><tag k="ele" v="1"/></node>
  <way id="10"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/><tag k="name" v="A &amp; B"/></way>
  <relation id="5"><member type="way" ref="10" role="left"/><tag k="type" v="lanelet"/></relation>
</osm>"#;

    #[test]
    fn an_element_longer_than_the_limit_is_refused_before_it_is_all_read() {
        let mut text = String::from("<osm><node id=\"1\" lat=\"49\" lon=\"8\" note=\"");
        text.push_str(&"x".repeat(3 * MAX_ELEMENT_BYTES));
        text.push_str("\"/></osm>");
        let e = read_xml(text.as_bytes(), Path::new("big.osm")).unwrap_err();
        assert!(
            matches!(e, OsmError::ElementTooLarge { position: 5, .. }),
            "{e}"
        );
    }

    #[test]
    fn reads_nodes_ways_relations_and_tags() {
        let d = read_xml(SMALL.as_bytes(), Path::new("s.osm")).unwrap();
        assert_eq!(d.nodes.len(), 2);
        assert_eq!(d.ways[0].nodes, vec![1, 2]);
        assert_eq!(tag(&d.ways[0].tags, "name"), Some("A & B"));
        assert_eq!(d.relations[0].members[0].role, "left");
        assert_eq!(tag(&d.relations[0].tags, "type"), Some("lanelet"));
    }

    /// A node given again at the same place is one node; at another place the file is refused
    /// (the map took the last, and a PBF's blocks, merged in no fixed order, any of the two).
    #[test]
    fn a_node_given_twice_must_be_in_one_place() {
        let twice = |lat| {
            format!(
                r#"<osm><node id="1" lat="49" lon="8"/><node id="2" lat="49.1" lon="8"/>
                <node id="1" lat="{lat}" lon="8"/></osm>"#
            )
        };
        let d = read_xml(twice("49.0000000").as_bytes(), Path::new("t.osm")).unwrap();
        assert_eq!(d.nodes.len(), 2);
        let e = read_xml(twice("49.0000001").as_bytes(), Path::new("t.osm")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.osm: at byte 86: node 1 appears twice, at (49, 8) and at (49.0000001, 8) (an \
             OSM file holds each node once)"
        );
        let mut a = read_xml(twice("49").as_bytes(), Path::new("a.osm")).unwrap();
        let mut b = OsmData::default();
        b.add_node(2, (49_100_000_100, 8_000_000_000)).unwrap();
        assert_eq!(
            a.merge(b),
            Err(
                "node 2 appears twice, at (49.1, 8) and at (49.1000001, 8) (an OSM file holds \
                 each node once)"
                    .to_string()
            )
        );
    }

    #[test]
    fn refuses_non_osm_and_broken_xml() {
        let e = read_xml("this is not xml at all".as_bytes(), Path::new("t.osm")).unwrap_err();
        assert!(matches!(e, OsmError::NotOsm { .. }), "{e}");
        let e = read_xml("<html><body/></html>".as_bytes(), Path::new("t.osm")).unwrap_err();
        assert!(e.to_string().contains("expected <osm>"), "{e}");
        let e = read_xml(
            r#"<osm><node id="1" lat="x" lon="8"/></osm>"#.as_bytes(),
            Path::new("t.osm"),
        )
        .unwrap_err();
        assert!(e.to_string().contains("bad 'lat'"), "{e}");
        let e = read_xml(
            "<osm><way id=\"1\"><nd ref=\"2\"/></osm>".as_bytes(),
            Path::new("t.osm"),
        )
        .unwrap_err();
        assert!(matches!(e, OsmError::Xml { .. }), "{e}");
    }
}
