//! Command-line programs whose output goes into a pipe that closes early (`pinc inspect M |
//! head`): the reader has what it wanted, so the program stops quietly with status 0 rather
//! than panicking with a backtrace.

use std::io::ErrorKind;

/// True if `message` is the text of an `std::io::Error` of kind `BrokenPipe` (what
/// `println!` panics with, and what a write error turned into a string carries).
pub fn is_broken_pipe(message: &str) -> bool {
    // The standard library's wording for EPIPE on every Unix, and its own message.
    message.contains("Broken pipe") || message.contains(&ErrorKind::BrokenPipe.to_string())
}

/// Installs a panic hook that exits with status 0, printing nothing, when a write to stdout
/// or stderr failed because the reader went away; every other panic is reported as before.
pub fn exit_quietly_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let text = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if text.starts_with("failed printing to std") && is_broken_pipe(text) {
            std::process::exit(0);
        }
        default(info);
    }));
}
