//! What the booth console shows besides frames and images: the daemon's health once a
//! second (`health` message, to clients that subscribe with the `health` field), the last
//! neutral calibration and the takes of this session (in `status`).

use serde::{Deserialize, Serialize};

/// The daemon's health over the last second; the daemon sets it about once a second.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Health {
    /// Frames processed in the last second.
    pub fps: f64,
    /// Share (0–1) of the dots (lip and forehead) found over the last second's frames.
    pub dots_found: f64,
    /// Mean processing time per frame over the last second, milliseconds.
    pub processing_ms: f64,
    /// Mean time from capture to publish over the last second, milliseconds.
    pub capture_to_publish_ms: f64,
    /// Free space where takes are written, megabytes (absent when unknown).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub disk_free_mb: Option<u64>,
    /// Colour image size of the source, pixels (absent before the first frame).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image: Option<[u32; 2]>,
}

/// The last neutral calibration and how good it was.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CalibrationReport {
    /// When the neutral pose was taken, Unix microseconds.
    pub wall_us: i64,
    /// Frames averaged.
    pub frames: usize,
    /// The performer's neutral mouth width (corner to corner), millimetres.
    pub mouth_width_mm: f64,
    /// RMS motion of the lip dots over the calibration window with the head's motion
    /// removed, millimetres: how still the mouth was held.
    pub lip_wobble_mm: f64,
}

/// One take recorded in this run of the daemon.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TakeSummary {
    /// Slate.
    pub slate: String,
    /// Take number.
    pub take: u32,
    /// File written.
    pub file: String,
    /// Frames written.
    pub frames: u64,
    /// Length, seconds.
    pub seconds: f64,
    /// Why it ended early, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The last paint check (`tune_colours`), as `tune` in `status`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TuneReport {
    /// `sampling`, `done`, `failed` or `applied`.
    pub state: String,
    /// What happened, for the technician.
    pub message: String,
    /// Frames the counts were made on.
    pub frames: u32,
    /// What the ranges in use find.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub in_use: Option<TuneFound>,
    /// What the proposed ranges find.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub proposed: Option<TuneFound>,
    /// The proposal finds at least as many dots as the ranges in use: it may be applied.
    pub offered: bool,
    /// The proposal as `[[detect.class]]` entries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub toml: Option<String>,
}

/// What one set of colour ranges finds on the checked frames.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TuneFound {
    /// Share (0–1) of the dots found.
    pub share: f64,
    /// Dots found per frame, and how many there are.
    pub per_frame: f64,
    pub dots: usize,
    pub classes: Vec<TuneClass>,
}

/// One colour class and what it finds.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TuneClass {
    pub name: String,
    /// `lip`, `forehead` or `any`.
    pub role: String,
    /// OpenCV 8-bit HSV ranges.
    pub hue: Vec<[u8; 2]>,
    pub saturation: [u8; 2],
    pub value: [u8; 2],
    /// Dots it finds per frame.
    pub per_frame: f64,
}

/// The `health` message.
#[derive(Debug, Serialize)]
pub(crate) struct HealthMessage<'a> {
    #[serde(rename = "type")]
    pub(crate) kind: &'static str,
    /// Clients connected now.
    pub(crate) clients: u64,
    /// Clients receiving the preview now.
    pub(crate) preview_clients: usize,
    #[serde(flatten)]
    pub(crate) health: &'a Health,
}

/// How many takes `status` lists at most (the newest).
pub const MAX_LISTED_TAKES: usize = 50;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hub::Hub;

    #[test]
    fn the_take_list_keeps_the_newest() {
        let (hub, _control) = Hub::new(&crate::HubConfig::default());
        for take in 0..(MAX_LISTED_TAKES as u32 + 5) {
            hub.add_take(TakeSummary {
                take,
                ..TakeSummary::default()
            });
        }
        let takes = hub.status().takes;
        assert_eq!(takes.len(), MAX_LISTED_TAKES);
        assert_eq!(takes.last().unwrap().take, MAX_LISTED_TAKES as u32 + 4);
        assert_eq!(takes[0].take, 5);
    }

    #[test]
    fn health_message_names_clients_and_figures() {
        let (hub, _control) = Hub::new(&crate::HubConfig::default());
        hub.set_health(Health {
            fps: 30.0,
            dots_found: 0.98,
            disk_free_mb: Some(1234),
            ..Health::default()
        });
        let v: serde_json::Value = serde_json::from_str(&hub.health_json()).unwrap();
        assert_eq!(v["type"], "health");
        assert_eq!(v["fps"], 30.0);
        assert_eq!(v["clients"], 0);
        assert_eq!(v["disk_free_mb"], 1234);
        assert!(v.get("image").is_none());
    }
}
