//! LTC on one channel of an interleaved audio stream that stops and starts again (a device
//! reopened, its sample count back at zero): a fresh [`Decoder`] for each new stream, and each
//! frame stamped with the wall-clock time at which its last sample was captured.

use crate::{Decoded, Decoder, LtcRate};

/// One block of the interleaved stream.
#[derive(Debug, Clone, Copy)]
pub struct Block<'a> {
    /// Interleaved samples, `channels` per sample frame.
    pub samples: &'a [i16],
    pub sample_rate: u32,
    pub channels: u16,
    /// The stream's number of the block's first sample frame.
    pub first_frame: u64,
    /// Wall-clock time (Unix microseconds) at which that first sample frame was captured.
    pub first_wall_us: i64,
}

/// Decodes one channel of a stream's blocks.
pub struct ChannelDecoder {
    channel: usize,
    rate: LtcRate,
    /// The decoder and the stream it reads: (sample rate, channels, next expected frame).
    decoder: Option<(Decoder, u32, u16, u64)>,
    mono: Vec<i16>,
    decoded: Vec<Decoded>,
    /// The last block's first frame, its wall-clock time and sample rate.
    clock: (u64, i64, u32),
}

impl ChannelDecoder {
    /// Reads channel `channel` (0-based) for LTC at `rate`.
    pub fn new(channel: usize, rate: LtcRate) -> Self {
        Self {
            channel,
            rate,
            decoder: None,
            mono: Vec::new(),
            decoded: Vec::new(),
            clock: (0, 0, 1),
        }
    }

    /// The channel read (0-based).
    pub fn channel(&self) -> usize {
        self.channel
    }

    /// Forgets the stream (a source stopped or started): the next block starts a decoder.
    pub fn restart(&mut self) {
        self.decoder = None;
    }

    /// Decodes `block` ([`Self::decoded`]: the frames that ended in it). A block without the
    /// channel (or without a format) decodes nothing.
    pub fn block(&mut self, block: &Block<'_>) {
        self.decoded.clear();
        let channels = usize::from(block.channels);
        if block.sample_rate == 0 || self.channel >= channels {
            return;
        }
        let fresh = match &self.decoder {
            Some((_, rate, ch, next)) => {
                *rate != block.sample_rate || *ch != block.channels || block.first_frame < *next
            }
            None => true,
        };
        if fresh {
            self.decoder = Some((
                Decoder::new(block.sample_rate, self.rate),
                block.sample_rate,
                block.channels,
                block.first_frame,
            ));
        }
        let Some((decoder, _, _, next)) = self.decoder.as_mut() else {
            return;
        };
        self.mono.clear();
        self.mono
            .extend(block.samples.iter().skip(self.channel).step_by(channels));
        decoder.write(&self.mono, block.first_frame, &mut self.decoded);
        *next = block.first_frame + self.mono.len() as u64;
        self.clock = (block.first_frame, block.first_wall_us, block.sample_rate);
    }

    /// The frames that ended in the last block.
    pub fn decoded(&self) -> &[Decoded] {
        &self.decoded
    }

    /// The wall-clock time (Unix microseconds) at which sample frame `s` of the last block's
    /// stream was captured, at the stream's sample rate.
    pub fn wall_of(&self, s: u64) -> i64 {
        let (first, wall, rate) = self.clock;
        let offset = i128::from(s) - i128::from(first);
        wall + (offset * 1_000_000 / i128::from(rate.max(1))) as i64
    }

    /// The stream's next expected sample frame (the end of the last block decoded).
    pub fn next_frame(&self) -> Option<u64> {
        self.decoder.as_ref().map(|d| d.3)
    }
}
