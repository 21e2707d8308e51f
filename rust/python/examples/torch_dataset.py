"""A torch Dataset that re-noises clean raw crops on the fly.

Each sample gets its own RNG stream from (epoch, index) through ``noisecal.seed_for``: no state is
shared between DataLoader workers, and the same (epoch, index) gives the same noisy crop in any
worker, with any number of workers. Crops keep their CFA phase through ``cfa_origin``. Each file
is checked against the pack's sensor (``read_dng(..., pack=...)``). The pack pickles and works in
forked workers, so it may be loaded in the parent (and used there, e.g. ``ds[0]``) or lazily.

    python torch_dataset.py PACK CLEAN_DIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

import noisecal


class NoisyRawCrops(Dataset):
    def __init__(self, pack_path: str, clean_dir: str, isos=(100, 800, 3200), crop: int = 256, epoch: int = 0):
        self.pack_path = pack_path
        self.files = sorted(Path(clean_dir).glob("*.dng"))
        self.isos, self.crop, self.epoch = isos, crop, epoch
        self._pack = None  # loaded lazily in each worker process

    @property
    def pack(self) -> noisecal.Pack:
        if self._pack is None:
            self._pack = noisecal.Pack.load(self.pack_path)
        return self._pack

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, i: int):
        seed = noisecal.seed_for(f"{self.epoch}:{i}")
        rng = np.random.default_rng(seed)
        clean, meta = noisecal.read_dng(self.files[i], pack=self.pack)
        h, w = clean.shape
        c = min(self.crop, h, w)
        y, x = int(rng.integers(0, h - c + 1)), int(rng.integers(0, w - c + 1))
        crop = clean[y:y + c, x:x + c]
        iso = int(rng.choice(self.isos))
        noisy = self.pack.synth(crop, iso, seed, black_level=meta["black"], cfa_origin=(y, x), extrapolate=True)
        return torch.from_numpy(noisy.astype(np.float32)), torch.from_numpy(crop.astype(np.float32)), iso


if __name__ == "__main__":
    ds = NoisyRawCrops(sys.argv[1], sys.argv[2])
    for noisy, clean, iso in DataLoader(ds, batch_size=2, num_workers=2):
        print(noisy.shape, iso.tolist(), float((noisy - clean).std()))
