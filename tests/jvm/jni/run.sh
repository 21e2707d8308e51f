#!/usr/bin/env bash
# Host JVM tests of the JNI boundary (rust/jni + android/.../org/noisecal/jni/NoisecalSession.kt).
#
# Usage: tests/jvm/jni/run.sh [--rec SESSION.rec] [--filter NAME] [--bench-size WxH] [--bench-targets N]
#   Takes the cdylib and its helper with the harness's hooks (feature testkit: the Android library is
#   built without them) from the workspace's test build in target/debug (`cargo test --workspace
#   --no-run`, nothing to build after `cargo test --workspace`; tests/jvm/kotlin.sh), installs the Kotlin
#   compiler (npm kotlin-compiler, pinned) into .tools/ if missing, compiles NoisecalSession.kt and
#   the capture library's plan package with the harness in tests/jvm/jni/src, and runs it against a recording: by default a synthetic one
#   written by `noisecal-jni-tool write-recording` (pass --rec to use e.g. one from
#   `noisecal simulate --rec`). The reference pack is the Rust replay of the same recording (what
#   `noisecal calibrate session.rec` does). Last line: "N passed, M failed"; non-zero exit on failure.
#   Needs java (17+), npm and cargo. Outputs go to target/jvm-jni/.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
# shellcheck source=../kotlin.sh
source "$ROOT/tests/jvm/kotlin.sh"
OUT="$ROOT/target/jvm-jni"
WORK="$OUT/work"

ensure_test_build noisecal-jni-tool
LIB_DIR="$TEST_LIB_DIR"
TOOL="$TEST_BUILD_DIR/noisecal-jni-tool"

ensure_kotlinc

# The capture library's plan package too: the gap calls finish returns are read by its own
# parser (GainGap.parseCalls) and fed to GainGapFollowUp.propose.
SOURCES=("$ROOT/android/capture/src/main/kotlin/org/noisecal/jni/NoisecalSession.kt")
mapfile -t -O 1 SOURCES < <(find "$ROOT/android/capture/src/main/kotlin/org/noisecal/capture/plan" "$ROOT/tests/jvm/jni/src" -name '*.kt' | sort)
compile_kotlin "$OUT/classes" "${SOURCES[@]}"

rm -rf "$WORK"
mkdir -p "$WORK"
ARGS=("$@")
if [[ " ${ARGS[*]-} " != *" --rec "* ]]; then
  "$TOOL" write-recording "$WORK/session.rec" --size 320x240 --seed 1 --row-stride 656 >&2
  ARGS+=(--rec "$WORK/session.rec")
fi

java -Xmx2g -XX:MaxDirectMemorySize=1g -Djava.library.path="$LIB_DIR" \
  -cp "$OUT/classes:$KC_LIB/kotlin-stdlib.jar" org.noisecal.jni.test.JniTestsKt \
  --tool "$TOOL" --work "$WORK" "${ARGS[@]}"
