"""Re-noise a folder of clean raw DNGs at one ISO with Ray Data.

    python ray_renoise.py PACK ISO IN_DIR OUT_DIR [--address ray://head:10001] [--actors 4]

Runs on this machine with ``ray.init()``, or on a cluster with ``--address`` (no other change).
The output folder equals ``noisecal synth --pack PACK --iso ISO --seed BASE IN_DIR -o OUT_DIR``
(``BASE`` = ``--base-seed``; the folder rule of every noisecal tool): each file gets
``S = noisecal.seed_for(file name, BASE)`` and equals ``noisecal synth ... --seed S`` on that file.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import ray

from noisecal.ray import RenoiseActor


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pack")
    ap.add_argument("iso", type=int)
    ap.add_argument("input", type=Path)
    ap.add_argument("output", type=Path)
    ap.add_argument("--address", default=None, help="Ray cluster address (default: start Ray locally)")
    ap.add_argument("--actors", type=int, default=2)
    ap.add_argument("--base-seed", type=int, default=0)
    ap.add_argument("--format", choices=["dng", "npy"], default="dng")
    a = ap.parse_args(argv)
    ray.init(address=a.address, ignore_reinit_error=True)
    files = sorted(str(p) for p in a.input.iterdir() if p.suffix.lower() == ".dng")
    ds = ray.data.from_items([{"path": f} for f in files])
    out = ds.map_batches(
        RenoiseActor,
        fn_constructor_kwargs={"pack_path": a.pack, "iso": a.iso, "out_dir": str(a.output),
                               "base_seed": a.base_seed, "fmt": a.format},
        batch_size=4,
        batch_format="numpy",
        concurrency=a.actors,
    )
    rows = out.take_all()
    for r in rows:
        print(f"{r['path']} -> {r['output']} (seed {r['seed']})")
    return rows


if __name__ == "__main__":
    main()
