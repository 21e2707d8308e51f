"""The Ray example's outputs equal `noisecal synth` with the same per-image seeds, and its folder
run on the same folder and seed (runs when Ray is
installed; CI installs it when it can, see tests/run_all.sh)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

import noisecal
from conftest import run

pytest.importorskip("ray")
pytestmark = pytest.mark.ray

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))


def test_ray_example_equals_cli(session, cli, tmp_path):
    import numpy as np
    import ray_renoise

    src = tmp_path / "in"
    src.mkdir()
    for f in sorted(session["cal"].glob("*.dng"))[100:106]:
        shutil.copy(f, src / f.name)
    rows = ray_renoise.main([str(session["cli_pack"]), "800", str(src), str(tmp_path / "out"), "--actors", "2",
                             "--base-seed", "5"])
    assert len(rows) == 6
    for f in sorted(src.iterdir()):
        seed = noisecal.seed_for(f.name, 5)
        run(cli, "synth", "--pack", session["cli_pack"], "--iso", "800", "--seed", str(seed), f, "-o",
            tmp_path / f"cli_{f.name}")
        ours, _ = noisecal.read_dng(tmp_path / "out" / f.name)
        theirs, _ = noisecal.read_dng(tmp_path / f"cli_{f.name}")
        np.testing.assert_array_equal(ours, theirs)
        assert (tmp_path / "out" / f.name).read_bytes() == (tmp_path / f"cli_{f.name}").read_bytes()
    # The same folder rule: `noisecal synth` on the folder with --seed 5 writes the same files.
    run(cli, "synth", "--pack", session["cli_pack"], "--iso", "800", "--seed", "5", src, "-o", tmp_path / "cli_folder")
    for f in sorted(src.iterdir()):
        assert (tmp_path / "out" / f.name).read_bytes() == (tmp_path / "cli_folder" / f.name).read_bytes(), f.name
