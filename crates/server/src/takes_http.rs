//! Takes played back in the console: `GET /take?file=NAME&from=S&seconds=S` answers with one
//! chunk of a take (its images as JPEG, the dots in image pixels, the sound as PCM) read by
//! the daemon's [`TakeArchive`].
//!
//! Safe by construction: the token is checked as for a WebSocket (`?token=` or
//! `Authorization: Bearer`); the name is a plain file name (the archive refuses anything
//! else and only opens files inside its takes folder); a chunk is at most
//! [`MAX_CHUNK_SECONDS`] long and the archive caps its bytes; at most
//! [`MAX_CONCURRENT_READS`] chunks are read at once (others get 503), so memory stays bounded
//! whatever the clients ask.
//!
//! The answer (`application/octet-stream`): `MPT1`, a u32 (little-endian) length, that many
//! bytes of JSON (`ChunkHeader`), then the data the header's `[offset, length]` pairs point
//! into (offsets from the first byte after the JSON).

use std::sync::{Arc, Mutex};

use serde::Serialize;

use crate::preview::ImageDot;

/// Longest chunk asked for, seconds.
pub const MAX_CHUNK_SECONDS: f64 = 10.0;
/// Chunks read at the same time, over all clients.
pub const MAX_CONCURRENT_READS: usize = 2;

/// One frame of a chunk.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ChunkFrame {
    /// Seconds from the take's first frame.
    pub t: f64,
    /// The colour image, JPEG.
    pub jpeg: Vec<u8>,
    /// The tracked dots in the image's pixels (the dots not seen are left out).
    pub dots: Vec<ImageDot>,
}

/// The sound of a chunk: interleaved signed 16-bit little-endian PCM.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ChunkAudio {
    pub sample_rate: u32,
    pub channels: u16,
    /// When the first sample sounds, seconds from the take's first frame.
    pub start_s: f64,
    pub pcm_s16le: Vec<u8>,
}

/// A piece of a take.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TakeChunk {
    /// Image size the dots are measured in (the take's colour image).
    pub width: u32,
    pub height: u32,
    pub frames: Vec<ChunkFrame>,
    pub audio: Option<ChunkAudio>,
    /// Where the next chunk starts, seconds (earlier than asked when the chunk hit its byte
    /// cap).
    pub next_s: f64,
    /// The take ends within this chunk.
    pub end: bool,
    /// Said to the technician (e.g. why the sound is missing).
    pub notes: Vec<String>,
}

/// Why a chunk could not be served.
#[derive(Debug, Clone, PartialEq)]
pub enum TakeChunkError {
    /// The name is not a take's file name (HTTP 400).
    BadName(String),
    /// No such take in the folder (HTTP 404).
    NotFound(String),
    /// The file could not be read (HTTP 500).
    Unreadable(String),
}

/// Reads chunks of the takes in one folder (the daemon's `[takes] folder`).
pub trait TakeArchive: Send + Sync + std::fmt::Debug {
    /// The chunk of take `file` (a file name, no folder) from `from_s` for `seconds`
    /// (both already checked: finite, `0 ≤ from_s`, `0 < seconds ≤` [`MAX_CHUNK_SECONDS`]).
    fn chunk(&self, file: &str, from_s: f64, seconds: f64) -> Result<TakeChunk, TakeChunkError>;
}

/// The archive the server reads from, and the reads in flight.
#[derive(Debug)]
pub(crate) struct TakeService {
    archive: Mutex<Option<Arc<dyn TakeArchive>>>,
    reads: Arc<tokio::sync::Semaphore>,
}

impl Default for TakeService {
    fn default() -> Self {
        Self {
            archive: Mutex::new(None),
            reads: Arc::new(tokio::sync::Semaphore::new(MAX_CONCURRENT_READS)),
        }
    }
}

impl TakeService {
    /// Serves the takes of `archive` (`None`: none).
    pub(crate) fn set_archive(&self, archive: Option<Arc<dyn TakeArchive>>) {
        *self.archive.lock().unwrap_or_else(|e| e.into_inner()) = archive;
    }

