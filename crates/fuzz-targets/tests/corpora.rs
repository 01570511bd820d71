//! Replays every committed fuzz corpus file through its target, so that a regression fails
//! `cargo test` without a fuzzer. The corpora are in `fuzz/corpus/<target>/`.

use std::path::Path;

#[test]
fn every_corpus_file_runs_clean() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus");
    let mut total = 0;
    for (name, target) in mouthpiece_fuzz_targets::TARGETS {
        let dir = root.join(name);
        let entries =
            std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("corpus {}: {e}", dir.display()));
        let mut files = 0;
        for entry in entries {
            let path = entry.unwrap().path();
            let data = std::fs::read(&path).unwrap();
            target(&data);
            files += 1;
        }
        assert!(files > 0, "corpus {name} is empty");
        total += files;
    }
    assert!(total > 0);
}
