"""The package in other processes: forked after the parent used it (the thread pool is per
process), spawned (the Pack pickles by its bytes), in a torch DataLoader and on Ray.

Before the pool was per process, a child forked after the parent synthesized hung forever in its
first synth (rayon's global pool was inherited without its threads): every wait here has a
timeout so that regression fails instead of hanging."""

from __future__ import annotations

import copy
import multiprocessing as mp
import os
import pickle
from pathlib import Path

import numpy as np
import pytest

import noisecal
from workers import NoisyDataset, RaySynth, clean_image, in_forked_child, renoise_file, synth_from_path, synth_with

TIMEOUT = 120


def expected(pack: noisecal.Pack, seeds) -> list[bytes]:
    return [synth_with(pack, s) for s in seeds]


def test_pickle_and_copies_synthesize_the_same_bytes(pack):
    data = pickle.dumps(pack)
    assert len(data) >= len(pack.to_bytes())
    back = pickle.loads(data)
    assert isinstance(back, noisecal.Pack) and back is not pack
    assert back.to_bytes() == pack.to_bytes()
    clean = clean_image(3)
    ref = pack.synth(clean, 800, 5)
    for other in (back, copy.copy(pack), copy.deepcopy(pack), copy.deepcopy({"p": pack})["p"]):
        np.testing.assert_array_equal(other.synth(clean, 800, 5), ref)
    assert pickle.loads(pickle.dumps(pack, protocol=2)).to_bytes() == pack.to_bytes()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_os_fork_after_the_parent_synthesized(pack):
    pack.synth(clean_image(0), 800, 0)  # the parent's pool exists now
    got = in_forked_child(lambda: synth_with(pack, 4) == synth_with(pack, 4), TIMEOUT)
    assert got != "hung", f"the forked child did not synthesize within {TIMEOUT} s (hung)"
    assert got == "ok"


@pytest.mark.parametrize("method", ["fork", "spawn", "forkserver"])
def test_multiprocessing_after_the_parent_synthesized(pack, session, method, tmp_path):
    if method not in mp.get_all_start_methods():
        pytest.skip(f"start method {method} not available here")
    want = expected(pack, [1, 2, 3, 4])  # the parent uses the package first
    src = str(sorted(session["cal"].glob("*.dng"))[100])
    want_file = renoise_file(pack, src, str(tmp_path / "parent.dng"), 9)
    ctx = mp.get_context(method)
    with ctx.Pool(2) as pool:
        # The Pack itself is pickled to the workers (by its bytes), and a path works too.
        got = pool.starmap_async(synth_with, [(pack, s) for s in (1, 2, 3, 4)]).get(TIMEOUT)
        by_path = pool.starmap_async(synth_from_path, [(str(session["cli_pack"]), s) for s in (1, 2)]).get(TIMEOUT)
        files = pool.starmap_async(renoise_file, [(pack, src, str(tmp_path / f"w{i}.dng"), 9) for i in (0, 1)])
        files = files.get(TIMEOUT)
    assert got == want
    assert files == [want_file, want_file]
    cli_pack = noisecal.Pack.load(session["cli_pack"])
    assert by_path == expected(cli_pack, [1, 2])


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_torch_dataloader_two_workers(pack, method):
    torch = pytest.importorskip("torch", reason="torch is not installed (optional: pip install noisecal[torch])")
    from torch.utils.data import DataLoader

    ds = NoisyDataset(pack)
    first = ds[0]  # the usual sanity check in the parent, before the workers start
    loader = DataLoader(ds, batch_size=2, num_workers=2, multiprocessing_context=method, timeout=TIMEOUT)
    batches = list(loader)
    got = torch.cat(batches).numpy()
    assert got.shape == (len(ds), 48, 64)
    want = np.stack([ds[i] for i in range(len(ds))])
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got[0], first)
    assert not np.array_equal(got[0], clean_image(0)), "noise was added"


def test_ray_actor_and_task_with_a_pickled_pack(pack):
    ray = pytest.importorskip("ray", reason="Ray is not installed (optional: pip install noisecal[ray])")
    import ray.data

    want = expected(pack, range(6))
    if ray.is_initialized():
        ray.shutdown()
    # Ray's workers import this test's helpers (workers.py) from the tests folder.
    tests = str(Path(__file__).resolve().parent)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": tests}})
    try:
        task = ray.remote(synth_with)
        assert ray.get([task.remote(pack, s) for s in range(3)], timeout=TIMEOUT) == want[:3]
        ds = ray.data.from_items([{"seed": s} for s in range(6)])
        out = ds.map_batches(RaySynth, fn_constructor_kwargs={"pack": pack}, batch_size=2, batch_format="numpy",
                             concurrency=2).take_all()
    finally:
        ray.shutdown()
    got = {int(r["seed"]): r["noisy"].astype(np.uint16).tobytes() for r in out}
    assert got == dict(enumerate(want))
