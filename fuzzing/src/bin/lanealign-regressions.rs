//! Writes the regression inputs (see `lanealign_fuzzing::regressions`) into a folder.

use anyhow::Context;

fn main() -> anyhow::Result<()> {
    let dir = std::env::args_os()
        .nth(1)
        .context("usage: lanealign-regressions DIR")?;
    let names = lanealign_fuzzing::regressions::write_all(std::path::Path::new(&dir))
        .with_context(|| format!("writing into {}", dir.to_string_lossy()))?;
    for name in names {
        println!("{name}");
    }
    Ok(())
}
