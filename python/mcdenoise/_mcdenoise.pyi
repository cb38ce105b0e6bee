"""Type stubs of the mcdenoise extension module."""
from os import PathLike
from typing import Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[Union[np.float32, np.float16]]
Path = Union[str, "PathLike[str]"]

__version__: str
METHODS: List[str]

def denoise(
    color: Array,
    albedo: Optional[Array] = None,
    normal: Optional[Array] = None,
    depth: Optional[Array] = None,
    position: Optional[Array] = None,
    motion: Optional[Array] = None,
    second: Optional[Array] = None,
    method: str = "atrous",
    precision: str = "f32",
    threads: Optional[int] = None,
    *,
    layers: int = 6,
    weights: Optional[str] = None,
    refine: bool = True,
    fallback: bool = True,
    phi_color: Optional[float] = None,
    firefly_clamp: Optional[float] = None,
    ta_clamp: Optional[float] = None,
    ta_reject: Optional[float] = None,
    ta_reject_scales: Optional[int] = None,
    pair: str = "mean",
    seed: int = ...,
    cross_lr: float = 1e-3,
    cross_spatial_only: bool = False,
    load_state: Optional[str] = None,
    save_state: Optional[str] = None,
    isa: Optional[str] = None,
) -> npt.NDArray[np.float32]:
    """Denoises one frame; see help(mcdenoise.denoise)."""

class Denoiser:
    """A denoiser for a sequence (keeps temporal state between frames)."""

    def __init__(
        self,
        method: str = "atrous",
        precision: str = "f32",
        threads: Optional[int] = None,
        *,
        layers: int = 6,
        weights: Optional[str] = None,
        refine: bool = True,
        fallback: bool = True,
        phi_color: Optional[float] = None,
        firefly_clamp: Optional[float] = None,
        ta_clamp: Optional[float] = None,
        ta_reject: Optional[float] = None,
        ta_reject_scales: Optional[int] = None,
        pair: str = "mean",
        seed: int = ...,
        cross_lr: float = 1e-3,
        cross_spatial_only: bool = False,
        load_state: Optional[str] = None,
        save_state: Optional[str] = None,
        isa: Optional[str] = None,
    ) -> None: ...
    def denoise(
        self,
        color: Array,
        albedo: Optional[Array] = None,
        normal: Optional[Array] = None,
        depth: Optional[Array] = None,
        position: Optional[Array] = None,
        motion: Optional[Array] = None,
        second: Optional[Array] = None,
    ) -> npt.NDArray[np.float32]:
        """Denoises the next frame of the sequence."""
    def reset(self) -> None:
        """Starts a new sequence."""
    def save_state(self, path: Path) -> None:
        """Writes cross-regression's state."""
    def load_state(self, path: Path) -> None:
        """Starts the next sequence from a saved cross-regression state."""
    @property
    def plan(self) -> Optional[str]: ...
    @property
    def frames(self) -> int: ...
    def timings(self) -> List[Tuple[str, float]]: ...

def read_exr(path: Path) -> Dict[str, npt.NDArray[np.float32]]:
    """The buffers of a frame file, as the command line reads them."""
