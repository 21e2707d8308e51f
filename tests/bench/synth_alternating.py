"""`noisecal synth` of an uncompressed 12 MP DNG, end to end, two binaries alternating in one run
(issue 26 item 4): on a shared machine the process's CPU time (user + system, from the kernel's
rusage of the child) compares two builds where wall time mostly measures the neighbours. Every
case runs both binaries in each round, the order flipping from round to round, and the outputs of
the two are compared byte for byte.

Cases: a structured pack with a fixed pattern (a simulated `--structured --dark` session, ISO
1600) and the demo's pack (rows only, no fixed pattern, ISO 3200), each with the default
components and with `--components pixel`; and `fpn-target` (not run unless named in `--cases`):
the structured pack with `--clean-at target`.

    python3 tests/bench/synth_alternating.py --old /tmp/noisecal-old --new target/release/noisecal

With `--small`, the clean image is 64×48 instead: the run is then the pack's load and the
sampler build (the deconvolution of every bin with structured components), and the difference
between a case and its `-pixel` case is the build's cost of the components.

Mpix/s is 12 MP over the median CPU time divided by the 2 cores (what the process would do on two
free cores), and over the median wall time; `uptime`'s load is printed before and after.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

W, H = 4000, 3000


def run(binary: Path, args: list[str]) -> tuple[float, float]:
    """Runs `binary args` and returns (CPU seconds of the child, wall seconds)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(binary), *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode() if proc.stderr else ""
    if proc.stderr:
        proc.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{binary} {' '.join(args)} failed: {err}")
    return usage.ru_utime + usage.ru_stime, wall


def load() -> str:
    return Path("/proc/loadavg").read_text().split(" ")[0]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--old", type=Path, required=True)
    ap.add_argument("--new", type=Path, required=True)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--work", type=Path, help="folder for the pack and images (kept; made if missing)")
    ap.add_argument("--cases", default="fpn,fpn-pixel,demo,demo-pixel")
    ap.add_argument("--small", action="store_true", help="a 64x48 clean image: the pack load and sampler build alone")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="synth_alt_"))
    work.mkdir(parents=True, exist_ok=True)
    make = a.new.resolve()

    def setup(args: list[str], made: Path) -> None:
        if not made.exists():
            subprocess.run([str(make), "-q", *args], check=True, cwd=work)

    setup(["simulate", "--width", "256", "--height", "192", "--frames", "6", "--isos", "100,400,1600",
           "--structured", "--dark", "3", "--seed", "11", "--dngs", "caps"], work / "caps")
    setup(["calibrate", "caps", "-o", "fpn.pack"], work / "fpn.pack")
    setup(["demo", "--out", "demo"], work / "demo")
    setup(["simulate", "--width", str(W), "--height", str(H), "--frames", "1", "--isos", "100", "--ev=0",
           "--dngs", "big"], work / "big")
    setup(["simulate", "--width", "64", "--height", "48", "--frames", "1", "--isos", "100", "--ev=0",
           "--dngs", "small"], work / "small")
    clean = str(min((work / ("small" if a.small else "big")).glob("*.dng")))
    demo_pack = str(min((work / "demo").glob("*.pack")))
    cases = {
        "fpn": ["--pack", str(work / "fpn.pack"), "--iso", "1600"],
        "fpn-pixel": ["--pack", str(work / "fpn.pack"), "--iso", "1600", "--components", "pixel"],
        "fpn-target": ["--pack", str(work / "fpn.pack"), "--iso", "1600", "--clean-at", "target"],
        "demo": ["--pack", demo_pack, "--iso", "3200"],
        "demo-pixel": ["--pack", demo_pack, "--iso", "3200", "--components", "pixel"],
    }
    names = a.cases.split(",")
    size = "64x48" if a.small else f"12 MP = {W}x{H}"
    print(f"load before: {load()}; {a.rounds} rounds; {size}")
    cpu = {(c, s): [] for c in names for s in ("old", "new")}
    wall = {(c, s): [] for c in names for s in ("old", "new")}
    for r in range(a.rounds):
        for c in names:
            order = ("old", "new") if r % 2 == 0 else ("new", "old")
            for side in order:
                binary = a.old if side == "old" else a.new
                out = work / f"out_{c}_{side}.dng"
                t, w = run(binary, ["-q", "synth", *cases[c], "--seed", "7", clean, "-o", str(out)])
                cpu[(c, side)].append(t)
                wall[(c, side)].append(w)
            if not filecmp.cmp(work / f"out_{c}_old.dng", work / f"out_{c}_new.dng", shallow=False):
                raise SystemExit(f"case {c}: old and new outputs differ")
    print(f"load after: {load()}; outputs of old and new identical in every case and round")
    mp = (64 * 48 if a.small else W * H) / 1e6
    print("case        side  CPU median ms (range)        Mpix/s (CPU/2)  wall median ms  Mpix/s (wall)")
    for c in names:
        for side in ("old", "new"):
            t, w = cpu[(c, side)], wall[(c, side)]
            mt, mw = statistics.median(t), statistics.median(w)
            print(f"{c:11} {side:4}  {mt * 1e3:7.1f} ({min(t) * 1e3:.0f}-{max(t) * 1e3:.0f})"
                  f"        {mp / (mt / 2):7.1f}  {mw * 1e3:12.1f}  {mp / mw:9.1f}")
    for pack in ("fpn", "demo"):
        if pack in names and f"{pack}-pixel" in names:
            for side in ("old", "new"):
                ratio = statistics.median(cpu[(pack, side)]) / statistics.median(cpu[(f"{pack}-pixel", side)])
                print(f"{pack} default / pixel-only CPU, {side}: {ratio:.3f}")


if __name__ == "__main__":
    main()
