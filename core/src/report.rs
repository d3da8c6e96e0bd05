//! How lanealign's commands report an error to a person: the message and each cause on a line
//! of its own, never a backtrace, whatever `RUST_BACKTRACE` says; the error's full debug form
//! (with anyhow's backtrace when one was captured) only when `LANEALIGN_BACKTRACE=1`.

use std::error::Error;
use std::fmt::Write as _;
use std::process::ExitCode;

/// `error: <message>` followed by `  caused by: <cause>` for each source in the chain (a cause
/// whose text its parent already shows is not repeated).
pub fn error_chain(error: &(dyn Error + 'static)) -> String {
    let mut out = format!("error: {error}");
    for cause in causes(error) {
        let _ = write!(out, "\n  caused by: {cause}");
    }
    out
}

/// `<message>: <cause>: <cause>` on one line, the causes as [`error_chain`] shows them: for a
/// log, where a record is a line and its level already says it is an error. A message of
/// several lines (a TOML error's, which quotes the line at fault and marks the column) has its
/// lines joined by spaces, each trimmed, the empty ones dropped.
pub fn error_line(error: &(dyn Error + 'static)) -> String {
    let mut out = error.to_string();
    for cause in causes(error) {
        let _ = write!(out, ": {cause}");
    }
    if out.contains('\n') {
        out = out
            .lines()
            .map(str::trim)
            .filter(|line| !line.is_empty())
            .collect::<Vec<_>>()
            .join(" ");
    }
    out
}

/// The texts of `error`'s sources, each unless its parent's text already shows it.
fn causes(error: &(dyn Error + 'static)) -> Vec<String> {
    let mut shown = error.to_string();
    let mut texts = Vec::new();
    let mut cause = error.source();
    while let Some(e) = cause {
        let text = e.to_string();
        if !shown.contains(&text) {
            texts.push(text.clone());
        }
        shown = text;
        cause = e.source();
    }
    texts
}

/// True when the person asked for backtraces with `LANEALIGN_BACKTRACE=1`.
pub fn backtrace_requested() -> bool {
    std::env::var("LANEALIGN_BACKTRACE").is_ok_and(|v| v == "1")
}

/// Lets a command whose output goes to a pipe end quietly when the reader goes away (`lanealign
/// eval ... | head -1`), as Unix filters do. Rust starts programs with SIGPIPE ignored, so a
/// write to a closed pipe fails instead, and `println!` panics on that failure. For the
/// commands only: a daemon must outlive a closed log pipe.
pub fn end_quietly_on_closed_pipe() {
    // SAFETY: setting SIGPIPE back to its default action happens before any thread starts and
    // touches no Rust state.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// A command's exit: success, or the error reported on stderr ([`error_chain`]) and failure.
pub fn exit_code<E>(result: Result<(), E>) -> ExitCode
where
    E: std::fmt::Debug + AsRef<dyn Error + Send + Sync + 'static>,
{
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let error: &(dyn Error + 'static) = e.as_ref();
            eprintln!("{}", error_chain(error));
            if backtrace_requested() {
                eprintln!("{e:?}");
            }
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("outer")]
    struct Outer(#[source] std::io::Error);

    #[derive(Debug, thiserror::Error)]
    #[error("file.txt: {0}")]
    struct Shows(#[source] std::io::Error);

    #[test]
    fn every_cause_gets_a_line_once() {
        let e = Outer(std::io::Error::other("inner"));
        assert_eq!(error_chain(&e), "error: outer\n  caused by: inner");
        let e = Shows(std::io::Error::other("inner"));
        assert_eq!(error_chain(&e), "error: file.txt: inner");
    }

    #[test]
    fn a_log_line_holds_every_cause_once() {
        let e = Outer(std::io::Error::other("inner"));
        assert_eq!(error_line(&e), "outer: inner");
        let e = Shows(std::io::Error::other("inner"));
        assert_eq!(error_line(&e), "file.txt: inner");
        let e = Outer(std::io::Error::other(
            "at line 7\n  |\n7 | x = 1\n  | ^\nunknown field",
        ));
        assert_eq!(
            error_line(&e),
            "outer: at line 7 | 7 | x = 1 | ^ unknown field"
        );
    }
}
