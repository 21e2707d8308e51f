"""Python `Pack.synth` against the Rust criterion bench of the same entry point, interleaved:
rounds alternate a short criterion run (`rust/core/benches/synth.rs`, global pool) and the same
number of `Pack.synth` calls in this process, so that both see the same load on a shared machine;
the ratio is taken per round. Also times the vectorised numpy sampler of `tests/test_bench.py`.

    CARGO_TARGET_DIR=... python rust/python/benches/interleaved.py --pack bench.pack --rounds 5
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import noisecal

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "rust" / "python" / "tests"))
from test_bench import H, SEED, W, NumpySynth  # noqa: E402

MPIX = H * W / 1e6


def clean() -> np.ndarray:
    x = np.arange(W, dtype=np.int64)
    return np.ascontiguousarray(np.broadcast_to((64 + x * 936 // (W - 1)).astype(np.uint16), (H, W)))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pack", type=Path, required=True)
    ap.add_argument("--iso", type=int, default=800)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=10)
    ap.add_argument("--workspace", type=Path, default=REPO)
    ap.add_argument("--cpu", action="store_true",
                    help="compare process CPU time per frame (plain loops on both sides) instead of criterion wall time")
    a = ap.parse_args()
    env = dict(os.environ, NOISECAL_BENCH_PACK=str(a.pack.resolve()), NOISECAL_BENCH_ISO=str(a.iso))
    target = Path(env.get("CARGO_TARGET_DIR", a.workspace / "target"))
    subprocess.run(["cargo", "bench", "-q", "-p", "noisecal-core", "--bench", "synth", "--no-run"],
                   cwd=a.workspace, env=env, check=True)
    exes = [p for p in glob.glob(str(target / "release" / "deps" / "synth-*")) if "." not in Path(p).name and os.access(p, os.X_OK)]
    exe = max(exes, key=os.path.getmtime)
    pack = noisecal.Pack.load(a.pack)
    img = clean()
    pack.synth(img, a.iso, SEED)
    npy = NumpySynth(pack.tables(a.iso))
    rng = np.random.default_rng(0)
    if a.cpu:
        return cpu_rounds(a, env, exe, pack, img)
    rows = []
    for r in range(a.rounds):
        subprocess.run([exe, "--bench", "--noplot", "--sample-size", "10", "--warm-up-time", "1",
                        "--measurement-time", "2", "global pool"], env=env, check=True, capture_output=True)
        bench = glob.glob(str(target / "criterion" / "synth 12MP" / "*global pool*" / "new" / "sample.json"))[0]
        s = json.loads(Path(bench).read_text())
        rust = sorted(t / n / 1e9 for t, n in zip(s["times"], s["iters"]))
        py = []
        for _ in range(a.calls):
            t0 = time.perf_counter()
            pack.synth(img, a.iso, SEED)
            py.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        npy(img, rng)
        nt = time.perf_counter() - t0
        rm, pm = statistics.median(rust), statistics.median(py)
        rows.append((rm, pm, min(rust), min(py), nt))
        print(f"round {r}: Rust {MPIX / rm:6.1f} Mpix/s (best {MPIX / min(rust):6.1f}), Python {MPIX / pm:6.1f} "
              f"(best {MPIX / min(py):6.1f}), numpy {MPIX / nt:5.2f}; Python/Rust median {rm / pm:.3f}, "
              f"best {min(rust) / min(py):.3f}; Python/numpy {nt / pm:.1f}", flush=True)
    med = lambda i: statistics.median(x[i] for x in rows)  # noqa: E731
    print(f"\nmedians over {a.rounds} rounds, threads {os.environ.get('RAYON_NUM_THREADS', os.cpu_count())}: "
          f"Rust {MPIX / med(0):.1f} Mpix/s, Python {MPIX / med(1):.1f}, numpy {MPIX / med(4):.2f}; "
          f"Python/Rust {statistics.median(x[0] / x[1] for x in rows):.3f} "
          f"(best-of: {statistics.median(x[2] / x[3] for x in rows):.3f}); "
          f"Python/numpy {statistics.median(x[4] / x[1] for x in rows):.1f}")


def cpu_rounds(a, env: dict, exe: str, pack: noisecal.Pack, img: np.ndarray) -> None:
    """Per round: the Rust loop (`NOISECAL_BENCH_LOOP`) and as many `Pack.synth` calls, each with
    wall and process CPU time per frame (all threads, rayon's idle spinning included on both)."""
    rows = []
    for r in range(a.rounds):
        out = subprocess.run([exe, "--bench"], env=dict(env, NOISECAL_BENCH_LOOP=str(a.calls)), check=True,
                             capture_output=True, text=True).stdout
        m = re.search(r"wall ([\d.]+) ms, cpu ([\d.]+) ms", out)
        rw, rc = float(m.group(1)) / 1e3, float(m.group(2)) / 1e3
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(a.calls):
            pack.synth(img, a.iso, SEED)
        pw, pc = (time.perf_counter() - t0) / a.calls, (time.process_time() - c0) / a.calls
        rows.append((rw, rc, pw, pc))
        print(f"round {r}: Rust wall {MPIX / rw:6.1f} Mpix/s, {MPIX / rc:6.1f} Mpix per CPU s; Python wall "
              f"{MPIX / pw:6.1f}, {MPIX / pc:6.1f} per CPU s; Python/Rust wall {rw / pw:.3f}, CPU {rc / pc:.3f}",
              flush=True)
    med = lambda i: statistics.median(x[i] for x in rows)  # noqa: E731
    print(f"\nmedians over {a.rounds} rounds of {a.calls} frames: Rust {MPIX / med(0):.1f} Mpix/s wall, "
          f"{MPIX / med(1):.1f} Mpix per CPU s; Python {MPIX / med(2):.1f}, {MPIX / med(3):.1f}; Python/Rust wall "
          f"{statistics.median(x[0] / x[2] for x in rows):.3f}, CPU {statistics.median(x[1] / x[3] for x in rows):.3f}")


if __name__ == "__main__":
    main()
