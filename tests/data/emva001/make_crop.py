"""Writes burst-128x64x50.u16le from a clone of the EMVA 1288 datasets repository (README.md here).

    python3 tests/data/emva001/make_crop.py DATASETS [OUT]

DATASETS: a clone, bare or not, of github.com/EMVA1288/datasets. Standard library only: the
frames are 16-bit greyscale PNGs with filter type 0 on every row (any other is refused).
"""

import struct
import subprocess
import sys
import zlib
from pathlib import Path

SET = "EMVA1288_ReferenceSet_001_CCD_12Bit"
FRAMES = 50  # images/b_s_000_snap_000.png … _049.png: the 50-frame burst at 5.16 ms
X0, Y0, W, H = 256, 208, 128, 64  # the crop: the frame's centre (640 × 480), even offsets


def png16(data: bytes, name: str) -> tuple[int, int, bytes]:
    """A 16-bit greyscale, non-interlaced PNG as (width, height, filtered rows)."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        sys.exit(f"{name}: not a PNG file")
    at, idat, head = 8, [], None
    while at < len(data):
        (n,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + n]
        at += 12 + n
        if kind == b"IHDR":
            head = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
    if head is None or head[2:5] != (16, 0, 0) or head[6] != 0:
        sys.exit(f"{name}: not a 16-bit greyscale non-interlaced PNG")
    return head[0], head[1], zlib.decompress(b"".join(idat))


def main() -> None:
    repo = Path(sys.argv[1])
    out = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(__file__).with_name("burst-128x64x50.u16le")
    crop = bytearray()
    for k in range(FRAMES):
        name = f"{SET}/images/b_s_000_snap_{k:03d}.png"
        data = subprocess.run(["git", "-C", str(repo), "show", f"HEAD:{name}"], capture_output=True, check=True).stdout
        w, h, raw = png16(data, name)
        stride = 2 * w + 1
        for y in range(Y0, Y0 + H):
            row = raw[y * stride : (y + 1) * stride]
            if row[0] != 0:
                sys.exit(f"{name}: row {y} uses PNG filter {row[0]}; only filter 0 is read here")
            values = struct.unpack(f">{W}H", row[1 + 2 * X0 : 1 + 2 * (X0 + W)])
            crop += struct.pack(f"<{W}H", *values)
    out.write_bytes(bytes(crop))
    print(f"{out}: {FRAMES} frames of {W}×{H} from x={X0}, y={Y0}, {len(crop)} bytes")


if __name__ == "__main__":
    main()
