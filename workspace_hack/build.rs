// Cargo reads a package's build-dependencies only when it has a build script: the generated
// build-dependencies pin the features of proc-macro and build-script dependencies.
fn main() {}
