#!/usr/bin/env python3
"""The JNI names of the native methods in `javap -p -s` output, checked against a library's exports.

Usage: jni_names.py JAVAP_OUTPUT EXPORTS
  JAVAP_OUTPUT: `javap -p -s` of the compiled classes (NoisecalSession and its nested classes).
  EXPORTS: the library's defined dynamic symbols that start with Java_, one per line.

Both directions: every native method must have exactly one export, under its short name
(Java_<class>_<method>) or its long name (short name + "__" + the mangled argument signature);
an overloaded native method must use the long name, since the JVM binds a short name to every
overload. Every Java_ export must belong to a native method. Prints one line per problem and exits
1 when there is any; 0 and a summary line otherwise. The mangling is the JNI specification's
("Resolving Native Method Names").
"""

import re
import sys


def mangle(text):
    out = []
    for ch in text:
        if ch == "/" or ch == ".":
            out.append("_")
        elif ch == "_":
            out.append("_1")
        elif ch == ";":
            out.append("_2")
        elif ch == "[":
            out.append("_3")
        elif ch.isascii() and ch.isalnum():
            out.append(ch)
        else:
            out.append("_0%04x" % ord(ch))
    return "".join(out)


CLASS_RE = re.compile(r"^(?:[\w ]*\s)?(?:class|interface|enum)\s+([\w.$]+)")
METHOD_RE = re.compile(r"\bnative\b.*?\s([\w$]+)\(")
DESC_RE = re.compile(r"^\s*descriptor:\s*(\S+)")


def natives(javap_text):
    """(class binary name, method name, descriptor) of every native method."""
    found = []
    cls = None
    pending = None
    for line in javap_text.splitlines():
        if not line.startswith(" "):
            m = CLASS_RE.match(line)
            if m:
                cls = m.group(1)
            continue
        d = DESC_RE.match(line)
        if d and pending is not None:
            found.append((cls, pending, d.group(1)))
            pending = None
            continue
        m = METHOD_RE.search(line)
        pending = m.group(1) if m and cls else None
    return found


def main(argv):
    if len(argv) != 3:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    with open(argv[1], encoding="utf-8") as f:
        methods = natives(f.read())
    with open(argv[2], encoding="utf-8") as f:
        exports = {line.strip() for line in f if line.strip()}
    if not methods:
        print(f"FAIL jni: no native methods in the javap output {argv[1]} (wrong classes?)", file=sys.stderr)
        return 1

    counts = {}
    for cls, name, _ in methods:
        counts[(cls, name)] = counts.get((cls, name), 0) + 1

    problems = []
    claimed = {}
    for cls, name, desc in methods:
        short = "Java_" + mangle(cls) + "_" + mangle(name)
        args = desc[1 : desc.index(")")]
        long = short + "__" + mangle(args)
        overloaded = counts[(cls, name)] > 1
        valid = [long] if overloaded else [short, long]
        hits = [n for n in valid if n in exports]
        where = f"{cls}.{name}{desc}"
        if not hits:
            problems.append(
                f"FAIL jni: Kotlin external {where} has no export in the library: expected {long}"
                + ("" if overloaded else f" (or {short})")
                + " (renamed on one side only? rust/jni/src/jni_api.rs NATIVE_METHODS and NoisecalSession.kt must match)"
            )
        elif len(hits) > 1:
            problems.append(f"FAIL jni: {where} is exported twice ({', '.join(hits)}); keep one")
        for n in hits:
            claimed[n] = where
        if overloaded:
            if short in exports:
                problems.append(f"FAIL jni: {short} binds every overload of {cls}.{name}; export the long names only")
                claimed[short] = where

    for name in sorted(exports - set(claimed)):
        problems.append(
            f"FAIL jni: export {name} matches no native method of the Kotlin classes "
            "(a Kotlin external renamed or removed, or a signature changed, without the Rust side)"
        )

    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        return 1
    print(f"ok   jni: {len(methods)} native methods, {len(exports)} Java_ exports, one to one", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
