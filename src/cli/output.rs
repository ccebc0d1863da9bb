//! Printing results: one JSON document with `--json`, human text otherwise; and
//! printing an error with its chain of causes.
//!
//! Output goes through [`write_stdout`], so a reader that goes away early
//! (`cell ... --json | head -c1`) ends the command quietly with success instead of a
//! panic from `println!`.

use anyhow::Context;
use serde::Serialize;
use std::io::{ErrorKind, Write};

/// Prints `value` as pretty JSON when `json` is set, else the text `human` makes.
pub fn emit<T: Serialize>(
    json: bool,
    value: &T,
    human: impl FnOnce(&T) -> String,
) -> anyhow::Result<()> {
    emit_to(&mut std::io::stdout().lock(), json, value, human)
}

/// [`emit`] to any writer (a closed pipe is not an error).
pub fn emit_to<T: Serialize>(
    out: &mut impl Write,
    json: bool,
    value: &T,
    human: impl FnOnce(&T) -> String,
) -> anyhow::Result<()> {
    let text = if json {
        let mut text = serde_json::to_string_pretty(value)?;
        text.push('\n');
        text
    } else {
        human(value)
    };
    write_to(out, &text)
}

/// Writes `text` to stdout and flushes; a closed pipe (the reader exited) is not an
/// error, any other write failure is.
pub fn write_stdout(text: &str) -> anyhow::Result<()> {
    write_to(&mut std::io::stdout().lock(), text)
}

/// Writes `text` to `out` and flushes; `BrokenPipe` counts as success.
fn write_to(out: &mut impl Write, text: &str) -> anyhow::Result<()> {
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == ErrorKind::BrokenPipe => Ok(()),
        result => result.context("cannot write to stdout"),
    }
}

/// The error and its causes on one line, joined by `": "`, leaving out a cause whose
/// text the line already holds (error types that print their source in their own
/// message would otherwise show it twice).
pub fn error_chain(err: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if text.is_empty() || line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fsio::{FileError, FileOp};
    use std::path::Path;

    /// A writer whose reader has gone: every write fails with `BrokenPipe`.
    struct ClosedPipe;

    impl Write for ClosedPipe {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(ErrorKind::BrokenPipe.into())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Err(ErrorKind::BrokenPipe.into())
        }
    }

    /// A writer that fails with another error.
    struct FullDisk;

    impl Write for FullDisk {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(ErrorKind::StorageFull.into())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn emit_to_a_closed_pipe_succeeds_quietly() {
        let value = serde_json::json!({"epsilon": 0.1});
        emit_to(&mut ClosedPipe, true, &value, |_| unreachable!()).unwrap();
        emit_to(&mut ClosedPipe, false, &value, |_| "text\n".into()).unwrap();
        let err = emit_to(&mut FullDisk, true, &value, |_| String::new()).unwrap_err();
        assert!(
            error_chain(&err).starts_with("cannot write to stdout: "),
            "{err:#}"
        );
        let mut out = Vec::new();
        emit_to(&mut out, true, &value, |_| String::new()).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.ends_with("}\n"), "{text:?}");
        assert_eq!(
            serde_json::from_str::<serde_json::Value>(&text).unwrap(),
            value
        );
    }

    /// How often `needle` occurs in `text`.
    fn occurrences(text: &str, needle: &str) -> usize {
        text.matches(needle).count()
    }

    #[test]
    fn error_chain_names_each_cause_once() {
        let io = || std::io::Error::new(ErrorKind::NotFound, "no such file (os error 2)");
        let mesh =
            crate::mesh::MeshError::File(FileError::new(FileOp::Read, Path::new("mug.obj"), io()));
        let err = anyhow::Error::new(mesh).context("loading the scene");
        let line = error_chain(&err);
        assert_eq!(
            line,
            "loading the scene: cannot read mug.obj: no such file (os error 2)"
        );
        // anyhow's own `{:#}` repeats the I/O error: what this function is for.
        assert_eq!(occurrences(&format!("{err:#}"), "no such file"), 2);

        let config = crate::config::ConfigError::Read(FileError::new(
            FileOp::Read,
            Path::new("robot/cell.toml"),
            io(),
        ));
        let line = error_chain(&anyhow::Error::new(config));
        assert_eq!(
            line,
            "cannot read config robot/cell.toml: no such file (os error 2)"
        );

        // A cause that its parent does not print is kept.
        let err = anyhow::Error::new(io()).context("cannot open mug.obj");
        assert_eq!(
            error_chain(&err),
            "cannot open mug.obj: no such file (os error 2)"
        );
    }
}
