"""Type stubs of chirpmap (see __init__.py for the full docstrings)."""

import os
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str
ECHO_COLUMNS: Tuple[str, ...]

SceneLike = Union[None, str, os.PathLike[str], Dict[str, Any]]

@dataclass(frozen=True, eq=False)
class MapResult:
    """A finished map: grid (ny, nx) rows = y, extent (x_min, x_max, y_min, y_max)."""

    grid: npt.NDArray[np.float64]
    extent: Tuple[float, float, float, float]
    bounds: Tuple[float, float, float, float]
    cell: float
    highlights: npt.NDArray[np.float64]
    surfaces: List[Dict[str, Any]]
    cells_updated: int
    mapping: Dict[str, Any]

@dataclass(frozen=True, eq=False)
class Simulation(MapResult):
    """One simulated run: echoes (n, 9), its map, scores and resolved scene."""

    echoes: npt.NDArray[np.float64]
    scores: Dict[str, Any]
    scene: str
    seed: int
    n_measurements: int
    n_obstacles: int
    simulate_elapsed_s: float

def simulate(scene: SceneLike = None, seed: Optional[int] = None) -> Simulation:
    """Simulate a scene (particle model, paper §II.B), map it and score it."""

def read_echoes(path: Union[str, os.PathLike[str]]) -> npt.NDArray[np.float64]:
    """An echoes.csv read by column name as the (n, 9) array map_echoes takes."""

def map_echoes(
    echoes: npt.ArrayLike,
    bounds: Optional[Sequence[float]] = None,
    cell: float = 0.1,
    mapper: str = "paper",
    keep_top: Optional[float] = None,
    min_of_max: Optional[float] = None,
    peak_radius: Optional[float] = None,
    sigma: Union[None, float, npt.ArrayLike] = None,
    evidence: Optional[Dict[str, Any]] = None,
    ellipse_points: int = 0,
) -> MapResult:
    """Map echoes (n, 5..9) with Algorithm 1 or the evidence mapper."""

def synth(
    scene: SceneLike = None,
) -> Tuple[npt.NDArray[np.float32], int, List[npt.NDArray[np.float64]]]:
    """Render what each listener records: (samples (n, listeners), rate, poses)."""

def range(
    samples: npt.ArrayLike,
    sample_rate: float,
    speaker: Sequence[float],
    mic: Sequence[float],
    wall_normal: Optional[Sequence[float]] = None,
    method: str = "gap",
    f_start: float = 10000.0,
    f_end: float = 200.0,
    duration: float = 0.5,
    speed_of_sound: float = 343.0,
    max_delta_d: Optional[float] = None,
    compare: bool = False,
    channel: int = 0,
) -> Dict[str, Any]:
    """Range a recording (paper §IV): the keys of range's summary.json."""

@dataclass(frozen=True, eq=False)
class RecordingEchoes:
    """Echoes (n, 8 or 9) of a moving listener's recording, with chirp counts."""

    echoes: npt.NDArray[np.float64]
    chirps: int
    chirps_without_pose: int
    delta_d_rate: npt.NDArray[np.float64]

def echoes_from_recording(
    samples: npt.ArrayLike,
    sample_rate: float,
    poses: npt.ArrayLike,
    speaker: Sequence[float],
    method: str = "doppler",
    period_ms: float = 10.0,
    frame_ms: Optional[float] = None,
    f_start: float = 10000.0,
    f_end: float = 200.0,
    duration: float = 0.5,
    speed_of_sound: float = 343.0,
    max_delta_d: Optional[float] = None,
    channel: int = 0,
    pattern: Optional[str] = None,
    echoes_per_frame: Optional[int] = None,
    sweep: str = "linear",
) -> RecordingEchoes:
    """Echoes of a moving listener's recording (chirpmap map --wav)."""

ROOM_ECHO_COLUMNS: Tuple[str, ...]

@dataclass(frozen=True, eq=False)
class RoomEchoes:
    """Every reflection of every chirp (chirpmap range --echoes): echoes (n, 8) for the map, and per echo
    chirp, rank, path_delta_m, strength_db, plane; the chirps' onsets, clusters, echogram (m, 2), predictions."""

    echoes: npt.NDArray[np.float64]
    chirp: npt.NDArray[np.int64]
    rank: npt.NDArray[np.int64]
    path_delta_m: npt.NDArray[np.float64]
    strength_db: npt.NDArray[np.float64]
    plane: npt.NDArray[np.str_]
    chirp_onsets_s: npt.NDArray[np.float64]
    clusters: List[Dict[str, Any]]
    echogram: npt.NDArray[np.float64]
    predicted: List[Dict[str, Any]]
    min_delta_d_m: float
    max_delta_d_m: float
    calibrated: bool
    def table(self) -> npt.NDArray[np.void]:
        """The rows of echoes.csv as a structured array (fields: ROOM_ECHO_COLUMNS)."""

def room_echoes(
    samples: npt.ArrayLike,
    sample_rate: float,
    speaker: Sequence[float],
    mic: Sequence[float],
    *,
    input: str = "recording",
    max_echoes: int = 20,
    floor_z: Optional[float] = None,
    ceiling_z: Optional[float] = None,
    calibration: Optional[npt.ArrayLike] = None,
    echo_threshold_db: float = -30.0,
    ringing_ms: float = 2.0,
    echo_atom_ms: float = 0.6,
    plane_tolerance: float = 0.08,
    f_start: float = 10000.0,
    f_end: float = 200.0,
    duration: float = 0.5,
    speed_of_sound: float = 343.0,
    max_delta_d: Optional[float] = None,
    sweep: str = "linear",
    channel: int = 0,
    listener: Optional[int] = None,
) -> RoomEchoes:
    """Every reflection of every chirp in a room (chirpmap range --echoes; input="rir": --input rir)."""