    /// The archive served now.
    fn archive(&self) -> Option<Arc<dyn TakeArchive>> {
        self.archive
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }
}

#[derive(Serialize)]
struct HeaderFrame<'a> {
    t: f64,
    image: [usize; 2],
    dots: &'a [ImageDot],
}

#[derive(Serialize)]
struct HeaderAudio {
    sample_rate: u32,
    channels: u16,
    start_s: f64,
    data: [usize; 2],
}

/// The JSON at the head of a chunk.
#[derive(Serialize)]
struct ChunkHeader<'a> {
    width: u32,
    height: u32,
    from_s: f64,
    next_s: f64,
    end: bool,
    frames: Vec<HeaderFrame<'a>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    audio: Option<HeaderAudio>,
    notes: &'a [String],
}

/// The chunk as sent: `MPT1`, JSON length, JSON, data.
pub fn encode_chunk(chunk: &TakeChunk, from_s: f64) -> Vec<u8> {
    let mut data_len = 0usize;
    let mut frames = Vec::with_capacity(chunk.frames.len());
    for f in &chunk.frames {
        frames.push(HeaderFrame {
            t: f.t,
            image: [data_len, f.jpeg.len()],
            dots: &f.dots,
        });
        data_len += f.jpeg.len();
    }
    let audio = chunk.audio.as_ref().map(|a| {
        let h = HeaderAudio {
            sample_rate: a.sample_rate,
            channels: a.channels,
            start_s: a.start_s,
            data: [data_len, a.pcm_s16le.len()],
        };
        data_len += a.pcm_s16le.len();
        h
    });
    let header = serde_json::to_vec(&ChunkHeader {
        width: chunk.width,
        height: chunk.height,
        from_s,
        next_s: chunk.next_s,
        end: chunk.end,
        frames,
        audio,
        notes: &chunk.notes,
    })
    .unwrap_or_default();
    let mut out = Vec::with_capacity(8 + header.len() + data_len);
    out.extend_from_slice(b"MPT1");
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(&header);
    for f in &chunk.frames {
        out.extend_from_slice(&f.jpeg);
    }
    if let Some(a) = &chunk.audio {
        out.extend_from_slice(&a.pcm_s16le);
    }
    out
}

/// What a `/take` request asks for, checked.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ChunkRequest {
    pub(crate) file: String,
    pub(crate) from_s: f64,
    pub(crate) seconds: f64,
}

/// Reads `file`, `from` (default 0) and `seconds` (default 4) from the query.
pub(crate) fn parse_request(req: &crate::http::Request) -> Result<ChunkRequest, String> {
    let file = req
        .query_param("file")
        .ok_or("missing ?file= (a take's file name)")?;
    if file.is_empty() || file.len() > 255 {
        return Err("file: expected a take's file name (1–255 bytes)".into());
    }
    let number = |key: &str, default: f64| -> Result<f64, String> {
        match req.query_param(key) {
            None => Ok(default),
            Some(v) => v.trim().parse::<f64>().map_err(|_| {
                format!(
                    "{key}: expected a number of seconds, got {:?}",
                    v.chars().take(40).collect::<String>()
                )
            }),
        }
    };
    let from_s = number("from", 0.0)?;
    if !(from_s.is_finite() && (0.0..=86_400.0).contains(&from_s)) {
        return Err(format!("from: expected 0–86400 seconds, got {from_s}"));
    }
    let seconds = number("seconds", 4.0)?;
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= MAX_CHUNK_SECONDS) {
        return Err(format!(
            "seconds: expected more than 0 and at most {MAX_CHUNK_SECONDS}, got {seconds}"
        ));
    }
    Ok(ChunkRequest {
        file,
        from_s,
        seconds,
    })
}

