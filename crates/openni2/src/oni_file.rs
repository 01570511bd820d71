//! `.oni` file surgery, in plain Rust (no OpenNI calls): listing records and the
//! cropping-record fix. Writing new recordings is [`crate::oni_writer`].
//!
//! OpenNI2 2.2's recorder writes a stream's `xnCropping` (and `xnFOV`) property records only
//! when the stream answers those properties; its file player drops every frame of a node
//! whose cropping it cannot read. Streams of the Dummy driver (and some third-party drivers)
//! do not answer, so their recordings play no frames at all. [`add_missing_cropping`] inserts
//! a disabled `xnCropping` record and an `xnFOV` record before each such node's `STATE_READY`
//! record and moves every file position that points past an insertion.
//!
//! Format (OpenNI2 `Source/Core/OniDataRecords.*`, all little-endian, packed):
//! - file header, 24 bytes: `NI10`, version (u8, u8, u16, u32), max timestamp u64,
//!   max node id u32;
//! - records: header of 28 bytes (magic `NIR\0`, type u32, node id u32, fields size u32 *including
//!   the header*, payload size u32, undo position u64), then fields, then payload;
//! - positions stored in the file: every header's undo position, `NODE_ADDED`'s seek-table
//!   position (its last field), and each seek-table entry's position (entries of 20 bytes:
//!   timestamp u64, configuration id u32, position u64).

use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

pub(crate) const FILE_HEADER_LEN: u64 = 24;
pub(crate) const RECORD_HEADER_LEN: usize = 28;
const RECORD_MAGIC: u32 = 0x0052_494E;
pub(crate) const SEEK_ENTRY_LEN: usize = 20;

/// Record types this module cares about.
pub mod record_type {
    pub const INT_PROPERTY: u32 = 0x03;
    pub const REAL_PROPERTY: u32 = 0x04;
    pub const STRING_PROPERTY: u32 = 0x05;
    pub const GENERAL_PROPERTY: u32 = 0x06;
    pub const NODE_REMOVED: u32 = 0x07;
    pub const NODE_DATA_BEGIN: u32 = 0x08;
    pub const NODE_STATE_READY: u32 = 0x09;
    pub const NEW_DATA: u32 = 0x0A;
    pub const END: u32 = 0x0B;
    pub const NODE_ADDED_1_0_0_5: u32 = 0x0C;
    pub const NODE_ADDED: u32 = 0x0D;
    pub const SEEK_TABLE: u32 = 0x0E;
}

/// What is wrong with an `.oni` file.
#[derive(Debug, thiserror::Error)]
pub enum OniFileError {
    #[error("cannot read or write {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("{path} is not an OpenNI recording: {reason}")]
    NotOni { path: PathBuf, reason: String },
    #[error("{path}: corrupt record at byte {offset}: {reason}")]
    Corrupt {
        path: PathBuf,
        offset: u64,
        reason: String,
    },
    #[error("cannot write {path}: {reason}")]
    Invalid { path: PathBuf, reason: String },
}

/// One record's header, and where it starts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordHeader {
    pub offset: u64,
    pub kind: u32,
    pub node_id: u32,
    pub fields_size: u32,
    pub payload_size: u32,
    pub undo_position: u64,
    /// The property name of property records.
    pub property: Option<String>,
}

