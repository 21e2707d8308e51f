//! `noisecal-fuzz`: mutation fuzzing of noisecal's decoders (see the crate docs and
//! `docs/fuzzing.md`).
//!
//! ```text
//! noisecal-fuzz <target|all> [--seconds N] [--seed S] [--corpus DIR] [--crashes DIR] [--limit-ms MS]
//! noisecal-fuzz replay <target> FILE…     run saved inputs once (a crash's regression check)
//! noisecal-fuzz seeds jni-frame DIR        write the jni-frame seeds
//! ```
//! Each input runs under `catch_unwind`; a panic, or a run longer than `--limit-ms` (2000), is a
//! failure: the input is saved to `<crashes>/<target>/` and the exit status is 1. A run stuck 5×
//! past the limit is saved by a watchdog, which then ends the process (status 2). An input that
//! aborts the process (a failed allocation, a stack overflow) is saved as
//! `<crashes>/<target>/abort.bin` by a SIGABRT handler (see `abort.rs`).

mod abort;

use std::panic::{self, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use noisecal_fuzz::Target;
use noisecal_fuzz::mutate::{self, Rng};

struct Options {
    seconds: f64,
    seed: u64,
    corpus: PathBuf,
    crashes: PathBuf,
    limit: Duration,
}

fn usage() -> ExitCode {
    eprintln!(
        "usage: noisecal-fuzz <dng|recording|pack|jni-frame|all> [--seconds N] [--seed S] [--corpus DIR] [--crashes DIR] [--limit-ms MS]\n       noisecal-fuzz replay <target> FILE…\n       noisecal-fuzz seeds jni-frame DIR"
    );
    ExitCode::from(2)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(first) = args.first() else { return usage() };
    match first.as_str() {
        "replay" => {
            let Some(target) = args.get(1).and_then(|t| Target::parse(t)) else { return usage() };
            replay(target, &args[2..])
        }
        "seeds" => {
            let (Some("jni-frame"), Some(dir)) = (args.get(1).map(String::as_str), args.get(2)) else {
                return usage();
            };
            let dir = Path::new(dir);
            if let Err(e) = std::fs::create_dir_all(dir) {
                eprintln!("cannot create {}: {e}", dir.display());
                return ExitCode::FAILURE;
            }
            for (i, s) in noisecal_fuzz::jni_seeds().iter().enumerate() {
                if let Err(e) = std::fs::write(dir.join(format!("seed-{i}.bin")), s) {
                    eprintln!("cannot write a seed: {e}");
                    return ExitCode::FAILURE;
                }
            }
            ExitCode::SUCCESS
        }
        name => {
            let targets: Vec<Target> = if name == "all" {
                Target::ALL.to_vec()
            } else if let Some(t) = Target::parse(name) {
                vec![t]
            } else {
                return usage();
            };
            let Some(opts) = parse_options(&args[1..]) else { return usage() };
            quiet_panics();
            let mut failed = false;
            for t in targets {
                failed |= !fuzz(t, &opts);
            }
            if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS }
        }
    }
}

fn parse_options(args: &[String]) -> Option<Options> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut o = Options {
        seconds: 45.0,
        seed: 1,
        corpus: root.join("tests/fuzz-corpus"),
        crashes: root.join("target/fuzz-crashes"),
        limit: Duration::from_millis(2000),
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let v = it.next()?;
        match a.as_str() {
            "--seconds" => o.seconds = v.parse().ok()?,
            "--seed" => o.seed = v.parse().ok()?,
            "--corpus" => o.corpus = v.into(),
            "--crashes" => o.crashes = v.into(),
            "--limit-ms" => o.limit = Duration::from_millis(v.parse().ok()?),
            _ => return None,
        }
    }
    Some(o)
}

thread_local! {
    static LAST_PANIC: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
}

/// Panics are expected findings: their message is kept for the report instead of printed.
fn quiet_panics() {
    panic::set_hook(Box::new(|info| {
        let msg = match info.payload().downcast_ref::<&str>() {
            Some(s) => s.to_string(),
            None => info.payload().downcast_ref::<String>().cloned().unwrap_or_else(|| "a panic".into()),
        };
        let at = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
        LAST_PANIC.with(|p| *p.borrow_mut() = format!("{msg}{at}"));
    }));
}

fn load_seeds(target: Target, corpus: &Path) -> Vec<Vec<u8>> {
    let dir = corpus.join(target.name());
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|rd| rd.flatten().map(|e| e.path()).filter(|p| p.is_file()).collect())
        .unwrap_or_default();
    files.sort();
    let mut seeds: Vec<Vec<u8>> = files.iter().filter_map(|p| std::fs::read(p).ok()).collect();
    if target == Target::JniFrame {
        seeds.extend(noisecal_fuzz::jni_seeds());
    }
    if seeds.is_empty() {
        seeds.push(Vec::new());
    }
    seeds
}

fn save(crashes: &Path, target: Target, input: &[u8], why: &str) -> PathBuf {
    let dir = crashes.join(target.name());
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!("crash-{:08x}.bin", crc32fast::hash(input)));
    let _ = std::fs::write(&path, input);
    let _ = std::fs::write(path.with_extension("txt"), why);
    path
}

