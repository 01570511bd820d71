//! The Foxglove image and calibration messages as ROS 2 message definitions (`ros2msg`
//! schemas) encoded in little-endian CDR (`cdr` message encoding).
//!
//! Why this encoding: Foxglove Studio decodes `ros2msg` + `cdr` natively and recognises the
//! `foxglove_msgs/msg/*` names in its Image and calibration panels; the schema is plain text
//! (readable in the file and in `docs/recording-format.md`); and CDR carries `uint8[]` as raw
//! bytes (no base64 as JSON would need). The encoder and decoder below are small and cover
//! exactly the types these three messages use.

/// Foxglove `RawImage`, ROS 2 flavour.
pub const RAW_IMAGE_SCHEMA_NAME: &str = "foxglove_msgs/msg/RawImage";
/// Foxglove `CompressedImage`, ROS 2 flavour.
pub const COMPRESSED_IMAGE_SCHEMA_NAME: &str = "foxglove_msgs/msg/CompressedImage";
/// Foxglove `RawAudio`, ROS 2 flavour.
pub const RAW_AUDIO_SCHEMA_NAME: &str = "foxglove_msgs/msg/RawAudio";
/// Foxglove `CameraCalibration`, ROS 2 flavour.
pub const CAMERA_CALIBRATION_SCHEMA_NAME: &str = "foxglove_msgs/msg/CameraCalibration";

const TIME_DEFINITION: &str =
    "================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// The `ros2msg` schema text of [`RAW_IMAGE_SCHEMA_NAME`].
pub fn raw_image_schema() -> String {
    format!(
        "builtin_interfaces/Time timestamp\nstring frame_id\nuint32 width\nuint32 height\n\
         string encoding\nuint32 step\nuint8[] data\n{TIME_DEFINITION}"
    )
}

/// The `ros2msg` schema text of [`COMPRESSED_IMAGE_SCHEMA_NAME`].
pub fn compressed_image_schema() -> String {
    format!("builtin_interfaces/Time timestamp\nstring frame_id\nuint8[] data\nstring format\n{TIME_DEFINITION}")
}

/// The `ros2msg` schema text of [`RAW_AUDIO_SCHEMA_NAME`].
pub fn raw_audio_schema() -> String {
    format!(
        "builtin_interfaces/Time timestamp\nuint8[] data\nstring format\nuint32 sample_rate\n\
         uint32 number_of_channels\n{TIME_DEFINITION}"
    )
}

/// The `ros2msg` schema text of [`CAMERA_CALIBRATION_SCHEMA_NAME`].
pub fn camera_calibration_schema() -> String {
    format!(
        "builtin_interfaces/Time timestamp\nstring frame_id\nuint32 width\nuint32 height\n\
         string distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\n{TIME_DEFINITION}"
    )
}

/// A timestamp as `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    pub fn from_micros(us: u64) -> Self {
        Self {
            sec: (us / 1_000_000) as i32,
            nanosec: ((us % 1_000_000) * 1000) as u32,
        }
    }

    /// Microseconds, clamping times before 1970 to 0.
    pub fn to_micros(self) -> u64 {
        (self.sec.max(0) as u64) * 1_000_000 + u64::from(self.nanosec) / 1000
    }
}

/// Foxglove `RawImage`.
#[derive(Debug, Clone, PartialEq)]
pub struct RawImage {
    pub timestamp: Time,
    pub frame_id: String,
    pub width: u32,
    pub height: u32,
    pub encoding: String,
    pub step: u32,
    pub data: Vec<u8>,
}

/// Foxglove `CompressedImage`.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage {
    pub timestamp: Time,
    pub frame_id: String,
    pub data: Vec<u8>,
    pub format: String,
}

/// Foxglove `RawAudio`: `pcm-s16` is signed 16-bit little-endian, interleaved.
#[derive(Debug, Clone, PartialEq)]
pub struct RawAudio {
    pub timestamp: Time,
    pub data: Vec<u8>,
    pub format: String,
    pub sample_rate: u32,
    pub number_of_channels: u32,
}

