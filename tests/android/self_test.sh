#!/usr/bin/env bash
# Self-tests of tests/android/run.sh: every check shown failing on an input made wrong on purpose
# (and, where cheap, passing on the same input made right), so a check that silently passes
# everything is caught. Run by run.sh after the real checks (so the sysroot and the Kotlin compiler
# are there); alone: tests/android/self_test.sh [LIBRARY] (LIBRARY: the linked arm64 noisecal-jni,
# default target/aarch64-linux-android/release/libnoisecal_jni.so).
# Prints "PASSED FAILED" on stdout; the details on stderr. Exit 1 when any self-test failed.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
export ROOT
# shellcheck source=lib.sh
source "$ROOT/tests/android/lib.sh"
# shellcheck source=../jvm/kotlin.sh
source "$ROOT/tests/jvm/kotlin.sh"
SO="${1:-$ROOT/target/$ANDROID_TRIPLE/release/libnoisecal_jni.so}"
T="$ANDROID_OUT/self-test"
rm -rf "$T"
mkdir -p "$T"
ensure_android_tools
ensure_kotlinc
build_sysroot
android_cargo_env

passed=0
failed=0
# expect_fail NAME PATTERN COMMAND...: COMMAND must fail and its stderr must match PATTERN (egrep).
expect_fail() {
  local name="$1" pattern="$2" log="$T/$1.log"
  shift 2
  if "$@" > "$log" 2>&1; then
    echo "SELF-TEST FAIL $name: the check passed on a bad input" >&2
    sed 's/^/    /' "$log" >&2
    failed=$((failed + 1))
  elif ! grep -Eq "$pattern" "$log"; then
    echo "SELF-TEST FAIL $name: failed, but without the expected message /$pattern/:" >&2
    sed 's/^/    /' "$log" >&2
    failed=$((failed + 1))
  else
    echo "self-test ok  $name: fails as it should: $(grep -Em1 "$pattern" "$log")" >&2
    passed=$((passed + 1))
  fi
}
# expect_pass NAME COMMAND...: the control, COMMAND must pass.
expect_pass() {
  local name="$1" log="$T/$1.log"
  shift
  if "$@" > "$log" 2>&1; then
    echo "self-test ok  $name: passes" >&2
    passed=$((passed + 1))
  else
    echo "SELF-TEST FAIL $name: the control failed:" >&2
    sed 's/^/    /' "$log" >&2
    failed=$((failed + 1))
  fi
}

LINKER="$ROOT/tests/android/linker"
CC=("$CLANG" "--target=$ANDROID_TRIPLE$ANDROID_API" -fPIC -O1 -ffreestanding -fno-builtin -w)
lib="$SYSROOT/usr/lib"

# --- link: -z defs against the allowlists ----------------------------------------------------------
# A symbol glibc has and bionic does not, and one bionic has that is not on the list: both refused.
cat > "$T/glibc_only.c" <<'EOF'
extern const char *gnu_get_libc_version(void);
const char *which_libc(void) { return gnu_get_libc_version(); }
EOF
cat > "$T/unlisted.c" <<'EOF'
extern int __register_atfork(void (*)(void), void (*)(void), void (*)(void), void *);
int hook(void) { return __register_atfork(0, 0, 0, 0); }
EOF
cat > "$T/listed.c" <<'EOF'
extern void *malloc(unsigned long);
extern void free(void *);
void roundtrip(void) { free(malloc(16)); }
EOF
for f in glibc_only unlisted listed; do "${CC[@]}" -c "$T/$f.c" -o "$T/$f.o"; done
if grep -qx '__register_atfork\( .*\)\?' <(sed 's/#.*//; s/[[:space:]]*$//' "$SYSROOT_SRC/libc.txt"); then
  echo "error: self_test.sh assumes __register_atfork is not in the allowlist; pick another unlisted bionic symbol" >&2
  exit 2
fi
expect_fail link-glibc-only 'undefined symbol: gnu_get_libc_version' \
  "$LINKER" -shared -o "$T/glibc_only.so" "$T/glibc_only.o" -lc
