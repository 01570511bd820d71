//! Writing the file: the binary buffer assembled from the spools, the `.glb` / `.gltf` +
//! `.bin` / embedded layouts, written under a temporary name and renamed.

use super::*;

/// Stand-in for the data URI in the serialised JSON; the base64 is streamed in its place.
pub(super) const DATA_URI_SENTINEL: &str = "mouthpiece-embedded-buffer";
pub(super) const DATA_URI_PREFIX: &str = "data:application/octet-stream;base64,";

pub(super) fn accessor(
    view: json::Index<json::buffer::View>,
    count: u64,
    type_: json::accessor::Type,
    component: json::accessor::ComponentType,
    bounds: Option<(Value, Value)>,
) -> json::Accessor {
    let (min, max) = bounds.unzip();
    json::Accessor {
        buffer_view: Some(view),
        byte_offset: None,
        count: USize64(count),
        component_type: Valid(json::accessor::GenericComponentType(component)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(type_),
        min,
        max,
        name: None,
        normalized: false,
        sparse: None,
    }
}

/// Marker half-size: 2 % of the mouth width, or 1 mm-ish when the width is unknown (0).
pub(super) fn marker_size(width: f64) -> f32 {
    if width > 0.0 {
        (0.02 * width) as f32
    } else {
        0.001
    }
}

/// An octahedron of half-size `s`: positions (6 × VEC3 f32), indices (24 × u16, outward
/// counter-clockwise), and the positions' bounds.
pub(super) fn octahedron(s: f32) -> (Vec<u8>, Vec<u8>, Bounds<3>) {
    let vertices = [
        [s, 0.0, 0.0],
        [-s, 0.0, 0.0],
        [0.0, s, 0.0],
        [0.0, -s, 0.0],
        [0.0, 0.0, s],
        [0.0, 0.0, -s],
    ];
    let mut bounds = Bounds::new();
    let mut positions = Vec::with_capacity(72);
    for v in &vertices {
        bounds.add(v);
        for c in v {
            positions.extend_from_slice(&c.to_le_bytes());
        }
    }
    let mut indices = Vec::with_capacity(48);
    for (sx, sy, sz) in [
        (0, 2, 4),
        (1, 2, 4),
        (0, 3, 4),
        (1, 3, 4),
        (0, 2, 5),
        (1, 2, 5),
        (0, 3, 5),
        (1, 3, 5),
    ] {
        // (+x, +y, +z) is counter-clockwise seen from outside; each negated axis flips it.
        let flips = sx % 2 + sy % 2 + sz % 2;
        let tri: [u16; 3] = if flips % 2 == 0 {
            [sx, sy, sz]
        } else {
            [sx, sz, sy]
        };
        for i in tri {
            indices.extend_from_slice(&i.to_le_bytes());
        }
    }
    (positions, indices, bounds)
}

/// Percent-encodes a file name for a relative URI (RFC 3986 unreserved characters stay).
pub(super) fn uri_escape(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for b in name.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Copies the binary buffer's pieces, in order, from memory and the spool files.
pub(super) struct Assembler<'a> {
    pub(super) channels: &'a [Channel],
    pub(super) spools: &'a mut [File],
    pub(super) pieces: &'a [Piece],
}

impl Assembler<'_> {
    pub(super) fn write_bin(&mut self, out: &mut dyn Write) -> Result<(), WriteError> {
        for piece in self.pieces {
            match *piece {
                Piece::Bytes(ref bytes) => out.write_all(bytes).map_err(WriteError::Out)?,
                Piece::Times { channel } => self.copy_column(channel, 0..4, out)?,
                Piece::Values { channel } => {
                    let end = self.channels[channel].record_len();
                    self.copy_column(channel, 4..end, out)?
                }
            }
        }
        Ok(())
    }

    fn copy_column(
        &mut self,
        channel: usize,
        columns: std::ops::Range<usize>,
        out: &mut dyn Write,
    ) -> Result<(), WriteError> {
        let spool = &mut self.spools[channel];
        spool.seek(SeekFrom::Start(0)).map_err(WriteError::Spool)?;
        let mut reader = BufReader::with_capacity(64 * 1024, spool);
        let mut buffer = [0u8; RECORD];
        let record = &mut buffer[..self.channels[channel].record_len()];
        for _ in 0..self.channels[channel].keys {
            reader.read_exact(record).map_err(WriteError::Spool)?;
            out.write_all(&record[columns.clone()])
                .map_err(WriteError::Out)?;
        }
        Ok(())
    }

    pub(super) fn write_glb(
        &mut self,
        mut json: Vec<u8>,
        bin_len: u64,
        out: &mut dyn Write,
    ) -> Result<(), WriteError> {
        // Chunks are 4-byte aligned: JSON padded with spaces; our buffer is all 4-byte data.
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        debug_assert_eq!(bin_len % 4, 0);
        let total = 12 + 8 + json.len() as u64 + 8 + bin_len;
        let total32 = u32::try_from(total).map_err(|_| WriteError::TooLarge(total))?;
        out.write_all(b"glTF").map_err(WriteError::Out)?;
        out.write_all(&2u32.to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(&total32.to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(&(json.len() as u32).to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(b"JSON").map_err(WriteError::Out)?;
        out.write_all(&json).map_err(WriteError::Out)?;
        out.write_all(&(bin_len as u32).to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(b"BIN\0").map_err(WriteError::Out)?;
        self.write_bin(out)
    }

    pub(super) fn write_embedded(
        &mut self,
        json: &str,
        out: &mut dyn Write,
    ) -> Result<(), WriteError> {
        let (before, after) = json
            .split_once(DATA_URI_SENTINEL)
            .expect("the document holds the sentinel URI");
        out.write_all(before.as_bytes()).map_err(WriteError::Out)?;
        out.write_all(DATA_URI_PREFIX.as_bytes())
            .map_err(WriteError::Out)?;
        {
            let mut encoder = base64::write::EncoderWriter::new(
                &mut *out,
                &base64::engine::general_purpose::STANDARD,
            );
            self.write_bin(&mut encoder)?;
            encoder.finish().map_err(WriteError::Out)?;
        }
        out.write_all(after.as_bytes()).map_err(WriteError::Out)
    }
}

/// Failures while assembling an output file, told apart so the message names the right file.
#[derive(Debug)]
pub(super) enum WriteError {
    Out(io::Error),
    Spool(io::Error),
    TooLarge(u64),
}

impl From<io::Error> for WriteError {
    fn from(e: io::Error) -> Self {
        Self::Out(e)
    }
}

/// Writes `path` through a temporary file in the same directory, renamed when complete.
pub(super) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<(), WriteError>,
) -> Result<(), ExportError> {
    let out_err = |cause: io::Error| ExportError::write(path, cause);
    let mut pending = PendingFile::create(path).map_err(out_err)?;
    write(&mut pending).map_err(|e| match e {
        WriteError::Out(cause) => out_err(cause),
        WriteError::Spool(cause) => ExportError::write(parent_dir(path), cause),
        WriteError::TooLarge(bytes) => ExportError::TooLargeForGlb { bytes },
    })?;
    pending.commit().map_err(out_err)
}
