#!/usr/bin/env bash
# Every test of noisecal: the Rust workspace (unit, statistical, end-to-end, CLI), then the host JVM
# harnesses (the Android capture library, and the JNI boundary driven from the app's Kotlin class),
# then the Python package (one wheel built with `pip wheel ./rust/python`, installed into a venv, tested with pytest;
# Ray is installed too when PyPI allows, for the Ray Data test; NOISECAL_NO_RAY=1 skips it), then
# the denoiser benchmark's torch tests in a venv with torch (target/torchenv; NOISECAL_NO_TORCH=1 skips).
# Needs cargo, java 17+, npm (the Kotlin compiler comes from npm into .tools/) and python3 with venv.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# One build serves every stage: `cargo test --workspace` builds the workspace once, in the
# `test` profile (optimised, see Cargo.toml), with the library, noisecal-jni-tool, the CLI and the
# fuzzer in target/debug; the JVM harnesses and the fuzzer below run those (their
# `cargo test --workspace --no-run` finds nothing to do), no release build of their own.
echo "== every file the docs name exists" >&2
bash tests/doc_paths.sh

echo "== cargo test --workspace" >&2
cargo test --workspace

echo "== JVM: Android capture library (plan, controller, simulated sweep)" >&2
bash tests/jvm/capture/run.sh

echo "== JVM: JNI boundary (Kotlin NoisecalSession over the host-built library)" >&2
bash tests/jvm/jni/run.sh

echo "== JVM: full simulated sweep, plan → controller → JNI → pack, against noisecal calibrate" >&2
bash tests/jvm/sweep/run.sh

echo "== Python: pip install ./rust/python, then pytest" >&2
venv=target/pyenv
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
fi
"$venv/bin/pip" install -q --upgrade pip >&2
"$venv/bin/pip" install -q "maturin>=1.16,<2" numpy pytest pytest-benchmark >&2
# dngpy (the Adobe DNG SDK) judges the DNGs we write (tests/test_dng_sdk.py); its wheels cover few
# Pythons (3.11 here), so no source build: without a wheel that test is skipped, with the reason.
"$venv/bin/pip" install -q --only-binary dngpy "dngpy==0.1.*" >&2 || echo "warning: dngpy could not be installed; the DNG SDK test is skipped" >&2
if [ "${NOISECAL_NO_RAY:-0}" != 1 ]; then
  "$venv/bin/pip" install -q "ray[data]==2.60.*" >&2 || echo "warning: Ray could not be installed; the Ray test is skipped" >&2
fi
# One abi3 wheel, built once and installed into this venv and the torch one below.
rm -rf target/wheels
"$venv/bin/pip" wheel -q --no-deps -w target/wheels ./rust/python >&2
wheel=$(ls target/wheels/noisecal-*.whl)
"$venv/bin/pip" install -q --force-reinstall --no-deps "$wheel" >&2
(cd rust/python && NOISECAL_BIN="$PWD/../../target/debug/noisecal" "../../$venv/bin/python" -m pytest -q -p no:cacheprovider tests)
# The type stubs (python/noisecal/__init__.pyi) against the installed extension: a function, argument
# or default added on one side only fails here.
"$venv/bin/pip" install -q "mypy>=1.13,<2" >&2
echo "== Python: mypy.stubtest noisecal (the .pyi against the extension)" >&2
(cd rust/python && "../../$venv/bin/python" -m mypy.stubtest noisecal --allowlist stubtest-allowlist.txt --mypy-config-file stubtest.ini)

# The denoiser benchmark with torch: tests/test_denoise_bench.py again, now with its torch
# tests — determinism and CI's small run (oracle, noisecal, HG, the wrong and the loud model, 2 seeds
# × 500 steps on 32-px crops of a simulated set, ~2–2.5 min on 2 cores), which asserts every network
# beats the noisy input, the wrong model is clearly worst, the loud one below HG and the oracle best
# within the seed spread. Torch
# (5.6 GB with its CUDA libraries, ~3 min from PyPI) goes into its own venv cached under target/,
# reused when present; when it cannot be installed the stage is skipped with one line.
# NOISECAL_NO_TORCH=1 skips it.
echo "== Python: denoiser benchmark with torch (venv target/torchenv)" >&2
tvenv=target/torchenv
if [ "${NOISECAL_NO_TORCH:-0}" = 1 ]; then
  echo "skipped: NOISECAL_NO_TORCH=1" >&2
else
  [ -x "$tvenv/bin/python" ] || python3 -m venv "$tvenv"
  if "$tvenv/bin/python" -c "import torch" 2>/dev/null || "$tvenv/bin/python" -m pip install -q "torch>=2.0" >&2; then
    "$tvenv/bin/python" -m pip install -q "maturin>=1.16,<2" numpy pytest pytest-benchmark >&2
    "$tvenv/bin/python" -m pip install -q --force-reinstall --no-deps "$wheel" >&2
    (cd rust/python && NOISECAL_BIN="$PWD/../../target/debug/noisecal" "../../$tvenv/bin/python" -m pytest -q -p no:cacheprovider tests/test_denoise_bench.py)
  else
    echo "warning: torch could not be installed from PyPI; the denoiser benchmark's torch tests are skipped" >&2
  fi
fi

# Fuzzing: each decoder target — DNG reader, recording reader, pack decoder, JNI
# frame-view entry — mutated from tests/fuzz-corpus/ for NOISECAL_FUZZ_SECONDS (default 45). The
# binary is the one `cargo test --workspace` above built for rust/fuzz/tests (the `test` profile:
# optimised, with overflow checks), so this costs no build (a `cargo build -p noisecal-fuzz` would:
# features unify over the selected packages only). A panic or an input slower than the limit fails the run and is saved
# under target/fuzz-crashes/. Longer runs: docs/fuzzing.md. NOISECAL_FUZZ_SECONDS=0: seeds only.
echo "== fuzz: dng, recording, pack, jni-frame (${NOISECAL_FUZZ_SECONDS:-45} s each)" >&2
[[ -x target/debug/noisecal-fuzz ]] || { echo "error: target/debug/noisecal-fuzz not built by cargo test --workspace" >&2; exit 1; }
# A 20 s per-input limit in CI (2 s by default), for a loaded shared runner; hangs still fail.
# (Two fuzzed recordings that took ~3 s, a session estimating ISOs it then left out, now replay
# in ~2 ms and are seeds in tests/fuzz-corpus/recording/.)
# The seed is the commit's (its first 8 hex digits), so a failure replays from the log on any
# machine (each target prints its seed) and every commit still mutates differently; an input
# that aborts the process is saved as target/fuzz-crashes/<target>/abort.bin.
fuzz_seed=$((16#$(git rev-parse --short=8 HEAD 2>/dev/null || echo 1)))
# A failing input is also printed (base64), since a CI machine does not outlive its log.
if ! target/debug/noisecal-fuzz all --seconds "${NOISECAL_FUZZ_SECONDS:-45}" --seed "${NOISECAL_FUZZ_SEED:-$fuzz_seed}" --limit-ms "${NOISECAL_FUZZ_LIMIT_MS:-20000}"; then
    for f in target/fuzz-crashes/*/*.bin; do
        [ -f "$f" ] || continue
        echo "== failing fuzz input $f ($(wc -c <"$f") bytes), base64:" >&2
        head -c 262144 "$f" | base64 -w 120 >&2
    done
    exit 1
fi
