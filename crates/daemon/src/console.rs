//! What the booth console page needs from the processing thread: the camera image with the
//! dots for the preview and health figures once a second (how good a calibration was is the
//! live pipeline's, `mouthpiece_pipeline::quality`).
//!
//! Nothing here runs unless asked for: the preview's image and dots are handed over only
//! when [`mouthpiece_server::Hub::preview_due`] says a client wants one (the JPEG encoding
//! runs on the server's preview thread); the health figures are sums updated per frame and
//! sent once a second.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mouthpiece_detect::PixelRect;
use mouthpiece_frame::Frame;
use mouthpiece_server::{BgrImage, DotState, Health, ImageDot, Overlay, PixelBox};

/// A frame's colour image, shared with the preview encoder without a copy.
pub struct FrameImage(pub Arc<Frame>);

impl BgrImage for FrameImage {
    fn width(&self) -> u32 {
        self.0.color.width
    }
    fn height(&self) -> u32 {
        self.0.color.height
    }
    fn bgr(&self) -> &[u8] {
        &self.0.color.data
    }
}

/// Where each dot was last seen in the image, and for how many frames some dot has been
/// missing. Updated every frame without allocating.
#[derive(Debug, Clone, Default)]
pub struct DotPlaces {
    /// Pixel of each dot in this frame (`None`: not found).
    pub now: Vec<Option<[f64; 2]>>,
    /// Pixel where each dot was last found.
    pub last_seen: Vec<Option<[f64; 2]>>,
    /// Consecutive frames with at least one dot missing.
    pub frames_with_missing: u32,
}

impl DotPlaces {
    /// Takes this frame's pixels (lip dots, then forehead).
    pub fn update(&mut self, pixels: &[Option<[f64; 2]>]) {
        self.now.clear();
        self.now.extend_from_slice(pixels);
        self.last_seen.resize(pixels.len(), None);
        for (last, now) in self.last_seen.iter_mut().zip(pixels) {
            if now.is_some() {
                *last = *now;
            }
        }
        if pixels.iter().any(Option::is_none) {
            self.frames_with_missing = self.frames_with_missing.saturating_add(1);
        } else {
            self.frames_with_missing = 0;
        }
    }

    /// The overlay: each dot at its pixel when found, else where `predicted` places it,
    /// else where it was last seen; and, while dots are missing, the rectangle the detector
    /// rectangles the detector searched on this frame as the tracker reports them (`searched`).
    pub fn overlay(
        &self,
        names: &[String],
        predicted: impl Fn(usize) -> Option<[f64; 2]>,
        searched: &[PixelRect],
    ) -> Overlay {
        let mut dots = Vec::with_capacity(names.len());
        for (i, name) in names.iter().enumerate() {
            let place = match self.now.get(i).copied().flatten() {
                Some(p) => Some((p, DotState::Tracked)),
                None => match predicted(i) {
                    Some(p) => Some((p, DotState::Predicted)),
                    None => self
                        .last_seen
                        .get(i)
                        .copied()
                        .flatten()
                        .map(|p| (p, DotState::Lost)),
                },
            };
            if let Some((p, state)) = place {
                dots.push(ImageDot {
                    name: name.clone(),
                    x: p[0] as f32,
                    y: p[1] as f32,
                    state,
                });
            }
        }
        let search = if self.frames_with_missing > 0 {
            searched
                .iter()
                .map(|r| PixelBox {
                    x: r.x as f32,
                    y: r.y as f32,
                    width: r.width as f32,
                    height: r.height as f32,
                })
                .collect()
        } else {
            Vec::new()
        };
        Overlay { dots, search }
    }
}

/// Sums over the current second for the `health` message.
#[derive(Debug)]
pub struct HealthMeter {
    started: Instant,
    frames: u32,
    dots_seen: u64,
    dots_total: u64,
    processing: Duration,
    capture_to_publish: Duration,
    image: Option<[u32; 2]>,
    takes_folder: PathBuf,
}

impl HealthMeter {
    /// Health over each second; free space measured in `takes_folder`.
    pub fn new(takes_folder: PathBuf) -> Self {
        Self {
            started: Instant::now(),
            frames: 0,
            dots_seen: 0,
            dots_total: 0,
            processing: Duration::ZERO,
            capture_to_publish: Duration::ZERO,
            image: None,
            takes_folder,
        }
    }

    /// Counts one processed frame.
    pub fn frame(
        &mut self,
        dots_total: usize,
        dots_missing: usize,
        processing: Duration,
        capture_to_publish: Duration,
        image: [u32; 2],
    ) {
        self.frames += 1;
        self.dots_total += dots_total as u64;
        self.dots_seen += dots_total.saturating_sub(dots_missing) as u64;
        self.processing += processing;
        self.capture_to_publish += capture_to_publish;
        self.image = Some(image);
    }

