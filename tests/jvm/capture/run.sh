#!/usr/bin/env bash
# Host JVM tests of the Android capture library (:capture): plan, controller, simulated sweep.
#
# Usage: tests/jvm/capture/run.sh [NAME-FILTER]
#   Installs the Kotlin compiler (npm package kotlin-compiler, pinned) into .tools/ if missing,
#   compiles android/capture/src/main/kotlin plus tests/jvm/capture/src, runs every test (or those
#   whose "suite :: name" contains NAME-FILTER) and exits non-zero on any failure. The last line is
#   "N passed, M failed". Needs java (17+) and npm. The fake-sink path never loads the native library.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
# shellcheck source=../kotlin.sh
source "$ROOT/tests/jvm/kotlin.sh"
OUT="$ROOT/tests/jvm/build/capture"

ensure_kotlinc

mapfile -t SOURCES < <(find "$ROOT/android/capture/src/main/kotlin" "$ROOT/tests/jvm/capture/src" -name '*.kt' | sort)
compile_kotlin "$OUT/classes" "${SOURCES[@]}"

java -cp "$OUT/classes:$KC_LIB/kotlin-stdlib.jar" org.noisecal.capture.test.TestRunnerKt "$@"