impl RecordHeader {
    pub fn len(&self) -> u64 {
        self.fields_size as u64 + self.payload_size as u64
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(io::Error) -> OniFileError + '_ {
    move |source| OniFileError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

pub(crate) fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

pub(crate) fn is_property(kind: u32) -> bool {
    matches!(
        kind,
        record_type::INT_PROPERTY
            | record_type::REAL_PROPERTY
            | record_type::STRING_PROPERTY
            | record_type::GENERAL_PROPERTY
    )
}

/// Reads a length-prefixed string field at `at` of a record's fields.
pub(crate) fn string_field(rec: &[u8], at: usize) -> Option<(String, usize)> {
    let len = u32_at(rec.get(at..at + 4)?, 0) as usize;
    let bytes = rec.get(at + 4..at + 4 + len)?;
    let text = bytes.split(|&b| b == 0).next().unwrap_or_default();
    Some((String::from_utf8_lossy(text).into_owned(), at + 4 + len))
}

/// Lists the records of an `.oni` file up to its `END` record. A file cut short ends the list
/// without an error only if `allow_truncated`.
pub fn list_records(path: &Path, allow_truncated: bool) -> Result<Vec<RecordHeader>, OniFileError> {
    let mut file = BufReader::new(File::open(path).map_err(io_err(path))?);
    let file_len = file.get_ref().metadata().map_err(io_err(path))?.len();
    let mut header = [0u8; FILE_HEADER_LEN as usize];
    file.read_exact(&mut header).map_err(|e| match e.kind() {
        io::ErrorKind::UnexpectedEof => OniFileError::NotOni {
            path: path.to_path_buf(),
            reason: format!("only {file_len} bytes"),
        },
        _ => OniFileError::Io {
            path: path.to_path_buf(),
            source: e,
        },
    })?;
    if &header[0..2] != b"NI" {
        return Err(OniFileError::NotOni {
            path: path.to_path_buf(),
            reason: format!("file starts with {:02x?}, not \"NI\"", &header[0..4]),
        });
    }
    let mut records = Vec::new();
    let mut offset = FILE_HEADER_LEN;
    let mut buf = [0u8; RECORD_HEADER_LEN];
    loop {
        if offset == file_len {
            if allow_truncated {
                return Ok(records);
            }
            return Err(OniFileError::Corrupt {
                path: path.to_path_buf(),
                offset,
                reason: "file ends without an END record".into(),
            });
        }
        if offset + RECORD_HEADER_LEN as u64 > file_len {
            if allow_truncated {
                return Ok(records);
            }
            return Err(OniFileError::Corrupt {
                path: path.to_path_buf(),
                offset,
                reason: "file ends inside a record header".into(),
            });
        }
        file.seek(SeekFrom::Start(offset)).map_err(io_err(path))?;
        file.read_exact(&mut buf).map_err(io_err(path))?;
        let magic = u32_at(&buf, 0);
        let fields_size = u32_at(&buf, 12);
        if magic != RECORD_MAGIC || (fields_size as usize) < RECORD_HEADER_LEN {
            return Err(OniFileError::Corrupt {
                path: path.to_path_buf(),
                offset,
                reason: format!(
                    "bad record header (magic {magic:#010x}, fields size {fields_size})"
                ),
            });
        }
        let mut rec = RecordHeader {
            offset,
            kind: u32_at(&buf, 4),
            node_id: u32_at(&buf, 8),
            fields_size,
            payload_size: u32_at(&buf, 16),
            undo_position: u64_at(&buf, 20),
            property: None,
        };
        if offset + rec.len() > file_len {
            if allow_truncated {
                return Ok(records);
            }
            return Err(OniFileError::Corrupt {
                path: path.to_path_buf(),
                offset,
                reason: format!(
                    "record of {} bytes runs past the end of the file",
                    rec.len()
                ),
            });
        }
        if is_property(rec.kind) {
            let mut fields = vec![0u8; fields_size as usize];
            file.seek(SeekFrom::Start(offset)).map_err(io_err(path))?;
            file.read_exact(&mut fields).map_err(io_err(path))?;
            rec.property = string_field(&fields, RECORD_HEADER_LEN).map(|(s, _)| s);
        }
        offset += rec.len();
        let end = rec.kind == record_type::END;
        records.push(rec);
        if end {
            return Ok(records);
        }
    }
}

/// Builds a `GENERAL_PROPERTY` record.
fn general_property(node_id: u32, name: &str, data: &[u8]) -> Vec<u8> {
    let name_len = name.len() + 1;
    let fields_size = RECORD_HEADER_LEN + 4 + name_len + 4 + data.len();
    let mut rec = Vec::with_capacity(fields_size);
    rec.extend_from_slice(&RECORD_MAGIC.to_le_bytes());
    rec.extend_from_slice(&record_type::GENERAL_PROPERTY.to_le_bytes());
    rec.extend_from_slice(&node_id.to_le_bytes());
    rec.extend_from_slice(&(fields_size as u32).to_le_bytes());
    rec.extend_from_slice(&0u32.to_le_bytes());
    rec.extend_from_slice(&0u64.to_le_bytes());
    rec.extend_from_slice(&(name_len as u32).to_le_bytes());
    rec.extend_from_slice(name.as_bytes());
    rec.push(0);
    rec.extend_from_slice(&(data.len() as u32).to_le_bytes());
    rec.extend_from_slice(data);
    rec
}

/// A disabled OpenNI 1.x `XnCropping` (`XnBool` enabled, four `u16`): 12 zero bytes.
fn disabled_cropping() -> [u8; 12] {
    [0; 12]
}

/// An `XnFieldOfView` (two doubles, radians).
fn field_of_view(hfov: f64, vfov: f64) -> [u8; 16] {
    let mut b = [0u8; 16];
    b[..8].copy_from_slice(&hfov.to_le_bytes());
    b[8..].copy_from_slice(&vfov.to_le_bytes());
    b
}

/// What [`add_missing_cropping`] changed.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CroppingFix {
    /// Nodes that got an `xnCropping` record.
    pub cropping_added: Vec<u32>,
    /// Nodes that got an `xnFOV` record.
    pub fov_added: Vec<u32>,
}

impl CroppingFix {
    pub fn changed(&self) -> bool {
        !self.cropping_added.is_empty() || !self.fov_added.is_empty()
    }
}

/// Inserts a disabled `xnCropping` record, and an `xnFOV` record (`fov(node_type)` gives
/// horizontal and vertical field of view in radians for node types 2 = depth, 3 = image,
/// 5 = IR), before the `STATE_READY` record of every node that lacks them, fixing all stored
/// file positions. Rewrites the file through a temporary file next to it; a file that needs
/// nothing is left untouched.
pub fn add_missing_cropping(
    path: &Path,
    fov: impl Fn(u32) -> (f64, f64),
) -> Result<CroppingFix, OniFileError> {
    let records = list_records(path, false)?;
    let mut node_types: BTreeMap<u32, u32> = BTreeMap::new();
    let mut has_cropping = HashSet::new();
    let mut has_fov = HashSet::new();
    let mut ready_seen = HashSet::new();
    // Insertions, keyed by the offset of the STATE_READY record they go before.
    let mut inserts: BTreeMap<u64, Vec<u8>> = BTreeMap::new();
    let mut fix = CroppingFix::default();
    let mut reader = BufReader::new(File::open(path).map_err(io_err(path))?);
    for rec in &records {
        match rec.kind {
            record_type::NODE_ADDED | record_type::NODE_ADDED_1_0_0_5 => {
                let fields = read_range(&mut reader, path, rec.offset, rec.fields_size as usize)?;
                let (_, after_name) =
                    string_field(&fields, RECORD_HEADER_LEN).ok_or_else(|| {
                        OniFileError::Corrupt {
                            path: path.to_path_buf(),
                            offset: rec.offset,
                            reason: "NODE_ADDED without a node name".into(),
                        }
                    })?;
                let node_type = fields
                    .get(after_name..after_name + 4)
                    .map(|b| u32_at(b, 0))
                    .unwrap_or(0);
                node_types.insert(rec.node_id, node_type);
            }
            k if is_property(k) => match rec.property.as_deref() {
                Some("xnCropping") => {
                    has_cropping.insert(rec.node_id);
                }
                Some("xnFOV") => {
                    has_fov.insert(rec.node_id);
                }
                _ => {}
            },
            record_type::NODE_STATE_READY if ready_seen.insert(rec.node_id) => {
                let mut bytes = Vec::new();
                if !has_cropping.contains(&rec.node_id) {
                    bytes.extend(general_property(
                        rec.node_id,
                        "xnCropping",
                        &disabled_cropping(),
                    ));
                    fix.cropping_added.push(rec.node_id);
                }
                if !has_fov.contains(&rec.node_id) {
                    let (h, v) = fov(node_types.get(&rec.node_id).copied().unwrap_or(0));
                    bytes.extend(general_property(rec.node_id, "xnFOV", &field_of_view(h, v)));
                    fix.fov_added.push(rec.node_id);
                }
                if !bytes.is_empty() {
                    inserts.insert(rec.offset, bytes);
                }
            }
            _ => {}
        }
    }
    if !fix.changed() {
        return Ok(fix);
    }

    // new position of an old one: shifted by everything inserted at or before it.
    let points: Vec<(u64, u64)> = {
        let mut acc = 0u64;
        inserts
            .iter()
            .map(|(&at, bytes)| {
                acc += bytes.len() as u64;
                (at, acc)
            })
            .collect()
    };
    let moved = |pos: u64| -> u64 {
        if pos == 0 {
            return 0;
        }
        let shift = points
            .iter()
            .take_while(|(at, _)| *at <= pos)
            .last()
            .map_or(0, |&(_, acc)| acc);
        // Positions come from the file: a corrupt one near u64::MAX stays nonsense rather
        // than overflowing.
        pos.saturating_add(shift)
    };

    let tmp_path = path.with_extension("oni.fixing");
    let tmp = File::create(&tmp_path).map_err(io_err(&tmp_path))?;
    let mut out = BufWriter::new(tmp);
    let header = read_range(&mut reader, path, 0, FILE_HEADER_LEN as usize)?;
    out.write_all(&header).map_err(io_err(&tmp_path))?;
    for rec in &records {
        if let Some(bytes) = inserts.get(&rec.offset) {
            out.write_all(bytes).map_err(io_err(&tmp_path))?;
        }
        let mut bytes = read_range(&mut reader, path, rec.offset, rec.len() as usize)?;
        let undo = u64_at(&bytes, 20);
        bytes[20..28].copy_from_slice(&moved(undo).to_le_bytes());
        match rec.kind {
            record_type::NODE_ADDED => {
                // The seek-table position is the last field.
                let at = rec.fields_size as usize - 8;
                let pos = u64_at(&bytes, at);
                bytes[at..at + 8].copy_from_slice(&moved(pos).to_le_bytes());
            }
            record_type::SEEK_TABLE => {
                let start = rec.fields_size as usize;
                let entries = rec.payload_size as usize / SEEK_ENTRY_LEN;
                for i in 0..entries {
                    let at = start + i * SEEK_ENTRY_LEN + 12;
                    let pos = u64_at(&bytes, at);
                    bytes[at..at + 8].copy_from_slice(&moved(pos).to_le_bytes());
                }
            }
            _ => {}
        }
        out.write_all(&bytes).map_err(io_err(&tmp_path))?;
    }
    out.flush().map_err(io_err(&tmp_path))?;
    out.get_ref().sync_all().map_err(io_err(&tmp_path))?;
    drop(out);
    std::fs::rename(&tmp_path, path).map_err(io_err(path))?;
    tracing::info!(
        file = %path.display(),
        cropping = ?fix.cropping_added,
        fov = ?fix.fov_added,
        "added the property records OpenNI2's player needs"
    );
    Ok(fix)
}

/// What [`repair_truncated`] kept.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TruncationRepair {
    /// Frames kept per node id.
    pub frames: BTreeMap<u32, u32>,
    /// Bytes of the original file that were dropped (a partial record at the cut and any
    /// records after the last frame).
    pub dropped_bytes: u64,
}

