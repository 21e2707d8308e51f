"""In-memory synthesis throughput, in one run: the Rust criterion bench of the entry point the
Python binding calls (`rust/core/benches/synth.rs`), `Pack.synth` from Python and a vectorised
numpy implementation of the same sampling (`rust/python/tests/test_bench.py`), all on one pack
file, one ISO, one 12 MP clean image and the same thread count. Prints the Mpix/s table and the
ratios the package promises (Python ≥ 0.9 × Rust, Python ≥ 20 × numpy).

Run from the repository root in the venv where the package is installed:

    python rust/python/benches/throughput.py [--iso 800] [--threads N] [--pack some.pack]

Without --pack, a pack is calibrated with the CLI from the simulated session the tests use
(96×64 phone10, ISO 100 and 800, `NOISECAL_BIN` or target/{release,debug}/noisecal).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
MPIX = 3000 * 4000 / 1e6


def cli() -> str:
    env = os.environ.get("NOISECAL_BIN")
    if env:
        return env
    for profile in ("release", "debug"):
        p = REPO / "target" / profile / "noisecal"
        if p.exists():
            return str(p)
    subprocess.run(["cargo", "build", "-q", "--release", "-p", "noisecal-cli"], cwd=REPO, check=True)
    return str(REPO / "target" / "release" / "noisecal")


def make_pack(d: Path) -> Path:
    exe = cli()
    subprocess.run([exe, "-q", "simulate", "--dngs", str(d / "cal"), "--width", "96", "--height", "64",
                    "--frames", "6", "--isos", "100,800", "--seed", "3"], check=True)
    subprocess.run([exe, "-q", "calibrate", str(d / "cal"), "-o", str(d / "bench.pack")], check=True)
    return d / "bench.pack"


def rust(env: dict, workspace: Path) -> dict[str, tuple[float, float, float]]:
    """Criterion: {bench name: (mean ns, median ns, fastest sample ns)}."""
    subprocess.run(["cargo", "bench", "-q", "-p", "noisecal-core", "--bench", "synth", "--", "--noplot"],
                   cwd=workspace, env=env, check=True)
    target = Path(env.get("CARGO_TARGET_DIR", workspace / "target"))
    out = {}
    for bench in glob.glob(str(target / "criterion" / "synth 12MP" / "*" / "new" / "benchmark.json")):
        name = json.loads(Path(bench).read_text())["function_id"]
        est = json.loads((Path(bench).parent / "estimates.json").read_text())
        sample = json.loads((Path(bench).parent / "sample.json").read_text())
        fastest = min(t / n for t, n in zip(sample["times"], sample["iters"]))
        out[name] = (est["mean"]["point_estimate"], est["median"]["point_estimate"], fastest)
    return out


def python(env: dict, d: Path) -> dict[str, tuple[float, float, float]]:
    """pytest-benchmark: {test name: (mean ns, median ns, fastest round ns)}."""
    js = d / "bench.json"
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_bench.py",
                    "--benchmark-enable", "--benchmark-min-rounds=20", "--benchmark-warmup=on",
                    f"--benchmark-json={js}"], cwd=REPO / "rust" / "python", env=env, check=True)
    res = json.loads(js.read_text())
    return {b["name"]: tuple(b["stats"][k] * 1e9 for k in ("mean", "median", "min")) for b in res["benchmarks"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iso", type=int, default=800)
    ap.add_argument("--threads", type=int, default=None, help="RAYON_NUM_THREADS for both (default: all cores)")
    ap.add_argument("--pack", type=Path, default=None)
    ap.add_argument("--workspace", type=Path, default=REPO,
                    help="where to run the Rust bench (a checkout of the sources the installed package was built from)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as t:
        d = Path(t)
        pack = a.pack or make_pack(d)
        env = dict(os.environ, NOISECAL_BENCH_PACK=str(pack.resolve()), NOISECAL_BENCH_ISO=str(a.iso))
        if a.threads:
            env["RAYON_NUM_THREADS"] = str(a.threads)
        r = rust(env, a.workspace)
        p = python(env, d)
    mpix = lambda ns: MPIX / (ns / 1e9)  # noqa: E731
    rows = [(f"Rust  {k}", v) for k, v in sorted(r.items())]
    rows += [(f"Python {k}", v) for k, v in sorted(p.items())]
    print(f"\n12 MP (3000×4000), ISO {a.iso}, pack {pack.name}, threads {a.threads or os.cpu_count()}")
    print(f"{'':50s} {'mean ms':>8s} {'Mpix/s':>7s} {'median ms':>10s} {'Mpix/s':>7s} {'min ms':>7s} {'Mpix/s':>7s}")
    for name, v in rows:
        print(f"{name:50s} " + " ".join(f"{t / 1e6:{w}.1f} {mpix(t):7.1f}" for t, w in zip(v, (8, 10, 7))))
    rust_all = next(v for k, v in r.items() if "global pool" in k)
    pkg = p["test_bench_package_synth"]
    npy = p["test_bench_numpy_synth"]
    ratio = lambda a, b: ", ".join(f"{k} {x / y:.3f}" for k, x, y in zip(("mean", "median", "min"), a, b))  # noqa: E731
    print(f"\nPython / Rust (same entry point, same threads): {ratio(rust_all, pkg)}   (target ≥ 0.9)")
    print(f"Python / numpy: {ratio(npy, pkg)}   (target ≥ 20)")


if __name__ == "__main__":
    main()
