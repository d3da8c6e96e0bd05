//! Reading files that come from outside: regular files only (a FIFO, a device or a folder is
//! refused before anything is read), lines of bounded length (memory stays proportional to the
//! valid input), and errors that quote at most [`QUOTE_CHARS`] characters of what they refuse.
//! And writing outputs whole or not at all ([`Outputs`]), never over an input, a read-only file
//! or another output.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

/// The longest line a text input may have (bytes).
pub const MAX_LINE_BYTES: usize = 4096;
/// The most characters of an input an error message quotes.
pub const QUOTE_CHARS: usize = 80;

/// An input file that could not be opened or read.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// The file could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Not a regular file.
    #[error("{path}: not a regular file (a folder, FIFO or device is not read)")]
    NotAFile {
        /// The path.
        path: PathBuf,
    },
    /// A whole-file input larger than its limit.
    #[error("{path}: {len} bytes, more than the {limit} bytes such a file may have")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its length (bytes).
        len: u64,
        /// The limit (bytes).
        limit: u64,
    },
    /// A line longer than [`MAX_LINE_BYTES`].
    #[error("{path}:{line}: longer than {MAX_LINE_BYTES} bytes, starting '{start}'")]
    LineTooLong {
        /// The file.
        path: PathBuf,
        /// The 1-based line number.
        line: usize,
        /// Its first characters.
        start: String,
    },
    /// A line that is not UTF-8 text.
    #[error("{path}:{line}: not UTF-8 text")]
    NotText {
        /// The file.
        path: PathBuf,
        /// The 1-based line number.
        line: usize,
    },
    /// An output names a file that nobody may write (no write permission bit).
    #[error("{path}: read-only, and an output replaces its file: make it writable (chmod u+w) or write elsewhere")]
    ReadOnly {
        /// The output as given.
        path: PathBuf,
    },
    /// Two outputs name the same file.
    #[error(
        "{path}: named for two outputs, which would overwrite each other: give each its own file"
    )]
    OutputTwice {
        /// The second output as given.
        path: PathBuf,
    },
    /// An output names a file that is also an input.
    #[error("{output}: is the input {input}, which writing it would replace: write the output elsewhere")]
    OutputIsInput {
        /// The output as given.
        output: PathBuf,
        /// The input as given.
        input: PathBuf,
    },
}

/// Refuses an output that names the same file as an input (by device and inode, whatever path
/// or link names it): an output replaces its file whole, so the input would be lost. An output
/// that does not exist yet is no input; `None` stands for a path not given.
pub fn check_outputs_apart(
    outputs: &[Option<&Path>],
    inputs: &[Option<&Path>],
) -> Result<(), InputError> {
    use std::os::unix::fs::MetadataExt;
    let file_id = |p: &Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
    for output in outputs.iter().flatten() {
        let Some(id) = file_id(output) else {
            continue;
        };
        if let Some(input) = inputs.iter().flatten().find(|i| file_id(i) == Some(id)) {
            return Err(InputError::OutputIsInput {
                output: output.to_path_buf(),
                input: input.to_path_buf(),
            });
        }
    }
    Ok(())
}

/// At most [`QUOTE_CHARS`] characters of `text`, with `...` when cut; control characters are
/// escaped (`\0` as `\u{0}`), so that a quote never writes raw bytes to a terminal, and the
/// escapes count towards the limit.
pub fn quote(text: &str) -> String {
    let mut head = String::new();
    let mut shown = 0;
    for c in text.chars() {
        let piece: String = if c.is_control() {
            c.escape_default().collect()
        } else {
            c.to_string()
        };
        let len = piece.chars().count();
        if shown + len > QUOTE_CHARS {
            head.push_str("...");
            return head;
        }
        head.push_str(&piece);
        shown += len;
    }
    head
}

/// Opens `path` for reading if it is a regular file. The file is opened non-blocking, so a FIFO
/// without a writer is refused at once instead of waited on.
pub fn open_regular(path: &Path) -> Result<File, InputError> {
    use std::os::unix::fs::OpenOptionsExt;
    let io = |source| InputError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(io)?;
    if !file.metadata().map_err(io)?.is_file() {
        return Err(InputError::NotAFile {
            path: path.to_path_buf(),
        });
    }
    Ok(file)
}