    /// Once a second: the figures of the second that ended, and a new second begins.
    pub fn tick(&mut self, now: Instant) -> Option<Health> {
        let elapsed = now.saturating_duration_since(self.started);
        if elapsed < Duration::from_secs(1) {
            return None;
        }
        let frames = f64::from(self.frames.max(1));
        let health = Health {
            fps: f64::from(self.frames) / elapsed.as_secs_f64(),
            dots_found: if self.dots_total > 0 {
                self.dots_seen as f64 / self.dots_total as f64
            } else {
                0.0
            },
            processing_ms: self.processing.as_secs_f64() * 1e3 / frames,
            capture_to_publish_ms: self.capture_to_publish.as_secs_f64() * 1e3 / frames,
            disk_free_mb: std::fs::create_dir_all(&self.takes_folder)
                .ok()
                .and_then(|()| mouthpiece_takes::free_mb(&self.takes_folder)),
            image: self.image,
        };
        self.started = now;
        self.frames = 0;
        self.dots_seen = 0;
        self.dots_total = 0;
        self.processing = Duration::ZERO;
        self.capture_to_publish = Duration::ZERO;
        Some(health)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlay_states_and_search_region() {
        let names: Vec<String> = ["D1", "D2", "F1"].iter().map(|s| s.to_string()).collect();
        let mut places = DotPlaces::default();
        places.update(&[
            Some([100.0, 100.0]),
            Some([120.0, 100.0]),
            Some([110.0, 50.0]),
        ]);
        let searched = PixelRect {
            x: 61,
            y: 10,
            width: 104,
            height: 132,
        };
        let below = PixelRect {
            x: 61,
            y: 150,
            width: 104,
            height: 40,
        };
        let o = places.overlay(&names, |_| None, &[searched]);
        assert!(o.dots.iter().all(|d| d.state == DotState::Tracked));
        assert!(o.search.is_empty(), "all found: no search region");
        // D2 missing: predicted by the caller; F1 missing with no prediction: last seen.
        places.update(&[Some([101.0, 100.0]), None, None]);
        let o = places.overlay(
            &names,
            |i| (i == 1).then_some([125.0, 102.0]),
            &[searched, below],
        );
        let state = |n: &str| o.dots.iter().find(|d| d.name == n).unwrap().state;
        assert_eq!(state("D1"), DotState::Tracked);
        assert_eq!(state("D2"), DotState::Predicted);
        assert_eq!(state("F1"), DotState::Lost);
        let f1 = o.dots.iter().find(|d| d.name == "F1").unwrap();
        assert_eq!((f1.x, f1.y), (110.0, 50.0), "where it was last seen");
        // Exactly the rectangles the tracker reports, nothing re-derived.
        let boxes: Vec<_> = o
            .search
            .iter()
            .map(|s| (s.x, s.y, s.width, s.height))
            .collect();
        assert_eq!(
            boxes,
            [(61.0, 10.0, 104.0, 132.0), (61.0, 150.0, 104.0, 40.0)]
        );
        // A frame that was not searched draws no region.
        assert!(places.overlay(&names, |_| None, &[]).search.is_empty());
    }

    /// The console's region is the tracker's: on a tracked session where a dot goes
    /// missing, every frame's drawn box is the detector's searched rectangle.
    #[test]
    fn the_drawn_region_is_the_one_the_tracker_searched() {
        use mouthpiece_pipeline::{Pipeline, PipelineConfig};
        use mouthpiece_synth::{Synth, SynthConfig};
        let human =
            mouthpiece_retarget::Character::from_toml_str(mouthpiece_pipeline::setup::BUILTIN[0].1)
                .unwrap();
        let mut pipeline =
            Pipeline::for_characters(PipelineConfig::default(), vec![human]).unwrap();
        let names: Vec<String> = (1..=15).map(|i| format!("X{i}")).collect();
        let mut places = DotPlaces::default();
        let synth = Synth::new(SynthConfig {
            seed: 3,
            seconds: 3.0,
            ..SynthConfig::default()
        })
        .unwrap();
        let (mut drawn, mut restricted, mut apart) = (0, 0, 0);
        for (i, (mut frame, _)) in synth.enumerate() {
            // From 2 s on, every other frame paints over the mouth's left half: dots go
            // missing and the tracker widens (and now and then drops) its region.
            if i >= 60 && i % 2 == 0 {
                let w = frame.color.width as usize;
                for row in frame.color.data.chunks_mut(3 * w) {
                    row[..3 * w / 2].fill(0);
                }
            }
            pipeline.step(&frame).unwrap();
            let tracked = pipeline.tracked();
            places.update(&tracked.pixels);
            let o = places.overlay(&names, |_| None, &tracked.searched);
            if o.search.is_empty() {
                continue;
            }
            drawn += 1;
            let boxes: Vec<_> = o
                .search
                .iter()
                .map(|b| (b.x, b.y, b.width, b.height))
                .collect();
            let rects: Vec<_> = tracked
                .searched
                .iter()
                .map(|r| (r.x as f32, r.y as f32, r.width as f32, r.height as f32))
                .collect();
            assert_eq!(boxes, rects, "frame {i}: drawn is not what was searched");
            let full = i64::from(frame.color.width * frame.color.height);
            if tracked.searched.iter().map(|r| r.area()).sum::<i64>() < full {
                restricted += 1;
            }
            if tracked.searched.len() == 2 {
                apart += 1;
            }
        }
        assert!(
            drawn > 10 && restricted > 0 && apart > 0,
            "{drawn} drawn, {restricted} restricted, {apart} as two regions"
        );
    }

    #[test]
    fn health_over_a_second() {
        let mut m = HealthMeter::new(std::env::temp_dir());
        let start = m.started;
        for _ in 0..30 {
            m.frame(
                15,
                1,
                Duration::from_millis(1),
                Duration::from_millis(2),
                [640, 480],
            );
        }
        assert!(m.tick(start + Duration::from_millis(500)).is_none());
        let h = m.tick(start + Duration::from_secs(1)).unwrap();
        assert!((h.fps - 30.0).abs() < 1e-9);
        assert!((h.dots_found - 14.0 / 15.0).abs() < 1e-9);
        assert!((h.processing_ms - 1.0).abs() < 1e-9);
        assert!((h.capture_to_publish_ms - 2.0).abs() < 1e-9);
        assert!(h.disk_free_mb.is_some());
        assert_eq!(h.image, Some([640, 480]));
        let idle = m.tick(start + Duration::from_secs(2)).unwrap();
        assert_eq!(idle.fps, 0.0);
    }
}
