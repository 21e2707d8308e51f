"""Every bad input is refused by name with the fix, by category: a wrong dtype or type is a
TypeError, a wrong value an InputError (a NoisecalError, so a ValueError), an image of another
sensor a MismatchError; nothing is clamped or reinterpreted silently. BAD_INPUTS is the table of
the issue (python tests/test_inputs.py prints it)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import noisecal
from conftest import run

C = np.full((32, 32), 300, np.uint16)  # a clean image of the test pack's sensor (10-bit, black 64)
F = ((C.astype(np.float32) - 64) / (1023 - 64)).astype(np.float32)


def twelve_bit() -> np.ndarray:
    """A 12-bit image (up to 4095) for the 10-bit pack: 1/4 of its pixels above white."""
    img = np.full((32, 32), 800, np.uint16)
    img[::2, ::2] = 4000
    img[0, 0] = 4095
    return img


def nan_image() -> np.ndarray:
    f = F.copy()
    f[3, 4] = np.nan
    f[5, 6] = np.inf
    return f


# (what, call(pack), exception, message pattern)
BAD_INPUTS = [
    ("synth: float64 clean", lambda p: p.synth(C.astype(np.float64), 800), TypeError,
     r"clean must be a numpy array of uint16, got ndarray of dtype float64: raw DN as uint16 .*synth_float"),
    ("synth: int32 clean", lambda p: p.synth(C.astype(np.int32), 800), TypeError,
     r"clean must be a numpy array of uint16, got ndarray of dtype int32: .*clean.astype\(np.uint16\)"),
    ("synth: a list", lambda p: p.synth([[1, 2], [3, 4]], 800), TypeError, r"clean must be a numpy array of uint16, got list"),
    ("synth_float: float64 clean", lambda p: p.synth_float(F.astype(np.float64), 800), TypeError,
     r"clean must be a numpy array of float32, got ndarray of dtype float64: pass clean.astype\(np.float32\)"),
    ("synth_float: uint16 clean", lambda p: p.synth_float(C, 800), TypeError, r"of dtype uint16: for uint16 DN use synth"),
    ("synth: (H, W, 3) RGB", lambda p: p.synth(np.zeros((32, 32, 3), np.uint16), 800), noisecal.InputError,
     r"clean has shape \(32, 32, 3\): a trailing axis of 3 is colour channels; pass the raw CFA mosaic, not RGB"),
    ("synth_float: (H, W, 4) RGBA", lambda p: p.synth_float(np.zeros((32, 32, 4), np.float32), 800),
     noisecal.InputError, r"trailing axis of 4 is colour channels; pass the raw CFA mosaic, not RGB"),
    ("synth: (H, W, 1)", lambda p: p.synth(np.zeros((32, 32, 1), np.uint16), 800), noisecal.InputError,
     r"drop the channel axis \(clean\[\.\.\., 0\]\)"),
    ("synth: 4-D", lambda p: p.synth(np.zeros((2, 2, 8, 8), np.uint16), 800), noisecal.InputError,
     r"clean has 4 dimensions \(shape \(2, 2, 8, 8\)\): give one raw image \(H, W\) or a batch \(N, H, W\)"),
    ("synth: 1-D", lambda p: p.synth(np.zeros(64, np.uint16), 800), noisecal.InputError, r"clean has 1 dimensions"),
    ("synth: empty", lambda p: p.synth(np.zeros((0, 8), np.uint16), 800), noisecal.InputError, r"clean is empty"),
    ("synth: 12-bit image, 10-bit pack", lambda p: p.synth(twelve_bit(), 800), noisecal.InputError,
     r"clean has 256 pixels \(25\.0 %\) above the pack's white level 1023, up to 4095 \(12-bit values for the pack's "
     r"10-bit sensor.*out_of_range=\"warn\" or \"allow\""),
    ("renoise: 12-bit image", lambda p: p.renoise(twelve_bit(), 100, 800), noisecal.InputError,
     r"noisy has 256 pixels \(25\.0 %\) above the pack's white level 1023"),
    ("synth_float: DN, not normalised", lambda p: p.synth_float(C.astype(np.float32), 800), noisecal.InputError,
     r"clean has 1024 values \(100\.0 %\) outside the pack's codes: 0 below DN 0 .* and 1024 above white .*look like DN"),
    ("synth_float: NaN and inf", lambda p: p.synth_float(nan_image(), 800), noisecal.InputError,
     r"clean has 1 NaN and 1 infinite values \(0\.2 % of the pixels\).*np\.nan_to_num"),
    ("synth: black_level above white", lambda p: p.synth(C, 800, black_level=[2000]), noisecal.InputError,
     r"black_level\[0\] = 2000(\.0)? is not a black level of this sensor \(0 ≤ black < white 1023\)"),
    ("synth: black_level NaN", lambda p: p.synth(C, 800, black_level=[64, 64, float("nan"), 64]), noisecal.InputError,
     r"black_level\[2\] = NaN"),
    ("synth: 3 black levels", lambda p: p.synth(C, 800, black_level=[1, 2, 3]), noisecal.InputError,
     r"black_level has 3 values: give one number, or four in CFA order"),
    ("synth: ISO outside the range", lambda p: p.synth(C, 25600), noisecal.NoisecalError,
     r"ISO 25600 is outside the pack's calibrated range 100–800; calibrate it, or allow extrapolation \(extrapolate=True\)"),
    ("synth: unknown model", lambda p: p.synth(C, 800, model="gauss"), noisecal.InputError, r"unknown model \"gauss\""),
    ("synth: unknown component", lambda p: p.synth(C, 800, components="pixel,rows2"), noisecal.InputError,
     r"unknown noise component \"rows2\""),
    ("synth: components without pixel", lambda p: p.synth(C, 800, components="row"), noisecal.InputError,
     r"the components must include pixel"),
    ("synth: clean_at", lambda p: p.synth(C, 800, clean_at="nowhere"), noisecal.InputError, r"clean_at"),
    ("synth: out_of_range", lambda p: p.synth(C, 800, out_of_range="sometimes"), noisecal.InputError,
     r"out_of_range=\"sometimes\": use \"raise\" \(default\), \"warn\" or \"allow\""),
    ("synth: negative seed", lambda p: p.synth(C, 800, -1), OverflowError, r"can't convert negative int"),
    ("renoise: to_iso not above from_iso", lambda p: p.renoise(C, 800, 100), noisecal.InputError,
     r"to_iso must be above from_iso"),
    ("renoise: unknown method", lambda p: p.renoise(C, 100, 800, method="magic"), noisecal.InputError,
     r"unknown method \"magic\""),
    ("renoise: float input", lambda p: p.renoise(F, 100, 800), TypeError, r"noisy must be a numpy array of uint16"),
    ("renoise: float64 estimate", lambda p: p.renoise(C, 100, 800, estimate=C.astype(np.float64)), TypeError,
     r"estimate must be a numpy array of float32, got ndarray of dtype float64: .*astype\(np.float32\)"),
    ("renoise: estimate of another size", lambda p: p.renoise(C, 100, 800, estimate=np.zeros((8, 8), np.float32)),
     noisecal.InputError, r"estimate has shape \[8, 8\] but noisy has \[32, 32\]: give one clean estimate per capture"),
    ("renoise: NaN in the estimate", lambda p: p.renoise(C, 100, 800, estimate=np.full((32, 32), np.nan, np.float32)),
     noisecal.NoisecalError, r"non-finite"),
    ("Pack.from_bytes: not a pack", lambda p: noisecal.Pack.from_bytes(b"nope"), noisecal.NoisecalError,
     r"cannot load the model pack"),
    ("seed_for: negative base seed", lambda p: noisecal.seed_for("a.dng", -1), ValueError, r"base_seed -1 is not a 64-bit seed"),
]


@pytest.mark.parametrize("what,call,exc,pattern", BAD_INPUTS, ids=[b[0] for b in BAD_INPUTS])
def test_bad_input_is_refused_by_name(pack, what, call, exc, pattern):
    with pytest.raises(exc, match=pattern) as e:
        call(pack)
    assert "--" not in str(e.value), f"a CLI flag in a Python message: {e.value}"


def test_integer_arguments_are_named(pack):
    # pyo3 names the argument in a note on the exception (shown in the traceback).
    for kwargs, name in (({"seed": -1}, "seed"), ({"cfa_origin": (-1, 0)}, "cfa_origin"), ({"iso": -5}, "iso")):
        args = {"iso": 800, **kwargs}
        with pytest.raises(OverflowError) as e:
            pack.synth(C, **args)
        assert any(name in n for n in getattr(e.value, "__notes__", [])), (kwargs, e.value)


def test_categories():
    assert issubclass(noisecal.InputError, noisecal.NoisecalError)
    assert issubclass(noisecal.MismatchError, noisecal.InputError)
    assert issubclass(noisecal.NoisecalError, ValueError)
    assert issubclass(noisecal.NoisecalWarning, UserWarning)


def test_out_of_range_warn_and_allow_are_explicit(pack):
    img = twelve_bit()
    with pytest.warns(noisecal.NoisecalWarning, match=r"256 pixels \(25\.0 %\) above the pack's white level 1023"):
        warned = pack.synth(img, 800, 1, out_of_range="warn")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        allowed = pack.synth(img, 800, 1, out_of_range="allow")
    np.testing.assert_array_equal(warned, allowed)
    assert allowed.max() <= 1023, "the output is clipped to the sensor's codes"
    # In range: no warning, and the same bytes whatever the policy.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(pack.synth(C, 800, 2, out_of_range="warn"), pack.synth(C, 800, 2))
    # Floats: clamped knowingly, with the counts in the warning.
    with pytest.warns(noisecal.NoisecalWarning, match=r"1024 values \(100\.0 %\) outside"):
        out = pack.synth_float(C.astype(np.float32), 800, 1, out_of_range="warn")
    assert out.dtype == np.float32
    # Below black is a level of the sensor, not out of range.
    below = np.full((16, 16), -30 / 959, np.float32)
    assert pack.synth_float(below, 800, 1).shape == (16, 16)


def test_non_contiguous_inputs_are_read_as_they_are(pack):
    base = (np.arange(64 * 96).reshape(64, 96) % 800 + 64).astype(np.uint16)
    for view in (base[:, ::2], base.T, base[::-1, ::-1], base[1:-1:3, 2::5]):
        assert not view.flags["C_CONTIGUOUS"]
        np.testing.assert_array_equal(pack.synth(view, 800, 3), pack.synth(np.ascontiguousarray(view), 800, 3))
    f = ((base.astype(np.float32) - 64) / 959)[:, ::3]
    np.testing.assert_array_equal(pack.synth_float(f, 800, 3), pack.synth_float(np.ascontiguousarray(f), 800, 3))
    big = base.astype(">u2")  # byte-swapped: refused with the conversion to make
    with pytest.raises(TypeError, match=r"clean must be a numpy array of uint16"):
        pack.synth(big, 800)


@pytest.fixture(scope="module")
def phone12_dng(cli, tmp_path_factory) -> "Path":  # noqa: F821
    """A 12-bit GRBG DNG (another camera than the test pack's 10-bit RGGB one)."""
    d = tmp_path_factory.mktemp("phone12")
    run(cli, "simulate", "--preset", "phone12", "--dngs", d, "--width", "32", "--height", "24", "--frames", "2",
        "--isos", "800", "--ev", "0", "--seed", "4")
    return sorted(d.glob("*.dng"))[0]


def test_read_dng_checks_the_image_against_the_pack(pack, session, phone12_dng):
    with pytest.raises(noisecal.MismatchError) as e:
        noisecal.read_dng(phone12_dng, pack=pack)
    msg = str(e.value)
    assert "has CFA GRBG but the pack's sensor is RGGB" in msg
    assert "cfa_origin=(0, 1)" in msg and "pixels[0:, 1:]" in msg
    assert "has white level 4095 (12-bit) but the pack's sensor has 1023 (10-bit)" in msg
    assert 'mismatch="warn"' in msg
    with pytest.warns(noisecal.NoisecalWarning, match="has CFA GRBG"):
        img, meta = noisecal.read_dng(phone12_dng, pack=pack, mismatch="warn")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        img2, _ = noisecal.read_dng(phone12_dng, pack=pack, mismatch="ignore")
        img3, _ = noisecal.read_dng(phone12_dng)  # without a pack: nothing to check
    np.testing.assert_array_equal(img, img2)
    np.testing.assert_array_equal(img, img3)
    assert meta["cfa"] == "GRBG" and meta["white"] == 4095
    # ... and its pixels are then refused by synth (12-bit values), not clamped.
    with pytest.raises(noisecal.InputError, match="above the pack's white level 1023"):
        pack.synth(img, 800, black_level=meta["black"])
    # The pack's own camera passes without a word.
    own = sorted(session["cal"].glob("*.dng"))[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        noisecal.read_dng(own, pack=pack)
    with pytest.raises(noisecal.InputError, match=r"mismatch=\"never\""):
        noisecal.read_dng(own, pack=pack, mismatch="never")


def test_write_dng_checks_its_pixels(pack, session, tmp_path):
    src = sorted(session["cal"].glob("*.dng"))[0]
    img, _ = noisecal.read_dng(src)
    with pytest.raises(TypeError, match=r"pixels must be a numpy array of uint16, got ndarray of dtype float32"):
        noisecal.write_dng(tmp_path / "o.dng", img.astype(np.float32), template=src, iso=800)
    with pytest.raises(noisecal.InputError, match=r"pixels is a batch of 2 images"):
        noisecal.write_dng(tmp_path / "o.dng", np.stack([img, img]), template=src, iso=800)
    with pytest.raises(noisecal.InputError, match=r"pass the raw CFA mosaic, not RGB"):
        noisecal.write_dng(tmp_path / "o.dng", np.zeros((*img.shape, 3), np.uint16), template=src, iso=800)


if __name__ == "__main__":  # the table for notes: what each bad input raises
    import sys

    p = noisecal.Pack.load(sys.argv[1])
    for what, call, _, _ in BAD_INPUTS:
        try:
            call(p)
            print(f"| {what} | (no error) |")
        except Exception as e:  # noqa: BLE001
            notes = "".join(f" [{n}]" for n in getattr(e, "__notes__", []))
            print(f"| {what} | `{type(e).__name__}`: {e}{notes} |")
