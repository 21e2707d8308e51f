# Shared by the JVM harnesses (source it after setting ROOT): the pinned Kotlin compiler from npm,
# installed into .tools/ when missing, and a Java check.
KOTLIN_VERSION="2.4.20"
TOOLS="$ROOT/.tools"
KC_LIB="$TOOLS/node_modules/kotlin-compiler/lib"

ensure_kotlinc() {
  command -v java >/dev/null || { echo "error: java not found; install a JDK 17+ (apt-get install openjdk-17-jdk-headless)" >&2; exit 2; }
  if [[ ! -f "$KC_LIB/kotlin-compiler.jar" ]] || ! grep -qx "$KOTLIN_VERSION" "$TOOLS/node_modules/kotlin-compiler/build.txt" 2>/dev/null; then
    command -v npm >/dev/null || { echo "error: npm not found; install Node.js and npm (apt-get install nodejs npm)" >&2; exit 2; }
    echo "installing kotlin-compiler@$KOTLIN_VERSION into $TOOLS" >&2
    mkdir -p "$TOOLS"
    npm install --silent --no-audit --no-fund --prefix "$TOOLS" "kotlin-compiler@$KOTLIN_VERSION" >&2
  fi
  local jar
  for jar in kotlin-compiler.jar kotlin-stdlib.jar; do
    [[ -f "$KC_LIB/$jar" ]] || { echo "error: $KC_LIB/$jar missing after npm install; remove $TOOLS/node_modules/kotlin-compiler and retry" >&2; exit 2; }
  done
}

# compile_kotlin CLASSES_DIR SOURCE...: compiles the sources into CLASSES_DIR against the Kotlin
# stdlib, skipped when neither the file list nor any file changed since the last compile.
compile_kotlin() {
  local classes="$1"
  shift
  local stamp="$classes/.sources.sha256" hash
  hash="$( (printf '%s\n' "$@"; cat "$@") | sha256sum | cut -d' ' -f1)"
  if [[ -f "$stamp" ]] && [[ "$(cat "$stamp")" == "$hash" ]]; then
    return 0
  fi
  rm -rf "$classes"
  mkdir -p "$classes"
  echo "compiling $# Kotlin files" >&2
  # -Werror: a warning fails the compile (the self-test in tests/android/self_test.sh shows it).
  # The exit status is checked here, not left to `set -e`, which a caller's `if` would switch off.
  if ! java -Xss8m -cp "$KC_LIB/kotlin-compiler.jar" org.jetbrains.kotlin.cli.jvm.K2JVMCompiler \
    -no-stdlib -no-reflect -classpath "$KC_LIB/kotlin-stdlib.jar" -jvm-target 17 -Werror \
    -d "$classes" "$@"; then
    rm -rf "$classes"
    echo "error: kotlinc failed on $# files (above); warnings are errors here" >&2
    return 1
  fi
  echo "$hash" > "$stamp"
}

# The native side of the harnesses: the library, noisecal-jni-tool and the CLI from the workspace's
# one test build, the `test` profile that `cargo test --workspace` builds (optimised: see
# [profile.test] in Cargo.toml; noisecal-jni's `testkit` feature comes through its dev-dependency
# on itself). After `cargo test --workspace` (tests/run_all.sh runs it first) this builds nothing;
# a build of its own (another profile, or -p with other features) would rebuild the crate graph.
TEST_BUILD_DIR="$ROOT/target/debug"
# The cdylib is built there as a dependency of the tests, so cargo leaves it in deps/ (no hash in a
# cdylib's file name) instead of copying it up beside the binaries.
TEST_LIB_DIR="$TEST_BUILD_DIR/deps"
ensure_test_build() {
  command -v cargo >/dev/null || { echo "error: cargo not found; install Rust (rustup)" >&2; exit 2; }
  echo "checking the workspace's test build (cargo test --workspace --no-run; nothing to do after cargo test)" >&2
  (cd "$ROOT" && cargo test --workspace --no-run -q >&2)
  local f
  for f in "$@"; do
    [[ -e "$TEST_BUILD_DIR/$f" ]] || { echo "error: $TEST_BUILD_DIR/$f not built by cargo test --workspace --no-run" >&2; exit 2; }
  done
  [[ -f "$TEST_LIB_DIR/libnoisecal_jni.so" || -f "$TEST_LIB_DIR/libnoisecal_jni.dylib" ]] || {
    echo "error: libnoisecal_jni not built in $TEST_LIB_DIR by cargo test --workspace --no-run" >&2; exit 2; }
}
