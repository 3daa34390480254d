# Type stubs of the package cvt_engine (docs/python.md). Units: times in s, torques in N m,
# forces in N, speeds in rad/s, ratios and efficiencies dimensionless.
import os
from typing import Any, Callable, Mapping, Sequence, Union

import numpy as np
import numpy.typing as npt

from ._core import BlowUpError as BlowUpError
from ._core import Config as Config
from ._core import ConfigError as ConfigError
from ._core import OutputError as OutputError

__version__: str

Path = Union[str, os.PathLike[str]]
Value = Union[bool, int, float, str, Sequence[Any], npt.NDArray[Any]]
Overrides = Union[Mapping[str, Value], Sequence[str], None]
Row = dict[str, Any]

def shipped_config(name: str) -> str: ...
def load_config(path: Path, overrides: Overrides = ...) -> Config: ...
def parse_config(text: str, overrides: Overrides = ..., origin: str = ...) -> Config: ...
def config_value(config: Config, key: str) -> Any: ...
def model_info(config: Union[Path, Config]) -> dict[str, Any]: ...
def read_channels(path: Path) -> dict[str, npt.NDArray[np.float64]]: ...

class Result:
    summary: dict[str, Any]
    channels: dict[str, npt.NDArray[np.float64]]
    file: Union[str, None]
    units: dict[str, str]
    def __init__(self, summary: dict[str, Any], channels: dict[str, npt.NDArray[np.float64]],
                 file: Union[str, None], units: Union[Mapping[str, str], None] = ...) -> None: ...
    def to_pandas(self) -> Any: ...
    def to_xarray(self) -> Any: ...

def run(config: Union[Path, Config], *, overrides: Overrides = ..., t_end: Union[float, None] = ...,
        until_steady: Union[bool, None] = ..., step: Union[float, None] = ..., method: Union[str, None] = ...,
        out: Union[Path, None] = ..., threads: int = ..., scheduler: Union[str, None] = ..., grain: int = ...,
        quiet: bool = ..., progress: Union[Callable[[dict[str, float]], Any], None] = ...,
        progress_seconds: float = ..., checkpoint_every: int = ..., channels: bool = ...) -> Result: ...
def resume(checkpoint: Path, *, t_end: Union[float, None] = ..., out: Union[Path, None] = ...,
           overrides: Overrides = ..., threads: int = ..., scheduler: Union[str, None] = ..., grain: int = ...,
           quiet: bool = ..., progress: Union[Callable[[dict[str, float]], Any], None] = ...,
           progress_seconds: float = ..., checkpoint_every: int = ..., channels: bool = ...) -> Result: ...
def read_units(path: Path) -> dict[str, str]: ...
def sweep(config: Union[Path, None] = ..., *, axes: Union[Mapping[str, Sequence[Value]], None] = ...,
          points: Union[Path, None] = ..., out: str = ..., overrides: Overrides = ...,
          from_checkpoint: Union[Path, None] = ..., keep_runs: bool = ..., warm_ramp: float = ...,
          threads: int = ..., scheduler: Union[str, None] = ..., grain: int = ..., quiet: bool = ...,
          log: Union[Callable[[str], Any], None] = ...) -> list[Row]: ...
def study_slip(config: Path, *, clamping: Sequence[float], thrust_ratio: float = ...,
               ratios: Union[Sequence[Value], None] = ..., tolerance: float = ..., out: Path = ...,
               overrides: Overrides = ..., threads: int = ..., scheduler: Union[str, None] = ..., grain: int = ...,
               quiet: bool = ..., log: Union[Callable[[str], Any], None] = ...) -> list[Row]: ...
def study_shift(config: Path, *, thrust_ratios: Sequence[float], speeds: Union[Sequence[float], None] = ...,
                settle: float = ..., window: float = ..., steady_bound: float = ..., out: Path = ...,
                overrides: Overrides = ..., threads: int = ..., scheduler: Union[str, None] = ..., grain: int = ...,
                quiet: bool = ..., log: Union[Callable[[str], Any], None] = ...) -> list[Row]: ...