/// Fuzzes one target for the given time; false when it found a failure.
fn fuzz(target: Target, o: &Options) -> bool {
    let seeds = load_seeds(target, &o.corpus);
    let mut pool = seeds.clone();
    let mut outcomes = std::collections::HashSet::new();
    let mut rng = Rng::new(o.seed ^ (target as u64).wrapping_mul(0x1000_0000_01b3));
    let deadline = Instant::now() + Duration::from_secs_f64(o.seconds.max(0.0));
    eprintln!("fuzz {}: seed {}, {} s", target.name(), o.seed, o.seconds);
    abort::arm(&o.crashes, target.name());

    // The watchdog: an input stuck far past the limit is saved, then the process ends.
    let current = Arc::new(Mutex::new(Vec::<u8>::new()));
    let started = Arc::new(AtomicU64::new(0));
    let epoch = Instant::now();
    {
        let (current, started, crashes, limit) = (current.clone(), started.clone(), o.crashes.clone(), o.limit);
        std::thread::spawn(move || {
            loop {
                std::thread::sleep(Duration::from_millis(200));
                let s = started.load(Ordering::Relaxed);
                if s == 0 {
                    continue;
                }
                let running = epoch.elapsed().saturating_sub(Duration::from_nanos(s));
                if running > limit * 5 {
                    let input = current.lock().map(|g| g.clone()).unwrap_or_default();
                    let p = save(&crashes, target, &input, &format!("hang: still running after {running:?}"));
                    eprintln!("fuzz {}: HANG, input saved to {}", target.name(), p.display());
                    std::process::exit(2);
                }
            }
        });
    }

    let (mut execs, mut failures, mut slowest) = (0u64, 0u64, Duration::ZERO);
    let mut mutator_panics = 0u64;
    let mut i = 0usize;
    while Instant::now() < deadline || execs < seeds.len() as u64 {
        // The seeds themselves first, then mutations of the pool.
        let input = if (i) < seeds.len() {
            seeds[i].clone()
        } else {
            let a = &pool[rng.below(pool.len())];
            let b = &pool[rng.below(pool.len())];
            // The mutator is the harness's own code, outside the input's `catch_unwind`: a panic
            // there would end the process silently (the hook keeps messages for the report), so it
            // is caught, named and counted, and the round moves on.
            match panic::catch_unwind(AssertUnwindSafe(|| {
                mutate::mutate(&mut rng, a, b, target.framing(), target.max_len())
            })) {
                Ok(m) => m,
                Err(_) => {
                    mutator_panics += 1;
                    if mutator_panics == 1 {
                        let msg = LAST_PANIC.with(|p| p.borrow().clone());
                        eprintln!(
                            "fuzz {}: the mutator panicked ({msg}) on inputs of {} and {} bytes (a harness bug)",
                            target.name(),
                            a.len(),
                            b.len()
                        );
                    }
                    continue;
                }
            }
        };
        i += 1;
        if let Ok(mut g) = current.lock() {
            g.clone_from(&input);
        }
        let t0 = Instant::now();
        started.store((t0 - epoch).as_nanos().max(1) as u64, Ordering::Relaxed);
        abort::running(&input);
        let result = panic::catch_unwind(AssertUnwindSafe(|| target.run(&input)));
        abort::finished();
        let took = t0.elapsed();
        started.store(0, Ordering::Relaxed);
        execs += 1;
        slowest = slowest.max(took);
        match result {
            Ok(outcome) if took <= o.limit => {
                if outcomes.insert(outcome) && pool.len() < 512 {
                    pool.push(input);
                }
            }
            Ok(_) => {
                failures += 1;
                let p = save(&o.crashes, target, &input, &format!("slow: {took:?}"));
                eprintln!("fuzz {}: SLOW ({took:?}), input saved to {}", target.name(), p.display());
            }
            Err(_) => {
                failures += 1;
                let msg = LAST_PANIC.with(|p| p.borrow().clone());
                let p = save(&o.crashes, target, &input, &format!("panic: {msg}"));
                eprintln!("fuzz {}: PANIC {msg}; input saved to {}", target.name(), p.display());
            }
        }
    }
    println!(
        "fuzz {}: {execs} executions in {:.0} s, {} seeds, {} distinct outcomes, slowest {:.0} ms, {failures} failures",
        target.name(),
        o.seconds,
        seeds.len(),
        outcomes.len(),
        slowest.as_secs_f64() * 1e3
    );
    if mutator_panics > 0 {
        println!(
            "fuzz {}: {mutator_panics} mutations panicked in the harness (not counted as failures)",
            target.name()
        );
    }
    failures == 0
}

fn replay(target: Target, files: &[String]) -> ExitCode {
    quiet_panics();
    let mut failed = false;
    for f in files {
        let Ok(input) = std::fs::read(f) else {
            eprintln!("cannot read {f}");
            failed = true;
            continue;
        };
        let t0 = Instant::now();
        match panic::catch_unwind(AssertUnwindSafe(|| target.run(&input))) {
            Ok(outcome) => println!("{f}: {outcome} ({:.0} ms)", t0.elapsed().as_secs_f64() * 1e3),
            Err(_) => {
                failed = true;
                println!("{f}: PANIC {}", LAST_PANIC.with(|p| p.borrow().clone()));
            }
        }
    }
    if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS }
}
