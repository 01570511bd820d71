//! Writing `.oni` recordings in plain Rust (no OpenNI calls): one depth stream (16-bit
//! millimetres) and one colour stream (RGB888), both uncompressed, in the record format
//! OpenNI2's file player reads (see [`crate::oni_file`] for the layout).
//!
//! What is written, in order (node 1 = `Depth`, node 2 = `Image`, like OpenNI2's recorder):
//! - the file header (`NI10`, format 1.0.1.0, the largest timestamp, max node id 2);
//! - per node: `NODE_ADDED` (codec `NONE`; frame count, timestamps and seek-table position
//!   filled in by [`OniWriter::finish`]), the property records OpenNI2's recorder writes for
//!   the Dummy device (`oniRequiredFrameSize`, `xnIsGenerating`, `xnDeviceMaxDepth` (depth),
//!   `xnSupportedMapOutputModesCount`, `xnSupportedMapOutputModes`, `xnMapOutputMode`,
//!   `xnSupportedPixelFormats`, `xnPixelFormat`, `oniPixelFormat`) plus the `xnCropping`
//!   (disabled) and `xnFOV` records the player needs, then `NODE_STATE_READY`;
//! - `NODE_DATA_BEGIN` for both nodes (after both are ready: the player stops setting up at the
//!   first one, so a node added after it would have no stream);
//! - `NEW_DATA` per frame (timestamp in microseconds, 1-based frame number, undo position =
//!   the node's previous frame);
//! - per node `NODE_REMOVED` and `SEEK_TABLE` (one empty entry, then timestamp, configuration
//!   0 and file position per frame), then `END`.
//!
//! A recording holds no registration property (the Dummy device has none either): the player
//! reports none, and a reader that registers depth to colour from the two fields of view gets
//! the identity when both streams share size and field of view.

use std::fs::File;
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::oni_file::{record_type, OniFileError};

const RECORD_MAGIC: u32 = 0x0052_494E;
const RECORD_HEADER_LEN: usize = 28;
const DEPTH_NODE: u32 = 1;
const COLOR_NODE: u32 = 2;
/// OpenNI 1.x production node types.
const NODE_TYPE_DEPTH: u32 = 2;
const NODE_TYPE_IMAGE: u32 = 3;
/// `XN_CODEC_UNCOMPRESSED`: the four characters `NONE`.
const CODEC_NONE: u32 = u32::from_le_bytes(*b"NONE");
/// OpenNI 1.x pixel formats (`XnPixelFormat`).
const XN_PIXEL_FORMAT_RGB24: u64 = 1;
const XN_PIXEL_FORMAT_GRAYSCALE_16_BIT: u64 = 4;
/// `OniPixelFormat`.
const ONI_PIXEL_FORMAT_DEPTH_1_MM: u64 = 100;
const ONI_PIXEL_FORMAT_RGB888: u64 = 200;
/// The player's buffer for one uncompressed frame (`PlayerNode::DATA_MAX_SIZE`,
/// 1600x1200x3 bytes).
pub const MAX_FRAME_BYTES: usize = 1600 * 1200 * 3;

/// One stream's geometry: image size, nominal frame rate, and field of view in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OniStreamSpec {
    pub width: u32,
    pub height: u32,
    pub fps: u32,
    pub hfov: f64,
    pub vfov: f64,
}

/// What [`OniWriter::finish`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OniWriteSummary {
    pub depth_frames: u32,
    pub color_frames: u32,
    pub bytes: u64,
}

struct Node {
    id: u32,
    name: &'static str,
    node_type: u32,
    spec: OniStreamSpec,
    bytes_per_pixel: usize,
    added_at: u64,
    /// (timestamp, file position) of every frame.
    frames: Vec<(u64, u64)>,
}

impl Node {
    fn frame_bytes(&self) -> usize {
        self.spec.width as usize * self.spec.height as usize * self.bytes_per_pixel
    }

    fn last_ts(&self) -> Option<u64> {
        self.frames.last().map(|&(ts, _)| ts)
    }
}

/// Writes a depth + colour `.oni` recording frame by frame. Nothing is valid until
/// [`finish`](Self::finish) (frame counts, seek tables and the `END` record come last).
pub struct OniWriter {
    path: PathBuf,
    out: BufWriter<File>,
    pos: u64,
    depth: Node,
    color: Node,
    scratch: Vec<u8>,
}