/// Reads a whole regular file of at most `limit` bytes into memory (a FIFO or a device is never
/// waited on or read without end).
pub fn read_regular_file(path: &Path, limit: u64) -> Result<Vec<u8>, InputError> {
    let io = |source| InputError::Io {
        path: path.to_path_buf(),
        source,
    };
    let too_large = |len| InputError::TooLarge {
        path: path.to_path_buf(),
        len,
        limit,
    };
    let file = open_regular(path)?;
    let len = file.metadata().map_err(io)?.len();
    if len > limit {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    // One byte past the limit tells a file that grew while being read.
    file.take(limit + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// The UTF-8 encoding of the byte-order mark U+FEFF.
const UTF8_BOM: &[u8] = b"\xEF\xBB\xBF";

/// The lines of a reader (by default a regular file), each at most [`MAX_LINE_BYTES`], as
/// `(line number, text)`, without their line ends (`\n` or `\r\n`) and without a byte-order
/// mark that begins the first. Iteration stops after the first error.
pub struct Lines<R = BufReader<File>> {
    reader: R,
    path: PathBuf,
    line: usize,
    buf: Vec<u8>,
    failed: bool,
}

impl Lines {
    /// The lines of `path` (refused up front when it is not a regular file).
    pub fn open(path: &Path) -> Result<Lines, InputError> {
        Ok(Lines::new(BufReader::new(open_regular(path)?), path))
    }
}

impl<R: BufRead> Lines<R> {
    /// The lines of `reader`; `path` names it in errors.
    pub fn new(reader: R, path: &Path) -> Lines<R> {
        Lines {
            reader,
            path: path.to_path_buf(),
            line: 0,
            buf: Vec::new(),
            failed: false,
        }
    }
}

impl<R: BufRead> Iterator for Lines<R> {
    type Item = Result<(usize, String), InputError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        self.buf.clear();
        self.line += 1;
        let limit = (MAX_LINE_BYTES + 1) as u64;
        let read = (&mut self.reader)
            .take(limit)
            .read_until(b'\n', &mut self.buf);
        let fail = |e: InputError| Some(Err(e));
        match read {
            Err(source) => {
                self.failed = true;
                return fail(InputError::Io {
                    path: self.path.clone(),
                    source,
                });
            }
            Ok(0) => return None,
            Ok(_) => {}
        }
        // A byte-order mark, which some editors and Windows tools begin a text file with, is no
        // part of the first line's text.
        if self.line == 1 && self.buf.starts_with(UTF8_BOM) {
            self.buf.drain(..UTF8_BOM.len());
        }
        if self.buf.last() == Some(&b'\n') {
            self.buf.pop();
            if self.buf.last() == Some(&b'\r') {
                self.buf.pop();
            }
        } else if self.buf.len() > MAX_LINE_BYTES {
            self.failed = true;
            return fail(InputError::LineTooLong {
                path: self.path.clone(),
                line: self.line,
                start: quote(&String::from_utf8_lossy(
                    &self.buf[..QUOTE_CHARS.min(self.buf.len())],
                )),
            });
        }
        match std::str::from_utf8(&self.buf) {
            Ok(text) => Some(Ok((self.line, text.to_string()))),
            Err(_) => {
                self.failed = true;
                fail(InputError::NotText {
                    path: self.path.clone(),
                    line: self.line,
                })
            }
        }
    }
}

/// Writes output files so that they appear only together, when everything succeeded: each is
/// written to a temporary file beside it, and all are renamed into place by [`Outputs::commit`].
/// Dropped without committing, the temporary files are removed.
///
/// A path that names an existing file through symbolic links replaces the file the links name
/// (the links stay). A path that names something other than a file (`/dev/null`, a FIFO, a
/// terminal) is written to directly at commit: renaming over it would replace a device node
/// (for root, the system's `/dev/null`) with a plain file.
#[derive(Default)]
pub struct Outputs {
    staged: Vec<(PathBuf, PathBuf)>,
    direct: Vec<(PathBuf, Vec<u8>)>,
}

impl Outputs {
    /// Stages `bytes` for `path` (written now to a temporary file beside the file it names, or
    /// kept for commit when it names a device or FIFO). A file without any write permission bit
    /// is refused, even for root (who may write anything, and a rename would replace it): a
    /// read-only file is one its owner means to keep.
    pub fn stage(&mut self, path: &Path, bytes: &[u8]) -> Result<(), InputError> {
        let io = |source| InputError::Io {
            path: path.to_path_buf(),
            source,
        };
        let target = match std::fs::metadata(path) {
            Ok(m) if m.is_dir() => {
                return Err(io(std::io::Error::from(std::io::ErrorKind::IsADirectory)))
            }
            Ok(m) if !m.is_file() => {
                self.direct.push((path.to_path_buf(), bytes.to_vec()));
                return Ok(());
            }
            Ok(m) if m.permissions().readonly() => {
                return Err(InputError::ReadOnly {
                    path: path.to_path_buf(),
                })
            }
            Ok(_) => std::fs::canonicalize(path).map_err(io)?,
            Err(_) => new_file_path(path),
        };
        if self.staged.iter().any(|(_, staged)| *staged == target) {
            return Err(InputError::OutputTwice {
                path: path.to_path_buf(),
            });
        }
        let mut name = target.as_os_str().to_owned();
        name.push(format!(".partial-{}", std::process::id()));
        let tmp = PathBuf::from(name);
        std::fs::write(&tmp, bytes).map_err(io)?;
        self.staged.push((tmp, target));
        Ok(())
    }

    /// Renames every staged file into place, then writes to the devices and FIFOs.
    pub fn commit(mut self) -> Result<(), InputError> {
        for (tmp, path) in std::mem::take(&mut self.staged) {
            std::fs::rename(&tmp, &path).map_err(|source| InputError::Io {
                path: path.clone(),
                source,
            })?;
        }
        for (path, bytes) in std::mem::take(&mut self.direct) {
            std::fs::write(&path, bytes).map_err(|source| InputError::Io { path, source })?;
        }
        Ok(())
    }
}

/// Where a file not made yet will be: its folder's canonical path and its name, so that two
/// spellings of one new file are one path. The path as given when its folder does not exist
/// either (writing there fails).
fn new_file_path(path: &Path) -> PathBuf {
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    match (std::fs::canonicalize(folder), path.file_name()) {
        (Ok(folder), Some(name)) => folder.join(name),
        _ => path.to_path_buf(),
    }
}

/// Writes one file atomically: it appears whole or not at all.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), InputError> {
    let mut outputs = Outputs::default();
    outputs.stage(path, bytes)?;
    outputs.commit()
}

impl Drop for Outputs {
    fn drop(&mut self) {
        for (tmp, _) in &self.staged {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_through_links_replace_the_file_and_fifos_are_written_not_replaced() {
        use std::os::unix::fs::FileTypeExt;
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("file.txt");
        std::fs::write(&file, "old").unwrap();
        let link = dir.path().join("link.txt");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link).unwrap().is_symlink(),
            "the link stays"
        );
        assert_eq!(std::fs::read(&file).unwrap(), b"new");

        let fifo = dir.path().join("fifo");
        let c_path = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        write_atomic(&fifo, b"through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        let kind = std::fs::symlink_metadata(&fifo).unwrap().file_type();
        assert!(kind.is_fifo(), "still a FIFO, not a file renamed over it");

        let e = write_atomic(dir.path(), b"x").unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
    }

    #[test]
    fn quotes_are_short_and_escape_control_characters() {
        assert_eq!(quote("a\0b\x1b"), "a\\u{0}b\\u{1b}");
        assert_eq!(
            quote(&"\0".repeat(100)),
            format!("{}...", "\\u{0}".repeat(16))
        );
        assert_eq!(quote(&"x".repeat(100)), format!("{}...", "x".repeat(80)));
    }

    #[test]
    fn lines_are_bounded_and_quoted_short() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.txt");
        let long = "7".repeat(10_000);
        std::fs::write(&path, format!("a b\r\nc\n{long}\nafter\n")).unwrap();
        let mut lines = Lines::open(&path).unwrap();
        assert_eq!(lines.next().unwrap().unwrap(), (1, "a b".to_string()));
        assert_eq!(lines.next().unwrap().unwrap(), (2, "c".to_string()));
        let e = lines.next().unwrap().unwrap_err().to_string();
        assert!(
            e.contains(":3: longer than 4096 bytes") && e.len() < 250,
            "{e}"
        );
        assert!(lines.next().is_none(), "reading stops at the first error");
        std::fs::write(&path, [b'a', 0xff, b'\n']).unwrap();
        let e = Lines::open(&path).unwrap().next().unwrap().unwrap_err();
        assert!(matches!(e, InputError::NotText { line: 1, .. }), "{e}");
    }

    #[test]
    fn a_byte_order_mark_begins_no_line() {
        let text = b"\xEF\xBB\xBF1 2\r\n\xEF\xBB\xBF3\n";
        let lines: Vec<_> = Lines::new(&text[..], Path::new("bom.txt"))
            .collect::<Result<_, _>>()
            .unwrap();
        // Only the file's first bytes are a mark; further on U+FEFF is text, left to the parser.
        assert_eq!(
            lines,
            [(1, "1 2".to_string()), (2, "\u{feff}3".to_string())]
        );
    }

    #[test]
    fn only_regular_files_are_read() {
        let dir = tempfile::tempdir().unwrap();
        for p in [dir.path(), Path::new("/dev/zero")] {
            assert!(
                matches!(Lines::open(p), Err(InputError::NotAFile { .. })),
                "{}",
                p.display()
            );
        }
    }

    #[test]
    fn outputs_appear_together_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.txt"), dir.path().join("b.txt"));
        let mut out = Outputs::default();
        out.stage(&a, b"1").unwrap();
        out.stage(&b, b"2").unwrap();
        assert!(!a.exists() && !b.exists());
        out.commit().unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), b"1");
        let mut out = Outputs::default();
        out.stage(&a, b"changed").unwrap();
        drop(out);
        assert_eq!(
            std::fs::read(&a).unwrap(),
            b"1",
            "an abandoned output changes nothing"
        );
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            2,
            "no temporary file left"
        );
    }

    #[test]
    fn an_output_that_is_an_input_by_any_name_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.txt");
        std::fs::write(&input, "keep").unwrap();
        let link = dir.path().join("link.txt");
        std::os::unix::fs::symlink(&input, &link).unwrap();
        let hard = dir.path().join("hard.txt");
        std::fs::hard_link(&input, &hard).unwrap();
        let dotted = dir.path().join(".").join("in.txt");
        for output in [&input, &link, &hard, &dotted] {
            let e = check_outputs_apart(&[Some(output)], &[Some(Path::new("other")), Some(&input)])
                .unwrap_err();
            assert!(
                e.to_string().contains("is the input") && e.to_string().contains("in.txt"),
                "{e}"
            );
        }
        let new = dir.path().join("new.txt");
        let copy = dir.path().join("copy.txt");
        std::fs::write(&copy, "keep").unwrap();
        check_outputs_apart(&[Some(&new), Some(&copy), None], &[Some(&input), None]).unwrap();
        assert_eq!(std::fs::read(&input).unwrap(), b"keep");
    }

    #[test]
    fn two_outputs_naming_one_file_are_refused_and_nothing_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let new = dir.path().join("new.txt");
        let dotted = dir.path().join(".").join("new.txt");
        let mut outputs = Outputs::default();
        outputs.stage(&new, b"trajectory").unwrap();
        let e = outputs.stage(&dotted, b"status").unwrap_err();
        assert!(e.to_string().contains("named for two outputs"), "{e}");
        drop(outputs);
        let existing = dir.path().join("old.txt");
        std::fs::write(&existing, "old").unwrap();
        let mut outputs = Outputs::default();
        outputs.stage(&existing, b"trajectory").unwrap();
        assert!(outputs.stage(&existing, b"status").is_err());
        drop(outputs);
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().flatten().collect();
        assert_eq!(
            left.len(),
            1,
            "neither the new file nor a temporary one: {left:?}"
        );
        assert_eq!(std::fs::read(&existing).unwrap(), b"old");
    }

    #[test]
    fn a_read_only_file_is_not_replaced_even_by_root() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let kept = dir.path().join("kept.txt");
        std::fs::write(&kept, "keep").unwrap();
        std::fs::set_permissions(&kept, std::fs::Permissions::from_mode(0o444)).unwrap();
        let e = write_atomic(&kept, b"new").unwrap_err();
        assert!(e.to_string().contains("read-only"), "{e}");
        assert_eq!(std::fs::read(&kept).unwrap(), b"keep");
        std::fs::set_permissions(&kept, std::fs::Permissions::from_mode(0o644)).unwrap();
        write_atomic(&kept, b"new").unwrap();
        assert_eq!(std::fs::read(&kept).unwrap(), b"new");
    }
}
