#!/usr/bin/env bash
# Host JVM test of the capture path end to end: a whole simulated sweep plan → CaptureController → REAL JNI
# library (NoisecalSinkFactory) → pack, byte-identical to `noisecal calibrate` of the recording the
# session wrote, with and without faults (settings lag, dropped images/results, failed captures,
# wrong black levels, a kill mid-burst and a resume), and sane according to `noisecal inspect --json`.
#
# Usage: tests/jvm/sweep/run.sh [--filter NAME]
#   Takes the cdylib (with the harness feature testkit, as tests/jvm/jni does) and the CLI from the
#   workspace's test build in target/debug (`cargo test --workspace --no-run`, nothing to build
#   after `cargo test --workspace`; tests/jvm/kotlin.sh); installs the Kotlin compiler (npm kotlin-compiler,
#   pinned) into .tools/ if missing; compiles android/capture/src/main/kotlin plus
#   tests/jvm/sweep/src (skipped when the sources did not change) and runs the tests (or those whose
#   "suite :: name" contains NAME). Last line: "N passed, M failed"; non-zero exit on failure.
#   Needs java (17+), npm and cargo. Outputs go to target/jvm-sweep/.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
# shellcheck source=../kotlin.sh
source "$ROOT/tests/jvm/kotlin.sh"
OUT="$ROOT/target/jvm-sweep"
WORK="$OUT/work"
LIB_DIR="$TEST_LIB_DIR"
CLI="$TEST_BUILD_DIR/noisecal"

ARGS=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    # --build: accepted for older callers; the test build is always brought up to date.
    --build) shift ;;
    --filter) [[ $# -ge 2 ]] || { echo "error: --filter needs a value" >&2; exit 2; }; ARGS+=(--filter "$2"); shift 2 ;;
    *) echo "error: unknown argument $1 (usage: $0 [--filter NAME])" >&2; exit 2 ;;
  esac
done

ensure_test_build noisecal

ensure_kotlinc

mapfile -t SOURCES < <(find "$ROOT/android/capture/src/main/kotlin" "$ROOT/tests/jvm/sweep/src" -name '*.kt' | sort)
compile_kotlin "$OUT/classes" "${SOURCES[@]}"

rm -rf "$WORK"
mkdir -p "$WORK"
java -Xmx1g -Djava.library.path="$LIB_DIR" \
  -cp "$OUT/classes:$KC_LIB/kotlin-stdlib.jar" org.noisecal.capture.sweeptest.RunnerKt \
  --cli "$CLI" --work "$WORK" "${ARGS[@]+"${ARGS[@]}"}"
