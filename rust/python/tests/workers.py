"""Helpers the worker tests run in other processes (importable, so spawn can find them)."""

from __future__ import annotations

import os
import select
from typing import Callable

import numpy as np

import noisecal


def in_forked_child(check: Callable[[], bool], timeout: float) -> str:
    """Runs `check` in a child made by `os.fork()` and says what came of it: "ok" or "no" (its
    answer), "hung" (no answer within `timeout` s: the child is killed) or "died" (it raised)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        try:
            os.close(r)
            os.write(w, b"ok" if check() else b"no")
        finally:
            os._exit(0)
    os.close(w)
    ready, _, _ = select.select([r], [], [], timeout)
    if not ready:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        return "hung"
    got = os.read(r, 2)
    os.waitpid(pid, 0)
    return got.decode() or "died"


def clean_image(i: int = 0) -> np.ndarray:
    """A clean raw image with levels across the pack's range (black 64, white 1023)."""
    return ((np.arange(48 * 64).reshape(48, 64) * 7 + 97 * i) % 900 + 64).astype(np.uint16)


def synth_with(pack: noisecal.Pack, seed: int) -> bytes:
    """The noisy bytes of `clean_image(seed)` at ISO 800 with `seed` (runs in a worker)."""
    return pack.synth(clean_image(seed), 800, seed).tobytes()


def renoise_file(pack: noisecal.Pack, src: str, dst: str, seed: int) -> bytes:
    """A DNG read, synthesized and written in a worker (every entry that runs in parallel)."""
    clean, meta = noisecal.read_dng(src, pack=pack)
    noisy = pack.synth(clean, 800, seed, black_level=meta["black"])
    noisecal.write_dng(dst, noisy, template=src, iso=800, pack=pack)
    with open(dst, "rb") as f:
        return f.read()


def synth_from_path(path: str, seed: int) -> bytes:
    return synth_with(noisecal.Pack.load(path), seed)


class NoisyDataset:
    """A map-style dataset holding a Pack (pickled to spawned workers, inherited by forked ones)."""

    def __init__(self, pack: noisecal.Pack, n: int = 6):
        self.pack, self.n = pack, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int):
        return self.pack.synth(clean_image(i), 800, noisecal.seed_for(f"sample:{i}")).astype(np.int32)


class RaySynth:
    """A Ray Data callable class: a stateful actor holding a pickled Pack."""

    def __init__(self, pack: noisecal.Pack):
        self.pack = pack

    def __call__(self, batch: dict) -> dict:
        outs = [synth_with(self.pack, int(s)) for s in batch["seed"]]
        return {"seed": batch["seed"], "noisy": np.array([np.frombuffer(o, np.uint16) for o in outs])}
