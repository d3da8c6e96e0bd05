//! The cargo-fuzz starting corpora: every target gets its seeds and its regression cases, and
//! the dictionaries are in libFuzzer's format.

use lanealign_fuzzing::corpus::{dictionary, write_all};
use lanealign_fuzzing::regressions::cases;
use lanealign_fuzzing::targets::Target;

#[test]
fn every_target_gets_its_seeds_and_regressions() {
    let dir = tempfile::tempdir().unwrap();
    let written = write_all(dir.path()).unwrap();
    assert_eq!(written.len(), Target::ALL.len());
    let regressions = cases();
    for w in &written {
        let folder = dir.path().join(w.target.name());
        let files = std::fs::read_dir(&folder).unwrap().count();
        let expected =
            w.target.seeds().len() + regressions.iter().filter(|c| c.target == w.target).count();
        assert!(expected > 0, "{}", w.target.name());
        assert_eq!(
            (w.inputs, files),
            (expected, expected),
            "{}",
            w.target.name()
        );
        let dict = dir.path().join(format!("{}.dict", w.target.name()));
        assert_eq!(
            dict.is_file(),
            !w.target.dictionary().is_empty(),
            "{}",
            w.target.name()
        );
        assert_eq!(w.dictionary, dict.is_file());
    }
    let journal = dir.path().join("journal");
    for case in regressions.iter().filter(|c| c.target == Target::Journal) {
        assert_eq!(std::fs::read(journal.join(case.name)).unwrap(), case.bytes);
    }
}

#[test]
fn dictionary_tokens_are_quoted_and_escaped() {
    let text = dictionary(&[b"<tag k=\"a\"/>", b"\\", &[0, 0xF8, 0x7F, b'a']]);
    assert_eq!(
        text,
        "\"<tag k=\\\"a\\\"/>\"\n\"\\\\\"\n\"\\x00\\xF8\\x7Fa\"\n"
    );
}