fn record_header(
    kind: u32,
    node_id: u32,
    fields_len: usize,
    payload_len: usize,
    undo: u64,
) -> Vec<u8> {
    let mut r = Vec::with_capacity(RECORD_HEADER_LEN + fields_len);
    r.extend_from_slice(&RECORD_MAGIC.to_le_bytes());
    r.extend_from_slice(&kind.to_le_bytes());
    r.extend_from_slice(&node_id.to_le_bytes());
    r.extend_from_slice(&((RECORD_HEADER_LEN + fields_len) as u32).to_le_bytes());
    r.extend_from_slice(&(payload_len as u32).to_le_bytes());
    r.extend_from_slice(&undo.to_le_bytes());
    r
}

fn record(kind: u32, node_id: u32, fields: &[u8]) -> Vec<u8> {
    let mut r = record_header(kind, node_id, fields.len(), 0, 0);
    r.extend_from_slice(fields);
    r
}

fn name_field(name: &str) -> Vec<u8> {
    let mut f = ((name.len() + 1) as u32).to_le_bytes().to_vec();
    f.extend_from_slice(name.as_bytes());
    f.push(0);
    f
}

/// A property record: name, data size, data.
fn property(kind: u32, node_id: u32, name: &str, data: &[u8]) -> Vec<u8> {
    let mut f = name_field(name);
    f.extend_from_slice(&(data.len() as u32).to_le_bytes());
    f.extend_from_slice(data);
    record(kind, node_id, &f)
}

fn int_property(node_id: u32, name: &str, value: u64) -> Vec<u8> {
    property(
        record_type::INT_PROPERTY,
        node_id,
        name,
        &value.to_le_bytes(),
    )
}

fn general_property(node_id: u32, name: &str, data: &[u8]) -> Vec<u8> {
    property(record_type::GENERAL_PROPERTY, node_id, name, data)
}

/// `NODE_ADDED` fields: name, node type, codec, frame count, min and max timestamp,
/// seek-table position.
fn node_added_fields(
    node: &Node,
    frames: u32,
    min_ts: u64,
    max_ts: u64,
    seek_table: u64,
) -> Vec<u8> {
    let mut f = name_field(node.name);
    f.extend_from_slice(&node.node_type.to_le_bytes());
    f.extend_from_slice(&CODEC_NONE.to_le_bytes());
    f.extend_from_slice(&frames.to_le_bytes());
    f.extend_from_slice(&min_ts.to_le_bytes());
    f.extend_from_slice(&max_ts.to_le_bytes());
    f.extend_from_slice(&seek_table.to_le_bytes());
    f
}

fn map_output_mode(spec: &OniStreamSpec) -> [u8; 12] {
    let mut b = [0u8; 12];
    b[0..4].copy_from_slice(&spec.width.to_le_bytes());
    b[4..8].copy_from_slice(&spec.height.to_le_bytes());
    b[8..12].copy_from_slice(&spec.fps.to_le_bytes());
    b
}

fn file_header(max_ts: u64) -> [u8; 24] {
    let mut h = [0u8; 24];
    h[0..4].copy_from_slice(b"NI10");
    // Format version 1.0.1.0: major u8, minor u8, maintenance u16, build u32.
    h[4..12].copy_from_slice(&[1, 0, 1, 0, 0, 0, 0, 0]);
    h[12..20].copy_from_slice(&max_ts.to_le_bytes());
    h[20..24].copy_from_slice(&COLOR_NODE.to_le_bytes());
    h
}

