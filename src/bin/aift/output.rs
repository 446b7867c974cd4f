//! stdout and stderr that never panic. A closed pipe (`aift schema | head`) is the end of the
//! output: later lines are dropped and the command finishes its work (exit 0, as common command
//! line tools behave). Any other write error on stdout (`> /dev/full`) is remembered and makes the
//! command exit 1 once its work is done. Lines on stderr are best effort: a failing stderr is
//! ignored, never a panic.

use std::io::{ErrorKind, Write};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

static CLOSED: AtomicBool = AtomicBool::new(false);
static FAILURE: Mutex<Option<std::io::Error>> = Mutex::new(None);

fn note(error: std::io::Error) {
    CLOSED.store(true, Ordering::Relaxed);
    if error.kind() != ErrorKind::BrokenPipe
        && let Ok(mut slot) = FAILURE.lock()
    {
        slot.get_or_insert(error);
    }
}

/// Writes to stdout (see the module's notes).
pub fn stdout(args: std::fmt::Arguments<'_>) {
    if CLOSED.load(Ordering::Relaxed) {
        return;
    }
    if let Err(e) = std::io::stdout().lock().write_fmt(args) {
        note(e);
    }
}

/// Writes bytes to stdout (see the module's notes).
pub fn stdout_bytes(bytes: &[u8]) {
    if CLOSED.load(Ordering::Relaxed) {
        return;
    }
    if let Err(e) = std::io::stdout().lock().write_all(bytes) {
        note(e);
    }
}

/// Writes to stderr, ignoring failure.
pub fn stderr(args: std::fmt::Arguments<'_>) {
    let _ = std::io::stderr().lock().write_fmt(args);
}

/// Flushes stdout; the first write error other than a closed pipe, if any.
pub fn finish() -> Option<std::io::Error> {
    if !CLOSED.load(Ordering::Relaxed)
        && let Err(e) = std::io::stdout().lock().flush()
    {
        note(e);
    }
    FAILURE.lock().ok().and_then(|mut slot| slot.take())
}

macro_rules! outln {
    () => { $crate::output::stdout(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::output::stdout(format_args!("{}\n", format_args!($($arg)*))) };
}

macro_rules! out {
    ($($arg:tt)*) => { $crate::output::stdout(format_args!($($arg)*)) };
}

macro_rules! errln {
    ($($arg:tt)*) => { $crate::output::stderr(format_args!("{}\n", format_args!($($arg)*))) };
}