expect_fail link-unlisted 'undefined symbol: __register_atfork' \
  "$LINKER" -shared -o "$T/unlisted.so" "$T/unlisted.o" -lc
expect_pass link-listed "$LINKER" -shared -o "$T/listed.so" "$T/listed.o" -lc

# --- NEEDED ------------------------------------------------------------------------------------------
printf '\t.text\n\t.globl deflate\n\t.type deflate, %%function\ndeflate:\n\tret\n' > "$T/libz.S"
"${CC[@]}" -c "$T/libz.S" -o "$T/libz.o"
"$LLD" -shared -soname libz.so -o "$T/libz.so" "$T/libz.o"
expect_fail needed-extra 'FAIL needed: .*libz\.so' bash -c "
  '$LINKER' -shared -o '$T/extra.so' '$T/listed.o' -Wl,--no-as-needed -L'$T' -lz -lc -ldl -llog -lm &&
  source '$ROOT/tests/android/lib.sh' && check_needed '$T/extra.so'"
expect_fail needed-missing 'FAIL needed: .*\[libc\.so\]' bash -c "
  '$LINKER' -shared -o '$T/onlyc.so' '$T/listed.o' -lc && source '$ROOT/tests/android/lib.sh' && check_needed '$T/onlyc.so'"
expect_pass needed-exact bash -c "
  '$LINKER' -shared -o '$T/exact.so' '$T/listed.o' -Wl,--no-as-needed -lc -ldl -llog -lm &&
  source '$ROOT/tests/android/lib.sh' && check_needed '$T/exact.so'"

# --- 16 KiB LOAD alignment -----------------------------------------------------------------------------
expect_fail align-4k 'FAIL align' bash -c "
  '$LLD' -shared -z max-page-size=4096 -o '$T/page4k.so' '$T/listed.o' -L'$lib' -lc &&
  source '$ROOT/tests/android/lib.sh' && check_load_alignment '$T/page4k.so'"
expect_pass align-16k bash -c "source '$ROOT/tests/android/lib.sh' && check_load_alignment '$T/listed.so'"

# --- text relocations ------------------------------------------------------------------------------------
# An absolute address stored in .text: a text relocation, allowed only with -z notext.
printf '\t.text\n\t.globl f\n\t.type f, %%function\nf:\n\tret\n\t.p2align 3\nslot:\n\t.quad malloc\n' > "$T/textrel.S"
"${CC[@]}" -c "$T/textrel.S" -o "$T/textrel.o"
expect_fail textrel 'FAIL textrel' bash -c "
  '$LLD' -shared -z notext -o '$T/textrel.so' '$T/textrel.o' -L'$lib' -lc &&
  source '$ROOT/tests/android/lib.sh' && check_no_textrel '$T/textrel.so'"
expect_fail textrel-linker 'relocation .* against .*malloc' "$LINKER" -shared -o "$T/textrel2.so" "$T/textrel.o" -lc

