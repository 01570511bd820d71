//! Counters and state of the daemon's NATS link (docs/nats.md), kept here so that `/metrics`
//! and `/healthz` can show them: the NATS task updates them with plain atomics, the server
//! reads them when asked.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The NATS link's counters. All zero and `enabled == false` while `[nats]` is off.
#[derive(Debug, Default)]
pub struct NatsCounters {
    /// `[nats]` is configured.
    pub enabled: AtomicBool,
    /// The client is connected to a server now.
    pub connected: AtomicBool,
    /// Connections made (the first and each reconnection).
    pub connects: AtomicU64,
    /// Frames handed to the connection (`.frame`; `.frame.bin` and `.rig.*` go with them).
    pub frames_published: AtomicU64,
    /// Frames lost before the connection: the outgoing queue was full (oldest dropped) or
    /// the broker was away.
    pub frames_dropped: AtomicU64,
    /// Control requests answered over NATS.
    pub control_requests: AtomicU64,
    /// Takes uploaded to the object store (with their metadata).
    pub takes_uploaded: AtomicU64,
    /// Uploads that failed (retried later).
    pub upload_errors: AtomicU64,
    /// Closed takes in the folder still waiting for upload.
    pub takes_waiting: AtomicU64,
}

impl NatsCounters {
    /// Appends the Prometheus text (`/metrics`); nothing while NATS is off.
    pub fn render_metrics(&self, out: &mut String) {
        if !self.enabled.load(Ordering::Relaxed) {
            return;
        }
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        for (name, kind, help, value) in [
            (
                "mouthpiece_nats_connected",
                "gauge",
                "1 while connected to a NATS server.",
                u64::from(self.connected.load(Ordering::Relaxed)),
            ),
            (
                "mouthpiece_nats_connects_total",
                "counter",
                "Connections to a NATS server (first and reconnections).",
                load(&self.connects),
            ),
            (
                "mouthpiece_nats_frames_published_total",
                "counter",
                "Frames published on NATS.",
                load(&self.frames_published),
            ),
            (
                "mouthpiece_nats_frames_dropped_total",
                "counter",
                "Frames not published on NATS: queue full (oldest dropped) or broker away.",
                load(&self.frames_dropped),
            ),
            (
                "mouthpiece_nats_control_requests_total",
                "counter",
                "Control requests answered over NATS.",
                load(&self.control_requests),
            ),
            (
                "mouthpiece_nats_takes_uploaded_total",
                "counter",
                "Takes uploaded to the object store.",
                load(&self.takes_uploaded),
            ),
            (
                "mouthpiece_nats_upload_errors_total",
                "counter",
                "Take uploads that failed (retried).",
                load(&self.upload_errors),
            ),
            (
                "mouthpiece_nats_takes_waiting",
                "gauge",
                "Closed takes waiting for upload.",
                load(&self.takes_waiting),
            ),
        ] {
            let _ = writeln!(
                out,
                "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {value}"
            );
        }
    }

    /// `/healthz`'s `nats` entry; `None` while NATS is off.
    pub fn health_json(&self) -> Option<serde_json::Value> {
        if !self.enabled.load(Ordering::Relaxed) {
            return None;
        }
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        Some(serde_json::json!({
            "connected": self.connected.load(Ordering::Relaxed),
            "frames_published": load(&self.frames_published),
            "frames_dropped": load(&self.frames_dropped),
            "takes_uploaded": load(&self.takes_uploaded),
            "takes_waiting": load(&self.takes_waiting),
        }))
    }

    /// One phrase for the daemon's status line; `None` while NATS is off.
    pub fn status(&self) -> Option<String> {
        if !self.enabled.load(Ordering::Relaxed) {
            return None;
        }
        let waiting = self.takes_waiting.load(Ordering::Relaxed);
        let mut text = if self.connected.load(Ordering::Relaxed) {
            "NATS up".to_owned()
        } else {
            "NATS down (reconnecting)".to_owned()
        };
        if waiting > 0 {
            let _ = write!(text, ", {waiting} takes waiting for upload");
        }
        Some(text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nats_shows_in_metrics_and_health_only_when_enabled() {
        let counters = NatsCounters::default();
        let mut text = String::new();
        counters.render_metrics(&mut text);
        assert!(text.is_empty());
        assert_eq!(counters.health_json(), None);
        counters.enabled.store(true, Ordering::Relaxed);
        counters.frames_dropped.fetch_add(3, Ordering::Relaxed);
        counters.render_metrics(&mut text);
        assert!(
            text.contains("mouthpiece_nats_frames_dropped_total 3"),
            "{text}"
        );
        assert!(text.contains("mouthpiece_nats_connected 0"), "{text}");
        let health = counters.health_json().unwrap();
        assert_eq!(health["connected"], false, "{health}");
        assert_eq!(
            counters.status().as_deref(),
            Some("NATS down (reconnecting)")
        );
    }
}
