//! Counters and histograms behind `/metrics` (Prometheus text exposition format 0.0.4).
//!
//! Plain atomics: the processing thread and every client task update them without locks.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};

/// Counters kept outside this crate (the Live Link output and its remote control, the
/// iFacialMocap output) that `/metrics` shows: each appends its own Prometheus text.
pub trait MetricsSource: Send + Sync + std::fmt::Debug {
    /// Appends `# HELP`, `# TYPE` and sample lines, each metric named `mouthpiece_…`.
    fn render_metrics(&self, out: &mut String);
}

/// Upper bounds (seconds) of the histogram buckets: 50 µs .. 1 s.
const BUCKETS: [f64; 14] = [
    0.000_05, 0.000_1, 0.000_25, 0.000_5, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5,
    1.0,
];

/// A fixed-bucket histogram of seconds.
#[derive(Debug, Default)]
pub struct Histogram {
    buckets: [AtomicU64; BUCKETS.len()],
    count: AtomicU64,
    /// Sum in nanoseconds, so it can be an integer atomic.
    sum_ns: AtomicU64,
}

impl Histogram {
    /// Records one observation.
    pub fn observe(&self, seconds: f64) {
        if !seconds.is_finite() || seconds < 0.0 {
            return;
        }
        if let Some(i) = BUCKETS.iter().position(|b| seconds <= *b) {
            self.buckets[i].fetch_add(1, Ordering::Relaxed);
        }
        self.count.fetch_add(1, Ordering::Relaxed);
        self.sum_ns
            .fetch_add((seconds * 1e9) as u64, Ordering::Relaxed);
    }

    pub(crate) fn render(&self, out: &mut String, name: &str, help: &str) {
        let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} histogram");
        let mut cumulative = 0;
        for (bound, bucket) in BUCKETS.iter().zip(&self.buckets) {
            cumulative += bucket.load(Ordering::Relaxed);
            let _ = writeln!(out, "{name}_bucket{{le=\"{bound}\"}} {cumulative}");
        }
        let count = self.count.load(Ordering::Relaxed);
        let _ = writeln!(out, "{name}_bucket{{le=\"+Inf\"}} {count}");
        let sum = self.sum_ns.load(Ordering::Relaxed) as f64 / 1e9;
        let _ = writeln!(out, "{name}_sum {sum}\n{name}_count {count}");
    }
}

/// Everything `/metrics` reports.
#[derive(Debug, Default)]
pub struct Metrics {
    /// Frames published by the pipeline.
    pub frames_in: AtomicU64,
    /// Frame messages written to clients (all clients together).
    pub frames_out: AtomicU64,
    /// Frames clients lost because they were too slow (ring overrun).
    pub frames_dropped: AtomicU64,
    /// WebSocket clients connected now.
    pub clients: AtomicU64,
    /// WebSocket sessions accepted since start.
    pub clients_accepted: AtomicU64,
    /// Clients closed for being too slow.
    pub clients_closed_slow: AtomicU64,
    /// Connections refused before the upgrade (auth, origin, limits, bad HTTP).
    pub connections_rejected: AtomicU64,
    /// Client messages answered with `error` or a close.
    pub bad_messages: AtomicU64,
    /// Plain HTTP requests served.
    pub http_requests: AtomicU64,
    /// Pipeline time per frame, as reported by the daemon.
    pub processing: Histogram,
    /// Publish to written-to-socket, per frame per client.
    pub fanout_latency: Histogram,
    /// Capture (the frame's `wall_us`) to written-to-socket, per frame per client.
    pub capture_latency: Histogram,
}

impl Metrics {
    /// The Prometheus text.
    pub fn render(&self) -> String {
        let mut out = String::with_capacity(4096);
        let counters: [(&str, &str, &AtomicU64, &str); 9] = [
            (
                "mouthpiece_frames_in_total",
                "Frames published by the pipeline.",
                &self.frames_in,
                "counter",
            ),
            (
                "mouthpiece_frames_out_total",
                "Frame messages sent to clients.",
                &self.frames_out,
                "counter",
            ),
            (
                "mouthpiece_frames_dropped_total",
                "Frames slow clients lost (oldest dropped).",
                &self.frames_dropped,
                "counter",
            ),
            (
                "mouthpiece_clients",
                "WebSocket clients connected.",
                &self.clients,
                "gauge",
            ),
            (
                "mouthpiece_clients_accepted_total",
                "WebSocket sessions accepted.",
                &self.clients_accepted,
                "counter",
            ),
            (
                "mouthpiece_clients_closed_slow_total",
                "Clients closed for staying behind.",
                &self.clients_closed_slow,
                "counter",
            ),
            (
                "mouthpiece_connections_rejected_total",
                "Connections refused before the WebSocket upgrade.",
                &self.connections_rejected,
                "counter",
            ),
            (
                "mouthpiece_bad_messages_total",
                "Client messages answered with an error or a close.",
                &self.bad_messages,
                "counter",
            ),
            (
                "mouthpiece_http_requests_total",
                "Plain HTTP requests served.",
                &self.http_requests,
                "counter",
            ),
        ];
        for (name, help, value, kind) in counters {
            let _ = writeln!(
                out,
                "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {}",
                value.load(Ordering::Relaxed)
            );
        }
        self.processing.render(
            &mut out,
            "mouthpiece_processing_seconds",
            "Pipeline time per frame.",
        );
        self.fanout_latency.render(
            &mut out,
            "mouthpiece_fanout_latency_seconds",
            "From publish to written to a client socket.",
        );
        self.capture_latency.render(
            &mut out,
            "mouthpiece_capture_latency_seconds",
            "From capture (the frame's wall_us) to written to a client socket.",
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative() {
        let m = Metrics::default();
        m.processing.observe(0.000_2);
        m.processing.observe(0.003);
        m.processing.observe(7.0);
        let text = m.render();
        assert!(text.contains("mouthpiece_processing_seconds_bucket{le=\"0.00025\"} 1"));
        assert!(text.contains("mouthpiece_processing_seconds_bucket{le=\"0.005\"} 2"));
        assert!(text.contains("mouthpiece_processing_seconds_bucket{le=\"1\"} 2"));
        assert!(text.contains("mouthpiece_processing_seconds_bucket{le=\"+Inf\"} 3"));
        assert!(text.contains("mouthpiece_processing_seconds_count 3"));
    }
}
