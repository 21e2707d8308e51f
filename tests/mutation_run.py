#!/usr/bin/env python3
"""Whole-program mutation run of the release `noisecal` binary (issue 13; not part of CI).

Every command gets mutated packs, DNGs and recordings (bit flips, byte sets, truncations, splices,
CRC-repaired mutations, records removed or duplicated) and bad arguments, each run with a timeout
(60 s) and a memory cap (ulimit -v). Counted:
  aborts      exit 134/SIGSEGV/any signal, exit 3 (internal error), or a panic message
  hangs       runs past the timeout
  harmed      an input whose hash changed
  silent      exit 0 on an input known to be damaged (a CRC-covered byte changed without repair,
              frame records removed or duplicated, a DNG cut inside its pixel data)

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


def run(counts, binary, args, inputs, damaged, label):
    before = {p: sha(p) for p in inputs}
    t0 = time.time()
    try:
        p = subprocess.run([binary] + args, capture_output=True, timeout=TIMEOUT, preexec_fn=limit)
        code, err = p.returncode, p.stderr.decode("utf-8", "replace")
    except subprocess.TimeoutExpired:
        code, err = None, "timeout"
    counts.cases += 1
    cmd = args[0]
    counts.by_cmd[cmd] = counts.by_cmd.get(cmd, 0) + 1
    what = f"{label}: noisecal {' '.join(args)}"
    if code is None:
        counts.hangs.append(what)
    elif code < 0 or code in (3, 134) or "panicked" in err:
        counts.aborts.append(f"{what} → exit {code}: {err[-300:]}")
    for p in inputs:
        if sha(p) != before[p]:
            counts.harmed.append(f"{what}: {p} changed")
    if code == 0 and damaged:
        counts.silent.append(f"{what}: exit 0 on damaged input ({damaged})")
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
                    + (["remove", "dup"] if kind == "rec" else []))
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
        kind = rng.choice(["pack", "pack", "rec", "rec", "dng", "dngdir", "args"])
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
        elif kind == "rec":
            m, damaged, op = mutate(rng, good["rec"], "rec")
            mr = os.path.join(case_dir, "m.rec")
            open(mr, "wb").write(m)
            existing = os.path.join(out, "kept.pack")
            shutil.copy(pack, existing)
            code, _ = run(counts, binary, ["calibrate", "-q", mr, "-o", existing], [mr], damaged, f"rec/{op}")
            if code != 0 and sha(existing) != sha(pack):
                counts.harmed.append(f"rec/{op}: a failed calibrate replaced the existing pack")
        elif kind == "dng":
            m, _, op = mutate(rng, good["dng"], "dng")
            damaged = None
            reg = dng_pixel_region(good["dng"])
            if op == "trunc" and reg and len(m) < reg[0] + reg[1]:
                damaged = "cut inside its pixel data"
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
            ])
            run(counts, binary, cmd, [pack, rec, dngs, clean, held], None, "args")
        if counts.cases % 250 == 0:
            print(f"{counts.cases} cases, {time.time() - t_start:.0f} s: aborts {len(counts.aborts)}, hangs "
                  f"{len(counts.hangs)}, harmed {len(counts.harmed)}, silent {len(counts.silent)}", file=sys.stderr)

    print(f"cases {counts.cases} in {time.time() - t_start:.0f} s; per command {counts.by_cmd}")
    for name in ("aborts", "hangs", "harmed", "silent"):
        items = getattr(counts, name)
        print(f"{name}: {len(items)}")
        for it in items[:15]:
            print(f"  {it}")
    bad = len(counts.aborts) + len(counts.hangs) + len(counts.harmed) + len(counts.silent)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
