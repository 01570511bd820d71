//! Broadcast WAV (EBU Tech 3285): a RIFF WAVE file of 16-bit PCM with a `bext` chunk whose
//! time reference places sample 0 on the day's clock, so a DAW or an engine's sequencer puts
//! the sound where the take's timecode says, without manual sync.

use std::io::{self, Write};

/// The `bext` chunk's fields that mouthpiece fills.
#[derive(Debug, Clone, PartialEq)]
pub struct BextInfo {
    /// Free text (at most 256 bytes kept): the take and its timecode.
    pub description: String,
    /// `yyyy-mm-dd` and `hh-mm-ss` of the recording (UTC).
    pub origination_date: String,
    pub origination_time: String,
    /// Sample 0's position: samples since midnight (of the timecode's day).
    pub time_reference: u64,
}

/// Largest data chunk a RIFF file can hold (its sizes are 32-bit), less the header room.
pub const MAX_WAV_DATA_BYTES: u64 = u32::MAX as u64 - 4096;

/// The `bext` chunk's fixed part, bytes (version 1, without coding history).
const BEXT_LEN: usize = 602;

fn fixed(out: &mut Vec<u8>, text: &str, len: usize) {
    let bytes: Vec<u8> = text.bytes().filter(|b| b.is_ascii()).take(len).collect();
    out.extend_from_slice(&bytes);
    out.resize(out.len() + (len - bytes.len()), 0);
}

/// Writes a Broadcast WAV of interleaved 16-bit `samples` at `sample_rate` with `channels`.
pub fn write_bwf<W: Write>(
    mut out: W,
    sample_rate: u32,
    channels: u16,
    bext: &BextInfo,
    samples: &[i16],
) -> io::Result<()> {
    let data_bytes = samples.len() as u64 * 2;
    if data_bytes > MAX_WAV_DATA_BYTES || channels == 0 || sample_rate == 0 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "a WAV file holds at most {MAX_WAV_DATA_BYTES} bytes of sound with at least one channel; this is {data_bytes} bytes, {channels} channels at {sample_rate} Hz"
            ),
        ));
    }
    let mut b = Vec::with_capacity(BEXT_LEN);
    fixed(&mut b, &bext.description, 256);
    fixed(&mut b, "mouthpiece", 32);
    fixed(&mut b, "", 32);
    fixed(&mut b, &bext.origination_date, 10);
    fixed(&mut b, &bext.origination_time, 8);
    b.extend_from_slice(&(bext.time_reference as u32).to_le_bytes());
    b.extend_from_slice(&((bext.time_reference >> 32) as u32).to_le_bytes());
    b.extend_from_slice(&1u16.to_le_bytes());
    b.resize(BEXT_LEN, 0); // UMID, loudness fields, reserved
    let block_align = channels * 2;
    let riff_len = 4 + (8 + BEXT_LEN as u64) + (8 + 16) + (8 + data_bytes + data_bytes % 2);
    out.write_all(b"RIFF")?;
    out.write_all(&(riff_len as u32).to_le_bytes())?;
    out.write_all(b"WAVE")?;
    out.write_all(b"bext")?;
    out.write_all(&(BEXT_LEN as u32).to_le_bytes())?;
    out.write_all(&b)?;
    out.write_all(b"fmt ")?;
    out.write_all(&16u32.to_le_bytes())?;
    out.write_all(&1u16.to_le_bytes())?; // PCM
    out.write_all(&channels.to_le_bytes())?;
    out.write_all(&sample_rate.to_le_bytes())?;
    out.write_all(&(sample_rate * u32::from(block_align)).to_le_bytes())?;
    out.write_all(&block_align.to_le_bytes())?;
    out.write_all(&16u16.to_le_bytes())?;
    out.write_all(b"data")?;
    out.write_all(&(data_bytes as u32).to_le_bytes())?;
    let mut chunk = Vec::with_capacity(64 * 1024);
    for part in samples.chunks(32 * 1024) {
        chunk.clear();
        for s in part {
            chunk.extend_from_slice(&s.to_le_bytes());
        }
        out.write_all(&chunk)?;
    }
    out.flush()
}

/// How far a block's time may be from the end of the block before it and still continue it
/// (the same 40 ms as GStreamer's `alignment-threshold`). A capture source stamps each block
/// from the host clock and refines that estimate as it learns the device's delivery latency,
/// so the times of blocks read back to back wobble by a few milliseconds; laying each at its
/// own time would overwrite or silence samples at every wobble. Farther than this is a real
/// gap (an overrun, the device reopened) and the block goes where its time says.
pub const CONTINUITY_TOLERANCE_NS: u64 = 40_000_000;

