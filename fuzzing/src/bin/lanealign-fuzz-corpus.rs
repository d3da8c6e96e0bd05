//! Writes the starting corpora and dictionaries of the cargo-fuzz targets (see
//! `lanealign_fuzzing::corpus`) into a folder.

use anyhow::Context;

fn main() -> anyhow::Result<()> {
    let dir = std::env::args_os()
        .nth(1)
        .context("usage: lanealign-fuzz-corpus DIR")?;
    let written = lanealign_fuzzing::corpus::write_all(std::path::Path::new(&dir))
        .with_context(|| format!("writing into {}", dir.to_string_lossy()))?;
    for w in written {
        let plural = if w.inputs == 1 { "" } else { "s" };
        let dictionary = if w.dictionary { ", a dictionary" } else { "" };
        println!(
            "{}: {} input{plural}{dictionary}",
            w.target.name(),
            w.inputs
        );
    }
    Ok(())
}
