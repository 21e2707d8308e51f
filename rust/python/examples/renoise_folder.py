"""Offline: add a pack's noise at one ISO to every clean raw DNG of a folder, one seed per file
from its name, writing DNGs beside nothing they read.

    python renoise_folder.py PACK ISO IN_DIR OUT_DIR [--seed S]

The output folder is byte for byte ``noisecal synth --pack PACK --iso ISO --seed S IN_DIR -o
OUT_DIR``: the same seed per file (``noisecal.seed_for(file name, S)``, the folder rule of every
noisecal tool), the same checks of each image against the pack (``read_dng(..., pack=pack)``) and
the same NoiseProfile tag, the pack's fit at ISO (``write_dng(..., pack=pack)``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import noisecal


def main(argv=None) -> list[tuple[Path, int]]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pack")
    ap.add_argument("iso", type=int)
    ap.add_argument("input", type=Path)
    ap.add_argument("output", type=Path)
    ap.add_argument("--seed", type=int, default=0, help="the run's seed; file f gets seed_for(f.name, seed)")
    a = ap.parse_args(argv)
    pack = noisecal.Pack.load(a.pack)
    a.output.mkdir(parents=True, exist_ok=True)
    done = []
    for f in sorted(a.input.glob("*.dng")):
        clean, meta = noisecal.read_dng(f, pack=pack)
        seed = noisecal.seed_for(f.name, a.seed)
        noisy = pack.synth(clean, a.iso, seed, black_level=meta["black"])
        noisecal.write_dng(a.output / f.name, noisy, template=f, iso=a.iso, pack=pack)
        print(f"{f} -> {a.output / f.name} (seed {seed})")
        done.append((a.output / f.name, seed))
    return done


if __name__ == "__main__":
    main()
