"""The compiled module; use the functions of `chirpmap` instead."""

import os
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

def simulate(scene_kind: str, scene_payload: Union[str, "os.PathLike[str]"], seed: Optional[int] = None) -> Dict[str, Any]: ...
def map_echoes(
    echoes: npt.NDArray[np.float64],
    sigma: Optional[npt.NDArray[np.float64]],
    bounds: Optional[List[float]],
    cell: float,
    keep_top: Optional[float],
    min_of_max: Optional[float],
    peak_radius: Optional[float],
    ellipse_points: int,
    mapper: str,
    evidence_json: Optional[str],
) -> Dict[str, Any]: ...
def synth(
    scene_kind: str, scene_payload: Union[str, "os.PathLike[str]"]
) -> Tuple[npt.NDArray[np.float32], int, List[npt.NDArray[np.float64]]]: ...
def range(
    samples: npt.NDArray[np.float32],
    sample_rate: float,
    speaker: List[float],
    mic: List[float],
    wall_normal: Optional[List[float]],
    methods: List[str],
    primary: int,
    f_start: float,
    f_end: float,
    duration: float,
    speed_of_sound: float,
    max_delta_d: Optional[float],
) -> str: ...
def echoes_from_recording(
    samples: npt.NDArray[np.float32],
    sample_rate: float,
    poses: npt.NDArray[np.float64],
    speaker: List[float],
    method: str,
    period_s: float,
    frame_s: Optional[float],
    listener: int,
    f_start: float,
    f_end: float,
    duration: float,
    speed_of_sound: float,
    max_delta_d: Optional[float],
    pattern: Optional[str] = None,
    echoes_per_frame: Optional[int] = None,
    sweep: Optional[str] = None,
) -> Tuple[npt.NDArray[np.float64], int, int, npt.NDArray[np.float64]]: ...
def room_echoes(
    samples: npt.NDArray[np.float32],
    sample_rate: float,
    speaker: List[float],
    mic: List[float],
    heights: Optional[Tuple[float, float]],
    floor_z: Optional[float],
    ceiling_z: Optional[float],
    input: str,
    calibration: Optional[npt.NDArray[np.float32]],
    max_echoes: int,
    echo_threshold_db: float,
    ringing_ms: float,
    echo_atom_ms: float,
    plane_tolerance: float,
    listener: int,
    f_start: float,
    f_end: float,
    duration: float,
    speed_of_sound: float,
    max_delta_d: Optional[float],
    sweep: str,
) -> Dict[str, Any]: ...
def room_echo_defaults() -> Dict[str, Any]: ...
def after_fork() -> None: ...