/// Answers `/take`: token, request, archive, a read slot, then the chunk.
pub(crate) async fn serve<S: tokio::io::AsyncWrite + Unpin>(
    hub: &crate::hub::Hub,
    config: &crate::config::ServerConfig,
    io: &mut S,
    req: &crate::http::Request,
) -> std::io::Result<()> {
    use crate::http::{respond, respond_error};
    let bearer = req
        .header("authorization")
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(|v| v.trim().to_owned());
    let token = bearer.or_else(|| req.query_param("token"));
    if hub.access_for(config, token.as_deref()).is_none() {
        let why = if token.is_some() {
            "wrong token"
        } else {
            "a token is required (?token= or Authorization: Bearer)"
        };
        return respond_error(io, 401, why).await;
    }
    let request = match parse_request(req) {
        Ok(r) => r,
        Err(why) => return respond_error(io, 400, &why).await,
    };
    let archive = hub.inner.takes.archive();
    let Some(archive) = archive else {
        return respond_error(io, 404, "takes are not served here (no takes folder)").await;
    };
    let Ok(permit) = hub.inner.takes.reads.clone().try_acquire_owned() else {
        return respond_error(io, 503, "busy reading other takes; try again").await;
    };
    let result = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        archive
            .chunk(&request.file, request.from_s, request.seconds)
            .map(|chunk| encode_chunk(&chunk, request.from_s))
    })
    .await;
    match result {
        Ok(Ok(body)) => respond(io, 200, "application/octet-stream", &body).await,
        Ok(Err(TakeChunkError::BadName(why))) => respond_error(io, 400, &why).await,
        Ok(Err(TakeChunkError::NotFound(why))) => respond_error(io, 404, &why).await,
        Ok(Err(TakeChunkError::Unreadable(why))) => respond_error(io, 500, &why).await,
        Err(_) => respond_error(io, 500, "reading the take failed").await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(query: &str) -> crate::http::Request {
        crate::http::Request {
            method: "GET".into(),
            path: "/take".into(),
            query: Some(query.into()),
            headers: Vec::new(),
        }
    }

    #[test]
    fn requests_are_checked_at_the_door() {
        let r = parse_request(&request("file=a_T001.mcap&from=2.5&seconds=3")).unwrap();
        assert_eq!(
            (r.file.as_str(), r.from_s, r.seconds),
            ("a_T001.mcap", 2.5, 3.0)
        );
        for (query, says) in [
            ("from=1", "missing ?file="),
            ("file=a.mcap&from=NaN", "from: expected 0–86400"),
            ("file=a.mcap&from=-1", "from: expected 0–86400"),
            ("file=a.mcap&seconds=inf", "seconds: expected"),
            ("file=a.mcap&seconds=11", "seconds: expected"),
            ("file=a.mcap&seconds=0", "seconds: expected"),
            ("file=a.mcap&from=x", "from: expected a number"),
        ] {
            let err = parse_request(&request(query)).unwrap_err();
            assert!(err.contains(says), "{query}: {err}");
        }
        let long = format!("file={}", "a".repeat(300));
        assert!(parse_request(&request(&long)).is_err());
    }

    #[test]
    fn a_chunk_points_into_its_data() {
        let chunk = TakeChunk {
            width: 320,
            height: 240,
            frames: vec![
                ChunkFrame {
                    t: 0.0,
                    jpeg: vec![1, 2, 3],
                    dots: Vec::new(),
                },
                ChunkFrame {
                    t: 0.033,
                    jpeg: vec![4, 5],
                    dots: Vec::new(),
                },
            ],
            audio: Some(ChunkAudio {
                sample_rate: 48000,
                channels: 1,
                start_s: 0.01,
                pcm_s16le: vec![9, 9, 8, 8],
            }),
            next_s: 0.066,
            end: true,
            notes: Vec::new(),
        };
        let bytes = encode_chunk(&chunk, 0.0);
        assert_eq!(&bytes[..4], b"MPT1");
        let len = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
        let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + len]).unwrap();
        let data = &bytes[8 + len..];
        let slice = |v: &serde_json::Value| {
            let (o, l) = (
                v[0].as_u64().unwrap() as usize,
                v[1].as_u64().unwrap() as usize,
            );
            data[o..o + l].to_vec()
        };
        assert_eq!(slice(&header["frames"][1]["image"]), vec![4, 5]);
        assert_eq!(slice(&header["audio"]["data"]), vec![9, 9, 8, 8]);
        assert_eq!(header["end"], true);
    }
}
