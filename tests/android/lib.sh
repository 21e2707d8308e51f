# Shared by tests/android/*.sh (source it after setting ROOT): the Debian tools, the stand-in
# bionic sysroot, the arm64 build of noisecal-jni, and the checks on an ELF library. Every check is
# a function over a file, so tests/android/self_test.sh can show each one failing on a bad input.

# API level the stubs and the link target: the app's minSdk (gradle/libs.versions.toml).
ANDROID_API="$(sed -n 's/^minSdk *= *"\([0-9]*\)".*/\1/p' "$ROOT/gradle/libs.versions.toml")"
[[ -n "$ANDROID_API" ]] || { echo "error: minSdk not found in gradle/libs.versions.toml" >&2; exit 2; }
ANDROID_TRIPLE="aarch64-linux-android"
ANDROID_OUT="$ROOT/target/android"
SYSROOT="$ANDROID_OUT/sysroot"
SYSROOT_SRC="$ROOT/tests/android/sysroot"
FRAMEWORK_RES="/usr/share/android-framework-res/framework-res.apk"
CLANG=clang-16
LLD=ld.lld-16
READELF=llvm-readelf-16
NM=llvm-nm-16
AR=llvm-ar-16
# The libraries the JNI library may depend on, and nothing else (what an NDK build links).
EXPECTED_NEEDED="libc.so libdl.so liblog.so libm.so"
PAGE=16384

have() { command -v "$1" >/dev/null 2>&1; }

