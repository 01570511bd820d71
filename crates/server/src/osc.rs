//! Counters of the daemon's OSC output (VMC protocol over UDP, docs/osc.md), kept here so
//! that `/metrics` and `/healthz` can show them: the daemon's OSC sender thread updates them
//! with plain atomics, the server reads them when asked.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// One OSC target's counters.
#[derive(Debug)]
pub struct OscTargetCounters {
    /// The target as configured (`host:port`).
    pub target: String,
    /// Datagrams the kernel took for this target.
    pub sent: AtomicU64,
    /// Sends that failed (refused: nothing listens there; unreachable; socket buffer full).
    pub errors: AtomicU64,
}

impl OscTargetCounters {
    pub fn new(target: impl Into<String>) -> Self {
        OscTargetCounters {
            target: target.into(),
            sent: AtomicU64::new(0),
            errors: AtomicU64::new(0),
        }
    }
}

/// The OSC output's counters: frames dropped before the sender thread (one queue serves every
/// target) and, per target, datagrams sent and send errors.
#[derive(Debug, Default)]
pub struct OscCounters {
    /// Frames lost because the sender thread's queue was full (the oldest was dropped).
    pub dropped: AtomicU64,
    targets: Mutex<Vec<Arc<OscTargetCounters>>>,
}

/// A copy of one target's counters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OscTargetFigures {
    pub target: String,
    pub sent: u64,
    pub errors: u64,
}

impl OscCounters {
    /// The targets now configured (a reload replaces the list; a target kept keeps its
    /// counters).
    pub fn set_targets(&self, targets: Vec<Arc<OscTargetCounters>>) {
        *self.targets.lock().unwrap_or_else(|e| e.into_inner()) = targets;
    }

    /// The configured targets' counters, in configuration order.
    pub fn targets(&self) -> Vec<OscTargetFigures> {
        self.targets
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .map(|t| OscTargetFigures {
                target: t.target.clone(),
                sent: t.sent.load(Ordering::Relaxed),
                errors: t.errors.load(Ordering::Relaxed),
            })
            .collect()
    }

    /// Appends the Prometheus text (`/metrics`) of the VMC output.
    pub fn render_metrics(&self, out: &mut String) {
        self.render_metrics_as("osc", "OSC", out);
    }

    /// Appends the Prometheus text of a UDP output counted this way, its metrics named
    /// `mouthpiece_{prefix}_…` and described as `what` (the Live Link output shares the type).
    pub fn render_metrics_as(&self, prefix: &str, what: &str, out: &mut String) {
        let targets = self.targets();
        let _ = writeln!(
            out,
            "# HELP mouthpiece_{prefix}_dropped_total Frames the {what} sender could not take in time (oldest dropped).\n\
             # TYPE mouthpiece_{prefix}_dropped_total counter\nmouthpiece_{prefix}_dropped_total {}",
            self.dropped.load(Ordering::Relaxed)
        );
        for (name, help, value) in [
            (
                format!("mouthpiece_{prefix}_sent_total"),
                format!("{what} datagrams sent, per target."),
                (|f: &OscTargetFigures| f.sent) as fn(&OscTargetFigures) -> u64,
            ),
            (
                format!("mouthpiece_{prefix}_errors_total"),
                format!("{what} sends that failed (refused, unreachable), per target."),
                |f: &OscTargetFigures| f.errors,
            ),
        ] {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} counter");
            for t in &targets {
                let label = t.target.replace('\\', "\\\\").replace('"', "\\\"");
                let _ = writeln!(out, "{name}{{target=\"{label}\"}} {}", value(t));
            }
        }
    }

    /// `/healthz`'s `osc` entry; `None` while no target is configured.
    pub fn health_json(&self) -> Option<serde_json::Value> {
        let targets = self.targets();
        if targets.is_empty() {
            return None;
        }
        Some(serde_json::json!({
            "dropped": self.dropped.load(Ordering::Relaxed),
            "targets": targets
                .iter()
                .map(|t| serde_json::json!({"target": t.target, "sent": t.sent, "errors": t.errors}))
                .collect::<Vec<_>>(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_show_in_metrics_and_health_per_target() {
        let counters = OscCounters::default();
        assert_eq!(counters.health_json(), None);
        let a = Arc::new(OscTargetCounters::new("127.0.0.1:39539"));
        let b = Arc::new(OscTargetCounters::new("[::1]:9000"));
        counters.set_targets(vec![a.clone(), b.clone()]);
        a.sent.fetch_add(5, Ordering::Relaxed);
        b.errors.fetch_add(2, Ordering::Relaxed);
        counters.dropped.fetch_add(1, Ordering::Relaxed);
        let mut text = String::new();
        counters.render_metrics(&mut text);
        assert!(text.contains("mouthpiece_osc_dropped_total 1"), "{text}");
        assert!(
            text.contains("mouthpiece_osc_sent_total{target=\"127.0.0.1:39539\"} 5"),
            "{text}"
        );
        assert!(
            text.contains("mouthpiece_osc_errors_total{target=\"[::1]:9000\"} 2"),
            "{text}"
        );
        let health = counters.health_json().unwrap();
        assert_eq!(health["targets"][1]["errors"], 2, "{health}");
        assert_eq!(health["dropped"], 1, "{health}");
    }
}
