"""The package and the `noisecal` command give the same bytes for the same inputs and seeds."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import noisecal
from conftest import run

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))


def test_calibrate_equals_cli_pack(session):
    assert session["pack"].to_bytes() == session["cli_pack"].read_bytes()


def test_synth_equals_cli_dng(session, cli, tmp_path):
    src = sorted(session["cal"].glob("*.dng"))[100]
    run(cli, "synth", "--pack", session["cli_pack"], "--iso", "400", "--seed", "7", src, "-o", tmp_path / "o.dng")
    clean, meta = noisecal.read_dng(src)
    expected, _ = noisecal.read_dng(tmp_path / "o.dng")
    got = session["pack"].synth(clean, 400, 7, black_level=meta["black"])
    assert got.dtype == np.uint16 and got.shape == clean.shape
    np.testing.assert_array_equal(got, expected)
    assert not np.array_equal(got, clean), "noise was added"


def _folder(session, tmp_path, n=3):
    files = sorted(session["cal"].glob("*.dng"))[100:100 + n]
    folder = tmp_path / "in"
    folder.mkdir()
    for f in files:
        (folder / f.name).write_bytes(f.read_bytes())
    return folder


def test_folder_is_byte_identical_from_cli_and_python(session, cli, tmp_path):
    """One seeding rule: the CLI's folder run, the Python example's and seed_for agree byte for byte."""
    import renoise_folder

    folder = _folder(session, tmp_path)
    run(cli, "synth", "--pack", session["cli_pack"], "--iso", "800", "--seed", "11", folder, "-o", tmp_path / "cli")
    done = renoise_folder.main([str(session["cli_pack"]), "800", str(folder), str(tmp_path / "py"), "--seed", "11"])
    names = sorted(f.name for f in folder.iterdir())
    assert [p.name for p, _ in done] == names
    for (out, seed), name in zip(done, names):
        assert seed == noisecal.seed_for(name, 11)
        cli_bytes = (tmp_path / "cli" / name).read_bytes()
        assert out.read_bytes() == cli_bytes, name  # pixels, NoiseProfile and every other tag
        assert noisecal.read_dng(out)[1]["noise_profile"], "the NoiseProfile is written"
    # Seeds by name: a file keeps its noise when the folder changes.
    (folder / names[0]).unlink()
    run(cli, "synth", "--pack", session["cli_pack"], "--iso", "800", "--seed", "11", folder, "-o", tmp_path / "cli2")
    assert (tmp_path / "cli2" / names[1]).read_bytes() == (tmp_path / "cli" / names[1]).read_bytes()


def test_folder_seed_by_index_matches_a_batch(session, cli, tmp_path):
    folder = _folder(session, tmp_path)
    run(cli, "synth", "--pack", session["cli_pack"], "--iso", "800", "--seed", "11", "--seed-by", "index", folder,
        "-o", tmp_path / "out")
    batch = np.stack([noisecal.read_dng(f)[0] for f in sorted(folder.iterdir())])
    got = session["pack"].synth(batch, 800, 11)
    for i, f in enumerate(sorted(folder.iterdir())):
        np.testing.assert_array_equal(got[i], noisecal.read_dng(tmp_path / "out" / f.name)[0])


def test_renoise_equals_cli(session, cli, tmp_path):
    src = sorted(session["cal"].glob("*.dng"))[100]
    noisy, meta = noisecal.read_dng(src)
    run(cli, "renoise", "--pack", session["cli_pack"], src, "--from-iso", "100", "--to-iso", "800", "--seed", "2",
        "-o", tmp_path / "r.dng")
    got = session["pack"].renoise(noisy, 100, 800, 2)
    np.testing.assert_array_equal(got, noisecal.read_dng(tmp_path / "r.dng")[0])


def test_renoise_with_an_estimate_equals_cli(session, cli, tmp_path):
    """Your own clean estimate: Python's ``estimate=`` and the CLI's ``--estimate`` DNG give the
    same bytes, and they differ from the built-in estimate's."""
    src = sorted(session["cal"].glob("*.dng"))[100]
    noisy, meta = noisecal.read_dng(src)
    est = sorted(session["cal"].glob("*.dng"))[101]  # another frame of the burst: a rough estimate
    run(cli, "renoise", "--pack", session["cli_pack"], src, "--from-iso", "100", "--to-iso", "800", "--seed", "2",
        "--estimate", est, "-o", tmp_path / "r.dng")
    got = session["pack"].renoise(noisy, 100, 800, 2, estimate=noisecal.read_dng(est)[0].astype(np.float32))
    np.testing.assert_array_equal(got, noisecal.read_dng(tmp_path / "r.dng")[0])
    assert not np.array_equal(got, session["pack"].renoise(noisy, 100, 800, 2))


def test_interp_equals_cli(session, cli, tmp_path):
    run(cli, "interp", "--pack", session["cli_pack"], "--iso", "300", "--iso", "500", "-o", tmp_path / "i.pack")
    got = session["pack"].interp([500, 300])
    assert got.isos == [100, 300, 500, 800]
    assert got.calibrated_isos == [100, 800]
    assert got.to_bytes() == (tmp_path / "i.pack").read_bytes()