# Installs what is missing from Debian (as .ci/run does); without root and apt-get, says what to
# install and fails.
ensure_android_tools() {
  local missing=()
  have "$CLANG" || missing+=(clang-16)
  have "$LLD" || missing+=(lld-16)
  { have "$READELF" && have "$NM" && have "$AR"; } || missing+=(llvm-16)
  have aapt2 || missing+=(aapt)
  [[ -f "$FRAMEWORK_RES" ]] || missing+=(android-framework-res)
  have javap || missing+=(openjdk-17-jdk-headless)
  have python3 || missing+=(python3)
  [[ ${#missing[@]} -eq 0 ]] && return 0
  if have apt-get && [[ "$(id -u)" == 0 ]]; then
    echo "installing ${missing[*]} (Debian)" >&2
    if [[ -z "${APT_UPDATED:-}" ]]; then apt-get update -qq >&2 || true; export APT_UPDATED=1; fi
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >&2 || {
      echo "error: apt-get install ${missing[*]} failed" >&2; exit 2; }
  else
    echo "error: missing ${missing[*]}: install them (Debian bookworm: apt-get install ${missing[*]}), as root" >&2
    exit 2
  fi
}

# Reads an allowlist: one symbol per line, optionally followed by "object" (a data symbol);
# '#' starts a comment. Prints "name kind" lines.
read_allowlist() {
  sed -e 's/#.*//' -e 's/[[:space:]]\+/ /g' -e 's/^ //' -e 's/ $//' "$1" | awk 'NF { print $1, ($2 == "object" ? "object" : "function") }'
}

# stub_asm ALLOWLIST: assembly that defines every listed symbol (functions as `ret`, objects as
# 16 zero bytes), for a stub shared library or archive.
stub_asm() {
  read_allowlist "$1" | awk '
    $2 == "function" { printf "\t.text\n\t.globl %s\n\t.type %s, %%function\n\t.p2align 2\n%s:\n\tret\n\t.size %s, 4\n", $1, $1, $1, $1 }
    $2 == "object"   { printf "\t.data\n\t.globl %s\n\t.type %s, %%object\n\t.p2align 3\n%s:\n\t.zero 16\n\t.size %s, 16\n", $1, $1, $1, $1 }'
}

# Builds the stand-in sysroot into target/android/sysroot from the committed sources in
# tests/android/sysroot (allowlists, crt objects), unless it is already built from the same
# sources: stub libc.so, libm.so, libdl.so, liblog.so (sonames as on Android), crtbegin_so.o,
# crtend_so.o and a stub libunwind.a.
build_sysroot() {
  local hash
  hash="$( (echo "api=$ANDROID_API"; "$CLANG" --version | head -1; cd "$SYSROOT_SRC" && for f in $(ls | sort); do echo "== $f"; cat "$f"; done) | sha256sum | cut -d' ' -f1)"
  if [[ -f "$SYSROOT/.inputs.sha256" ]] && [[ "$(cat "$SYSROOT/.inputs.sha256")" == "$hash" ]]; then
    return 0
  fi
  echo "building the stand-in bionic sysroot (API $ANDROID_API) in $SYSROOT" >&2
  rm -rf "$SYSROOT"
  local lib="$SYSROOT/usr/lib" tmp="$SYSROOT/obj"
  mkdir -p "$lib" "$tmp"
  local cc=("$CLANG" "--target=$ANDROID_TRIPLE$ANDROID_API" -fPIC -O2 -ffreestanding -fno-builtin -Werror)
  local name
  for name in c m dl log; do
    [[ -f "$SYSROOT_SRC/lib$name.txt" ]] || { echo "error: allowlist $SYSROOT_SRC/lib$name.txt missing" >&2; exit 2; }
    stub_asm "$SYSROOT_SRC/lib$name.txt" > "$tmp/lib$name.S"
    "${cc[@]}" -c "$tmp/lib$name.S" -o "$tmp/lib$name.o"
    "$LLD" -shared -soname "lib$name.so" -z max-page-size=$PAGE -o "$lib/lib$name.so" "$tmp/lib$name.o"
  done
  stub_asm "$SYSROOT_SRC/libunwind.txt" > "$tmp/libunwind.S"
  "${cc[@]}" -c "$tmp/libunwind.S" -o "$tmp/libunwind.o"
  "$AR" rcs "$lib/libunwind.a" "$tmp/libunwind.o"
  "${cc[@]}" -c "$SYSROOT_SRC/crtbegin_so.c" -o "$lib/crtbegin_so.o"
  "${cc[@]}" -c "$SYSROOT_SRC/crtend_so.S" -o "$lib/crtend_so.o"
  echo "$hash" > "$SYSROOT/.inputs.sha256"
}

# The environment under which cargo links for aarch64-linux-android against the sysroot: the
# target-specific linker variable only, so host builds (and build scripts) are untouched.
android_cargo_env() {
  export CARGO_TARGET_AARCH64_LINUX_ANDROID_LINKER="$ROOT/tests/android/linker"
  export NOISECAL_ANDROID_SYSROOT="$SYSROOT"
  export NOISECAL_ANDROID_API="$ANDROID_API"
}

# --- checks: each takes the library and prints what is wrong; non-zero when something is ---------

# NEEDED must be exactly EXPECTED_NEEDED.
check_needed() {
  local so="$1" got
  got="$("$READELF" -dW "$so" | sed -n 's/.*(NEEDED).*\[\(.*\)\].*/\1/p' | sort | tr '\n' ' ' | sed 's/ $//')"
  if [[ "$got" != "$EXPECTED_NEEDED" ]]; then
    echo "FAIL needed: $so depends on [$got], expected exactly [$EXPECTED_NEEDED] (a new NEEDED library is not on the device, or a crate links what the NDK build does not)" >&2
    return 1
  fi
  echo "ok   needed: $got" >&2
}

# Every PT_LOAD segment aligned to 16 KiB (Google Play's page-size rule, Android 15+ devices).
check_load_alignment() {
  local so="$1" line align bad="" loads=0
  while read -r line; do
    loads=$((loads + 1))
    align="${line##* }"
    if (( align < PAGE || align % PAGE != 0 )); then bad+="$line"$'\n'; fi
  done < <("$READELF" -lW "$so" | awk '$1 == "LOAD"')
  if [[ $loads -eq 0 ]]; then
    echo "FAIL align: $so has no LOAD segment (not a linked library?)" >&2
    return 1
  fi
  if [[ -n "$bad" ]]; then
    echo "FAIL align: LOAD segments of $so not aligned to $PAGE bytes (link with -Wl,-z,max-page-size=$PAGE; NDK r28+ does by default):" >&2
    printf '%s' "$bad" >&2
    return 1
  fi
  echo "ok   align: all $loads LOAD segments aligned to $PAGE" >&2
}

# No text relocations (refused by Android's loader for API 23+).
check_no_textrel() {
  local so="$1" dyn
  if ! dyn="$("$READELF" -dW "$so")" || ! grep -q '(SONAME)\|(NEEDED)' <<<"$dyn"; then
    echo "FAIL textrel: cannot read the dynamic section of $so" >&2
    return 1
  fi
  if grep -Eq '\(TEXTREL\)|\(FLAGS\).*TEXTREL' <<<"$dyn"; then
    echo "FAIL textrel: $so has text relocations (DT_TEXTREL), which Android refuses to load: build every object with -fPIC" >&2
    return 1
  fi
  echo "ok   textrel: none" >&2
}

# check_jni_exports SO CLASSES_DIR: the Java_* exports of SO against the native methods of the
# compiled Kotlin classes under CLASSES_DIR/org/noisecal/jni (javap -s), both directions.
check_jni_exports() {
  local so="$1" classes="$2" work
  work="$(mktemp -d)"
  local cls=()
  mapfile -t cls < <(cd "$classes" && find org/noisecal/jni -maxdepth 1 -name '*.class' | sed 's/\.class$//; s#/#.#g' | sort)
  if [[ ${#cls[@]} -eq 0 ]]; then
    echo "FAIL jni: no classes under $classes/org/noisecal/jni" >&2
    rm -rf "$work"
    return 1
  fi
  javap -p -s -cp "$classes" "${cls[@]}" > "$work/javap.txt"
  "$NM" -D --defined-only --format=just-symbols "$so" | grep '^Java_' > "$work/exports.txt" || true
  local rc=0
  python3 "$ROOT/tests/android/jni_names.py" "$work/javap.txt" "$work/exports.txt" || rc=$?
  rm -rf "$work"
  return $rc
}

# Builds (or relinks) the release noisecal-jni for arm64 against the sysroot; prints the library's
# path. Cargo does not see the sysroot, so the library is relinked whenever the sysroot changed
# since it was last linked.
build_android_jni() {
  android_cargo_env
  local so="$ROOT/target/$ANDROID_TRIPLE/release/libnoisecal_jni.so" stamp="$ANDROID_OUT/linked-against.sha256"
  if [[ -f "$so" ]] && [[ "$(cat "$stamp" 2>/dev/null)" != "$(cat "$SYSROOT/.inputs.sha256")" ]]; then
    (cd "$ROOT" && cargo clean -q --release --target "$ANDROID_TRIPLE" -p noisecal-jni >&2)
  fi
  if ! (cd "$ROOT" && cargo build --release --target "$ANDROID_TRIPLE" -p noisecal-jni --lib >&2); then
    echo "FAIL link: noisecal-jni does not link for $ANDROID_TRIPLE (above). An 'undefined symbol' is one outside the reviewed allowlists tests/android/sysroot/lib{c,m,dl,log,unwind}.txt: use something bionic has at API $ANDROID_API instead, or, if bionic really exports it at that level (bionic's libc.map.txt), add it to the allowlist with a comment, in a reviewed commit" >&2
    return 1
  fi
  [[ -f "$so" ]] || { echo "error: $so not built" >&2; return 1; }
  cp "$SYSROOT/.inputs.sha256" "$stamp"
  echo "$so"
}

# Reads `name = "value"` from a Gradle Kotlin script.
gradle_value() {
  sed -n "s/^ *$1 *= *\"\\([^\"]*\\)\".*/\\1/p" "$2" | head -1
}

# check_resources SRC_MAIN OUT: aapt2 compile of SRC_MAIN/res and link with SRC_MAIN's manifest
# against framework-res.apk, as AGP would (it substitutes ${applicationId} and adds package= from
# the namespace); then the manifest's own components must be classes of SRC_MAIN/kotlin.
check_resources() {
  local main="$1" out="$2" gradle="$ROOT/android/app/build.gradle.kts" catalog="$ROOT/gradle/libs.versions.toml"
  local ns appid target
  ns="$(gradle_value namespace "$gradle")"
  appid="$(gradle_value applicationId "$gradle")"
  target="$(sed -n 's/^targetSdk *= *"\([0-9]*\)".*/\1/p' "$catalog")"
  if [[ -z "$ns" || -z "$appid" || -z "$target" ]]; then
    echo "FAIL resources: namespace/applicationId ($gradle) or targetSdk ($catalog) not found" >&2
    return 1
  fi
  rm -rf "$out"
  mkdir -p "$out"
  if ! aapt2 compile --dir "$main/res" -o "$out/res.zip" 2> "$out/compile.log"; then
    cat "$out/compile.log" >&2
    echo "FAIL resources: aapt2 compile of $main/res failed (above)" >&2
    return 1
  fi
  sed -e "s/\${applicationId}/$appid/g" -e "0,/<manifest /s//<manifest package=\"$ns\" /" "$main/AndroidManifest.xml" > "$out/AndroidManifest.xml"
  if grep -n '\${' "$out/AndroidManifest.xml" >&2; then
    echo "FAIL resources: a manifest placeholder other than \${applicationId} (above) that the check does not know; AGP needs it in manifestPlaceholders" >&2
    return 1
  fi
  if ! aapt2 link -I "$FRAMEWORK_RES" --manifest "$out/AndroidManifest.xml" --min-sdk-version "$ANDROID_API" \
      --target-sdk-version "$target" -o "$out/app.apk" "$out/res.zip" 2> "$out/link.log"; then
    cat "$out/link.log" >&2
    echo "FAIL resources: aapt2 link of $main/AndroidManifest.xml and res/ against $FRAMEWORK_RES failed (above)" >&2
    return 1
  fi
  [[ -s "$out/link.log" ]] && cat "$out/link.log" >&2
  local missing
  missing="$(python3 - "$out/AndroidManifest.xml" "$main/kotlin" "$ns" <<'PY'
import os, re, sys, xml.etree.ElementTree as ET
manifest, src, ns = sys.argv[1:4]
A = "{http://schemas.android.com/apk/res/android}name"
for el in ET.parse(manifest).getroot().iter():
    if el.tag not in ("activity", "service", "receiver", "provider", "application") or A not in el.attrib:
        continue
    name = el.attrib[A]
    full = ns + name if name.startswith(".") else name
    if not full.startswith(ns + "."):
        continue  # a library's class (androidx...): not in this module's sources
    pkg, cls = full.rsplit(".", 1)
    d = os.path.join(src, *pkg.split("."))
    found = os.path.isdir(d) and any(
        re.search(r"\bclass\s+" + re.escape(cls) + r"\b", open(os.path.join(d, f), encoding="utf-8").read())
        for f in os.listdir(d) if f.endswith(".kt"))
    if not found:
        print(f"<{el.tag} android:name=\"{name}\"> ({full}): no class {cls} in {d}")
PY
)" || { echo "FAIL resources: could not read the components of $out/AndroidManifest.xml (above)" >&2; return 1; }
  if [[ -n "$missing" ]]; then
    echo "$missing" >&2
    echo "FAIL resources: the manifest names classes the app does not have (above)" >&2
    return 1
  fi
  echo "ok   resources: aapt2 compile + link of $(find "$main/res" -type f | wc -l) resource files and the manifest (package $ns, min $ANDROID_API, target $target)" >&2
}