/// Writes to `dst` a playable copy of a recording cut short at any byte (the recorder was
/// killed): every complete record up to the last complete frame, each node's `NODE_ADDED`
/// rewritten with the frames that remain (count, last timestamp, no seek table), and an `END`
/// record. OpenNI2's player refuses the cut file itself.
pub fn repair_truncated(src: &Path, dst: &Path) -> Result<TruncationRepair, OniFileError> {
    let records = list_records(src, true)?;
    let last_data = records
        .iter()
        .rposition(|r| r.kind == record_type::NEW_DATA)
        .ok_or_else(|| OniFileError::Corrupt {
            path: src.to_path_buf(),
            offset: FILE_HEADER_LEN,
            reason: "no complete frame before the cut".into(),
        })?;
    let kept = &records[..=last_data];
    let mut reader = BufReader::new(File::open(src).map_err(io_err(src))?);
    let mut frames: BTreeMap<u32, u32> = BTreeMap::new();
    let mut last_ts: BTreeMap<u32, u64> = BTreeMap::new();
    for rec in kept.iter().filter(|r| r.kind == record_type::NEW_DATA) {
        let fields = read_range(&mut reader, src, rec.offset, RECORD_HEADER_LEN + 8)?;
        *frames.entry(rec.node_id).or_default() += 1;
        last_ts.insert(rec.node_id, u64_at(&fields, RECORD_HEADER_LEN));
    }
    let out_file = File::create(dst).map_err(io_err(dst))?;
    let mut out = BufWriter::new(out_file);
    let header = read_range(&mut reader, src, 0, FILE_HEADER_LEN as usize)?;
    out.write_all(&header).map_err(io_err(dst))?;
    for rec in kept {
        let mut bytes = read_range(&mut reader, src, rec.offset, rec.len() as usize)?;
        if rec.kind == record_type::NODE_ADDED {
            // fields: header, name, node type u32, codec u32, frames u32, min ts u64, max ts u64,
            // seek-table position u64.
            let (_, after_name) =
                string_field(&bytes, RECORD_HEADER_LEN).ok_or_else(|| OniFileError::Corrupt {
                    path: src.to_path_buf(),
                    offset: rec.offset,
                    reason: "NODE_ADDED without a node name".into(),
                })?;
            let n = frames.get(&rec.node_id).copied().unwrap_or(0);
            let at = after_name + 8;
            if bytes.len() >= at + 28 {
                bytes[at..at + 4].copy_from_slice(&n.to_le_bytes());
                let max_ts = last_ts.get(&rec.node_id).copied().unwrap_or(0);
                bytes[at + 12..at + 20].copy_from_slice(&max_ts.to_le_bytes());
                bytes[at + 20..at + 28].copy_from_slice(&0u64.to_le_bytes());
            }
        }
        out.write_all(&bytes).map_err(io_err(dst))?;
    }
    let mut end = Vec::with_capacity(RECORD_HEADER_LEN);
    end.extend_from_slice(&RECORD_MAGIC.to_le_bytes());
    end.extend_from_slice(&record_type::END.to_le_bytes());
    end.extend_from_slice(&0u32.to_le_bytes());
    end.extend_from_slice(&(RECORD_HEADER_LEN as u32).to_le_bytes());
    end.extend_from_slice(&0u32.to_le_bytes());
    end.extend_from_slice(&0u64.to_le_bytes());
    out.write_all(&end).map_err(io_err(dst))?;
    out.flush().map_err(io_err(dst))?;
    let src_len = std::fs::metadata(src).map_err(io_err(src))?.len();
    let kept_end = kept.last().map_or(FILE_HEADER_LEN, |r| r.offset + r.len());
    Ok(TruncationRepair {
        frames,
        dropped_bytes: src_len - kept_end,
    })
}

