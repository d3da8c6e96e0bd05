//! Writes OSM data as an uncompressed OSM PBF file: seeds for the PBF harness, and PBF inputs a
//! converter would refuse to make (nodes outside WGS84). Written by hand because no kept Rust
//! crate writes PBF (`osmpbf` only reads); it covers what the reader under test needs: plain
//! nodes, ways and relations with tags, in raw (uncompressed) blobs.

use std::collections::BTreeMap;

use lanealign_map::osm::OsmData;

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn key(out: &mut Vec<u8>, field: u64, wire_type: u64) {
    varint(out, (field << 3) | wire_type);
}

fn bytes_field(out: &mut Vec<u8>, field: u64, data: &[u8]) {
    key(out, field, 2);
    varint(out, data.len() as u64);
    out.extend_from_slice(data);
}

fn varint_field(out: &mut Vec<u8>, field: u64, v: u64) {
    key(out, field, 0);
    varint(out, v);
}

fn packed(out: &mut Vec<u8>, field: u64, values: impl Iterator<Item = u64>) {
    let mut data = Vec::new();
    values.for_each(|v| varint(&mut data, v));
    bytes_field(out, field, &data);
}

/// Interns strings into the block's string table (index 0 is the empty string).
#[derive(Default)]
struct Strings {
    index: BTreeMap<String, u64>,
    table: Vec<String>,
}

impl Strings {
    fn id(&mut self, s: &str) -> u64 {
        if self.table.is_empty() {
            self.table.push(String::new());
            self.index.insert(String::new(), 0);
        }
        if let Some(&i) = self.index.get(s) {
            return i;
        }
        let i = self.table.len() as u64;
        self.table.push(s.to_string());
        self.index.insert(s.to_string(), i);
        i
    }
}

fn tags(out: &mut Vec<u8>, strings: &mut Strings, tags: &[(String, String)]) {
    let keys: Vec<u64> = tags.iter().map(|(k, _)| strings.id(k)).collect();
    let vals: Vec<u64> = tags.iter().map(|(_, v)| strings.id(v)).collect();
    packed(out, 2, keys.into_iter());
    packed(out, 3, vals.into_iter());
}

fn blob(out: &mut Vec<u8>, kind: &str, message: &[u8]) {
    let mut blob = Vec::new();
    bytes_field(&mut blob, 1, message);
    varint_field(&mut blob, 2, message.len() as u64);
    let mut header = Vec::new();
    bytes_field(&mut header, 1, kind.as_bytes());
    varint_field(&mut header, 3, blob.len() as u64);
    out.extend_from_slice(&(header.len() as u32).to_be_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(&blob);
}

/// `osm` as PBF bytes: a header block and one data block (nodes by id, then ways and
/// relations in their order). Coordinates are written as given, in units of 100 nanodegrees.
pub fn write(osm: &OsmData) -> Vec<u8> {
    let mut strings = Strings::default();
    let mut group = Vec::new();
    let nodes: BTreeMap<i64, (i64, i64)> = osm.nodes.iter().map(|(&k, &v)| (k, v)).collect();
    for (id, (lat, lon)) in nodes {
        let mut node = Vec::new();
        varint_field(&mut node, 1, zigzag(id));
        varint_field(&mut node, 8, zigzag(lat / 100));
        varint_field(&mut node, 9, zigzag(lon / 100));
        bytes_field(&mut group, 1, &node);
    }
    for way in &osm.ways {
        let mut w = Vec::new();
        varint_field(&mut w, 1, way.id as u64);
        tags(&mut w, &mut strings, &way.tags);
        let mut last = 0i64;
        let deltas: Vec<u64> = way
            .nodes
            .iter()
            .map(|&r| {
                let d = zigzag(r.wrapping_sub(last));
                last = r;
                d
            })
            .collect();
        packed(&mut w, 8, deltas.into_iter());
        bytes_field(&mut group, 3, &w);
    }
    for rel in &osm.relations {
        let mut r = Vec::new();
        varint_field(&mut r, 1, rel.id as u64);
        tags(&mut r, &mut strings, &rel.tags);
        let roles: Vec<u64> = rel.members.iter().map(|m| strings.id(&m.role)).collect();
        packed(&mut r, 8, roles.into_iter());
        let mut last = 0i64;
        let ids: Vec<u64> = rel
            .members
            .iter()
            .map(|m| {
                let d = zigzag(m.id.wrapping_sub(last));
                last = m.id;
                d
            })
            .collect();
        packed(&mut r, 9, ids.into_iter());
        // Any other kind is written as 3, a member type PBF does not define (a regression case).
        let kinds = rel.members.iter().map(|m| match m.kind.as_str() {
            "node" => 0,
            "way" => 1,
            "relation" => 2,
            _ => 3,
        });
        packed(&mut r, 10, kinds);
        bytes_field(&mut group, 4, &r);
    }
    let mut table = Vec::new();
    strings.id("");
    for s in &strings.table {
        bytes_field(&mut table, 1, s.as_bytes());
    }
    let mut block = Vec::new();
    bytes_field(&mut block, 1, &table);
    bytes_field(&mut block, 2, &group);
    let mut header_block = Vec::new();
    bytes_field(&mut header_block, 4, b"OsmSchema-V0.6");
    let mut out = Vec::new();
    blob(&mut out, "OSMHeader", &header_block);
    blob(&mut out, "OSMData", &block);
    out
}
