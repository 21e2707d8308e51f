"""Parity where it is easiest to lose: inputs whose black level is not the pack's. The command reads
an input's black level from its DNG and carries the image onto the pack's black level and back;
Python is given it as `black_level` and must write the same bytes (synth and renoise), on any
thread count of the command. Odd crop origins: a crop at `cfa_origin` is carried by the black
level of its true CFA positions."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

import noisecal
from conftest import run

BLACK_LEVEL = 50714
RATIONAL = 5


def _with_black(src: Path, dst: Path, black: list[float]) -> None:
    """A copy of the DNG `src` whose BlackLevel (the 2×2 RATIONAL pattern in IFD0 that `noisecal
    simulate` writes) says `black`; every other byte is kept."""
    b = bytearray(src.read_bytes())
    e = "<" if b[:2] == b"II" else ">"
    (ifd,) = struct.unpack_from(e + "I", b, 4)
    (n,) = struct.unpack_from(e + "H", b, ifd)
    for i in range(n):
        tag, ty, count, off = struct.unpack_from(e + "HHII", b, ifd + 2 + 12 * i)
        if tag == BLACK_LEVEL:
            assert ty == RATIONAL and count == 4, (ty, count)
            for k, v in enumerate(black):
                struct.pack_into(e + "II", b, off + 8 * k, round(v * 4), 4)
            dst.write_bytes(bytes(b))
            return
    raise AssertionError(f"{src} has no BlackLevel in IFD0")


@pytest.fixture(scope="module")
def shifted(session: dict, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[float]]:
    """An ISO 100 capture of the session whose black level is off the pack's, differently per
    CFA position (one up, one down, one fractional)."""
    src = sorted(session["cal"].glob("*.dng"))[100]
    pack_black = session["pack"].layout["black"]
    black = [pack_black[0] + 3, pack_black[1] - 2, pack_black[2] + 0.75, pack_black[3]]
    dst = tmp_path_factory.mktemp("shifted") / "shifted.dng"
    _with_black(src, dst, black)
    _, meta = noisecal.read_dng(dst)
    assert meta["black"] == black and meta["black"] != pack_black
    return dst, black


@pytest.mark.parametrize("threads", ["1", "3"])
def test_synth_off_the_packs_black_equals_cli(session, cli, shifted, tmp_path, threads):
    dng, black = shifted
    out = tmp_path / "o.dng"
    run(cli, "--threads", threads, "synth", "--pack", session["cli_pack"], "--iso", "400", "--seed", "7", dng,
        "-o", out)
    clean, meta = noisecal.read_dng(dng)
    got = session["pack"].synth(clean, 400, 7, black_level=meta["black"])
    np.testing.assert_array_equal(got, noisecal.read_dng(out)[0])
    # The black level matters: taken as the pack's, the same image gets other bytes.
    assert not np.array_equal(session["pack"].synth(clean, 400, 7), got)


@pytest.mark.parametrize("threads", ["1", "3"])
def test_renoise_off_the_packs_black_equals_cli(session, cli, shifted, tmp_path, threads):
    dng, black = shifted
    out = tmp_path / "r.dng"
    run(cli, "--threads", threads, "renoise", "--pack", session["cli_pack"], dng, "--from-iso", "100",
        "--to-iso", "800", "--seed", "2", "-o", out)
    noisy, meta = noisecal.read_dng(dng)
    got = session["pack"].renoise(noisy, 100, 800, 2, black_level=meta["black"])
    np.testing.assert_array_equal(got, noisecal.read_dng(out)[0])
    assert not np.array_equal(session["pack"].renoise(noisy, 100, 800, 2), got)


@pytest.mark.parametrize("origin", [(1, 0), (0, 1), (1, 1), (3, 5)])
def test_a_crop_is_carried_by_its_true_positions(session, shifted, origin):
    """At an odd origin, each pixel moves by the black level of its sensor position: synthesizing
    the crop with its black level equals synthesizing it carried onto the pack's black level by
    hand (each pixel by its true position's offset, rounded) and carried back."""
    dng, black = shifted
    clean, _ = noisecal.read_dng(dng)
    pack = session["pack"]
    oy, ox = origin
    crop = np.ascontiguousarray(clean[oy:oy + 32, ox:ox + 40])
    shift = np.rint(np.array(pack.layout["black"]) - np.array(black)).astype(np.int32)
    pos = (((np.arange(crop.shape[0])[:, None] + oy) & 1) * 2 + ((np.arange(crop.shape[1])[None, :] + ox) & 1))
    white = pack.layout["white"]
    moved = np.clip(crop.astype(np.int32) + shift[pos], 0, white).astype(np.uint16)
    noisy = pack.synth(moved, 400, 11, cfa_origin=origin)
    expected = np.clip(noisy.astype(np.int32) - shift[pos], 0, white).astype(np.uint16)
    got = pack.synth(crop, 400, 11, black_level=black, cfa_origin=origin)
    np.testing.assert_array_equal(got, expected)
