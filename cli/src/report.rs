//! What the examples print and keep: tables (markdown on the terminal, markdown and CSV in a
//! results folder), and progress on the terminal while long work runs.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};

/// A table that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("writing {path}")]
pub struct ReportError {
    /// The file.
    pub path: PathBuf,
    /// Why not.
    #[source]
    pub source: std::io::Error,
}

/// A titled table of text cells.
pub struct Table {
    title: String,
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// An empty table with a title (one line) and column names.
    pub fn new(title: impl Into<String>, header: Vec<String>) -> Table {
        Table {
            title: title.into(),
            header,
            rows: Vec::new(),
        }
    }

    /// Appends a row.
    pub fn push(&mut self, cells: Vec<String>) {
        self.rows.push(cells);
    }

    /// The title, a blank line and the table in markdown.
    pub fn markdown(&self) -> String {
        let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
        let mut text = format!("{}\n\n", self.title);
        text += &line(&self.header);
        text += &format!("|{}\n", "---|".repeat(self.header.len()));
        for row in &self.rows {
            text += &line(row);
        }
        text
    }

    /// The table as CSV (RFC 4180 quoting; markdown emphasis dropped).
    pub fn csv(&self) -> String {
        let cell = |c: &String| {
            let c = c.replace("**", "");
            if c.contains([',', '"', '\n']) {
                format!("\"{}\"", c.replace('"', "\"\""))
            } else {
                c
            }
        };
        std::iter::once(&self.header)
            .chain(&self.rows)
            .map(|r| r.iter().map(cell).collect::<Vec<_>>().join(",") + "\n")
            .collect()
    }

    /// Writes `dir/name.md` and `dir/name.csv`.
    pub fn save(&self, dir: &Path, name: &str) -> Result<(), ReportError> {
        for (extension, text) in [("md", self.markdown()), ("csv", self.csv())] {
            let path = dir.join(format!("{name}.{extension}"));
            std::fs::write(&path, text).map_err(|source| ReportError { path, source })?;
        }
        Ok(())
    }
}

/// A progress bar of `total` steps on standard error; drawn only on a terminal.
pub fn progress(total: usize, message: &'static str) -> ProgressBar {
    let bar = ProgressBar::new(total as u64).with_message(message);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({elapsed}, {eta} left)")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

/// A spinner with `message` and the time elapsed, ticking on standard error (only on a terminal)
/// until finished.
pub fn spinner(message: String) -> ProgressBar {
    let bar = ProgressBar::new_spinner().with_message(message);
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        bar.set_style(style);
    }
    // Off a terminal nothing is drawn: no ticking thread either (its start and stop cost a
    // short run a tenth of a millisecond or more).
    if !bar.is_hidden() {
        bar.enable_steady_tick(std::time::Duration::from_millis(200));
    }
    bar
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_and_csv_hold_the_same_cells() {
        let mut t = Table::new("Title", vec!["a".into(), "b, c".into()]);
        t.push(vec!["**1.5**".into(), "say \"hi\"".into()]);
        assert_eq!(
            t.markdown(),
            "Title\n\n| a | b, c |\n|---|---|\n| **1.5** | say \"hi\" |\n"
        );
        assert_eq!(t.csv(), "a,\"b, c\"\n1.5,\"say \"\"hi\"\"\"\n");
    }
}
