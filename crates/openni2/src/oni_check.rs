//! Validating an `.oni` file in plain Rust before OpenNI2's player sees it.
//!
//! OpenNI2's file player trusts the file: a frame of a stream that was never set up, a stream
//! never made ready, and similar inconsistencies crash it (signal 11) instead of failing. So
//! every record is checked here first (layout in [`crate::oni_file`]) and a file that fails is
//! refused with its path and the byte offset of the first bad record:
//! - every record header: magic, a known record type, sizes within the file and within what
//!   such a record holds (metadata fields at most [`MAX_FIELDS_BYTES`]);
//! - node ids: every record but `END` names a node added before it and not removed since (a
//!   seek table may follow its node's removal); a node is added once at a time, as a depth,
//!   image or IR stream with a known codec;
//! - order: a node's `NODE_STATE_READY` once, after its `NODE_ADDED`; `NODE_DATA_BEGIN` and
//!   frames only after it;
//! - property records: name and data inside the record;
//! - frames: the timestamp and frame number fields present; an uncompressed frame holds
//!   exactly width × height × bytes per pixel of its node's current `xnMapOutputMode` (or
//!   enabled `xnCropping`) and pixel format; no frame exceeds the player's buffer
//!   ([`MAX_FRAME_BYTES`]), and the mode's frame fits in it too;
//! - positions: undo positions point at an earlier record's start; `NODE_ADDED`'s seek-table
//!   position at its node's `SEEK_TABLE`, whose entries point at that node's frames; the frame
//!   count in `NODE_ADDED` is the number of frames the node has (complete files only: a file
//!   cut short is repaired first, which rewrites them).

use std::collections::{HashMap, HashSet};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use crate::oni_file::{
    io_err, is_property, list_records, read_range, record_type, string_field, u32_at, u64_at,
    OniFileError, RecordHeader, RECORD_HEADER_LEN, SEEK_ENTRY_LEN,
};
pub use crate::oni_writer::MAX_FRAME_BYTES;

/// Largest fields part of any record (names, properties and small headers: a few hundred
/// bytes in practice).
pub const MAX_FIELDS_BYTES: u32 = 1 << 20;
/// `NODE_ADDED` of format 1.0.0.4 (name, node type, codec).
const NODE_ADDED_1_0_0_4: u32 = 0x02;
/// `NEW_DATA` fields after the header: timestamp u64, frame number u32.
const NEW_DATA_FIELDS: usize = 12;

/// Codecs (`XnCodecID`: four characters, little-endian) OpenNI2 writes and plays.
const CODECS: [&[u8; 4]; 5] = [b"NONE", b"16zP", b"16zT", b"Im8z", b"JPEG"];

/// OpenNI 1.x production node types with frames: depth, image, IR.
fn node_type_name(t: u32) -> Option<&'static str> {
    match t {
        2 => Some("depth"),
        3 => Some("image"),
        5 => Some("IR"),
        _ => None,
    }
}

#[derive(Debug, Default)]
struct Node {
    node_type: u32,
    uncompressed: bool,
    declared_frames: Option<u32>,
    seek_table_at: u64,
    ready: bool,
    removed: bool,
    /// (width, height) of `xnMapOutputMode`.
    mode: Option<(u32, u32)>,
    /// Enabled `xnCropping`: (width, height).
    cropping: Option<(u32, u32)>,
    /// `oniPixelFormat`.
    oni_format: Option<u64>,
    /// `xnPixelFormat` (OpenNI 1.x).
    xn_format: Option<u64>,
    frames: HashSet<u64>,
    seek_tables: Vec<u64>,
}

impl Node {
    /// Bytes per pixel of an uncompressed frame; `None`: compressed or not known.
    fn bytes_per_pixel(&self) -> Option<u64> {
        match self.oni_format {
            Some(100..=103) | Some(201) | Some(203) | Some(205) => return Some(2),
            Some(200) => return Some(3),
            Some(202) => return Some(1),
            Some(_) => return None,
            None => {}
        }
        match self.xn_format {
            Some(1) => Some(3),
            Some(2) | Some(4) => Some(2),
            Some(3) => Some(1),
            Some(_) => None,
            None if self.node_type == 2 => Some(2),
            None => None,
        }
    }

    /// Frame size the node's current mode and format call for.
    fn expected_frame_bytes(&self) -> Option<u64> {
        let (w, h) = self.cropping.or(self.mode)?;
        Some(w as u64 * h as u64 * self.bytes_per_pixel()?)
    }
}

