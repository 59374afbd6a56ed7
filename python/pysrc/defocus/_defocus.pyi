"""Type stubs of the native module ``defocus._defocus`` (python/src/lib.rs).

The public API, with its documentation, is ``defocus/__init__.py``. These stubs follow the
``#[pyfunction]`` signatures parameter for parameter: ``python/tests/test_stubs.py`` compares
them with the compiled module's ``inspect.signature``.
"""

from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np

__version__: str

def blur(
    color: np.ndarray,
    depth: np.ndarray,
    method: str,
    depth_kind: str,
    depth_scale: float,
    zero_depth_is_far: bool,
    focus: Union[float, str, None],
    focus_pixel: Optional[Tuple[int, int]],
    fstop: float,
    focal_length: float,
    sensor_width: float,
    aperture: str,
    seed: int,
    flags: List[str],
    highlights: Optional[str] = None,
    timings: bool = False,
    device: str = "auto",
) -> Union[np.ndarray, Tuple[np.ndarray, Dict[str, Any]]]: ...
def render(
    scene: str,
    method: str,
    width: Optional[int],
    height: Optional[int],
    samples: Optional[int],
    seed: int,
    sampler: str,
    focus: Union[float, str, None],
    focus_pixel: Optional[Tuple[int, int]],
    fstop: Optional[float],
    focal_length: Optional[float],
    sensor_width: Optional[float],
    aperture: Optional[str],
    camera: Optional[str],
    allow_external_files: bool,
    with_depth: bool,
    flags: List[str],
    device: str = "auto",
) -> Tuple[np.ndarray, Optional[np.ndarray]]: ...
def compare(a: np.ndarray, b: np.ndarray) -> Dict[str, float]: ...
def report(flags: List[str]) -> Tuple[str, str, List[str]]: ...
def methods() -> List[Dict[str, Any]]: ...
def scenes() -> List[str]: ...
def blur_sequence(
    flags: List[str],
) -> Tuple[List[int], List[int], List[Tuple[int, str]], int, float]: ...
def check_array(name: str, shape: List[int], color: bool) -> None: ...
