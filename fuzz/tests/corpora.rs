//! Replays every committed corpus file (`fuzz/libfuzzer/corpus/<target>/*`) through its
//! target's function, on stable, so that `cargo test --workspace` keeps every input a fuzzer
//! ever kept (each crash among them) passing. A panic names the target and the file.

use cap::Cap;
use std::alloc::System;
use std::path::{Path, PathBuf};

/// The replay's allocator, with a limit: an input that makes a target allocate more than
/// [`HEADROOM`] beyond what was live before it aborts the replay (the allocation fails), as
/// libFuzzer's `-malloc_limit_mb` and `-rss_limit_mb` stop a fuzzing run. That is how an
/// allocation sized by a received field (issue 29) stays a failing test once found.
#[global_allocator]
static ALLOCATOR: Cap<System> = Cap::new(System, usize::MAX);

/// Memory one corpus file may take beyond what was live before it. The largest honest input
/// (a fleet capture through the `rtps` target) needs a few MiB.
const HEADROOM: usize = 64 * 1024 * 1024;

fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("libfuzzer/corpus")
        .join(target)
}

#[test]
fn every_corpus_file_replays() {
    let mut total = 0;
    for (target, run) in rove_fuzz::TARGETS {
        let dir = corpus_dir(target);
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|entry| entry.expect("corpus entry").path())
            .filter(|p| p.is_file())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "{}: no corpus", dir.display());
        for file in &files {
            let data = std::fs::read(file).expect("corpus file readable");
            ALLOCATOR
                .set_limit(ALLOCATOR.allocated() + HEADROOM)
                .expect("the limit is above what is allocated");
            let outcome = std::panic::catch_unwind(|| run(&data));
            ALLOCATOR.set_limit(usize::MAX).expect("no limit");
            assert!(outcome.is_ok(), "{target}: {} fails", file.display());
        }
        total += files.len();
    }
    assert!(total > 0);
}

/// Every target has a corpus directory and every corpus directory a target.
#[test]
fn corpora_match_targets() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("libfuzzer/corpus");
    let mut dirs: Vec<String> = std::fs::read_dir(&root)
        .expect("fuzz/libfuzzer/corpus")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    dirs.sort();
    let mut names: Vec<String> = rove_fuzz::TARGETS
        .iter()
        .map(|(n, _)| n.to_string())
        .collect();
    names.sort();
    assert_eq!(dirs, names);
}