/// Checks every record of the `.oni` file at `path` (see the module documentation) and
/// returns its records. A file cut short (no `END`, or a last record that runs past the end)
/// passes when `allow_truncated`, checked up to its last complete record.
pub fn validate(path: &Path, allow_truncated: bool) -> Result<Vec<RecordHeader>, OniFileError> {
    let records = list_records(path, allow_truncated)?;
    let complete = records.last().is_some_and(|r| r.kind == record_type::END);
    let mut reader = BufReader::new(File::open(path).map_err(io_err(path))?);
    let corrupt = |offset: u64, reason: String| OniFileError::Corrupt {
        path: path.to_path_buf(),
        offset,
        reason,
    };
    let mut nodes: HashMap<u32, Node> = HashMap::new();
    let starts: HashSet<u64> = records.iter().map(|r| r.offset).collect();
    for rec in &records {
        let at = rec.offset;
        if rec.fields_size > MAX_FIELDS_BYTES {
            return Err(corrupt(
                at,
                format!(
                    "record fields of {} bytes (at most {MAX_FIELDS_BYTES})",
                    rec.fields_size
                ),
            ));
        }
        if rec.undo_position != 0
            && (rec.undo_position >= at || !starts.contains(&rec.undo_position))
        {
            return Err(corrupt(
                at,
                format!(
                    "undo position {} is not the start of an earlier record",
                    rec.undo_position
                ),
            ));
        }
        let kind = rec.kind;
        if kind == record_type::END {
            break;
        }
        let fields = read_range(&mut reader, path, at, rec.fields_size as usize)?;
        let known = |nodes: &HashMap<u32, Node>| -> Result<(), OniFileError> {
            match nodes.get(&rec.node_id) {
                Some(n) if !n.removed => Ok(()),
                Some(_) => Err(corrupt(
                    at,
                    format!(
                        "record of type {kind:#x} for node {} after the node was removed",
                        rec.node_id
                    ),
                )),
                None => Err(corrupt(
                    at,
                    format!(
                        "record of type {kind:#x} for node {}, which was never added",
                        rec.node_id
                    ),
                )),
            }
        };
        let no_payload = || -> Result<(), OniFileError> {
            if rec.payload_size > MAX_FIELDS_BYTES {
                return Err(corrupt(
                    at,
                    format!(
                        "record of type {kind:#x} with a payload of {} bytes",
                        rec.payload_size
                    ),
                ));
            }
            Ok(())
        };
        match kind {
            record_type::NODE_ADDED | record_type::NODE_ADDED_1_0_0_5 | NODE_ADDED_1_0_0_4 => {
                no_payload()?;
                if nodes.get(&rec.node_id).is_some_and(|n| !n.removed) {
                    return Err(corrupt(
                        at,
                        format!("node {} is added a second time", rec.node_id),
                    ));
                }
                let (name, after) = string_field(&fields, RECORD_HEADER_LEN)
                    .ok_or_else(|| corrupt(at, "NODE_ADDED without a node name".into()))?;
                let tail = match kind {
                    record_type::NODE_ADDED => 36,
                    record_type::NODE_ADDED_1_0_0_5 => 28,
                    _ => 8,
                };
                if fields.len() < after + tail {
                    return Err(corrupt(
                        at,
                        format!("NODE_ADDED of node {} is cut short", rec.node_id),
                    ));
                }
                let node_type = u32_at(&fields, after);
                if node_type_name(node_type).is_none() {
                    return Err(corrupt(
                        at,
                        format!(
                            "node {} ({:.40}) has type {node_type}, not a depth (2), image (3) or \
                             IR (5) stream",
                            rec.node_id, name
                        ),
                    ));
                }
                let codec = fields[after + 4..after + 8].to_vec();
                if !CODECS.iter().any(|c| c[..] == codec[..]) {
                    return Err(corrupt(
                        at,
                        format!(
                            "node {} has codec {:02x?}, not one OpenNI2 plays (NONE, 16zP, 16zT, \
                             Im8z, JPEG)",
                            rec.node_id, codec
                        ),
                    ));
                }
                let node = Node {
                    node_type,
                    uncompressed: &codec[..] == b"NONE",
                    declared_frames: (kind != NODE_ADDED_1_0_0_4)
                        .then(|| u32_at(&fields, after + 8)),
                    seek_table_at: if kind == record_type::NODE_ADDED {
                        u64_at(&fields, after + 28)
                    } else {
                        0
                    },
                    ..Node::default()
                };
                nodes.insert(rec.node_id, node);
            }
            k if is_property(k) => {
                no_payload()?;
                known(&nodes)?;
                let (name, after) = string_field(&fields, RECORD_HEADER_LEN)
                    .ok_or_else(|| corrupt(at, "property record without a name".into()))?;
                let len = fields
                    .get(after..after + 4)
                    .map(|b| u32_at(b, 0) as usize)
                    .ok_or_else(|| corrupt(at, format!("property {name:.40} without a size")))?;
                let data = fields.get(after + 4..after + 4 + len).ok_or_else(|| {
                    corrupt(
                        at,
                        format!("property {name:.40} of {len} bytes runs past its record"),
                    )
                })?;
                let node = nodes.get_mut(&rec.node_id).expect("checked");
                let int = || (data.len() >= 8).then(|| u64_at(data, 0));
                match name.as_str() {
                    "xnMapOutputMode" => {
                        if data.len() < 8 {
                            return Err(corrupt(
                                at,
                                format!("xnMapOutputMode of {} bytes", data.len()),
                            ));
                        }
                        let (w, h) = (u32_at(data, 0), u32_at(data, 4));
                        if w == 0 || h == 0 || w as u64 * h as u64 > MAX_FRAME_BYTES as u64 {
                            return Err(corrupt(
                                at,
                                format!(
                                    "node {} declares {w}x{h} frames (OpenNI2's player holds \
                                     at most {MAX_FRAME_BYTES} bytes a frame)",
                                    rec.node_id
                                ),
                            ));
                        }
                        node.mode = Some((w, h));
                    }
                    "xnCropping" if data.len() >= 12 => {
                        let enabled = u32_at(data, 0) != 0;
                        let w = u16::from_le_bytes([data[8], data[9]]) as u32;
                        let h = u16::from_le_bytes([data[10], data[11]]) as u32;
                        node.cropping = enabled.then_some((w, h));
                    }
                    "oniPixelFormat" => node.oni_format = int(),
                    "xnPixelFormat" => node.xn_format = int(),
                    _ => {}
                }
            }
            record_type::NODE_STATE_READY => {
                no_payload()?;
                known(&nodes)?;
                let node = nodes.get_mut(&rec.node_id).expect("checked");
                if node.ready {
                    return Err(corrupt(
                        at,
                        format!("node {} is made ready a second time", rec.node_id),
                    ));
                }
                node.ready = true;
            }
            record_type::NODE_DATA_BEGIN | record_type::NEW_DATA => {
                known(&nodes)?;
                let node = nodes.get_mut(&rec.node_id).expect("checked");
                let what = if kind == record_type::NEW_DATA {
                    "a frame"
                } else {
                    "NODE_DATA_BEGIN"
                };
                if !node.ready {
                    return Err(corrupt(
                        at,
                        format!(
                            "{what} of node {} before the node's NODE_STATE_READY",
                            rec.node_id
                        ),
                    ));
                }
                if kind == record_type::NODE_DATA_BEGIN {
                    no_payload()?;
                    continue;
                }
                if (rec.fields_size as usize) < RECORD_HEADER_LEN + NEW_DATA_FIELDS {
                    return Err(corrupt(
                        at,
                        format!(
                            "frame of node {} without its timestamp and number ({} bytes of \
                             fields)",
                            rec.node_id, rec.fields_size
                        ),
                    ));
                }
                let size = rec.payload_size as u64;
                if size == 0 || size > MAX_FRAME_BYTES as u64 {
                    return Err(corrupt(
                        at,
                        format!(
                            "frame of node {} has {size} bytes (1 to {MAX_FRAME_BYTES})",
                            rec.node_id
                        ),
                    ));
                }
                let Some((w, h)) = node.mode else {
                    return Err(corrupt(
                        at,
                        format!(
                            "frame of node {} before the node's xnMapOutputMode",
                            rec.node_id
                        ),
                    ));
                };
                if node.uncompressed {
                    match node.expected_frame_bytes() {
                        Some(expected) if expected != size => {
                            return Err(corrupt(
                                at,
                                format!(
                                    "frame of node {} has {size} bytes; its {w}x{h} {} frames \
                                     have {expected}",
                                    rec.node_id,
                                    node_type_name(node.node_type).unwrap_or("?")
                                ),
                            ))
                        }
                        Some(_) => {}
                        None => {
                            return Err(corrupt(
                                at,
                                format!("frame of node {} in an unknown pixel format", rec.node_id),
                            ))
                        }
                    }
                }
                node.frames.insert(at);
            }
            record_type::NODE_REMOVED => {
                no_payload()?;
                known(&nodes)?;
                nodes.get_mut(&rec.node_id).expect("checked").removed = true;
            }
            record_type::SEEK_TABLE => {
                let Some(node) = nodes.get_mut(&rec.node_id) else {
                    return Err(corrupt(
                        at,
                        format!("seek table of node {}, which was never added", rec.node_id),
                    ));
                };
                if !(rec.payload_size as usize).is_multiple_of(SEEK_ENTRY_LEN) {
                    return Err(corrupt(
                        at,
                        format!(
                            "seek table of {} bytes, not whole entries of {SEEK_ENTRY_LEN}",
                            rec.payload_size
                        ),
                    ));
                }
                let entries = rec.payload_size as usize / SEEK_ENTRY_LEN;
                if entries as u64 > node.frames.len() as u64 + 1 {
                    return Err(corrupt(
                        at,
                        format!(
                            "seek table of {entries} entries for node {}'s {} frames",
                            rec.node_id,
                            node.frames.len()
                        ),
                    ));
                }
                reader
                    .seek(SeekFrom::Start(at + rec.fields_size as u64))
                    .map_err(io_err(path))?;
                let mut entry = [0u8; SEEK_ENTRY_LEN];
                for i in 0..entries {
                    reader.read_exact(&mut entry).map_err(io_err(path))?;
                    let pos = u64_at(&entry, 12);
                    if pos != 0 && !node.frames.contains(&pos) {
                        return Err(corrupt(
                            at,
                            format!(
                                "seek table entry {i} points at byte {pos}, not a frame of \
                                 node {}",
                                rec.node_id
                            ),
                        ));
                    }
                }
                node.seek_tables.push(at);
            }
            other => {
                return Err(corrupt(at, format!("unknown record type {other:#x}")));
            }
        }
    }
    if complete {
        let mut ids: Vec<_> = nodes.keys().copied().collect();
        ids.sort_unstable();
        for id in ids {
            let node = &nodes[&id];
            let added = records
                .iter()
                .rfind(|r| {
                    r.node_id == id
                        && matches!(
                            r.kind,
                            record_type::NODE_ADDED
                                | record_type::NODE_ADDED_1_0_0_5
                                | NODE_ADDED_1_0_0_4
                        )
                })
                .map_or(0, |r| r.offset);
            if let Some(n) = node.declared_frames {
                if n as usize != node.frames.len() {
                    return Err(corrupt(
                        added,
                        format!(
                            "node {id} declares {n} frames; the file holds {}",
                            node.frames.len()
                        ),
                    ));
                }
            }
            if node.seek_table_at != 0 && !node.seek_tables.contains(&node.seek_table_at) {
                return Err(corrupt(
                    added,
                    format!(
                        "node {id}'s seek table position {} is not its SEEK_TABLE record",
                        node.seek_table_at
                    ),
                ));
            }
        }
    }
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::oni_writer::{OniStreamSpec, OniWriter};

    fn spec() -> OniStreamSpec {
        OniStreamSpec {
            width: 4,
            height: 3,
            fps: 30,
            hfov: 1.0,
            vfov: 0.8,
        }
    }

    fn written(dir: &Path) -> std::path::PathBuf {
        let path = dir.join("ok.oni");
        let mut w = OniWriter::create(&path, spec(), spec()).unwrap();
        for i in 0..3u64 {
            w.write_depth(1 + i * 33_333, &[500; 12]).unwrap();
            w.write_color(1 + i * 33_333, &[9; 36]).unwrap();
        }
        w.finish().unwrap();
        path
    }

    #[test]
    fn the_writers_files_pass_and_a_frame_unlike_its_mode_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = written(dir.path());
        let records = validate(&path, false).unwrap();
        // Declare the depth stream 2x3: its frames of 4x3 no longer match.
        let mode = records
            .iter()
            .find(|r| r.node_id == 1 && r.property.as_deref() == Some("xnMapOutputMode"))
            .unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        let data = mode.offset as usize + RECORD_HEADER_LEN + 4 + "xnMapOutputMode".len() + 1 + 4;
        bytes[data..data + 4].copy_from_slice(&2u32.to_le_bytes());
        let bad = dir.path().join("bad.oni");
        std::fs::write(&bad, &bytes).unwrap();
        let first_frame = records
            .iter()
            .find(|r| r.kind == record_type::NEW_DATA)
            .unwrap();
        let err = validate(&bad, true).unwrap_err().to_string();
        assert!(err.contains("bad.oni"), "{err}");
        assert!(
            err.contains(&format!("byte {}", first_frame.offset))
                && err.contains("has 24 bytes; its 2x3 depth frames have 12"),
            "{err}"
        );
    }
}
