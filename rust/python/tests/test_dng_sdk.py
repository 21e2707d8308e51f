"""DNGs that keep everything (every tag, sub-IFD, preview and maker note of their template), judged by the Adobe DNG SDK through PyPI `dngpy`.

`noisecal synth`, `noisecal renoise` and `noisecal.write_dng` derive a DNG from an input DNG. Here
the SDK reads each input and each output as Adobe's tools do and the test asserts that

* the SDK reads the output and reports no validation message (`*** Warning: … ***` or
  `*** Error: … ***`) that it does not already report for the input;
* the output's ISO is the requested one, in every ISO tag the SDK sees (and in dngpy's `iso`);
* the output has a `NoiseProfile` in its raw IFD, one (scale, offset) pair per CFA colour, all
  positive, and it describes the noise that was added to the pixels;
* everything else the SDK parses is unchanged: every tag of every IFD (orientation, default
  crop, colour matrices, illuminants, neutral, baseline exposure, EXIF, XMP, …) except the ISO
  tags, `NoiseProfile`, where the raw data and the IFDs are (strip/tile offsets and counts,
  SubIFDs/ExifIFD pointers: what they point to is compared), the raw-image
  digests (dropped: they hash the old pixels) and `RawDataUniqueID` (changed); and so is
  everything dngpy's own API reports (make, model, exposure, crop size, raw size, white balance,
  baseline exposure, Bayer phase, active-area origin, gain map);
* the SDK decodes the same pixels as `noisecal.read_dng`.

How dngpy reports problems: `dngpy.Dng(path)` parses the file with the SDK (`dng_info::Parse`,
`IsValidDNG`, `dng_negative::Parse`/`PostParse`, `ReadStage1Image`, `ValidateRawImageDigest`) and
raises `RuntimeError` when it cannot read it; the SDK in dngpy's wheel is built for validation, so
everything else it finds wrong is printed on the C stderr as `*** Warning: … ***` / `*** Error: …
***` (as `dng_validate` prints it). dngpy's API exposes no NoiseProfile, orientation, crop origin
or colour matrix; the SDK's own tag dump (its global `gVerbose`, `dng_validate -v`) does, so each
file is read in a child Python with `gVerbose` set through ctypes on the libdng that dngpy loaded,
and that dump is parsed. The child also keeps a crash of the native code out of pytest.

Inputs: an Android-style DNG from `noisecal simulate` (everything in IFD0); that file written again
by the Adobe SDK itself (`dngpy.Dng.save`: XMP, NewRawImageDigest, RawDataUniqueID, default crop,
an OpcodeList2 GainMap, a white balance and a baseline exposure set through dngpy); and a DNG laid
out as DNG converters write them (big-endian, an RGB preview in IFD0 and the raw image in a
SubIFD, tiled, a masked border with ActiveArea, a default crop inside it, orientation 6, two
illuminants with colour and forward matrices, its own NoiseProfile, several ISO tags).
Skipped, with the reason, when dngpy cannot be imported; tests/run_all.sh installs it.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import struct
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

import noisecal
from conftest import run

# Skip, not fail, when dngpy is missing or its native library does not load on this machine.
pytest.importorskip("dngpy", reason="dngpy (the Adobe DNG SDK for Python, PyPI) is not installed or does not load: "
                    "pip install dngpy", exc_type=ImportError)

CAL_ISOS = (100, 800)
SYNTH_ISO = 400  # between the calibrated ISOs: interpolated
RENOISE_ISO = 800
WHITE = 1023
BLACK = 64

# --- The SDK's view of a file ---------------------------------------------------------------

# Runs in a child interpreter: argv = DNG path, JSON output path. Sets the SDK's gVerbose (its
# tag dump, on stdout) when the symbol is there, reads the file with dngpy, writes what dngpy's API
# reports as JSON. The SDK's validation messages go to stderr.
_PROBE = textwrap.dedent(
    r"""
    import ctypes, json, sys
    import dngpy
    verbose = False
    for line in open("/proc/self/maps"):
        if "libdng" in line:
            try:
                lib = ctypes.CDLL(line.split()[-1])
                ctypes.c_bool.in_dll(lib, "gVerbose").value = True
                verbose = True
            except (OSError, ValueError):
                pass
            break
    out = {"verbose": verbose}
    try:
        d = dngpy.Dng(sys.argv[1])
    except Exception as e:
        out["error"] = f"{type(e).__name__}: {e}"
    else:
        m = d.metadata
        out["meta"] = {k: getattr(m, k) for k in dir(m) if not k.startswith("_")}
        info = d.get_data_info()
        out["data"] = {k: getattr(info, k) for k in ("width", "height", "channels", "pixel_type", "top", "left")}
        out["white_balance"] = d.get_white_balance()
        out["baseline_exposure"] = d.get_baseline_exposure()
        out["bayer"] = d.get_bayer_pattern()
        g = d.get_gainmap()
        out["gainmap"] = None if g is None else {
            "rows": g.rows, "cols": g.cols, "planes": g.planes, "data": [float(x) for x in g.to_numpy().ravel()]}
        import numpy as np
        np.save(sys.argv[2] + ".npy", d.raw_pixels)
    libc = ctypes.CDLL(None)
    libc.fflush(None)
    with open(sys.argv[2], "w") as f:
        json.dump(out, f)
    """
)

_MESSAGE = re.compile(r"^\*\*\* (Warning|Error): (.*) \*\*\*$")
_SECTION = re.compile(r"^(.*IFD.*?): Offset = \d+")
_TAG = re.compile(r"^([A-Za-z][A-Za-z0-9 ]*?):(.*)$")


@dataclass
class SdkView:
    path: Path
    messages: list[str]  # "Warning: …" / "Error: …", as the SDK printed them
    api: dict  # what dngpy's API reports
    tags: dict[tuple[str, str], str] = field(default_factory=dict)  # (IFD, tag) -> the SDK's dump
    pixels: np.ndarray | None = None

    def tag(self, name: str) -> list[tuple[str, str]]:
        return [(ifd, v) for (ifd, t), v in self.tags.items() if t == name]


def _parse_dump(text: str) -> dict[tuple[str, str], str]:
    """The SDK's verbose dump as (IFD, tag) -> text, offsets blanked (the writer may move data)."""
    tags: dict[tuple[str, str], str] = {}
    section, current = None, None
    for line in text.splitlines():
        m = _SECTION.match(line)
        if m:
            section, current = re.sub(r"\s+", " ", m.group(1)).strip(), None
            continue
        if section is None or not line.strip():
            continue
        if line.startswith("NextIFD"):
            section, current = None, None
            continue
        line = re.sub(r"(?i)\b(offset = )\d+(?=,|\s|$)", r"\1_", line)  # not NoiseProfile's
        if line[0] in " \t" and current is not None:
            tags[current] += "\n" + line.strip()
            continue
        m = _TAG.match(line)
        if not m:
            continue
        key = (section, m.group(1).strip())
        if key == current:  # XMP: one dump line per packet line
            tags[key] += "\n" + m.group(2).strip()
        else:
            current = key
            tags[key] = (tags[key] + "\n" if key in tags else "") + m.group(2).strip()
    return tags


