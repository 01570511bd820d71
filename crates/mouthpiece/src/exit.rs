//! Exit codes, and the one place errors are printed.

use std::fmt;
use std::process::ExitCode;

use mouthpiece_output::shown_message;

/// Exit code for bad input or configuration (a file the user gave us is wrong).
pub const BAD_INPUT: u8 = 2;

/// Marks an error as the user's input or configuration being wrong, so `main` exits with
/// code 2. Wrap with [`bad_input`]; the message is the wrapped error's.
#[derive(Debug)]
pub struct BadInput(pub anyhow::Error);

impl fmt::Display for BadInput {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.0, f)
    }
}

impl std::error::Error for BadInput {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.0.source()
    }
}

/// Wraps an error as bad input (exit code 2).
pub fn bad_input(err: impl Into<anyhow::Error>) -> anyhow::Error {
    anyhow::Error::new(BadInput(err.into()))
}

/// Wraps an error as bad input (exit code 2) when `bad` says the user's input or
/// configuration is at fault (the error types' own `is_bad_input()`); otherwise exit 1.
pub fn bad_input_if<E>(bad: bool, err: E) -> anyhow::Error
where
    E: std::error::Error + Send + Sync + 'static,
{
    if bad {
        bad_input(err)
    } else {
        anyhow::Error::new(err)
    }
}

/// Prints `error: …` and every cause once, and picks the exit code.
pub fn report(err: &anyhow::Error) -> ExitCode {
    // The names in a message are escaped where it is made; this keeps an escape sequence
    // that slipped through (a cause from a library quoting its input) off the terminal.
    eprintln!("error: {}", shown_message(&err.to_string()));
    for cause in err.chain().skip(1) {
        eprintln!("  caused by: {}", shown_message(&cause.to_string()));
    }
    if err.chain().any(|e| e.is::<BadInput>()) {
        ExitCode::from(BAD_INPUT)
    } else {
        ExitCode::FAILURE
    }
}
