#!/usr/bin/env bash
# Every test of noisecal: the Rust workspace (unit, statistical, end-to-end, CLI), then the host JVM
# harnesses (the Android capture library, and the JNI boundary driven from the app's Kotlin class).
# Needs cargo, java 17+ and npm (the Kotlin compiler comes from npm into .tools/).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

echo "== cargo test --workspace" >&2
cargo test --workspace

echo "== JVM: Android capture library (plan, controller, simulated sweep)" >&2
bash tests/jvm/capture/run.sh

echo "== JVM: JNI boundary (Kotlin NoisecalSession over the host-built library)" >&2
bash tests/jvm/jni/run.sh

echo "== JVM: full simulated sweep, plan → controller → JNI → pack, against noisecal calibrate" >&2
bash tests/jvm/sweep/run.sh --build