# --- JNI names ---------------------------------------------------------------------------------------------
# Known answers of the JNI mangling: '_', '$', arrays and classes, an overload (long names only).
cat > "$T/fake-javap.txt" <<'EOF'
public class a.b.C$D {
  private static native void native_thing(java.lang.String[], int);
    descriptor: ([Ljava/lang/String;I)V
  public native int over(long);
    descriptor: (J)I
  public native int over(long, boolean);
    descriptor: (JZ)I
}
EOF
printf '%s\n' Java_a_b_C_00024D_native_1thing Java_a_b_C_00024D_over__J Java_a_b_C_00024D_over__JZ > "$T/fake-exports.txt"
expect_pass jni-mangling python3 "$ROOT/tests/android/jni_names.py" "$T/fake-javap.txt" "$T/fake-exports.txt"
printf '%s\n' Java_a_b_C_00024D_native_1thing Java_a_b_C_00024D_over > "$T/fake-exports-short.txt"
expect_fail jni-overload-short 'binds every overload' python3 "$ROOT/tests/android/jni_names.py" "$T/fake-javap.txt" "$T/fake-exports-short.txt"

# The real library against NoisecalSession.kt with one external renamed and one overload added,
# as a change to the Kotlin side alone would do.
SRC="$ROOT/android/capture/src/main/kotlin/org/noisecal/jni/NoisecalSession.kt"
mkdir -p "$T/kt"
sed -e 's/nativeBeginDark\b/nativeBeginDarkRenamed/g' \
    -e 's/^\( *\)@JvmStatic private external fun nativeClose(handle: Long)$/&\n\1@JvmStatic private external fun nativeClose(handle: Long, force: Boolean)/' \
    "$SRC" > "$T/kt/NoisecalSession.kt"
grep -q 'nativeBeginDarkRenamed' "$T/kt/NoisecalSession.kt" && grep -q 'force: Boolean' "$T/kt/NoisecalSession.kt" || {
  echo "error: self_test.sh could not edit a copy of $SRC (nativeBeginDark / nativeClose changed?): update the sed above" >&2; exit 2; }
if compile_kotlin "$T/kt-classes" "$T/kt/NoisecalSession.kt" > "$T/kotlin-edit.log" 2>&1; then
  expect_fail jni-renamed-external 'NoisecalSession\.nativeBeginDarkRenamed\(J\)V has no export' \
    bash -c "source '$ROOT/tests/android/lib.sh' && check_jni_exports '$SO' '$T/kt-classes'"
  expect_fail jni-orphan-export 'export Java_org_noisecal_jni_NoisecalSession_nativeBeginDark__J matches no native' \
    bash -c "source '$ROOT/tests/android/lib.sh' && check_jni_exports '$SO' '$T/kt-classes'"
  expect_fail jni-new-overload 'nativeClose\(JZ\)V has no export' \
    bash -c "source '$ROOT/tests/android/lib.sh' && check_jni_exports '$SO' '$T/kt-classes'"
else
  cat "$T/kotlin-edit.log" >&2
  echo "SELF-TEST FAIL jni: the edited copy of NoisecalSession.kt did not compile" >&2
  failed=$((failed + 1))
fi

# --- resources and manifest ------------------------------------------------------------------------
cp -r "$ROOT/android/app/src/main" "$T/main-badref"
sed -i 's#android:label="@string/app_name"#android:label="@string/app_title"#' "$T/main-badref/AndroidManifest.xml"
expect_fail resources-bad-reference 'string/app_title .*not found' \
  bash -c "source '$ROOT/tests/android/lib.sh' && check_resources '$T/main-badref' '$T/aapt-badref'"
cp -r "$ROOT/android/app/src/main" "$T/main-badstyle"
sed -i 's#parent="android:Theme.Material.NoActionBar"#parent="android:Theme.Material.NoSuchBar"#' "$T/main-badstyle/res/values/themes.xml"
expect_fail resources-bad-parent 'Theme.Material.NoSuchBar' \
  bash -c "source '$ROOT/tests/android/lib.sh' && check_resources '$T/main-badstyle' '$T/aapt-badstyle'"
cp -r "$ROOT/android/app/src/main" "$T/main-badclass"
sed -i 's#android:name=".MainActivity"#android:name=".MainScreen"#' "$T/main-badclass/AndroidManifest.xml"
expect_fail resources-missing-class 'no class MainScreen' \
  bash -c "source '$ROOT/tests/android/lib.sh' && check_resources '$T/main-badclass' '$T/aapt-badclass'"

# --- Kotlin warnings are errors (tests/jvm/kotlin.sh compile_kotlin, used by every JVM harness) ------
cat > "$T/Warn.kt" <<'EOF'
fun length(s: String): Int? = s?.length
EOF
expect_fail kotlin-warning-is-error 'warning.*(nnecessary safe call|safe call)' compile_kotlin "$T/warn-classes" "$T/Warn.kt"

echo "android self-tests: $passed passed, $failed failed" >&2
echo "$passed $failed"
[[ $failed -eq 0 ]]