/// Foxglove `CameraCalibration`.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraCalibration {
    pub timestamp: Time,
    pub frame_id: String,
    pub width: u32,
    pub height: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    pub k: [f64; 9],
    pub r: [f64; 9],
    pub p: [f64; 12],
}

/// Why a CDR message could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum CdrError {
    #[error("message ends at byte {at} but {needed} more bytes were expected")]
    Truncated { at: usize, needed: usize },
    #[error("unsupported CDR representation {0:#06x} (expected little-endian plain CDR 0x0001)")]
    Representation(u16),
    #[error("string is not valid UTF-8")]
    Utf8(#[source] std::string::FromUtf8Error),
}

/// Little-endian CDR writer. Alignment is relative to the end of the 4-byte encapsulation header.
struct Writer {
    buf: Vec<u8>,
}

impl Writer {
    fn with_capacity(n: usize) -> Self {
        let mut buf = Vec::with_capacity(n + 64);
        buf.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        Self { buf }
    }
    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - 4;
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn time(&mut self, t: Time) {
        self.i32(t.sec);
        self.u32(t.nanosec);
    }
    fn string(&mut self, s: &str) {
        // Length includes the terminating NUL.
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.buf.extend_from_slice(b);
    }
    fn f64_seq(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for &x in v {
            self.f64(x);
        }
    }
    fn f64_array(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }
}

/// Little-endian CDR reader.
struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(data: &'a [u8]) -> Result<Self, CdrError> {
        if data.len() < 4 {
            return Err(CdrError::Truncated {
                at: data.len(),
                needed: 4 - data.len(),
            });
        }
        let rep = u16::from_be_bytes([data[0], data[1]]);
        if rep != 0x0001 {
            return Err(CdrError::Representation(rep));
        }
        Ok(Self { data, pos: 4 })
    }
    fn align(&mut self, n: usize) {
        let rel = self.pos - 4;
        self.pos += (n - rel % n) % n;
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], CdrError> {
        if self.pos + n > self.data.len() {
            return Err(CdrError::Truncated {
                at: self.data.len(),
                needed: self.pos + n - self.data.len(),
            });
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u32(&mut self) -> Result<u32, CdrError> {
        self.align(4);
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn i32(&mut self) -> Result<i32, CdrError> {
        Ok(self.u32()? as i32)
    }
    fn f64(&mut self) -> Result<f64, CdrError> {
        self.align(8);
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }
    fn time(&mut self) -> Result<Time, CdrError> {
        Ok(Time {
            sec: self.i32()?,
            nanosec: self.u32()?,
        })
    }
    fn string(&mut self) -> Result<String, CdrError> {
        let n = self.u32()? as usize;
        let b = self.take(n)?;
        let b = b.strip_suffix(&[0]).unwrap_or(b);
        String::from_utf8(b.to_vec()).map_err(CdrError::Utf8)
    }
    fn bytes(&mut self) -> Result<&'a [u8], CdrError> {
        let n = self.u32()? as usize;
        self.take(n)
    }
    fn f64_seq(&mut self) -> Result<Vec<f64>, CdrError> {
        let n = self.u32()? as usize;
        // Bound the allocation by what the message can hold.
        if n > self.data.len() / 8 + 1 {
            return Err(CdrError::Truncated {
                at: self.data.len(),
                needed: n * 8,
            });
        }
        (0..n).map(|_| self.f64()).collect()
    }
    fn f64_array<const N: usize>(&mut self) -> Result<[f64; N], CdrError> {
        let mut a = [0.0; N];
        for x in &mut a {
            *x = self.f64()?;
        }
        Ok(a)
    }
}

impl RawImage {
    pub fn encode(&self) -> Vec<u8> {
        let mut w =
            Writer::with_capacity(self.data.len() + self.frame_id.len() + self.encoding.len());
        w.time(self.timestamp);
        w.string(&self.frame_id);
        w.u32(self.width);
        w.u32(self.height);
        w.string(&self.encoding);
        w.u32(self.step);
        w.bytes(&self.data);
        w.buf
    }

    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = Reader::new(data)?;
        Ok(Self {
            timestamp: r.time()?,
            frame_id: r.string()?,
            width: r.u32()?,
            height: r.u32()?,
            encoding: r.string()?,
            step: r.u32()?,
            data: r.bytes()?.to_vec(),
        })
    }
}

