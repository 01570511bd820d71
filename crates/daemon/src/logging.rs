//! Logging set-up, journald-friendly.
//!
//! Logs go to stderr. Colours only when stderr is a terminal; no timestamps when systemd
//! captures stderr (`$JOURNAL_STREAM` set: the journal stamps every line itself). The filter
//! is `$RUST_LOG` when set, otherwise `info`, and can be replaced later from the config file
//! (`[logging] level`) without restarting.

use std::io::IsTerminal;
use std::sync::OnceLock;

use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{fmt, reload, EnvFilter, Registry};

type FilterHandle = reload::Handle<EnvFilter, Registry>;

static FILTER: OnceLock<FilterHandle> = OnceLock::new();

/// How log lines are formatted, decided from the environment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Style {
    pub ansi: bool,
    pub timestamps: bool,
}

impl Style {
    pub fn from_env() -> Style {
        let under_journal = std::env::var_os("JOURNAL_STREAM").is_some();
        Style {
            ansi: std::io::stderr().is_terminal() && !under_journal,
            timestamps: !under_journal,
        }
    }
}

/// Installs the global subscriber. Call once, first thing in `main`.
pub fn init() {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let (filter, handle) = reload::Layer::new(filter);
    let style = Style::from_env();
    let layer = fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(style.ansi)
        .with_target(false);
    // Two arms because the timestamp-less formatter is a different type.
    let result = if style.timestamps {
        tracing_subscriber::registry()
            .with(filter)
            .with(layer)
            .try_init()
    } else {
        tracing_subscriber::registry()
            .with(filter)
            .with(layer.without_time())
            .try_init()
    };
    if result.is_ok() {
        let _ = FILTER.set(handle);
    }
}

/// Replaces the filter with the config file's `[logging] level`, unless `$RUST_LOG` is set
/// (the environment wins, for debugging a deployed unit).
pub fn set_level(level: &str) -> Result<(), String> {
    if std::env::var_os("RUST_LOG").is_some() {
        return Ok(());
    }
    let filter =
        EnvFilter::try_new(level).map_err(|e| format!("invalid log filter {level:?}: {e}"))?;
    if let Some(handle) = FILTER.get() {
        handle.reload(filter).map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Checks a filter string without applying it (config validation).
pub fn check_level(level: &str) -> Result<(), String> {
    EnvFilter::try_new(level)
        .map(|_| ())
        .map_err(|e| format!("invalid log filter {level:?}: {e}"))
}