/// Lays timed blocks of sound on one timeline: sample 0 at `start_ns`, `len` sample frames;
/// gaps stay silent, sound before the start or past the end is cut. A block within
/// [`CONTINUITY_TOLERANCE_NS`] of where the previous one ended continues it sample for sample;
/// any other block starts at the sample nearest its time.
#[derive(Debug)]
pub struct Timeline {
    pub sample_rate: u32,
    pub channels: u16,
    start_ns: u64,
    /// The sample frame after the last placed block (may be before 0: cut sound).
    next: Option<i128>,
    pub samples: Vec<i16>,
}

impl Timeline {
    /// `len` sample frames of silence; the caller has checked the size against
    /// [`MAX_WAV_DATA_BYTES`].
    pub fn new(sample_rate: u32, channels: u16, start_ns: u64, len: u64) -> Timeline {
        Timeline {
            sample_rate,
            channels,
            start_ns,
            next: None,
            samples: vec![0; (len * u64::from(channels)) as usize],
        }
    }

    /// Places a block whose first sample was at `at_ns`; returns the sample frame it went to
    /// (negative: before the start, cut).
    pub fn place(&mut self, at_ns: u64, samples: &[i16]) -> i128 {
        let ch = i128::from(self.channels);
        let rate = i128::from(self.sample_rate);
        let offset = (i128::from(at_ns) - i128::from(self.start_ns)) * rate;
        // Nearest sample frame.
        let by_time = (offset + offset.signum() * 500_000_000) / 1_000_000_000;
        let tolerance = i128::from(CONTINUITY_TOLERANCE_NS) * rate / 1_000_000_000;
        let first = match self.next {
            Some(next) if (by_time - next).abs() <= tolerance => next,
            _ => by_time,
        };
        let frames = samples.len() / self.channels as usize;
        self.next = Some(first + frames as i128);
        for (i, frame) in samples.chunks_exact(self.channels as usize).enumerate() {
            let at = first + i as i128;
            if at < 0 {
                continue;
            }
            let at = (at * ch) as usize;
            if at + frame.len() > self.samples.len() {
                break;
            }
            self.samples[at..at + frame.len()].copy_from_slice(frame);
        }
        first
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_land_on_the_sample_their_time_says_and_the_header_is_broadcast_wave() {
        // 1 kHz (the tolerance is 40 samples): a block at +50 ms starts at sample 50; one
        // before the start is cut; one 45 ms after the last one ended is a gap.
        let mut t = Timeline::new(1000, 1, 1_000_000_000, 110);
        assert_eq!(t.place(999_000_000, &[9, 8]), -1);
        assert_eq!(t.place(1_050_000_000, &[1, 2, 3]), 50);
        assert_eq!(
            t.place(1_098_000_000, &[7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7]),
            98
        );
        assert_eq!(t.samples[..3], [8, 0, 0]);
        assert_eq!(t.samples[49..54], [0, 1, 2, 3, 0]);
        assert_eq!(t.samples[97..], [0, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7]);
        let mut file = Vec::new();
        let bext = BextInfo {
            description: "take".into(),
            origination_date: "2026-12-05".into(),
            origination_time: "01-02-03".into(),
            time_reference: (1u64 << 32) + 7,
        };
        write_bwf(&mut file, 1000, 1, &bext, &t.samples).unwrap();
        assert_eq!(&file[..4], b"RIFF");
        assert_eq!(
            u32::from_le_bytes(file[4..8].try_into().unwrap()) as usize,
            file.len() - 8
        );
        assert_eq!(&file[12..16], b"bext");
        // TimeReferenceLow, High at 338 and 342 of the chunk's body.
        let body = 20;
        assert_eq!(
            u32::from_le_bytes(file[body + 338..body + 342].try_into().unwrap()),
            7
        );
        assert_eq!(
            u32::from_le_bytes(file[body + 342..body + 346].try_into().unwrap()),
            1
        );
        assert_eq!(&file[file.len() - 220 - 8..file.len() - 220 - 4], b"data");
    }

    #[test]
    fn blocks_stamped_a_little_early_or_late_continue_the_sound_sample_for_sample() {
        // 1 kHz, 10-sample blocks whose times wobble by up to 6 ms as a source refines its
        // latency estimate: laid back to back, no sample overwritten or silenced.
        let mut t = Timeline::new(1000, 1, 1_000_000_000, 60);
        let wobble_ms = [0i64, -6, 4, -3, 5];
        for (k, w) in wobble_ms.iter().enumerate() {
            let at = 1_000_000_000 + (k as i64 * 10 + w) * 1_000_000;
            let block: Vec<i16> = (0..10).map(|i| (k * 10 + i) as i16 + 1).collect();
            assert_eq!(t.place(at as u64, &block), k as i128 * 10);
        }
        let expected: Vec<i16> = (1..=50).collect();
        assert_eq!(t.samples[..50], expected[..]);
        assert_eq!(t.samples[50..], [0; 10]);
    }
}
