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
KOTLIN_VERSION="2.4.20"
TOOLS="$ROOT/.tools"
KC_LIB="$TOOLS/node_modules/kotlin-compiler/lib"
OUT="$ROOT/tests/jvm/build/capture"

if [[ ! -f "$KC_LIB/kotlin-compiler.jar" ]] || ! grep -qx "$KOTLIN_VERSION" "$TOOLS/node_modules/kotlin-compiler/build.txt" 2>/dev/null; then
  echo "installing kotlin-compiler@$KOTLIN_VERSION into $TOOLS" >&2
  mkdir -p "$TOOLS"
  npm install --silent --no-audit --no-fund --prefix "$TOOLS" "kotlin-compiler@$KOTLIN_VERSION" >&2
fi
for jar in kotlin-compiler.jar kotlin-stdlib.jar; do
  [[ -f "$KC_LIB/$jar" ]] || { echo "error: $KC_LIB/$jar missing after npm install; remove $TOOLS/node_modules/kotlin-compiler and retry" >&2; exit 2; }
done
command -v java >/dev/null || { echo "error: java not found; install a JDK 17+ (apt-get install openjdk-17-jdk-headless)" >&2; exit 2; }

rm -rf "$OUT"
mkdir -p "$OUT"
mapfile -t SOURCES < <(find "$ROOT/android/capture/src/main/kotlin" "$ROOT/tests/jvm/capture/src" -name '*.kt' | sort)
echo "compiling ${#SOURCES[@]} Kotlin files" >&2
java -Xss8m -cp "$KC_LIB/kotlin-compiler.jar" org.jetbrains.kotlin.cli.jvm.K2JVMCompiler \
  -no-stdlib -no-reflect -classpath "$KC_LIB/kotlin-stdlib.jar" -jvm-target 17 -Werror \
  -d "$OUT/classes" "${SOURCES[@]}"

java -cp "$OUT/classes:$KC_LIB/kotlin-stdlib.jar" org.noisecal.capture.test.TestRunnerKt "$@"
