//! [`MessageReader`]: the file's records through mcap's sans-io linear reader, chunk CRCs
//! checked before a chunk's messages are released, reads bounded by what the file holds;
//! channels and schemas resolved into [`RawMessage`]s, the cut of a truncated file logged.

use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

use crate::RecordingError;

const READ_SIZE: usize = 256 * 1024;

/// One message as stored.
#[derive(Debug, Clone)]
pub struct RawMessage {
    pub topic: Arc<str>,
    pub message_encoding: Arc<str>,
    /// Empty for schemaless channels.
    pub schema_name: Arc<str>,
    pub log_time: u64,
    pub publish_time: u64,
    pub data: Vec<u8>,
}

struct ChannelInfo {
    topic: Arc<str>,
    message_encoding: Arc<str>,
    schema_id: u16,
}

/// Every message of a session in file order, plus its metadata records, tolerant of a
/// truncated file.
pub struct MessageReader {
    path: PathBuf,
    file: File,
    linear: LinearReader,
    channels: HashMap<u16, ChannelInfo>,
    schemas: HashMap<u16, Arc<str>>,
    metadata: Vec<(String, std::collections::BTreeMap<String, String>)>,
    bytes_read: u64,
    truncated: bool,
    /// Warn about a cut once per reader, not once per loop.
    truncation_warned: bool,
    done: bool,
}

