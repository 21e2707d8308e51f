from os import PathLike
from typing import Any, Literal, Sequence, TypedDict, final

import numpy as np
import numpy.typing as npt

from .seeds import seed_for as seed_for

__version__: str

Model = Literal["noisecal", "hg", "pg", "noiseprofile"]
Method = Literal["bridge", "quantile", "denoised", "naive"]
CleanAt = Literal["reference", "target"]
OutOfRange = Literal["raise", "warn", "allow"]
Mismatch = Literal["raise", "warn", "ignore"]

class NoisecalError(ValueError): ...
class InputError(NoisecalError): ...
class MismatchError(InputError): ...
class NoisecalWarning(UserWarning): ...

def _pack_from_bytes(data: bytes, pattern_cache_mb: int = 192) -> Pack: ...

class Layout(TypedDict):
    cfa: str
    black: list[float]
    white: int
    bits: int
    width: int
    height: int

class Tables(TypedDict):
    iso: int
    lut: npt.NDArray[np.int64]
    cdf: npt.NDArray[np.uint64]
    first: npt.NDArray[np.int32]
    range: npt.NDArray[np.int32]
    lattice: npt.NDArray[np.bool_]
    white: int
    gain_ratio: list[float]
    clean_at: CleanAt
    shift: npt.NDArray[np.float64]
    structure: list[str]

@final
class Pack:
    @staticmethod
    def load(path: str | PathLike[str]) -> Pack: ...
    @staticmethod
    def from_bytes(data: bytes) -> Pack: ...
    def to_bytes(self) -> bytes: ...
    def __reduce__(self) -> tuple[Any, tuple[bytes, int]]: ...
    def __copy__(self) -> Pack: ...
    def __deepcopy__(self, memo: Any) -> Pack: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    @property
    def isos(self) -> list[int]: ...
    @property
    def calibrated_isos(self) -> list[int]: ...
    @property
    def layout(self) -> Layout: ...
    @property
    def make(self) -> str: ...
    @property
    def model(self) -> str: ...
    @property
    def bin_width(self) -> int: ...
    @property
    def warnings(self) -> list[str]: ...
    @property
    def pattern_cache_mb(self) -> int: ...
    def set_pattern_cache_mb(self, mb: int) -> None: ...
    def synth(
        self,
        clean: npt.NDArray[np.uint16],
        iso: int,
        seed: int = 0,
        *,
        model: Model = "noisecal",
        black_level: float | Sequence[float] | None = None,
        cfa_origin: tuple[int, int] = (0, 0),
        extrapolate: bool = False,
        # "pixel,row,column,frame,fpn" in any combination, "all", or "own" (all but fpn: for a clean
        # image averaged from this sensor's own frames, which carries its fixed pattern already)
        components: str | None = None,
        clean_at: CleanAt = "reference",
        out_of_range: OutOfRange = "raise",
    ) -> npt.NDArray[np.uint16]: ...
    def synth_float(
        self,
        clean: npt.NDArray[np.float32],
        iso: int,
        seed: int = 0,
        *,
        model: Model = "noisecal",
        cfa_origin: tuple[int, int] = (0, 0),
        extrapolate: bool = False,
        # "pixel,row,column,frame,fpn" in any combination, "all", or "own" (all but fpn: for a clean
        # image averaged from this sensor's own frames, which carries its fixed pattern already)
        components: str | None = None,
        clean_at: CleanAt = "reference",
        out_of_range: OutOfRange = "raise",
    ) -> npt.NDArray[np.float32]: ...
    def renoise(
        self,
        noisy: npt.NDArray[np.uint16],
        from_iso: int,
        to_iso: int,
        seed: int = 0,
        *,
        method: Method = "bridge",
        black_level: float | Sequence[float] | None = None,
        extrapolate: bool = False,
        out_of_range: OutOfRange = "raise",
        estimate: npt.NDArray[np.float32] | None = None,
    ) -> npt.NDArray[np.uint16]: ...
    def interp(self, isos: Sequence[int], *, extrapolate: bool = False) -> Pack: ...
    def gain_ratios(self, iso: int, *, extrapolate: bool = False) -> list[float]: ...
    def tables(
        self, iso: int, *, model: Model = "noisecal", extrapolate: bool = False, clean_at: CleanAt = "reference"
    ) -> Tables: ...

def calibrate(
    path: str | PathLike[str],
    *,
    reference_iso: int | None = None,
    bin_width: int | None = None,
    pooling: int | None = None,
    plain: bool = False,
) -> Pack: ...
def read_dng(
    path: str | PathLike[str], *, pack: Pack | None = None, mismatch: Mismatch = "raise"
) -> tuple[npt.NDArray[np.uint16], dict[str, Any]]: ...
def write_dng(
    path: str | PathLike[str],
    pixels: npt.NDArray[np.uint16],
    *,
    template: str | PathLike[str],
    iso: int,
    pack: Pack | None = None,
) -> None: ...
def write_raw_dng(
    path: str | PathLike[str],
    pixels: npt.NDArray[np.uint16],
    *,
    cfa: str,
    black: Sequence[float],
    white: int,
    iso: int,
    exposure_ns: int,
    make: str = "noisecal",
    model: str = "converted",
) -> None: ...
def rounded_gaussian_sd(var: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
def rounded_variance(sd: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
