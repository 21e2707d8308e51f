"""Writes burst-128x64x50.u16le from a clone of the EMVA 1288 datasets repository (README.md here).

    python3 tests/data/emva001/make_crop.py DATASETS [OUT]

DATASETS: a clone, bare or not, of github.com/EMVA1288/datasets. Needs numpy; the frames are
16-bit greyscale PNGs with filter type 0 on every row, read by tests/bench/png16.py (the real-data
bench's reader; any other PNG is refused).
"""

import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from png16 import ConvertError, read_png16  # noqa: E402  (a module under tests/bench, not a package)

SET = "EMVA1288_ReferenceSet_001_CCD_12Bit"
FRAMES = 50  # images/b_s_000_snap_000.png … _049.png: the 50-frame burst at 5.16 ms
X0, Y0, W, H = 256, 208, 128, 64  # the crop: the frame's centre (640 × 480), even offsets


def main() -> None:
    repo = Path(sys.argv[1])
    out = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(__file__).with_name("burst-128x64x50.u16le")
    crop = bytearray()
    for k in range(FRAMES):
        name = f"{SET}/images/b_s_000_snap_{k:03d}.png"
        data = subprocess.run(["git", "-C", str(repo), "show", f"HEAD:{name}"], capture_output=True, check=True).stdout
        try:
            frame = read_png16(data, name)
        except ConvertError as e:
            sys.exit(str(e))
        crop += frame[Y0 : Y0 + H, X0 : X0 + W].astype("<u2").tobytes()
    out.write_bytes(bytes(crop))
    print(f"{out}: {FRAMES} frames of {W}×{H} from x={X0}, y={Y0}, {len(crop)} bytes")


if __name__ == "__main__":
    main()
