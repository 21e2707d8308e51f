#!/usr/bin/env bash
# What can be proven about the Android app without a phone, the Android SDK or the NDK
# (docs/android.md says what these checks prove and what they do not):
#   1. resources: aapt2 compiles android/app/src/main/res and links it with the app's manifest
#      against Debian's framework-res.apk (API 29); any error fails. The manifest's own classes
#      (".MainActivity") must exist in the app's Kotlin sources.
#   2. link: noisecal-jni, release, for aarch64-linux-android, linked by Debian's clang-16/lld with
#      -z defs against a stand-in bionic sysroot built from the reviewed allowlists in
#      tests/android/sysroot/ (a symbol not listed fails the link), then checked: NEEDED exactly
#      libc, libdl, liblog, libm; every LOAD segment 16 KiB aligned; no text relocations; its Java_*
#      exports one to one with the native methods javap finds in the compiled NoisecalSession.kt.
#   3. self-tests (tests/android/self_test.sh): each check above shown failing on a bad input.
#
# Usage: tests/android/run.sh [--no-self-test]
#   Installs clang-16, lld-16, llvm-16, aapt and android-framework-res from Debian when missing
#   (root and apt-get), the Kotlin compiler from npm (tests/jvm/kotlin.sh). The sysroot and the
#   Android build are cached under target/android and target/aarch64-linux-android: a cold run
#   builds the crate graph for arm64 (minutes), a rerun only relinks what changed (seconds).
#   Last line: "N passed, M failed"; non-zero exit when a check failed.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
# shellcheck source=lib.sh
source "$ROOT/tests/android/lib.sh"
# shellcheck source=../jvm/kotlin.sh
source "$ROOT/tests/jvm/kotlin.sh"

SELF_TEST=1
for arg in "$@"; do
  case "$arg" in
    --no-self-test) SELF_TEST=0 ;;
    *) echo "error: unknown argument $arg (usage: $0 [--no-self-test])" >&2; exit 2 ;;
  esac
done

have cargo || { echo "error: cargo not found: install Rust with rustup" >&2; exit 2; }
if ! rustc --print target-libdir --target "$ANDROID_TRIPLE" 2>/dev/null | xargs -I{} test -d {}; then
  if have rustup; then rustup target add "$ANDROID_TRIPLE" >&2; fi
  rustc --print target-libdir --target "$ANDROID_TRIPLE" | xargs -I{} test -d {} || {
    echo "error: the Rust standard library for $ANDROID_TRIPLE is missing: rustup target add $ANDROID_TRIPLE" >&2; exit 2; }
fi
ensure_android_tools
ensure_kotlinc

passed=0
failed=0
record() { if "$@"; then passed=$((passed + 1)); else failed=$((failed + 1)); fi; }

echo "== android: resources and manifest (aapt2 against framework-res.apk)" >&2
record check_resources "$ROOT/android/app/src/main" "$ANDROID_OUT/aapt2"

echo "== android: link noisecal-jni for $ANDROID_TRIPLE against the stand-in sysroot" >&2
build_sysroot
SO="$(build_android_jni)"
record check_needed "$SO"
record check_load_alignment "$SO"
record check_no_textrel "$SO"

echo "== android: Java_ exports against javap of the compiled NoisecalSession.kt" >&2
compile_kotlin "$ANDROID_OUT/jni-classes" "$ROOT/android/capture/src/main/kotlin/org/noisecal/jni/NoisecalSession.kt"
record check_jni_exports "$SO" "$ANDROID_OUT/jni-classes"

if [[ $SELF_TEST == 1 ]]; then
  echo "== android: self-tests (every check above fails on a bad input)" >&2
  if out="$(bash "$ROOT/tests/android/self_test.sh" "$SO")"; then :; else failed=$((failed + 1)); fi
  # self_test.sh prints its own counts as "P F" on stdout.
  if [[ "$out" =~ ^([0-9]+)\ ([0-9]+)$ ]]; then
    passed=$((passed + BASH_REMATCH[1]))
    failed=$((failed + BASH_REMATCH[2]))
  fi
fi

echo "android: $passed passed, $failed failed"
[[ $failed -eq 0 ]]
