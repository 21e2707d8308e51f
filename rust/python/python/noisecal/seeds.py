"""Stable per-sample seeds: the same key gives the same seed in every process, worker and run.

The folder rule of every noisecal tool: file ``name`` of a run seeded with ``seed`` gets
``seed_for(name, seed)`` (``noisecal synth``/``renoise`` on a folder, :mod:`noisecal.ray`,
``examples/renoise_folder.py``), so the same folder and seed give the same bytes from each.
"""

from __future__ import annotations

import hashlib


def seed_for(key: str | bytes, base_seed: int = 0) -> int:
    """A 64-bit seed from a stable key (a file name, a dataset index) and a base seed.

    BLAKE2b (RFC 7693) of the key with an 8-byte digest, keyed by ``base_seed`` as 8 little-endian
    bytes, the digest read little-endian: not Python's ``hash`` (which changes between
    processes), so DataLoader workers, Ray actors, re-runs and the ``noisecal`` command (its Rust
    implementation, ``noisecal_cli::seeds``) agree. A ``str`` is hashed as UTF-8 (an undecodable
    file name as its raw bytes, ``os.fsencode``).
    """
    if isinstance(key, str):
        key = key.encode("utf-8", "surrogateescape")
    if not 0 <= int(base_seed) < 2**64:
        raise ValueError(f"base_seed {base_seed} is not a 64-bit seed: give an integer in [0, 2**64)")
    h = hashlib.blake2b(key, digest_size=8, key=int(base_seed).to_bytes(8, "little", signed=False))
    return int.from_bytes(h.digest(), "little")
