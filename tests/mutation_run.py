#!/usr/bin/env python3
"""Whole-program mutation run of the release `noisecal` binary (damaged inputs of every kind; not part of CI).

Every command gets mutated packs, DNGs and recordings (bit flips, byte sets, truncations, splices,
CRC-repaired mutations, records removed or duplicated) and bad arguments, each run with a timeout
(60 s) and a memory cap (ulimit -v). Counted:
  aborts      exit 134/SIGSEGV/any signal, exit 3 (internal error), or a panic message
  hangs       runs past the timeout
  harmed      an input whose hash changed
  silent      exit 0 on an input known to be damaged (a CRC-covered byte changed without repair,
              frame records removed or duplicated, a DNG cut inside its pixel data, 16-bit DNG data
              relabelled BitsPerSample 10/12/14) or on a degenerate capture folder (every frame's
              pixels identical, saturated at white, or at black)
Kill cases run calibrate, simulate --rec or synth and kill -9 them at a random moment: a target
that is neither the old file nor a complete new one counts as harmed; a temporary file that the
next run writing into the folder does not sweep (aged past the sweep's grace period first)
counts as an orphan.

usage: tests/mutation_run.py [--cases N] [--seed S] [--bin target/release/noisecal] [--work DIR]
"""
import argparse
import hashlib
import os
import random
import resource
import shutil
import struct
import subprocess
import sys
import time
import zlib

TIMEOUT = 60
MEM_KB = 4 * 1024 * 1024


def limit():
    resource.setrlimit(resource.RLIMIT_AS, (MEM_KB * 1024, MEM_KB * 1024))


def sha(path):
    h = hashlib.sha256()
    if os.path.isdir(path):
        for name in sorted(os.listdir(path)):
            h.update(name.encode())
            h.update(sha(os.path.join(path, name)).encode())
    elif os.path.exists(path):
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()


class Counts:
    def __init__(self):
        self.cases = 0
        self.aborts = []
        self.hangs = []
        self.harmed = []
        self.silent = []
        self.by_cmd = {}
        self.kills = 0
        self.kill_temps = 0
        self.orphans = []
        # per command: [cases, aborts, hangs, harmed, silent]
        self.table = {}

    def note(self, cmd, col):
        self.table.setdefault(cmd, [0, 0, 0, 0, 0])[col] += 1


def run(counts, binary, args, inputs, damaged, label):
    before = {p: sha(p) for p in inputs}
    t0 = time.time()
    try:
        p = subprocess.run([binary] + args, capture_output=True, timeout=TIMEOUT, preexec_fn=limit)
        code, err = p.returncode, p.stderr.decode("utf-8", "replace")
    except subprocess.TimeoutExpired:
        code, err = None, "timeout"
    counts.cases += 1
    cmd = args[2] if args[0] == "--threads" else args[0]
    counts.by_cmd[cmd] = counts.by_cmd.get(cmd, 0) + 1
    counts.note(cmd, 0)
    what = f"{label}: noisecal {' '.join(args)}"
    if code is None:
        counts.hangs.append(what)
        counts.note(cmd, 2)
    elif code < 0 or code in (3, 134) or "panicked" in err:
        counts.aborts.append(f"{what} → exit {code}: {err[-300:]}")
        counts.note(cmd, 1)
    for p in inputs:
        if sha(p) != before[p]:
            counts.harmed.append(f"{what}: {p} changed")
            counts.note(cmd, 3)
    if code == 0 and damaged:
        counts.silent.append(f"{what}: exit 0 on damaged input ({damaged})")
        counts.note(cmd, 4)
    return code, time.time() - t0


def sh(binary, *args):
    subprocess.run([binary] + list(args), check=True, capture_output=True)


# ---- mutations ---------------------------------------------------------------------------------


def reseal_pack(b):
    b = bytearray(b)
    if len(b) >= 24:
        b[12:20] = struct.pack("<Q", len(b) - 24)
        b[20:24] = struct.pack("<I", zlib.crc32(bytes(b[24:])))
    return bytes(b)


