"""Dataset-scale synthesis on Ray Data, with no cluster code of ours.

``RenoiseActor`` is a callable class for ``Dataset.map_batches(RenoiseActor, fn_constructor_kwargs=
{...}, batch_format="numpy", concurrency=...)``: Ray runs it as a stateful actor, so the pack is
loaded once per actor in ``__init__``. Each row names a clean raw DNG (column ``path``); its seed
comes from a stable key (the file name, :func:`noisecal.seed_for` with ``base_seed``), so a re-run,
or any number of actors, writes identical files: the folder equals ``noisecal synth --seed
<base_seed>`` on the folder (the same rule), and each file ``noisecal synth --seed <its seed>``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from . import Pack, read_dng, seed_for, write_dng


class RenoiseActor:
    """Adds a pack's noise at ``iso`` to each DNG of a batch and writes it to ``out_dir``
    (same file name), as DNG or, with ``fmt="npy"``, as a numpy array."""

    def __init__(self, pack_path: str, iso: int, out_dir: str, base_seed: int = 0, model: str = "noisecal",
                 fmt: str = "dng"):
        if fmt not in ("dng", "npy"):
            raise ValueError(f"fmt {fmt!r}: use 'dng' or 'npy'")
        self.pack = Pack.load(pack_path)
        self.iso, self.out_dir, self.base_seed, self.model, self.fmt = iso, Path(out_dir), base_seed, model, fmt
        os.makedirs(self.out_dir, exist_ok=True)

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        outs, seeds = [], []
        for path in batch["path"]:
            path = Path(str(path))
            seed = seed_for(path.name, self.base_seed)
            clean, meta = read_dng(path, pack=self.pack)
            noisy = self.pack.synth(clean, self.iso, seed, model=self.model, black_level=meta["black"])
            if self.fmt == "dng":
                out = self.out_dir / path.name
                write_dng(out, noisy, template=path, iso=self.iso, pack=self.pack)
            else:
                out = self.out_dir / (path.stem + ".npy")
                tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
                with open(tmp, "wb") as f:
                    np.save(f, noisy)
                os.replace(tmp, out)
            outs.append(str(out))
            seeds.append(seed)
        return {"path": batch["path"], "output": np.array(outs), "seed": np.array(seeds, dtype=np.uint64)}