impl OniWriter {
    /// Creates `path` (replacing it) and writes the header and both nodes' set-up records.
    pub fn create(
        path: &Path,
        depth: OniStreamSpec,
        color: OniStreamSpec,
    ) -> Result<OniWriter, OniFileError> {
        let invalid = |reason: String| OniFileError::Invalid {
            path: path.to_path_buf(),
            reason,
        };
        for (what, spec, bpp) in [("depth", &depth, 2usize), ("colour", &color, 3)] {
            if spec.width == 0 || spec.height == 0 {
                return Err(invalid(format!(
                    "{what} stream of {}x{} pixels",
                    spec.width, spec.height
                )));
            }
            let bytes = spec.width as usize * spec.height as usize * bpp;
            if bytes > MAX_FRAME_BYTES {
                return Err(invalid(format!(
                    "{what} frames of {}x{} ({bytes} bytes) exceed the {MAX_FRAME_BYTES} bytes \
                     OpenNI2's player can hold",
                    spec.width, spec.height
                )));
            }
            let fov_ok = |a: f64| a.is_finite() && a > 0.0 && a < std::f64::consts::PI;
            if !fov_ok(spec.hfov) || !fov_ok(spec.vfov) {
                return Err(invalid(format!(
                    "{what} field of view {} x {} rad is not within (0, π)",
                    spec.hfov, spec.vfov
                )));
            }
        }
        let file = File::create(path).map_err(|source| OniFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut w = OniWriter {
            path: path.to_path_buf(),
            out: BufWriter::with_capacity(1 << 20, file),
            pos: 0,
            depth: Node {
                id: DEPTH_NODE,
                name: "Depth",
                node_type: NODE_TYPE_DEPTH,
                spec: depth,
                bytes_per_pixel: 2,
                added_at: 0,
                frames: Vec::new(),
            },
            color: Node {
                id: COLOR_NODE,
                name: "Image",
                node_type: NODE_TYPE_IMAGE,
                spec: color,
                bytes_per_pixel: 3,
                added_at: 0,
                frames: Vec::new(),
            },
            scratch: Vec::new(),
        };
        w.put(&file_header(u64::MAX))?;
        for is_depth in [true, false] {
            let node = if is_depth { &w.depth } else { &w.color };
            let id = node.id;
            let mode = map_output_mode(&node.spec);
            let mut fov = [0u8; 16];
            fov[..8].copy_from_slice(&node.spec.hfov.to_le_bytes());
            fov[8..].copy_from_slice(&node.spec.vfov.to_le_bytes());
            let mut records = vec![
                record(
                    record_type::NODE_ADDED,
                    id,
                    &node_added_fields(node, 0, 0, 0, 0),
                ),
                int_property(id, "oniRequiredFrameSize", node.frame_bytes() as u64),
                int_property(id, "xnIsGenerating", 1),
            ];
            if is_depth {
                records.push(int_property(id, "xnDeviceMaxDepth", u16::MAX as u64));
            }
            records.extend([
                int_property(id, "xnSupportedMapOutputModesCount", 1),
                general_property(id, "xnSupportedMapOutputModes", &mode),
                general_property(id, "xnMapOutputMode", &mode),
                // XnSupportedPixelFormats bit field: Grayscale16 (depth) or RGB24 (image).
                general_property(
                    id,
                    "xnSupportedPixelFormats",
                    &(if is_depth { 8u32 } else { 1u32 }).to_le_bytes(),
                ),
                int_property(
                    id,
                    "xnPixelFormat",
                    if is_depth {
                        XN_PIXEL_FORMAT_GRAYSCALE_16_BIT
                    } else {
                        XN_PIXEL_FORMAT_RGB24
                    },
                ),
                int_property(
                    id,
                    "oniPixelFormat",
                    if is_depth {
                        ONI_PIXEL_FORMAT_DEPTH_1_MM
                    } else {
                        ONI_PIXEL_FORMAT_RGB888
                    },
                ),
                // A disabled XnCropping (XnBool + four u16).
                general_property(id, "xnCropping", &[0u8; 12]),
                general_property(id, "xnFOV", &fov),
                record(record_type::NODE_STATE_READY, id, &[]),
            ]);
            let added_at = w.pos;
            if is_depth {
                w.depth.added_at = added_at;
            } else {
                w.color.added_at = added_at;
            }
            for r in records {
                w.put(&r)?;
            }
        }
        for id in [DEPTH_NODE, COLOR_NODE] {
            // Frame count and largest timestamp unknown yet (OpenNI2's recorder leaves them
            // all ones too; the player reads them from NODE_ADDED).
            w.put(&record(record_type::NODE_DATA_BEGIN, id, &[0xff; 12]))?;
        }
        Ok(w)
    }

    fn put(&mut self, bytes: &[u8]) -> Result<(), OniFileError> {
        self.out
            .write_all(bytes)
            .map_err(|source| OniFileError::Io {
                path: self.path.clone(),
                source,
            })?;
        self.pos += bytes.len() as u64;
        Ok(())
    }

    fn write_frame(
        &mut self,
        is_depth: bool,
        ts_us: u64,
        payload: &[u8],
    ) -> Result<(), OniFileError> {
        let node = if is_depth { &self.depth } else { &self.color };
        let what = if is_depth { "depth" } else { "colour" };
        if payload.len() != node.frame_bytes() {
            return Err(OniFileError::Invalid {
                path: self.path.clone(),
                reason: format!(
                    "{what} frame {} has {} bytes, the stream's {}x{} frames have {}",
                    node.frames.len() + 1,
                    payload.len(),
                    node.spec.width,
                    node.spec.height,
                    node.frame_bytes()
                ),
            });
        }
        if let Some(last) = node.last_ts() {
            if ts_us <= last {
                return Err(OniFileError::Invalid {
                    path: self.path.clone(),
                    reason: format!(
                        "{what} frame {} has timestamp {ts_us} µs, not after the previous {last} µs",
                        node.frames.len() + 1
                    ),
                });
            }
        }
        let undo = node.frames.last().map_or(0, |&(_, pos)| pos);
        let number = node.frames.len() as u32 + 1;
        let id = node.id;
        let mut fields = [0u8; 12];
        fields[..8].copy_from_slice(&ts_us.to_le_bytes());
        fields[8..].copy_from_slice(&number.to_le_bytes());
        let at = self.pos;
        let mut header =
            record_header(record_type::NEW_DATA, id, fields.len(), payload.len(), undo);
        header.extend_from_slice(&fields);
        self.put(&header)?;
        self.put(payload)?;
        let node = if is_depth {
            &mut self.depth
        } else {
            &mut self.color
        };
        node.frames.push((ts_us, at));
        Ok(())
    }

    /// Appends a depth frame: row-major millimetres, 0 = no reading.
    pub fn write_depth(&mut self, ts_us: u64, depth_mm: &[u16]) -> Result<(), OniFileError> {
        let mut bytes = std::mem::take(&mut self.scratch);
        bytes.clear();
        bytes.extend(depth_mm.iter().flat_map(|d| d.to_le_bytes()));
        let result = self.write_frame(true, ts_us, &bytes);
        self.scratch = bytes;
        result
    }

    /// Appends a colour frame: row-major R, G, B bytes.
    pub fn write_color(&mut self, ts_us: u64, rgb: &[u8]) -> Result<(), OniFileError> {
        self.write_frame(false, ts_us, rgb)
    }

    /// Frames written so far: (depth, colour).
    pub fn frames(&self) -> (u32, u32) {
        (
            self.depth.frames.len() as u32,
            self.color.frames.len() as u32,
        )
    }

    /// Writes the trailing records, fills in frame counts, timestamps and seek-table
    /// positions, and syncs the file.
    pub fn finish(mut self) -> Result<OniWriteSummary, OniFileError> {
        let mut seek_tables = [0u64; 2];
        for (i, is_depth) in [true, false].into_iter().enumerate() {
            let node = if is_depth { &self.depth } else { &self.color };
            let removed = record_header(record_type::NODE_REMOVED, node.id, 0, 0, node.added_at);
            let mut table = vec![0u8; 20];
            for &(ts, pos) in &node.frames {
                table.extend_from_slice(&ts.to_le_bytes());
                table.extend_from_slice(&0u32.to_le_bytes());
                table.extend_from_slice(&pos.to_le_bytes());
            }
            let mut seek = record_header(record_type::SEEK_TABLE, node.id, 0, table.len(), 0);
            seek.extend_from_slice(&table);
            self.put(&removed)?;
            seek_tables[i] = self.pos;
            self.put(&seek)?;
        }
        self.put(&record(record_type::END, 0, &[]))?;
        let bytes = self.pos;

        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source: io::Error| OniFileError::Io { path, source }
        };
        self.out.flush().map_err(io(&self.path))?;
        let max_ts = self
            .depth
            .last_ts()
            .into_iter()
            .chain(self.color.last_ts())
            .max()
            .unwrap_or(0);
        let mut patches = vec![(0u64, file_header(max_ts).to_vec())];
        for (node, seek_table) in [(&self.depth, seek_tables[0]), (&self.color, seek_tables[1])] {
            let n = node.frames.len() as u32;
            let min_ts = node.frames.first().map_or(0, |&(ts, _)| ts);
            let max_ts = node.last_ts().unwrap_or(0);
            let seek_table = if n > 0 { seek_table } else { 0 };
            patches.push((
                node.added_at,
                record(
                    record_type::NODE_ADDED,
                    node.id,
                    &node_added_fields(node, n, min_ts, max_ts, seek_table),
                ),
            ));
        }
        let file = self.out.get_mut();
        for (at, bytes) in patches {
            file.seek(SeekFrom::Start(at)).map_err(io(&self.path))?;
            file.write_all(&bytes).map_err(io(&self.path))?;
        }
        file.sync_all().map_err(io(&self.path))?;
        Ok(OniWriteSummary {
            depth_frames: self.depth.frames.len() as u32,
            color_frames: self.color.frames.len() as u32,
            bytes,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::oni_file::list_records;

    fn spec(w: u32, h: u32) -> OniStreamSpec {
        OniStreamSpec {
            width: w,
            height: h,
            fps: 30,
            hfov: 1.0,
            vfov: 0.8,
        }
    }

    fn u64_at(b: &[u8], at: usize) -> u64 {
        u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
    }

    #[test]
    fn layout_matches_the_recorder_and_positions_point_at_frames() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.oni");
        let mut w = OniWriter::create(&path, spec(4, 3), spec(4, 3)).unwrap();
        for i in 0..3u64 {
            let ts = 1000 + i * 33_333;
            w.write_depth(ts, &[i as u16 + 500; 12]).unwrap();
            w.write_color(ts, &[i as u8; 36]).unwrap();
        }
        let summary = w.finish().unwrap();
        assert_eq!((summary.depth_frames, summary.color_frames), (3, 3));
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len() as u64, summary.bytes);
        assert_eq!(
            u64_at(&bytes, 12),
            1000 + 2 * 33_333,
            "header max timestamp"
        );

        let recs = list_records(&path, false).unwrap();
        let kinds: Vec<u32> = recs.iter().map(|r| r.kind).collect();
        let first_data_begin = kinds
            .iter()
            .position(|&k| k == record_type::NODE_DATA_BEGIN)
            .unwrap();
        let last_ready = kinds
            .iter()
            .rposition(|&k| k == record_type::NODE_STATE_READY)
            .unwrap();
        assert!(
            last_ready < first_data_begin,
            "both nodes set up before data begins"
        );
        assert_eq!(*kinds.last().unwrap(), record_type::END);
        for node in [DEPTH_NODE, COLOR_NODE] {
            let props: Vec<_> = recs
                .iter()
                .filter(|r| r.node_id == node)
                .filter_map(|r| r.property.clone())
                .collect();
            for needed in ["xnMapOutputMode", "oniPixelFormat", "xnCropping", "xnFOV"] {
                assert!(
                    props.iter().any(|p| p == needed),
                    "node {node} lacks {needed}"
                );
            }
            let datas: Vec<_> = recs
                .iter()
                .filter(|r| r.kind == record_type::NEW_DATA && r.node_id == node)
                .collect();
            assert_eq!(datas.len(), 3);
            assert_eq!(datas[0].undo_position, 0);
            assert_eq!(datas[1].undo_position, datas[0].offset);
            assert_eq!(datas[2].undo_position, datas[1].offset);
            // NODE_ADDED: counts, timestamps, and the seek table's position.
            let added = recs
                .iter()
                .find(|r| r.kind == record_type::NODE_ADDED && r.node_id == node)
                .unwrap();
            let end = (added.offset + added.fields_size as u64) as usize;
            let table_at = u64_at(&bytes, end - 8);
            assert_eq!(u64_at(&bytes, end - 16), 1000 + 2 * 33_333);
            assert_eq!(u64_at(&bytes, end - 24), 1000);
            assert_eq!(
                u32::from_le_bytes(bytes[end - 28..end - 24].try_into().unwrap()),
                3
            );
            let table = recs.iter().find(|r| r.offset == table_at).unwrap();
            assert_eq!(table.kind, record_type::SEEK_TABLE);
            assert_eq!(table.payload_size, 4 * 20);
            let entries = (table.offset + table.fields_size as u64) as usize;
            for (i, d) in datas.iter().enumerate() {
                let e = entries + (i + 1) * 20;
                assert_eq!(u64_at(&bytes, e), 1000 + i as u64 * 33_333);
                assert_eq!(u64_at(&bytes, e + 12), d.offset);
            }
            let removed = recs
                .iter()
                .find(|r| r.kind == record_type::NODE_REMOVED && r.node_id == node)
                .unwrap();
            assert_eq!(removed.undo_position, added.offset);
        }
        // Depth payloads are little-endian u16.
        let d = recs
            .iter()
            .filter(|r| r.kind == record_type::NEW_DATA && r.node_id == DEPTH_NODE)
            .nth(2)
            .unwrap();
        let at = (d.offset + d.fields_size as u64) as usize;
        assert_eq!(u16::from_le_bytes([bytes[at], bytes[at + 1]]), 502);
    }

    #[test]
    fn refuses_bad_frames_and_streams() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.oni");
        let err = OniWriter::create(&path, spec(2000, 1500), spec(4, 3))
            .err()
            .unwrap();
        assert!(err.to_string().contains("exceed"), "{err}");
        let mut w = OniWriter::create(&path, spec(4, 3), spec(4, 3)).unwrap();
        let err = w.write_depth(0, &[0; 11]).unwrap_err();
        assert!(err.to_string().contains("22 bytes"), "{err}");
        w.write_color(5, &[0; 36]).unwrap();
        let err = w.write_color(5, &[0; 36]).unwrap_err();
        assert!(err.to_string().contains("not after"), "{err}");
    }
}