def rec_records(b):
    """(tag, offset, length) of each whole record of a recording."""
    hlen = struct.unpack_from("<I", b, 10)[0]
    at = 14 + hlen + 4
    out = []
    while at < len(b):
        tag = b[at]
        if tag in (1, 255):
            n = 13
        elif tag == 3:
            n = 73
        elif tag == 2 and at + 50 <= len(b):
            n = 54 + struct.unpack_from("<I", b, at + 46)[0]
        else:
            break
        if at + n > len(b):
            break
        out.append((tag, at, n))
        at += n
    return out


def reseal_rec(b):
    b = bytearray(b)
    if len(b) < 14:
        return bytes(b)
    hlen = struct.unpack_from("<I", b, 10)[0]
    if 14 + hlen + 4 <= len(b):
        b[14 + hlen:18 + hlen] = struct.pack("<I", zlib.crc32(bytes(b[14:14 + hlen])))
    for _, at, n in rec_records(bytes(b)):
        b[at + n - 4:at + n] = struct.pack("<I", zlib.crc32(bytes(b[at:at + n - 4])))
    return bytes(b)


def mutate(rng, b, kind):
    """A mutated copy and, when the damage is certain to be detectable, why."""
    b = bytearray(b)
    op = rng.choice(["flip", "set", "trunc", "splice", "field", "repaired", "repaired", "crafted"]
                    + (["remove", "dup"] if kind == "rec" else [])
                    + (["tag", "tag"] if kind == "dng" else []))
    damaged = None
    if op == "flip" or op == "set":
        i = rng.randrange(len(b))
        if op == "flip":
            b[i] ^= 1 << rng.randrange(8)
        else:
            old = b[i]
            b[i] = rng.choice([0, 0xFF, 0x7F, 0x80, rng.randrange(256)])
            if b[i] == old:
                b[i] ^= 1
        if kind == "pack" and i >= 10:
            damaged = f"byte {i} changed under the CRC"
        if kind == "rec" and i >= 14:
            damaged = f"byte {i} changed under a CRC"
    elif op == "trunc":
        n = rng.randrange(len(b))
        del b[n:]
        if kind == "pack":
            damaged = "truncated"
    elif op == "splice":
        i, j = rng.randrange(len(b)), rng.randrange(len(b))
        n = rng.randrange(1, 512)
        b[i:i] = b[j:j + n]
        if kind == "pack":
            damaged = "bytes inserted"
    elif op == "field":
        i = rng.randrange(max(1, len(b) - 4))
        b[i:i + 4] = struct.pack("<I", rng.choice([0, 1, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 100000, 65536]))
    elif op == "repaired":
        for _ in range(rng.randrange(1, 4)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif op == "crafted":
        # Numbers that size things: a float or int field set to an absurd value, then resealed.
        i = rng.randrange(max(1, len(b) - 8))
        b[i:i + 8] = rng.choice([struct.pack("<d", 1e10), struct.pack("<d", float("nan")),
                                 struct.pack("<d", -1.0), struct.pack("<Q", 2 ** 63), struct.pack("<f", 1e30) * 2])
    elif op == "tag":
        b = bytearray(dng_tag_mutation(rng, bytes(b)))
    elif op in ("remove", "dup"):
        frames = [r for r in rec_records(bytes(b)) if r[0] == 2]
        if frames:
            _, at, n = rng.choice(frames[:-1] or frames)
            chunk = bytes(b[at:at + n])
            if op == "remove":
                del b[at:at + n]
            else:
                b[at + n:at + n] = chunk
            damaged = f"a frame record {op}d"
    if op in ("repaired", "crafted", "field") and kind in ("pack", "rec") and rng.random() < 0.8:
        b = bytearray(reseal_pack(bytes(b)) if kind == "pack" else reseal_rec(bytes(b)))
    return bytes(b), damaged, op


def dng_pixel_region(b):
    """Offset and length of the first strip of a little-endian TIFF (StripOffsets 273, StripByteCounts 279)."""
    try:
        if b[:2] != b"II":
            return None
        ifd = struct.unpack_from("<I", b, 4)[0]
        n = struct.unpack_from("<H", b, ifd)[0]
        off = cnt = None
        for k in range(n):
            tag, typ, count, val = struct.unpack_from("<HHII", b, ifd + 2 + 12 * k)
            if tag == 273:
                off = val
            if tag == 279:
                cnt = val
        return (off, cnt) if off is not None and cnt is not None else None
    except struct.error:
        return None


# Tags that lead the decoder elsewhere or size its buffers: IFD pointers rawler follows (SubIFDs,
# ExifIFD, GPSInfo, InterColorProfile), strip/tile geometry, sizes, compression.
STRUCTURAL_TAGS = [330, 34665, 34853, 34675, 256, 257, 258, 259, 273, 278, 279, 322, 323, 324, 325, 50829]


def dng_tag_mutation(rng, b):
    """One IFD0 entry of a little-endian DNG rewritten to a structural tag with an absurd type,
    count or value, often pointing at an IFD appended at the end whose one entry claims a huge
    count (rawler allocates a tag's count before reading it). How CI's fuzzer found a 32 GB
    allocation behind GPSInfo."""
    if b[:2] != b"II":
        return b
    b = bytearray(b)
    ifd = struct.unpack_from("<I", b, 4)[0]
    n = struct.unpack_from("<H", b, ifd)[0]
    at = ifd + 2 + 12 * rng.randrange(n)
    tag = rng.choice(STRUCTURAL_TAGS)
    typ = rng.choice([1, 2, 3, 4, 5, 7, 12, 13, 0, 99])
    count = rng.choice([0, 1, 2, 4, 16, 65536, 0x7FFFFFFF, 0xFFFFFFF0])
    # An appended IFD: one entry of a random type with a huge count.
    sub = len(b) + (len(b) & 1)
    b += b"\0" * (sub - len(b))
    b += struct.pack("<HHHII", 1, rng.choice([33434, 271, 305]), rng.choice([2, 3, 5, 12, 99]),
                     rng.choice([0xFFFFFFF0, 0x40000000, 0x10000000]), 8) + b"\0" * 20
    value = rng.choice([sub, sub, rng.randrange(len(b)), 0xFFFFFFFF, 1 << 20, 52546, 7])
    struct.pack_into("<HHII", b, at, tag, typ, count, value)
    return bytes(b)


def set_bits(b, bits):
    """The DNG with BitsPerSample (tag 258) set to `bits`: 16-bit data mislabelled."""
    b = bytearray(b)
    ifd = struct.unpack_from("<I", b, 4)[0]
    for k in range(struct.unpack_from("<H", b, ifd)[0]):
        at = ifd + 2 + 12 * k
        if struct.unpack_from("<H", b, at)[0] == 258:
            struct.pack_into("<H", b, at + 8, bits)
    return bytes(b)


def with_pixels(b, pixels):
    """The DNG with its (single, 16-bit) strip replaced by `pixels` (bytes of the same length)."""
    off, cnt = dng_pixel_region(b)
    b = bytearray(b)
    b[off:off + cnt] = pixels[:cnt]
    return bytes(b)


def temps_in(d):
    return [os.path.join(r, n) for r, _, names in os.walk(d) for n in names if ".noisecal-tmp." in n]


def kill_case(counts, rng, binary, out, rec, pack, dngs, synth_sizes):
    """Runs a writing command, kills it with SIGKILL at a random moment, checks its target, then
    has the next run writing into the same folder sweep the killed run's temporary files."""
    existing = os.path.join(out, "kept.pack")
    shutil.copy(pack, existing)
    old = sha(existing)
    which = rng.choice(["calibrate", "simulate", "synth"])
    syn = os.path.join(out, "syn")
    srec = os.path.join(out, "s.rec")
    args = {
        "calibrate": ["calibrate", "-q", rec, "-o", existing],
        "simulate": ["simulate", "-q", "--width", "512", "--height", "384", "--frames", "3", "--isos", "200,800",
                     "--ev=-1,1", "--rec", srec],
        "synth": ["synth", "-q", "--pack", pack, "--iso", "200", dngs, "-o", syn],
    }[which]
    p = subprocess.Popen([binary] + args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=limit)
    time.sleep(rng.uniform(0.0, 0.6))
    p.kill()
    p.wait()
    counts.cases += 1
    counts.kills += 1
    counts.by_cmd[which] = counts.by_cmd.get(which, 0) + 1
    counts.note(which, 0)
    what = f"kill -9: noisecal {' '.join(args)}"
    bad = None
    if which == "calibrate" and sha(existing) != old:
        if subprocess.run([binary, "inspect", existing], capture_output=True).returncode != 0:
            bad = "the pack is neither the old one nor a complete new one"
    elif which == "simulate" and os.path.exists(srec):
        b = open(srec, "rb").read()
        if len(b) < 13 or b[-13] != 255:
            bad = "a partial recording under the target name"
    elif which == "synth" and os.path.isdir(syn):
        for n in os.listdir(syn):
            if ".noisecal-tmp." not in n and os.path.getsize(os.path.join(syn, n)) != synth_sizes.get(n):
                bad = f"a partial {n}"
    if bad:
        counts.harmed.append(f"{what}: {bad}")
        counts.note(which, 3)
    # Past the sweep's grace period for dead processes (10 s), then the next write into each folder.
    left = temps_in(out)
    for t in left:
        past = time.time() - 60
        os.utime(t, (past, past))
    if left:
        counts.kill_temps += 1
        subprocess.run([binary, "calibrate", "-q", rec, "-o", os.path.join(out, "next.pack")], capture_output=True)
        if os.path.isdir(syn):
            subprocess.run([binary, "synth", "-q", "--pack", pack, "--iso", "200", os.path.join(dngs, sorted(os.listdir(dngs))[0]),
                            "-o", os.path.join(syn, "next.dng")], capture_output=True)
        for t in temps_in(out):
            counts.orphans.append(f"{what}: {t} not swept by the next run")


# ---- the run -----------------------------------------------------------------------------------


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=13)
    ap.add_argument("--bin", default="target/release/noisecal")
    ap.add_argument("--work", default="target/mutation-run")
    a = ap.parse_args()
    binary = os.path.abspath(a.bin)
    rng = random.Random(a.seed)
    work = os.path.abspath(a.work)
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    seeds = os.path.join(work, "seeds")
    os.makedirs(seeds)
    rec = os.path.join(seeds, "s.rec")
    dngs = os.path.join(seeds, "dngs")
    held = os.path.join(seeds, "held")
    sh(binary, "simulate", "-q", "--width", "48", "--height", "32", "--frames", "3", "--isos", "200,800",
       "--ev=-1,1", "--rec", rec, "--dngs", dngs)
    sh(binary, "simulate", "-q", "--width", "48", "--height", "32", "--frames", "2", "--isos", "200,800",
       "--ev=0", "--index-offset", "100000", "--dngs", held)
    pack = os.path.join(seeds, "p.pack")
    sh(binary, "calibrate", "-q", rec, "-o", pack, "--bin-width", "64")
    clean = os.path.join(dngs, sorted(os.listdir(dngs))[0])
    good = {"pack": open(pack, "rb").read(), "rec": open(rec, "rb").read(), "dng": open(clean, "rb").read()}
    dng_names = sorted(os.listdir(dngs))
    # The size of each complete synth output, to tell a partial one after a kill.
    syn_ref = os.path.join(seeds, "syn")
    sh(binary, "synth", "-q", "--pack", pack, "--iso", "200", dngs, "-o", syn_ref)
    synth_sizes = {n: os.path.getsize(os.path.join(syn_ref, n)) for n in os.listdir(syn_ref)}

    counts = Counts()
    case_dir = os.path.join(work, "case")
    t_start = time.time()
    i = 0
    while counts.cases < a.cases:
        i += 1
        shutil.rmtree(case_dir, ignore_errors=True)
        os.makedirs(case_dir)
        out = os.path.join(case_dir, "out")
        os.makedirs(out)
        kind = rng.choice(["pack", "pack", "rec", "rec", "dng", "dngdir", "args", "degenerate", "kill"])
        if kind == "pack":
            m, damaged, op = mutate(rng, good["pack"], "pack")
            mp = os.path.join(case_dir, "m.pack")
            open(mp, "wb").write(m)
            existing = os.path.join(out, "kept.pack")
            shutil.copy(pack, existing)
            cmd = rng.choice([
                ["inspect", mp], ["inspect", "--json", mp],
                ["synth", "--pack", mp, "--iso", "200", clean, "-o", os.path.join(out, "n.dng")],
                ["synth", "--pack", mp, "--iso", "400", "--model", rng.choice(["noisecal", "hg", "noiseprofile"]),
                 clean, "-o", os.path.join(out, "n.dng")],
                ["interp", "--pack", mp, "--iso", "400", "-o", existing],
                ["renoise", "--pack", mp, "--to-iso", "800", "--from-iso", "200", clean, "-o", os.path.join(out, "r.dng")],
                ["eval", "--pack", mp, held],
                ["report", "--pack", mp, "-o", os.path.join(out, "r.html")],
            ])
            code, _ = run(counts, binary, cmd, [mp, clean, held], damaged, f"pack/{op}")
            if code != 0 and sha(existing) != sha(pack):
                counts.harmed.append(f"pack/{op}: a failed {cmd[0]} replaced an existing output")
                counts.note(cmd[0], 3)
        elif kind == "rec":
            m, damaged, op = mutate(rng, good["rec"], "rec")
            mr = os.path.join(case_dir, "m.rec")
            open(mr, "wb").write(m)
            existing = os.path.join(out, "kept.pack")
            shutil.copy(pack, existing)
            code, _ = run(counts, binary, ["calibrate", "-q", mr, "-o", existing], [mr], damaged, f"rec/{op}")
            if code != 0 and sha(existing) != sha(pack):
                counts.harmed.append(f"rec/{op}: a failed calibrate replaced the existing pack")
                counts.note("calibrate", 3)
        elif kind == "dng":
            m, _, op = mutate(rng, good["dng"], "dng")
            damaged = None
            reg = dng_pixel_region(good["dng"])
            if op == "trunc" and reg and len(m) < reg[0] + reg[1]:
                damaged = "cut inside its pixel data"
            if rng.random() < 0.1:
                bits = rng.choice([10, 12, 14])
                m, op, damaged = set_bits(good["dng"], bits), "bits", f"16-bit data labelled {bits}-bit"
            md = os.path.join(case_dir, "m.dng")
            open(md, "wb").write(m)
            cmd = rng.choice([
                ["synth", "--pack", pack, "--iso", "200", md, "-o", os.path.join(out, "n.dng")],
                ["renoise", "--pack", pack, "--to-iso", "800", md, "-o", os.path.join(out, "r.dng")],
                ["renoise", "--pack", pack, "--to-iso", "800", "--from-iso", "200", "--estimate", md, clean,
                 "-o", os.path.join(out, "r.dng")],
            ])
            run(counts, binary, cmd, [md, clean, pack], damaged, f"dng/{op}")
        elif kind == "dngdir":
            d = os.path.join(case_dir, "dngs")
            shutil.copytree(dngs, d)
            victim = rng.choice(dng_names)
            m, _, op = mutate(rng, good["dng"] if victim == os.path.basename(clean) else open(os.path.join(dngs, victim), "rb").read(), "dng")
            open(os.path.join(d, victim), "wb").write(m)
            cmd = rng.choice([["calibrate", "-q", d, "-o", os.path.join(out, "p.pack")],
                              ["eval", "--pack", pack, d]])
            run(counts, binary, cmd, [d], None, f"dngdir/{op}")
        elif kind == "degenerate":
            d = os.path.join(case_dir, "dngs")
            shutil.copytree(dngs, d)
            how = rng.choice(["identical", "saturated", "black", "relabelled"])
            first = open(os.path.join(dngs, dng_names[0]), "rb").read()
            off, cnt = dng_pixel_region(first)
            for n in dng_names:
                f = os.path.join(d, n)
                b = open(f, "rb").read()
                if how == "identical":
                    b = with_pixels(b, first[off:off + cnt])
                elif how == "saturated":
                    b = with_pixels(b, struct.pack("<H", 1023) * (cnt // 2))
                elif how == "black":
                    b = with_pixels(b, struct.pack("<H", 64) * (cnt // 2))
                open(f, "wb").write(b)
            if how == "relabelled":
                victim = os.path.join(d, rng.choice(dng_names))
                b = set_bits(open(victim, "rb").read(), rng.choice([10, 12, 14]))
                open(victim, "wb").write(b)
            run(counts, binary, ["calibrate", "-q", d, "-o", os.path.join(out, "p.pack")], [d],
                f"a degenerate capture folder ({how})", f"degenerate/{how}")
        elif kind == "kill":
            kill_case(counts, rng, binary, out, rec, pack, dngs, synth_sizes)
        else:
            absurd = rng.choice(["0", "-1", "4294967295", "99999999999", "nan", "1e308", "", "x", "0,0,0,0",
                                 "1000000", "65536"])
            cmd = rng.choice([
                ["synth", "--pack", pack, "--iso", absurd, clean, "-o", os.path.join(out, "n.dng")],
                ["synth", "--pack", pack, "--iso", absurd, "--extrapolate", clean, "-o", os.path.join(out, "n.dng")],
                ["interp", "--pack", pack, "--iso", absurd, "-o", os.path.join(out, "i.pack")],
                ["renoise", "--pack", pack, "--to-iso", absurd, clean, "-o", os.path.join(out, "r.dng")],
                ["calibrate", "-q", rec, "-o", os.path.join(out, "p.pack"), "--bin-width", absurd],
                ["calibrate", "-q", rec, "-o", os.path.join(out, "p.pack"), "--roi", absurd],
                ["calibrate", "-q", rec, "-o", os.path.join(out, "p.pack"), "--flat-k", absurd],
                ["calibrate", "-q", rec, "-o", os.path.join(out, "p.pack"), "--pooling", absurd],
                ["calibrate", "-q", rec, "-o", rec],
                ["calibrate", "-q", dngs, "-o", os.path.join(dngs, dng_names[0])],
                ["synth", "--pack", pack, "--iso", "200", clean, "-o", clean],
                ["eval", "--pack", pack, held, "--seeds", absurd],
                ["simulate", "-q", "--width", absurd, "--rec", os.path.join(out, "s.rec")],
                ["simulate", "-q", "--padding", absurd, "--width", "8", "--height", "8", "--frames", "1",
                 "--isos", "200", "--ev=0", "--rec", os.path.join(out, "s.rec")],
                ["--threads", absurd, "inspect", pack],
                ["inspect", "/dev/zero"],
                ["calibrate", "/dev/null", "-o", os.path.join(out, "p.pack")],
                ["demo", "-q", "--out", os.path.join(out, "demo"), "--width", absurd, "--height", "16", "--frames", "2"],
                ["demo", "-q", "--out", os.path.join(out, "demo"), "--width", "16", "--height", "16", "--frames", absurd],
                ["demo", "-q", "--out", clean, "--width", "16", "--height", "16", "--frames", "2"],
            ])
            run(counts, binary, cmd, [pack, rec, dngs, clean, held], None, "args")
        if counts.cases % 250 == 0:
            print(f"{counts.cases} cases, {time.time() - t_start:.0f} s: aborts {len(counts.aborts)}, hangs "
                  f"{len(counts.hangs)}, harmed {len(counts.harmed)}, silent {len(counts.silent)}, orphans "
                  f"{len(counts.orphans)}", file=sys.stderr)

    print(f"cases {counts.cases} in {time.time() - t_start:.0f} s")
    print(f"{'command':<10} {'cases':>6} {'aborts':>6} {'hangs':>6} {'harmed':>6} {'silent':>6}")
    for c in sorted(counts.table):
        print(f"{c:<10} " + " ".join(f"{v:>6}" for v in counts.table[c]))
    print(f"kill -9 cases {counts.kills}, {counts.kill_temps} of them leaving a temporary file; not swept by the "
          f"next run: {len(counts.orphans)}")
    for name in ("aborts", "hangs", "harmed", "silent", "orphans"):
        items = getattr(counts, name)
        print(f"{name}: {len(items)}")
        by_label = {}
        for it in items:
            label = it.split(":", 1)[0]
            by_label[label] = by_label.get(label, 0) + 1
        for label, n in sorted(by_label.items(), key=lambda kv: -kv[1]):
            print(f"  {n:5}  {label}")
        for it in items[:15]:
            print(f"  {it}")
    bad = len(counts.aborts) + len(counts.hangs) + len(counts.harmed) + len(counts.silent) + len(counts.orphans)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