impl MessageReader {
    /// Opens a session file. A missing or unreadable file is an error; a truncated one is not.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref().to_path_buf();
        let file = File::open(&path).map_err(|source| RecordingError::Open {
            path: path.display().to_string(),
            source,
        })?;
        Ok(Self {
            path,
            file,
            linear: new_linear_reader(),
            channels: HashMap::new(),
            schemas: HashMap::new(),
            metadata: Vec::new(),
            bytes_read: 0,
            truncated: false,
            truncation_warned: false,
            done: false,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// True once the reader hit the end of a file that was cut off.
    pub fn is_truncated(&self) -> bool {
        self.truncated
    }

    /// Metadata records seen so far, in file order.
    pub fn metadata(&self) -> &[(String, std::collections::BTreeMap<String, String>)] {
        &self.metadata
    }

    /// Starts again from the beginning of the file.
    pub fn rewind(&mut self) -> Result<(), RecordingError> {
        use std::io::Seek;
        self.file
            .seek(std::io::SeekFrom::Start(0))
            .map_err(|source| RecordingError::Io {
                path: self.path_string(),
                source,
            })?;
        self.linear = new_linear_reader();
        self.channels.clear();
        self.schemas.clear();
        self.metadata.clear();
        self.bytes_read = 0;
        self.truncated = false;
        self.done = false;
        Ok(())
    }

    fn path_string(&self) -> String {
        self.path.display().to_string()
    }

    /// The next message, `Ok(None)` at the end (or at the cut of a truncated file).
    pub fn next_message(&mut self) -> Result<Option<RawMessage>, RecordingError> {
        if self.done {
            return Ok(None);
        }
        loop {
            // The mcap crate's reader does unchecked arithmetic on lengths from the file (an
            // uncompressed chunk whose record runs past the chunk underflows a counter): a
            // panic there is a corrupt file, not the end of the program.
            let linear = &mut self.linear;
            let next = std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || {
                let linear = linear;
                linear.next_event()
            }));
            let next = match next {
                Ok(next) => next,
                Err(_) => {
                    self.done = true;
                    return Err(RecordingError::Mcap {
                        path: self.path_string(),
                        offset: self.bytes_read,
                        source: mcap::McapError::UnexpectedEoc,
                    });
                }
            };
            let event = match next {
                None => {
                    self.done = true;
                    return Ok(None);
                }
                Some(Ok(event)) => event,
                // A writer killed while a chunk was open leaves that chunk's header with its
                // placeholder length (the writer patches it when the chunk closes); the mcap
                // reader reports that as an unexpected end of chunk. At the end of the file it
                // is the same cut as above.
                Some(Err(mcap::McapError::UnexpectedEof))
                | Some(Err(mcap::McapError::UnexpectedEoc))
                    if at_end_of_file(&self.file, self.bytes_read) =>
                {
                    self.done = true;
                    self.truncated = true;
                    if std::mem::replace(&mut self.truncation_warned, true) {
                        return Ok(None);
                    }
                    tracing::warn!(
                        path = %self.path.display(),
                        bytes = self.bytes_read,
                        "recording is truncated (the writer was probably killed): replayed up to its last complete chunk"
                    );
                    return Ok(None);
                }
                Some(Err(source)) => {
                    self.done = true;
                    return Err(RecordingError::Mcap {
                        path: self.path_string(),
                        offset: self.bytes_read,
                        source,
                    });
                }
            };
            match event {
                LinearReadEvent::ReadRequest(n) => {
                    // Never more than the file still holds: a record header claiming
                    // hundreds of megabytes in a small file costs no more than the file.
                    let left = self
                        .file
                        .metadata()
                        .map(|m| m.len().saturating_sub(self.bytes_read))
                        .unwrap_or(u64::MAX);
                    let want = n
                        .max(READ_SIZE)
                        .min(usize::try_from(left).unwrap_or(usize::MAX));
                    let buf = self.linear.insert(want.max(1));
                    let got =
                        read_some(&mut self.file, buf).map_err(|source| RecordingError::Io {
                            path: self.path.display().to_string(),
                            source,
                        })?;
                    self.bytes_read += got as u64;
                    self.linear.notify_read(got);
                }
                LinearReadEvent::Record { data, opcode } => {
                    // Only the records used here are parsed: the others (attachments,
                    // indexes, statistics) are skipped unread, so a malformed one can do
                    // nothing (the mcap crate's attachment parser panics on some).
                    use mcap::records::op;
                    if !matches!(
                        opcode,
                        op::SCHEMA | op::CHANNEL | op::METADATA | op::MESSAGE
                    ) {
                        continue;
                    }
                    let record = mcap::parse_record(opcode, data).map_err(|source| {
                        RecordingError::Mcap {
                            path: self.path.display().to_string(),
                            offset: self.bytes_read,
                            source,
                        }
                    })?;
                    match record {
                        Record::Schema { header, .. } => {
                            self.schemas.insert(header.id, header.name.into());
                        }
                        Record::Channel(c) => {
                            self.channels.insert(
                                c.id,
                                ChannelInfo {
                                    topic: c.topic.into(),
                                    message_encoding: c.message_encoding.into(),
                                    schema_id: c.schema_id,
                                },
                            );
                        }
                        Record::Metadata(m) => self.metadata.push((m.name, m.metadata)),
                        Record::Message { header, data } => {
                            let Some(channel) = self.channels.get(&header.channel_id) else {
                                return Err(RecordingError::Mcap {
                                    path: self.path.display().to_string(),
                                    offset: self.bytes_read,
                                    source: mcap::McapError::UnknownChannel(
                                        header.sequence,
                                        header.channel_id,
                                    ),
                                });
                            };
                            let schema_name = self
                                .schemas
                                .get(&channel.schema_id)
                                .cloned()
                                .unwrap_or_else(|| "".into());
                            return Ok(Some(RawMessage {
                                topic: channel.topic.clone(),
                                message_encoding: channel.message_encoding.clone(),
                                schema_name,
                                log_time: header.log_time,
                                publish_time: header.publish_time,
                                data: data.into_owned(),
                            }));
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}

/// True when every byte of the file has been read.
fn at_end_of_file(file: &File, bytes_read: u64) -> bool {
    file.metadata().map_or(true, |m| bytes_read >= m.len())
}

impl Iterator for MessageReader {
    type Item = Result<RawMessage, RecordingError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_message().transpose()
    }
}

/// Largest MCAP record (and decompressed chunk) read: a crafted length field is an error,
/// not an allocation of terabytes. The writer's chunks are 8 MiB; the largest image allowed
/// (4096 x 4096 RGB, 48 MiB) fits with room to spare.
pub const MAX_RECORD_BYTES: usize = 64 << 20;

fn new_linear_reader() -> LinearReader {
    // Check each chunk whole before releasing its messages: a chunk cut short by a killed
    // writer then yields nothing rather than a partial, possibly garbled, tail.
    LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES),
    )
}

fn read_some(file: &mut File, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match file.read(buf) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            other => return other,
        }
    }
}
