"""Every Python call with a command-line twin — calibrate, synth, renoise, interp, read_dng and
write_dng — gives the command's bytes on inputs whose black level is not the pack's, with the core
on 1 and on 3 threads on both sides. The command's threads are `--threads N`; the package's are
`RAYON_NUM_THREADS`, read once per process when its pool starts, so the Python side runs in a
child process per thread count.

Odd crop origins have no command-line twin (the command synthesizes whole DNGs at their own CFA
phase); `test_parity_black.py` checks them against the same image carried by hand."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import noisecal
from conftest import run
from test_parity_black import _with_black

THREADS = ["1", "3"]

# The Python side, run in a child with RAYON_NUM_THREADS set: every output to a file of `out`.
CHILD = r"""
import json, sys
from pathlib import Path
import numpy as np
import noisecal

args = json.loads(sys.argv[1])
out = Path(args["out"])
pack = noisecal.Pack.load(args["cli_pack"])
dng = args["shifted"]
pixels, meta = noisecal.read_dng(dng)
np.save(out / "read.npy", pixels)
(out / "black.json").write_text(json.dumps(meta["black"]))
noisy = pack.synth(pixels, 400, 7, black_level=meta["black"])
noisecal.write_dng(out / "synth.dng", noisy, template=dng, iso=400, pack=pack)
renoised = pack.renoise(pixels, 100, 800, 2, black_level=meta["black"])
noisecal.write_dng(out / "renoise.dng", renoised, template=dng, iso=800, pack=pack)
pack.interp([500, 300]).save(out / "interp.pack")
noisecal.calibrate(args["shifted_folder"]).save(out / "calibrate.pack")
"""


@pytest.fixture(scope="module")
def shifted_folder(session: dict, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's capture set, every DNG's black level moved off the pack's (differently per
    CFA position), so calibration and everything after it see a black level of their own."""
    pack_black = session["pack"].layout["black"]
    black = [pack_black[0] + 3, pack_black[1] - 2, pack_black[2] + 0.75, pack_black[3]]
    folder = tmp_path_factory.mktemp("shifted_set")
    for f in sorted(session["cal"].glob("*.dng")):
        _with_black(f, folder / f.name, black)
    return folder


@pytest.fixture(scope="module")
def shifted(session: dict, shifted_folder: Path) -> Path:
    """One ISO 100 capture of the shifted set (a clean-ish input for synth, a noisy one for
    renoise)."""
    src = sorted(shifted_folder.glob("*.dng"))[100]
    _, meta = noisecal.read_dng(src)
    assert meta["iso"] == 100 and meta["black"] != session["pack"].layout["black"]
    return src


@pytest.fixture(scope="module", params=THREADS)
def python_side(request, session, shifted, shifted_folder, tmp_path_factory) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp(f"python_{request.param}_threads")
    args = {"out": str(out), "cli_pack": str(session["cli_pack"]), "shifted": str(shifted),
            "shifted_folder": str(shifted_folder)}
    env = {**os.environ, "RAYON_NUM_THREADS": request.param}
    r = subprocess.run([sys.executable, "-c", CHILD, json.dumps(args)], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return request.param, out


@pytest.fixture(scope="module", params=THREADS)
def cli_side(request, session, cli, shifted, shifted_folder, tmp_path_factory) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp(f"cli_{request.param}_threads")
    t = ["--threads", request.param]
    pack = session["cli_pack"]
    run(cli, *t, "synth", "--pack", pack, "--iso", "400", "--seed", "7", shifted, "-o", out / "synth.dng")
    run(cli, *t, "renoise", "--pack", pack, shifted, "--from-iso", "100", "--to-iso", "800", "--seed", "2",
        "-o", out / "renoise.dng")
    run(cli, *t, "interp", "--pack", pack, "--iso", "300", "--iso", "500", "-o", out / "interp.pack")
    run(cli, *t, "calibrate", shifted_folder, "-o", out / "calibrate.pack")
    return request.param, out


@pytest.mark.parametrize("name", ["synth.dng", "renoise.dng", "interp.pack", "calibrate.pack"])
def test_python_file_equals_the_commands(python_side, cli_side, name):
    (pt, py), (ct, cl) = python_side, cli_side
    assert (py / name).read_bytes() == (cl / name).read_bytes(), f"{name}: Python on {pt} threads, CLI on {ct}"


def test_the_outputs_are_not_the_inputs(python_side, session, shifted):
    """The comparison above compares something: noise was added, and the shifted black level
    was read and used (taken as the pack's, the same image synthesizes to other bytes)."""
    _, py = python_side
    pixels = np.load(py / "read.npy")
    clean, meta = noisecal.read_dng(shifted)
    np.testing.assert_array_equal(pixels, clean)
    assert json.loads((py / "black.json").read_text()) == meta["black"]
    synth, _ = noisecal.read_dng(py / "synth.dng")
    assert not np.array_equal(synth, clean)
    assert not np.array_equal(session["pack"].synth(clean, 400, 7), synth)
    renoised, _ = noisecal.read_dng(py / "renoise.dng")
    assert not np.array_equal(renoised, clean)
    # Calibrated from the shifted set, the pack's black level is the set's.
    cal = noisecal.Pack.from_bytes((py / "calibrate.pack").read_bytes())
    assert cal.layout["black"] == meta["black"] != session["pack"].layout["black"]
