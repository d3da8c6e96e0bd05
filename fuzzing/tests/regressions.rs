//! Every known bad input is refused with its reason (or, where no error is due, handled without
//! a crash), and the generator writes them all as files.

use lanealign_fuzzing::regressions::{cases, write_all};

#[test]
fn every_known_bad_input_is_refused_with_its_reason() {
    let all = cases();
    assert!(all.len() >= 15, "{} cases", all.len());
    for case in all {
        let outcome = case.target.run(&case.bytes);
        match case.refused_with {
            Some(why) => {
                let e = outcome.expect_err(case.name);
                assert!(e.contains(why), "{}: {e}", case.name);
                assert!(
                    e.len() < 400,
                    "{}: the error quotes too much: {e}",
                    case.name
                );
            }
            None => drop(outcome),
        }
    }
}

#[test]
fn the_generator_writes_every_case() {
    let dir = tempfile::tempdir().unwrap();
    let names = write_all(dir.path()).unwrap();
    assert_eq!(names.len(), cases().len());
    for name in names {
        assert!(dir.path().join(&name).is_file(), "{name}");
    }
}
