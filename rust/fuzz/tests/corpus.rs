//! Every input of the seed corpus (tests/fuzz-corpus/<target>/, where each crash the fuzzer
//! found is kept as a regression input), every regression input kept out of the seeds
//! (tests/fuzz-corpus/regressions/<target>/: inputs whose mutants are slow to run, which would
//! take the fuzzer's time) and a short deterministic mutation run per target go through the
//! targets without a panic and within the time limit.

use std::path::Path;
use std::time::{Duration, Instant};

use noisecal_fuzz::Target;
use noisecal_fuzz::mutate::{Rng, mutate};

/// The files of one corpus folder, named by path and sorted.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .filter(|e| e.path().is_file())
                .map(|e| (e.path().display().to_string(), std::fs::read(e.path()).expect("read seed")))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

fn root() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fuzz-corpus")
}

/// The seeds the fuzzer starts from (the jni-frame target's built-in ones included).
fn seeds(target: Target) -> Vec<(String, Vec<u8>)> {
    let mut v = files(&root().join(target.name()));
    if target == Target::JniFrame {
        v.extend(noisecal_fuzz::jni_seeds().into_iter().enumerate().map(|(i, s)| (format!("built-in {i}"), s)));
    }
    v
}

/// The regression inputs kept out of the seeds.
fn regressions(target: Target) -> Vec<(String, Vec<u8>)> {
    files(&root().join("regressions").join(target.name()))
}

fn run_timed(target: Target, name: &str, input: &[u8]) {
    let t0 = Instant::now();
    let r = std::panic::catch_unwind(|| target.run(input));
    assert!(r.is_ok(), "{} input {name} panics", target.name());
    // Generous for a loaded CI machine; the fuzzer's own limit is 2 s in a release build.
    assert!(t0.elapsed() < Duration::from_secs(20), "{} input {name} took {:?}", target.name(), t0.elapsed());
}

#[test]
fn the_corpus_and_its_regressions_run_clean() {
    for t in Target::ALL {
        let seeds = seeds(t);
        assert!(!seeds.is_empty(), "no seeds for {}", t.name());
        for (name, input) in seeds.iter().chain(&regressions(t)) {
            run_timed(t, name, input);
        }
    }
}

#[test]
fn a_short_mutation_run_runs_clean() {
    for t in Target::ALL {
        // Seeds only, as the fuzzer takes them (not the slow regression inputs).
        let seeds: Vec<Vec<u8>> = seeds(t).into_iter().map(|(_, s)| s).collect();
        let mut rng = Rng::new(20261123);
        for i in 0..150 {
            let a = &seeds[rng.below(seeds.len())];
            let b = &seeds[rng.below(seeds.len())];
            let input = mutate(&mut rng, a, b, t.framing(), t.max_len());
            run_timed(t, &format!("mutation {i}"), &input);
        }
    }
}