impl CompressedImage {
    pub fn encode(&self) -> Vec<u8> {
        let mut w =
            Writer::with_capacity(self.data.len() + self.frame_id.len() + self.format.len());
        w.time(self.timestamp);
        w.string(&self.frame_id);
        w.bytes(&self.data);
        w.string(&self.format);
        w.buf
    }

    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = Reader::new(data)?;
        Ok(Self {
            timestamp: r.time()?,
            frame_id: r.string()?,
            data: r.bytes()?.to_vec(),
            format: r.string()?,
        })
    }
}

impl RawAudio {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::with_capacity(self.data.len() + self.format.len() + 16);
        w.time(self.timestamp);
        w.bytes(&self.data);
        w.string(&self.format);
        w.u32(self.sample_rate);
        w.u32(self.number_of_channels);
        w.buf
    }

    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = Reader::new(data)?;
        Ok(Self {
            timestamp: r.time()?,
            data: r.bytes()?.to_vec(),
            format: r.string()?,
            sample_rate: r.u32()?,
            number_of_channels: r.u32()?,
        })
    }
}

impl CameraCalibration {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::with_capacity(512);
        w.time(self.timestamp);
        w.string(&self.frame_id);
        w.u32(self.width);
        w.u32(self.height);
        w.string(&self.distortion_model);
        w.f64_seq(&self.d);
        w.f64_array(&self.k);
        w.f64_array(&self.r);
        w.f64_array(&self.p);
        w.buf
    }

    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = Reader::new(data)?;
        Ok(Self {
            timestamp: r.time()?,
            frame_id: r.string()?,
            width: r.u32()?,
            height: r.u32()?,
            distortion_model: r.string()?,
            d: r.f64_seq()?,
            k: r.f64_array()?,
            r: r.f64_array()?,
            p: r.f64_array()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_image_round_trips_and_is_aligned() {
        let img = RawImage {
            timestamp: Time {
                sec: 3,
                nanosec: 500,
            },
            frame_id: "cam".into(),
            width: 2,
            height: 1,
            encoding: "16UC1".into(),
            step: 4,
            data: vec![1, 2, 3, 4],
        };
        let bytes = img.encode();
        // header 4 + time 8 + "cam\0" 4+4 + w,h 8 + "16UC1\0" 4+6 (+2 pad) + step 4 + len 4 + 4
        assert_eq!(bytes.len(), 4 + 8 + 8 + 8 + 10 + 2 + 4 + 4 + 4);
        assert_eq!(RawImage::decode(&bytes).unwrap(), img);
    }

    #[test]
    fn calibration_round_trips() {
        let c = CameraCalibration {
            timestamp: Time::from_micros(1_500_000),
            frame_id: "color".into(),
            width: 640,
            height: 480,
            distortion_model: "plumb_bob".into(),
            d: vec![0.1, -0.2, 0.0, 0.0, 0.01],
            k: [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                525.0, 0.0, 319.5, 0.0, 0.0, 525.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
        };
        assert_eq!(CameraCalibration::decode(&c.encode()).unwrap(), c);
        assert_eq!(c.timestamp.to_micros(), 1_500_000);
    }

    #[test]
    fn truncated_message_is_an_error_not_a_panic() {
        let img = CompressedImage {
            timestamp: Time::default(),
            frame_id: String::new(),
            data: vec![9; 100],
            format: "jpeg".into(),
        };
        let bytes = img.encode();
        for cut in 0..bytes.len() {
            assert!(
                CompressedImage::decode(&bytes[..cut]).is_err(),
                "cut at {cut}"
            );
        }
    }
}