pub(crate) fn read_range(
    reader: &mut BufReader<File>,
    path: &Path,
    offset: u64,
    len: usize,
) -> Result<Vec<u8>, OniFileError> {
    let mut buf = vec![0u8; len];
    reader.seek(SeekFrom::Start(offset)).map_err(io_err(path))?;
    reader.read_exact(&mut buf).map_err(io_err(path))?;
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(kind: u32, node: u32, fields: &[u8], payload: &[u8], undo: u64) -> Vec<u8> {
        let mut r = Vec::new();
        r.extend_from_slice(&RECORD_MAGIC.to_le_bytes());
        r.extend_from_slice(&kind.to_le_bytes());
        r.extend_from_slice(&node.to_le_bytes());
        r.extend_from_slice(&((RECORD_HEADER_LEN + fields.len()) as u32).to_le_bytes());
        r.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        r.extend_from_slice(&undo.to_le_bytes());
        r.extend_from_slice(fields);
        r.extend_from_slice(payload);
        r
    }

    /// A minimal file shaped like the recorder's: header, NODE_ADDED, a property,
    /// STATE_READY, two NEW_DATA, NODE_REMOVED, SEEK_TABLE, NODE_ADDED rewritten, END.
    fn synthetic_file(seek_table_pos_placeholder: bool) -> (Vec<u8>, u64, [u64; 2]) {
        let mut file = b"NI10".to_vec();
        file.extend_from_slice(&[1, 0, 1, 0, 0, 0, 0, 0]);
        file.extend_from_slice(&u64::MAX.to_le_bytes());
        file.extend_from_slice(&1u32.to_le_bytes());
        let node_added_at = file.len() as u64;
        let mut name = (6u32).to_le_bytes().to_vec();
        name.extend_from_slice(b"Depth\0");
        let node_added_fields = |seek: u64| {
            let mut f = name.clone();
            f.extend_from_slice(&2u32.to_le_bytes()); // depth
            f.extend_from_slice(&0u32.to_le_bytes());
            f.extend_from_slice(&2u32.to_le_bytes());
            f.extend_from_slice(&0u64.to_le_bytes());
            f.extend_from_slice(&33_000u64.to_le_bytes());
            f.extend_from_slice(&seek.to_le_bytes());
            f
        };
        file.extend(record(
            record_type::NODE_ADDED,
            1,
            &node_added_fields(0),
            &[],
            0,
        ));
        let prop = general_property(1, "xnMapOutputMode", &[0; 12]);
        file.extend(prop);
        file.extend(record(record_type::NODE_STATE_READY, 1, &[], &[], 0));
        let d1 = file.len() as u64;
        file.extend(record(record_type::NEW_DATA, 1, &[0; 12], &[7; 10], 0));
        let d2 = file.len() as u64;
        file.extend(record(record_type::NEW_DATA, 1, &[0; 12], &[8; 10], d1));
        file.extend(record(
            record_type::NODE_REMOVED,
            1,
            &[],
            &[],
            node_added_at,
        ));
        let seek_at = file.len() as u64;
        let mut table = vec![0u8; SEEK_ENTRY_LEN];
        for (i, pos) in [d1, d2].iter().enumerate() {
            table.extend_from_slice(&(i as u64 * 33_000).to_le_bytes());
            table.extend_from_slice(&0u32.to_le_bytes());
            table.extend_from_slice(&pos.to_le_bytes());
        }
        file.extend(record(record_type::SEEK_TABLE, 1, &[], &table, 0));
        // The recorder rewrites NODE_ADDED in place with the seek-table position.
        let rewritten = record(
            record_type::NODE_ADDED,
            1,
            &node_added_fields(if seek_table_pos_placeholder {
                0
            } else {
                seek_at
            }),
            &[],
            0,
        );
        let at = node_added_at as usize;
        file[at..at + rewritten.len()].copy_from_slice(&rewritten);
        file.extend(record(record_type::END, 0, &[], &[], 0));
        (file, seek_at, [d1, d2])
    }

    #[test]
    fn inserts_cropping_and_fov_and_moves_every_position() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.oni");
        let (bytes, seek_at, data_at) = synthetic_file(false);
        std::fs::write(&path, &bytes).unwrap();

        let fix = add_missing_cropping(&path, |_| (1.0, 0.75)).unwrap();
        assert_eq!(fix.cropping_added, vec![1]);
        assert_eq!(fix.fov_added, vec![1]);

        let inserted = (general_property(1, "xnCropping", &[0; 12]).len()
            + general_property(1, "xnFOV", &[0; 16]).len()) as u64;
        let recs = list_records(&path, false).unwrap();
        let names: Vec<_> = recs.iter().filter_map(|r| r.property.clone()).collect();
        assert_eq!(names, ["xnMapOutputMode", "xnCropping", "xnFOV"]);
        let ready = recs
            .iter()
            .position(|r| r.kind == record_type::NODE_STATE_READY)
            .unwrap();
        assert_eq!(recs[ready - 1].property.as_deref(), Some("xnFOV"));

        let new = std::fs::read(&path).unwrap();
        assert_eq!(new.len() as u64, bytes.len() as u64 + inserted);
        // NEW_DATA #2's undo position points at NEW_DATA #1's new place.
        let datas: Vec<_> = recs
            .iter()
            .filter(|r| r.kind == record_type::NEW_DATA)
            .collect();
        assert_eq!(datas[0].offset, data_at[0] + inserted);
        assert_eq!(datas[1].undo_position, datas[0].offset);
        // NODE_REMOVED still points at NODE_ADDED (before the insertion, unmoved).
        let removed = recs
            .iter()
            .find(|r| r.kind == record_type::NODE_REMOVED)
            .unwrap();
        assert_eq!(removed.undo_position, FILE_HEADER_LEN);
        // NODE_ADDED's seek-table position and the table's entries moved.
        let added = &recs[0];
        let at = (added.offset + added.fields_size as u64 - 8) as usize;
        assert_eq!(u64_at(&new, at), seek_at + inserted);
        let table = recs
            .iter()
            .find(|r| r.kind == record_type::SEEK_TABLE)
            .unwrap();
        let entries = (table.offset + table.fields_size as u64) as usize;
        assert_eq!(u64_at(&new, entries + 12), 0, "entry 0 is the empty one");
        assert_eq!(
            u64_at(&new, entries + SEEK_ENTRY_LEN + 12),
            data_at[0] + inserted
        );
        assert_eq!(
            u64_at(&new, entries + 2 * SEEK_ENTRY_LEN + 12),
            data_at[1] + inserted
        );
        // The payload bytes themselves are untouched.
        let d = (datas[1].offset + datas[1].fields_size as u64) as usize;
        assert_eq!(&new[d..d + 10], &[8; 10]);

        // A second pass finds nothing to do.
        assert!(!add_missing_cropping(&path, |_| (1.0, 0.75))
            .unwrap()
            .changed());
    }

    #[test]
    fn rejects_files_that_are_not_oni() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.oni");
        std::fs::write(&path, b"this is not a recording at all, just text").unwrap();
        let err = list_records(&path, false).unwrap_err();
        assert!(matches!(err, OniFileError::NotOni { .. }), "{err}");
        let (bytes, _, _) = synthetic_file(true);
        std::fs::write(&path, &bytes[..bytes.len() - 40]).unwrap();
        let err = list_records(&path, false).unwrap_err();
        assert!(err.to_string().contains("corrupt record"), "{err}");
        assert!(list_records(&path, true).is_ok());
    }
}