def sdk_read(path: Path) -> SdkView:
    out = path.with_name(path.name + ".sdk.json")
    r = subprocess.run([sys.executable, "-c", _PROBE, str(path), str(out)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, f"reading {path} with dngpy crashed ({r.returncode}): {r.stderr[-2000:]}"
    res = json.loads(out.read_text())
    messages = [f"{m.group(1)}: {m.group(2)}" for m in map(_MESSAGE.match, r.stderr.splitlines()) if m]
    view = SdkView(path, messages, res)
    if "error" in res:
        return view
    view.pixels = np.load(str(out) + ".npy")[:, :, 0]
    if res["verbose"]:
        view.tags = _parse_dump(r.stdout)
    return view


def read_ok(path: Path) -> SdkView:
    v = sdk_read(path)
    assert "error" not in v.api, f"the DNG SDK cannot read {path.name}: {v.api['error']}; it said {v.messages}"
    return v


# --- Fixtures -------------------------------------------------------------------------------


class Tiff:
    """A minimal TIFF writer: blobs, then IFDs whose out-of-line values follow their table."""

    FMT = {1: "B", 3: "H", 4: "L", 8: "h", 9: "l", 12: "d"}

    def __init__(self, big: bool):
        self.e = ">" if big else "<"
        self.buf = bytearray(b"MM\0*" if big else b"II*\0") + bytearray(4)

    def _align(self) -> None:
        if len(self.buf) % 2:
            self.buf.append(0)

    def blob(self, data: bytes) -> int:
        self._align()
        off = len(self.buf)
        self.buf += data
        return off

    def _encode(self, ty: int, v) -> tuple[int, bytes]:
        e = self.e
        if ty == 2:
            b = v.encode() + b"\0"
            return len(b), b
        if ty == 7:
            return len(v), bytes(v)
        if ty in (5, 10):
            f = "L" if ty == 5 else "l"
            return len(v), b"".join(struct.pack(e + 2 * f, n, d) for n, d in v)
        return len(v), struct.pack(f"{e}{len(v)}{self.FMT[ty]}", *v)

    def ifd(self, entries: dict[int, tuple[int, object]]) -> int:
        self._align()
        off = len(self.buf)
        data_at = off + 2 + 12 * len(entries) + 4
        table, extra = struct.pack(self.e + "H", len(entries)), bytearray()
        for tag in sorted(entries):
            ty, v = entries[tag]
            count, raw = self._encode(ty, v)
            if len(raw) <= 4:
                fld = raw.ljust(4, b"\0")
            else:
                fld = struct.pack(self.e + "L", data_at + len(extra))
                extra += raw + (b"\0" if len(raw) % 2 else b"")
            table += struct.pack(self.e + "HHL", tag, ty, count) + fld
        self.buf += table + struct.pack(self.e + "L", 0) + extra
        return off

    def finish(self, ifd0: int) -> bytes:
        self.buf[4:8] = struct.pack(self.e + "L", ifd0)
        return bytes(self.buf)


def _srat(x: float) -> tuple[int, int]:
    return (round(x * 10000), 10000)


def converter_layout_dng(path: Path, active: np.ndarray) -> None:
    """`active` (RGGB, black 64, white 1023) as a DNG laid out as DNG converters write them."""
    h, w = active.shape
    top, left, bottom_pad, right_pad = 4, 8, 4, 8
    full = np.full((top + h + bottom_pad, left + w + right_pad), BLACK, np.uint16)
    full[:top] += np.arange(full.shape[1], dtype=np.uint16) % 3  # masked rows, not all equal
    full[top:top + h, left:left + w] = active
    fh, fw = full.shape
    t = Tiff(big=True)
    tile = 64
    tiles_down, tiles_across = -(-fh // tile), -(-fw // tile)
    padded = np.zeros((tiles_down * tile, tiles_across * tile), np.uint16)
    padded[:fh, :fw] = full
    offsets, counts = [], []
    for ty in range(tiles_down):
        for tx in range(tiles_across):
            data = padded[ty * tile:(ty + 1) * tile, tx * tile:(tx + 1) * tile].astype(">u2").tobytes()
            offsets.append(t.blob(data))
            counts.append(len(data))
    crop = 8
    raw = t.ifd({
        254: (4, [0]), 256: (4, [fw]), 257: (4, [fh]), 258: (3, [16]), 259: (3, [1]), 262: (3, [32803]),
        277: (3, [1]), 284: (3, [1]), 322: (3, [tile]), 323: (3, [tile]), 324: (4, offsets), 325: (4, counts),
        33421: (3, [2, 2]), 33422: (1, [0, 1, 1, 2]), 50710: (1, [0, 1, 2]), 50711: (3, [1]),
        50713: (3, [2, 2]), 50714: (5, [(BLACK, 1)] * 4), 50717: (3, [WHITE]),
        50718: (5, [(1, 1), (1, 1)]), 50719: (5, [(crop, 1), (crop, 1)]),
        50720: (5, [(w - 2 * crop, 1), (h - 2 * crop, 1)]), 50733: (4, [0]), 50738: (5, [(1, 1)]),
        50780: (5, [(1, 1)]), 50829: (4, [top, left, top + h, left + w]),
        51041: (12, [2.0e-5, 1.0e-6, 1.9e-5, 1.1e-6, 2.1e-5, 1.2e-6]),
    })
    exif = t.ifd({
        33434: (5, [(1, 250)]), 33437: (5, [(18, 10)]), 34850: (3, [2]), 34855: (3, [100]), 34864: (3, [2]),
        34866: (4, [100]), 36864: (7, b"0231"), 36867: (2, "2026:01:02 03:04:05"), 37386: (5, [(47, 10)]),
        41989: (3, [26]),
    })
    prev = np.zeros((24, 32, 3), np.uint8) + np.arange(32, dtype=np.uint8)[None, :, None] * 8
    prev_off = t.blob(prev.tobytes())
    cm1 = [0.8, -0.2, -0.1, -0.4, 1.3, 0.1, -0.1, 0.3, 0.6]
    cm2 = [0.7, -0.15, -0.05, -0.45, 1.25, 0.2, -0.1, 0.2, 0.65]
    fm1 = [0.6, 0.25, 0.1142, 0.25, 0.8, -0.05, 0.05, -0.15, 0.9249]  # rows sum to D50
    fm2 = [0.65, 0.2, 0.1142, 0.28, 0.75, -0.03, 0.04, -0.1, 0.8849]
    ifd0 = t.ifd({
        254: (4, [1]), 256: (4, [32]), 257: (4, [24]), 258: (3, [8, 8, 8]), 259: (3, [1]), 262: (3, [2]),
        271: (2, "Fixture"), 272: (2, "Converter Layout 10"), 273: (4, [prev_off]), 274: (3, [6]),
        277: (3, [3]), 278: (4, [24]), 279: (4, [prev.nbytes]), 284: (3, [1]), 305: (2, "noisecal test fixture"),
        306: (2, "2026:01:02 03:04:05"), 330: (4, [raw]), 34665: (4, [exif]),
        50706: (1, [1, 4, 0, 0]), 50707: (1, [1, 1, 0, 0]), 50708: (2, "Fixture Converter Layout 10"),
        50721: (10, [_srat(x) for x in cm1]), 50722: (10, [_srat(x) for x in cm2]),
        50728: (5, [(4700, 10000), (1, 1), (6200, 10000)]), 50730: (10, [(-35, 100)]),
        50731: (5, [(120, 100)]), 50732: (5, [(90, 100)]), 50734: (5, [(8, 10)]),
        50778: (3, [17]), 50779: (3, [21]), 50936: (2, "Fixture profile"), 50941: (4, [3]),
        50964: (10, [_srat(x) for x in fm1]), 50965: (10, [_srat(x) for x in fm2]),
    })
    path.write_bytes(t.finish(ifd0))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory, cli: Path) -> dict:
    d = tmp_path_factory.mktemp("dng_sdk")
    run(cli, "simulate", "--dngs", d / "cal", "--width", "256", "--height", "192", "--frames", "4",
        "--isos", ",".join(map(str, CAL_ISOS)), "--seed", "5")
    run(cli, "calibrate", d / "cal", "-o", d / "p.pack")
    # The brightest unclipped ISO-100 frame: the most levels to check the NoiseProfile against.
    best = None
    for f in sorted((d / "cal").glob("*.dng")):
        px, meta = noisecal.read_dng(f)
        if meta["iso"] == 100 and px.max() < WHITE and (best is None or px.mean() > best[0]):
            best = (px.mean(), f, px)
    assert best is not None
    _, src, pixels = best
    ins = d / "in"
    ins.mkdir()
    android = ins / "android.dng"
    shutil.copy(src, android)

    import dngpy

    adobe = ins / "adobe_sdk.dng"
    sdk = dngpy.Dng(str(android))
    sdk.set_baseline_exposure(0.25)
    sdk.set_white_balance([0.5, 1.0, 0.75])
    from dngpy._native import DngGainMap  # not re-exported by dngpy 0.1.3

    gm = DngGainMap()
    gm.rows, gm.cols, gm.planes = 3, 4, 1
    gm.spacing_v, gm.spacing_h, gm.origin_v, gm.origin_h = 0.5, 1 / 3, 0.0, 0.0
    gm.data = np.linspace(1.0, 1.3, 12, dtype=np.float32).reshape(3, 4, 1)
    sdk.set_gainmap(gm)
    assert sdk.save(str(adobe)) == dngpy.ErrorCode.NONE
    del sdk

    converter = ins / "converter.dng"
    converter_layout_dng(converter, pixels)
    return {"dir": d, "pack_path": d / "p.pack", "pack": noisecal.Pack.load(d / "p.pack"),
            "android": android, "adobe_sdk": adobe, "converter": converter}


def test_fixtures_are_what_they_claim(inputs):
    """The inputs read in the SDK and carry what the other tests check is kept."""
    for name in ("android", "adobe_sdk", "converter"):
        v = read_ok(inputs[name])
        assert v.tags, "the SDK's tag dump (gVerbose) is needed to compare tags"
        assert v.api["meta"]["iso"] == 100
        assert not [m for m in v.messages if m.startswith("Error")], (name, v.messages)
    adobe = read_ok(inputs["adobe_sdk"])
    assert adobe.tag("NewRawImageDigest") and adobe.tag("RawDataUniqueID") and adobe.tag("XMP")
    assert adobe.api["gainmap"] is not None and adobe.api["white_balance"] == [0.5, 1.0, 0.75]
    conv = read_ok(inputs["converter"])
    assert conv.tag("Orientation")[0][1].startswith("6") and conv.tag("NoiseProfile")
    assert {ifd for ifd, _ in conv.tag("ColorMatrix2")} and conv.tag("DefaultCropOrigin")
    assert conv.api["data"]["top"] == 4 and conv.api["data"]["left"] == 8
    assert conv.api["meta"]["width"] == 256 - 16 and conv.api["meta"]["height"] == 192 - 16


# --- Deriving DNGs and judging them ---------------------------------------------------------

ISO_TAGS = {"ISOSpeedRatings", "PhotographicSensitivity", "ISOSpeed", "StandardOutputSensitivity",
            "RecommendedExposureIndex"}
# Tags the derived DNG may change: the ISO, the NoiseProfile, where the raw data and the IFDs are,
# the digests of the old pixels (dropped), the raw data's unique ID (changed).
MAY_CHANGE = ISO_TAGS | {"NoiseProfile", "RawImageDigest", "NewRawImageDigest", "RawDataUniqueID", "StripOffsets",
                         "StripByteCounts", "TileOffsets", "TileByteCounts", "SubIFDs",
                         "ExifIFD", "GPSInfo"}  # pointers: what they point to is compared




def _may_change(tag: str) -> bool:
    return tag in MAY_CHANGE or tag.startswith("TotalByteCount")


def new_messages(before: SdkView, after: SdkView) -> list[str]:
    """The SDK's messages on `after` that it does not give on `before` (those are not ours)."""
    return [m for m in after.messages if m not in before.messages]


def changed_tags(before: SdkView, after: SdkView) -> list[tuple[str, str]]:
    """(IFD, tag) of every tag added, removed or changed, but those a derived DNG may change."""
    keys = set(before.tags) | set(after.tags)
    return sorted(k for k in keys if not _may_change(k[1]) and before.tags.get(k) != after.tags.get(k))


def derive(how: str, src: Path, out: Path, inputs: dict) -> tuple[int, np.ndarray]:
    """Writes `out` from `src` by `how`; returns the requested ISO and the pixels written."""
    if how == "synth":
        run(inputs["_cli"], "synth", "--pack", inputs["pack_path"], "--iso", SYNTH_ISO, "--seed", 3, src, "-o", out)
        return SYNTH_ISO, noisecal.read_dng(out)[0]
    if how == "renoise":
        run(inputs["_cli"], "renoise", "--pack", inputs["pack_path"], src, "--to-iso", RENOISE_ISO, "--seed", 4,
            "-o", out)
        return RENOISE_ISO, noisecal.read_dng(out)[0]
    assert how == "write_dng"
    clean, meta = noisecal.read_dng(src)
    noisy = inputs["pack"].synth(clean, SYNTH_ISO, 9, black_level=meta["black"])
    noisecal.write_dng(out, noisy, template=src, iso=SYNTH_ISO, pack=inputs["pack"])
    return SYNTH_ISO, noisy


def noise_profile(v: SdkView) -> list[tuple[float, float]]:
    found = v.tag("NoiseProfile")
    assert len(found) == 1, f"{v.path.name}: NoiseProfile in {len(found)} IFDs"
    pairs = re.findall(r"scale = ([-+0-9.eE]+), offset = ([-+0-9.eE]+)", found[0][1])
    return [(float(s), float(o)) for s, o in pairs]


def check_profile_describes_noise(pairs, clean: np.ndarray, noisy: np.ndarray) -> None:
    """var(noisy − clean | clean) ≈ (S·x + O)·R² with x = (clean − black)/R, per CFA colour."""
    r = WHITE - BLACK
    planes = {"R": (0, 0), "Gr": (0, 1), "Gb": (1, 0), "B": (1, 1)}
    plane_of = {"R": 0, "Gr": 1, "Gb": 1, "B": 2}
    ratios = []
    for name, (dy, dx) in planes.items():
        c = clean[dy::2, dx::2].astype(np.float64).ravel()
        diff = noisy[dy::2, dx::2].astype(np.float64).ravel() - c
        s, o = pairs[plane_of[name]] if len(pairs) == 3 else pairs[0]
        for lo in range(int(BLACK + 20), int(c.max()) - 40, 40):
            sel = (c >= lo) & (c < lo + 40) & (noisy[dy::2, dx::2].ravel() < WHITE)
            if sel.sum() < 400:
                continue
            x = (c[sel].mean() - BLACK) / r
            ratios.append(diff[sel].var() / ((s * x + o) * r * r))
    assert len(ratios) >= 8, "too few levels to check the NoiseProfile against the pixels"
    med = float(np.median(ratios))
    assert 0.8 < med < 1.25, f"the NoiseProfile predicts {1 / med:.2f}× the added noise's variance ({ratios})"


CASES = [(how, name) for name in ("android", "adobe_sdk", "converter") for how in ("synth", "renoise", "write_dng")]


@pytest.mark.parametrize(("how", "name"), CASES, ids=[f"{h}-{n}" for h, n in CASES])
def test_sdk_reads_derived_dng_with_everything_kept(how, name, inputs, cli, tmp_path):
    inputs = {**inputs, "_cli": cli}
    src = inputs[name]
    before = read_ok(src)
    out = tmp_path / f"{how}_{name}.dng"
    iso, written = derive(how, src, out, inputs)
    after = read_ok(out)

    # 1. No validation message the input does not already have.
    new = new_messages(before, after)
    assert not new, f"the DNG SDK reports on {out.name} (and not on its input {src.name}): {new}"

    # 2. The requested ISO, in dngpy's API and in every ISO tag the input had (or one if it had none).
    assert after.api["meta"]["iso"] == iso
    iso_tags = {k: v for k, v in after.tags.items() if k[1] in ISO_TAGS}
    assert iso_tags, "no ISO tag in the output"
    for (ifd, tag), value in iso_tags.items():
        assert value.split()[0] == str(iso), f"{ifd} {tag} is {value!r}, not {iso}"
    assert {k for k in before.tags if k[1] in ISO_TAGS} <= set(iso_tags)

    # 3. A NoiseProfile: one pair per CFA colour (or one for all), positive, finite, describing the
    #    noise the output has over its clean input (synth, write_dng), growing with the ISO.
    pairs = noise_profile(after)
    assert len(pairs) in (1, 3), pairs
    assert all(math.isfinite(s) and math.isfinite(o) and s > 0 and o > 0 for s, o in pairs), pairs
    raw_ifd = next(ifd for (ifd, t) in after.tags if t == "CFAPattern")
    assert after.tag("NoiseProfile")[0][0] == raw_ifd, "the NoiseProfile is not in the raw IFD"
    if before.tag("NoiseProfile"):
        assert noise_profile(before) != pairs, "the input's NoiseProfile was kept"
    clean = noisecal.read_dng(src)[0]
    if how != "renoise":
        check_profile_describes_noise(pairs, clean, written)

    # 4. Every other tag the SDK parses is unchanged; the digests of the old pixels are gone.
    changed = changed_tags(before, after)
    assert not changed, f"{out.name} changed tags of {src.name}: " + "; ".join(
        f"{ifd} {t}: {before.tags.get((ifd, t))!r} -> {after.tags.get((ifd, t))!r}" for ifd, t in changed)
    assert not after.tag("RawImageDigest") and not after.tag("NewRawImageDigest")
    for (ifd, t), v in before.tags.items():
        if t == "RawDataUniqueID":
            assert after.tags.get((ifd, t)) not in (None, v), "RawDataUniqueID kept: converters would reuse caches"
    api_before = {k: v for k, v in before.api.items() if k != "meta"} | {
        k: v for k, v in before.api["meta"].items() if k != "iso"}
    api_after = {k: v for k, v in after.api.items() if k != "meta"} | {
        k: v for k, v in after.api["meta"].items() if k != "iso"}
    assert api_after == api_before

    # 5. The SDK decodes what was written, where noisecal reads it.
    t, l = after.api["data"]["top"], after.api["data"]["left"]
    h, w = written.shape
    np.testing.assert_array_equal(after.pixels[t:t + h, l:l + w], written)
    np.testing.assert_array_equal(after.pixels[t:t + h, l:l + w], noisecal.read_dng(out)[0])
    assert not np.array_equal(written, clean), "noise was added"


def test_noise_profile_grows_with_iso_and_renoise_writes_the_targets(inputs, cli, tmp_path):
    profiles = {}
    for iso in (100, 400, 800):
        out = tmp_path / f"s{iso}.dng"
        run(cli, "synth", "--pack", inputs["pack_path"], "--iso", iso, "--seed", 1, inputs["android"], "-o", out)
        profiles[iso] = noise_profile(read_ok(out))
    for plane in range(len(profiles[100])):
        scales = [profiles[iso][plane][0] for iso in (100, 400, 800)]
        assert scales[0] < scales[1] < scales[2], scales
    run(cli, "renoise", "--pack", inputs["pack_path"], inputs["android"], "--to-iso", 800, "-o", tmp_path / "r.dng")
    assert noise_profile(read_ok(tmp_path / "r.dng")) == profiles[800]


def _patch_ifd0_entry(path: Path, tag: int, *, ty: int | None = None, value: int | None = None) -> None:
    """Sets the type or the (inline SHORT) value of `tag` in IFD0 of a little-endian TIFF."""
    b = bytearray(path.read_bytes())
    assert b[:2] == b"II"
    off = struct.unpack_from("<L", b, 4)[0]
    for i in range(struct.unpack_from("<H", b, off)[0]):
        at = off + 2 + 12 * i
        if struct.unpack_from("<H", b, at)[0] == tag:
            if ty is not None:
                struct.pack_into("<H", b, at + 2, ty)
            if value is not None:
                struct.pack_into("<H", b, at + 8, value)
            path.write_bytes(bytes(b))
            return
    raise KeyError(tag)


def test_the_checks_see_a_changed_tag_and_a_new_sdk_message(inputs, cli, tmp_path):
    """What the tests above compare can fail: a flipped orientation is a changed tag, a CFALayout
    stored as LONG is an SDK warning the input does not have."""
    out = tmp_path / "o.dng"
    run(cli, "synth", "--pack", inputs["pack_path"], "--iso", SYNTH_ISO, inputs["android"], "-o", out)
    good = read_ok(out)
    assert not changed_tags(good, good) and not new_messages(good, good)
    flipped = tmp_path / "flipped.dng"
    shutil.copy(out, flipped)
    _patch_ifd0_entry(flipped, 274, value=3)
    assert changed_tags(good, read_ok(flipped)) == [("IFD 0", "Orientation")]
    retyped = tmp_path / "retyped.dng"
    shutil.copy(out, retyped)
    _patch_ifd0_entry(retyped, 50711, ty=4)
    assert any("CFALayout" in m for m in new_messages(good, read_ok(retyped)))
