"""chirpmap: turn sound into maps.

The pipeline of *Acoustic Ellipses* (Swissler, Burke, Hyland Bruno, 2026): a
stationary Source plays a frequency sweep, a moving Listener hears the direct
and the reflected sound at once, each frequency gap is a path-length
difference Δd (paper Eq. 1-3), each Δd an ellipse of possible reflection
points (Eq. 4), and ellipses accumulated on a grid reveal obstacles
(Algorithm 1), which the scores of §III.A judge.

This package wraps the Rust library (crate ``chirpmap``) that the
``chirpmap`` command-line tool runs, so the numbers are the CLI's, bit for
bit, for the same inputs:

>>> import chirpmap, matplotlib.pyplot as plt
>>> run = chirpmap.simulate(seed=3)
>>> plt.imshow(run.grid, extent=run.extent, origin="lower")

Functions: :func:`simulate`, :func:`map_echoes`, :func:`synth`, :func:`range`,
:func:`echoes_from_recording`, :func:`room_echoes`, :func:`read_echoes`.
Results compare by identity (their arrays have no single truth value);
compare their fields with ``np.array_equal``. Calls work in forked
children (``multiprocessing``'s fork start method, the default on Linux
before Python 3.14): each process runs its own threads.
Arrays come back as numpy arrays that own Rust's buffers (no copies); every
long step runs with the GIL released, and Ctrl-C interrupts it within 50 ms
(the interrupted work finishes in the background and is dropped; the next
call waits for it, with a :class:`RuntimeWarning`). Bad input raises
:class:`ValueError` with the CLI's message.
"""

from __future__ import annotations

import json
import operator
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _chirpmap

__version__: str = _chirpmap.__version__

if hasattr(os, "register_at_fork"):
    # A child's first call builds its own threads (see _chirpmap's pool).
    os.register_at_fork(after_in_child=_chirpmap.after_fork)

__all__ = [
    "ECHO_COLUMNS",
    "MapResult",
    "ROOM_ECHO_COLUMNS",
    "RecordingEchoes",
    "RoomEchoes",
    "Simulation",
    "echoes_from_recording",
    "map_echoes",
    "range",
    "read_echoes",
    "room_echoes",
    "simulate",
    "synth",
]

#: Columns of the echo arrays, as in echoes.csv: the first five are required;
#: ``weight`` (default 1), ``t`` (s, default 0), ``listener`` (id, default 0)
#: and ``sigma_m`` (1-σ uncertainty of ``delta_d``, m; NaN = none) may follow.
ECHO_COLUMNS: Tuple[str, ...] = (
    "source_x",
    "source_y",
    "listener_x",
    "listener_y",
    "delta_d",
    "weight",
    "t",
    "listener",
    "sigma_m",
)

SceneLike = Union[None, str, "os.PathLike[str]", Dict[str, Any]]


@dataclass(frozen=True, eq=False)
class MapResult:
    """A finished map.

    Attributes:
        grid: ``(ny, nx)`` float64 map, rows = y, row 0 at ``bounds[1]``:
            accumulated ellipse weights (paper mapper) or log-odds of
            occupancy (evidence mapper). Draw it with
            ``plt.imshow(grid, extent=extent, origin="lower")``.
        extent: ``(x_min, x_max, y_min, y_max)`` in m, matplotlib's
            ``imshow`` order (note: not the order of ``bounds``).
        bounds: ``(x_min, y_min, x_max, y_max)`` in m, the order of the
            ``bounds`` argument and of the CLI's ``--bounds``.
        cell: grid cell side (m).
        highlights: ``(n, 3)`` float64 ``x, y, value``: local maxima of the
            map, the rows of highlights.csv in the same order.
        surfaces: reflecting surfaces found by the evidence mapper (empty
            with the paper's mapper), strongest first, each a dict with
            ``kind`` ("line" or "point"), ``x0, y0, x1, y1`` (a point's
            ``x1, y1`` equal ``x0, y0``), ``support`` (echoes explained) and
            ``ambiguous`` (mirror-ambiguous: collinear foci).
        cells_updated: cell updates made while mapping (a work measure).
        mapping: the mapping parameters used (the scene's ``[mapping]``).
    """

    grid: np.ndarray
    extent: Tuple[float, float, float, float]
    bounds: Tuple[float, float, float, float]
    cell: float
    highlights: np.ndarray
    surfaces: List[Dict[str, Any]]
    cells_updated: int
    mapping: Dict[str, Any] = field(repr=False)

    def __repr__(self) -> str:
        ny, nx = self.grid.shape
        return (
            f"MapResult(grid={ny}x{nx}, extent={self.extent}, "
            f"highlights={len(self.highlights)}, surfaces={len(self.surfaces)})"
        )


@dataclass(frozen=True, repr=False, eq=False)
class Simulation(MapResult):
    """One simulated run (paper §II.B): echoes, their map and its scores.

    Besides the fields of :class:`MapResult` (the map on the scene's world):

    Attributes:
        echoes: ``(n, 9)`` float64 in the columns of echoes.csv
            (:data:`ECHO_COLUMNS`; ``sigma_m``, the Δd uncertainty of a
            particle echo, last), the CLI's rows.
        scores: summary.json's scores: ``score_obstacle`` and
            ``score_highlight`` (paper §III.A; None when the scene has no
            obstacles), and the surface metrics against the scene's
            obstacles (issue 9; of the surfaces, or of the highlights as
            points for the paper mapper): ``surface_precision``,
            ``surface_recall``, ``surface_f1`` (within 0.1 m),
            ``chamfer_m`` (None when either side is empty) and ``walls``
            (per true wall: ``a``, ``b``, and its best line's ``offset_m``
            and ``angle_deg``, None when no line matches).
        scene: the resolved scene as TOML (random obstacles listed, duration
            explicit): ``simulate(run.scene)`` replays the run exactly.
        seed: the master seed used.
        n_measurements: listener measurements taken.
        n_obstacles: obstacles in the scene.
        simulate_elapsed_s: wall time of the particle simulation alone (s).
    """

    echoes: np.ndarray = field(default_factory=lambda: np.zeros((0, 8)))
    scores: Dict[str, Any] = field(default_factory=dict)
    scene: str = ""
    seed: int = 0
    n_measurements: int = 0
    n_obstacles: int = 0
    simulate_elapsed_s: float = 0.0

    def __repr__(self) -> str:
        return (
            f"Simulation(seed={self.seed}, echoes={len(self.echoes)}, "
            f"highlights={len(self.highlights)}, scores={self.scores})"
        )


def _map_kwargs(d: Dict[str, Any]) -> Dict[str, Any]:
    d = dict(d)
    d["mapping"] = json.loads(d["mapping"])
    return d


def _float(name: str, value: Any) -> float:
    """``float(value)``, with errors that name the argument."""
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"{name} must be a number, not {type(value).__name__}")
    try:
        return float(value)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} must be a number: {e}") from None


def _json_default(value: Any) -> Any:
    """numpy's scalars and arrays in a scene or ``evidence`` dict, as the
    Python numbers and lists they hold (``json`` knows neither)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"a value of type {type(value).__name__} is not a number, string, list or dict")


def _is_toml(text: str) -> bool:
    """Whether ``text`` parses as TOML (Python 3.11's tomllib); on older
    Pythons, whether it has a key (``x = ...``) with a space before the
    value, which a path hardly has."""
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        import re

        return re.search(r"\s=|=\s", text) is not None
    try:
        tomllib.loads(text)
        return True
    except tomllib.TOMLDecodeError:
        return False


def _check_integers(value: Any, at: str) -> None:
    """Refuses an integer a scene cannot hold (TOML's are 64-bit signed),
    naming its key; JSON would turn it into a float silently."""
    if isinstance(value, dict):
        for k, v in value.items():
            _check_integers(v, f"{at}.{k}" if at else str(k))
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_integers(v, f"{at}[{i}]")
    elif isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if not -(2**63) <= int(value) <= 2**63 - 1:
            raise ValueError(f"scene dict: `{at}` is {int(value)}, beyond a TOML integer's range (±2^63)")


def _scene_source(scene: SceneLike) -> Tuple[str, str]:
    """(kind, payload) for the compiled module: how to read ``scene``."""
    if scene is None:
        return "default", ""
    if isinstance(scene, dict):
        try:
            _check_integers(scene, "")
            return "json", json.dumps(scene, allow_nan=False, default=_json_default)
        except (TypeError, ValueError) as e:
            raise ValueError(f"scene dict: {e}") from None
        except RecursionError:
            raise ValueError("scene dict: nested too deeply to be a scene") from None
    if isinstance(scene, os.PathLike):
        return "path", os.fspath(scene)
    if isinstance(scene, str):
        # TOML text holds a key (`=`), a table header or a line break; a bare
        # name is a path, so a missing file is reported as one.
        if "=" in scene or "[" in scene or "\n" in scene or scene.strip() == "":
            # One line naming a .toml file that is not TOML text is a path,
            # `=` or `[` in it or not (hydra's run directories: runs/a=1.toml).
            one_path = "\n" not in scene and scene.strip().lower().endswith(".toml") and not _is_toml(scene)
            if os.path.isfile(scene) or one_path:
                return "path", scene
            return "toml", scene
        return "path", scene
    raise TypeError(
        f"scene must be None, a dict, TOML text or a path, not {type(scene).__name__}"
    )


def simulate(scene: SceneLike = None, seed: Optional[int] = None) -> Simulation:
    """Simulate a scene with the paper's particle model, map it, score it.

    The same as ``chirpmap simulate [SCENE.toml] --seed SEED``: the same
    echoes, map, highlights and scores, bit for bit.

    Args:
        scene: ``None`` for the paper's default scene (three random circles,
            one listener at 10 m/s); a dict shaped like the scene TOML
            (``{"seed": 3, "listeners": [{"start": [-2, 10]}]}``); TOML text;
            or the path (str or ``os.PathLike``) of a scene file. Every field
            is optional, unknown keys are errors (see the README's table).
        seed: master seed (0 to 2**63 - 1), overriding the scene's ``seed``.

    Returns:
        A :class:`Simulation`.

    Raises:
        ValueError: the scene is invalid (the message names the field).
    """
    if seed is not None:
        # Any integer type (numpy's too), but not a bool or a float.
        if isinstance(seed, bool) or not hasattr(seed, "__index__"):
            raise TypeError(f"seed must be an int, not {type(seed).__name__}")
        seed = operator.index(seed)
    if seed is not None and not 0 <= seed <= 2**63 - 1:
        raise ValueError(
            f"seed: must be between 0 and 2^63 - 1 (scene.toml records it as a TOML integer), got {seed}"
        )
    kind, payload = _scene_source(scene)
    d = _chirpmap.simulate(kind, payload, seed)
    return Simulation(**_map_kwargs(d))


def read_echoes(path: Union[str, "os.PathLike[str]"]) -> np.ndarray:
    """An echoes.csv as the ``(n, 9)`` array :func:`map_echoes` takes.

    Columns are found by the header's names, as ``chirpmap map --echoes``
    reads them (docs/file-formats.md), not by position: a file from ``map
    --wav --method doppler`` has ``delta_d_rate`` where a positional reader
    such as ``np.loadtxt`` would take ``sigma_m``. Absent columns and empty
    cells take their defaults (``weight`` 1, ``t`` 0, ``listener`` 0,
    ``sigma_m`` NaN = none); other columns are left out. Values are checked
    by :func:`map_echoes`, whose errors name the row (``echoes[i]``: the
    ``i``-th row of data, blank lines not counted).

    Raises:
        ValueError: no header, a required column missing or given twice, a
            row of the wrong length, or a cell that is not a finite number
            (the message names the file and line).
        OSError: the file cannot be read.
    """
    import csv

    name = os.fspath(path)
    defaults = {"weight": 1.0, "t": 0.0, "listener": 0.0, "sigma_m": float("nan")}
    # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark; bytes
    # that are not UTF-8 (in a column left out, say) become U+FFFD.
    with open(name, newline="", encoding="utf-8-sig", errors="replace") as f:
        rows = csv.reader(f)
        header = [h.strip() for h in next(rows, [])]
        if not header or header == [""]:
            raise ValueError(f"{name}:1: no header (the columns are named in the first line)")
        for k, h in enumerate(header):
            if h and h in header[:k]:
                raise ValueError(f"{name}:1: column `{h}` appears twice in the header")
        idx = {h: header.index(h) for h in ECHO_COLUMNS if h in header}
        missing = [h for h in ECHO_COLUMNS[:5] if h not in idx]
        if missing:
            raise ValueError(f"{name}:1: missing column `{missing[0]}` (header must include {','.join(ECHO_COLUMNS[:5])})")
        out = []
        for row in rows:
            line = rows.line_num
            if not row:
                continue
            if len(row) != len(header):
                raise ValueError(f"{name}:{line}: {len(row)} fields where the header has {len(header)}")
            values = []
            for h in ECHO_COLUMNS:
                cell = row[idx[h]].strip() if h in idx else ""
                if cell == "":
                    if h not in defaults:
                        raise ValueError(f"{name}:{line}: missing value for `{h}`")
                    values.append(defaults[h])
                    continue
                # Rust's number syntax, as the CLI reads it: no `1_0`.
                try:
                    v = float(cell) if "_" not in cell else None
                except ValueError:
                    v = None
                if v is None:
                    raise ValueError(f"{name}:{line}: `{h}` = {cell[:40]!r} is not a number")
                if not np.isfinite(v):
                    raise ValueError(f"{name}:{line}: `{h}` = {cell[:40]!r} is not finite")
                values.append(v)
            out.append(values)
    return np.array(out, dtype=np.float64).reshape(len(out), len(ECHO_COLUMNS))


def map_echoes(
    echoes: Any,
    bounds: Optional[Sequence[float]] = None,
    cell: float = 0.1,
    mapper: str = "paper",
    keep_top: Optional[float] = None,
    min_of_max: Optional[float] = None,
    peak_radius: Optional[float] = None,
    sigma: Union[None, float, Any] = None,
    evidence: Optional[Dict[str, Any]] = None,
    ellipse_points: int = 0,
) -> MapResult:
    """Map echoes: Algorithm 1 of the paper, or the evidence mapper.

    The same as ``chirpmap map --echoes E.csv`` with the same options: the
    same grid, highlights (highlights.csv) and surfaces (surfaces.csv).

    Args:
        echoes: ``(n, k)`` array-like, ``k`` from 5 to 9, in the columns of
            echoes.csv (:data:`ECHO_COLUMNS`): ``source_x, source_y,
            listener_x, listener_y, delta_d`` then optionally ``weight``
            (default 1), ``t`` (s), ``listener`` (integer id) and ``sigma_m``
            (m, NaN = none). Copied once, as float64. Read a CSV with
            :func:`read_echoes` (by column name), not by position.
        bounds: grid bounds ``(x_min, y_min, x_max, y_max)`` in m; ``None``
            covers every ellipse (snapped outward to whole cells, plus one).
        cell: grid cell side (m). Paper: 0.1.
        mapper: ``"paper"`` (Algorithm 1) or ``"evidence"`` (surfaces, free
            space, ghosts removed; the map is log-odds of occupancy).
        keep_top: fraction of non-zero cells kept by the percentile threshold
            (Algorithm 1 only; ``None``: 0.1).
        min_of_max: cells below this fraction of the maximum are zeroed
            (Algorithm 1 only; ``None``: 0.01).
        peak_radius: a highlight is the maximum within this radius (m)
            (Algorithm 1 only; ``None``: 5.0). The evidence mapper refuses
            these three, as ``chirpmap map`` does: its highlights are set in
            ``evidence`` (``peak_radius_m``, ``highlight_min_logodds``).
        sigma: the 1-σ uncertainty of Δd (m) for the evidence mapper: one
            number for every echo, or an ``(n,)`` array (NaN = none); it
            replaces the ``sigma_m`` column. Echoes without one use
            ``evidence["default_sigma_m"]``.
        evidence: the evidence mapper's parameters (the scene's
            ``[mapping.evidence]`` table), e.g. ``{"min_support": 8}``.
        ellipse_points: 0 (Algorithm 1 as stated) or N points per ellipse
            (the authors' implementation, §II.C), paper mapper only.

    Returns:
        A :class:`MapResult`.

    Raises:
        ValueError: bad echoes (the message names the row and column) or
            parameters, or a grid too large for the memory cap.
    """
    if np.iscomplexobj(echoes):
        # numpy would drop the imaginary part with only a warning.
        raise TypeError("echoes must be real, not complex")
    arr = np.ascontiguousarray(echoes, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"echoes must be a 2-D array (n, 5..9), got {arr.ndim} dimension(s)")
    sig = None
    if sigma is not None:
        sig = np.asarray(sigma, dtype=np.float64)
        if sig.ndim > 1 or (sig.ndim == 1 and sig.shape[0] != arr.shape[0]):
            raise ValueError(
                f"sigma: expected one number or {arr.shape[0]} values (one per echo), got shape {sig.shape}"
            )
        sig = np.ascontiguousarray(np.broadcast_to(sig, (arr.shape[0],)))
    b = None
    if bounds is not None:
        if isinstance(bounds, (str, bytes)) or not hasattr(bounds, "__len__"):
            raise TypeError(f"bounds must be (x_min, y_min, x_max, y_max), not {type(bounds).__name__}")
        b = [_float("bounds", v) for v in bounds]
        if len(b) != 4:
            raise ValueError(f"bounds: expected (x_min, y_min, x_max, y_max), got {len(b)} values")
    ev = None
    if evidence is not None:
        if not isinstance(evidence, dict):
            raise TypeError(f"evidence must be a dict of the evidence mapper's parameters, not {type(evidence).__name__}")
        try:
            ev = json.dumps(evidence, allow_nan=False, default=_json_default)
        except (TypeError, ValueError) as e:
            raise ValueError(f"evidence: {e}") from None
    if isinstance(ellipse_points, bool) or not isinstance(ellipse_points, int):
        raise TypeError("ellipse_points must be an int")
    if not 0 <= ellipse_points <= 2**32 - 1:
        raise ValueError(f"ellipse_points: must be >= 0, got {ellipse_points}")
    d = _chirpmap.map_echoes(
        arr,
        sig,
        b,
        _float("cell", cell),
        None if keep_top is None else _float("keep_top", keep_top),
        None if min_of_max is None else _float("min_of_max", min_of_max),
        None if peak_radius is None else _float("peak_radius", peak_radius),
        ellipse_points,
        str(mapper),
        ev,
    )
    return MapResult(**_map_kwargs(d))


def synth(scene: SceneLike = None) -> Tuple[np.ndarray, int, List[np.ndarray]]:
    """Render what every listener of a scene records (``chirpmap synth``).

    The chirp train, the direct path, specular reflections and noise, with
    exact per-sample propagation delays (a moving listener's Doppler is in
    the signal). The scene's optional ``[synth]`` table (a ``"synth"`` key of
    a dict) sets chirps, gap_s, snr_db, sample_rate_hz, ...

    Args:
        scene: as for :func:`simulate`.

    Returns:
        ``(samples, sample_rate, poses)``: ``samples`` is an ``(n_samples,
        n_listeners)`` float32 array (full scale = 1, before the WAV's
        quantisation), ``sample_rate`` in Hz, and ``poses`` one ``(m, 3)``
        float64 array ``t, x, y`` per listener (every ``pose_period_s``).
    """
    kind, payload = _scene_source(scene)
    return _chirpmap.synth(kind, payload)


_METHODS = ("gap", "matched", "dechirp")
_WAV_METHODS = ("doppler", "gap", "dechirp")


def range(  # noqa: A001 - the name the issue and the CLI use
    samples: Any,
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
    """Range a recording: Δd to the first reflection of every chirp (§IV).

    The same as ``chirpmap range REC.wav --speaker X,Y --mic X,Y --method M``
    on a recording with these samples: the summary holds the keys of its
    summary.json (without ``wav``, ``clipped_samples`` and ``elapsed_s``,
    which describe the file and the run), with equal values.

    Args:
        samples: 1-D array of samples, or 2-D ``(n_samples, n_channels)``
            with ``channel``: float (full scale ±1; converted to float32, as
            a WAV is read), or int16 / int32 PCM (scaled to ±1 as a WAV's).
        sample_rate: Hz.
        speaker: speaker position ``(x, y)`` (m).
        mic: microphone position ``(x, y)`` (m).
        wall_normal: direction from the speaker toward the wall; adds
            ``wall_distance_median`` and ``wall_distance_ci95``.
        method: ``"gap"`` (the paper's; the default, as the CLI's),
            ``"matched"`` or ``"dechirp"``.
        f_start, f_end: chirp start and end frequency (Hz).
        duration: chirp duration T (s).
        speed_of_sound: m/s.
        max_delta_d: largest path difference searched (m); default
            min(60, a·T/2).
        compare: run all three methods; ``compare`` lists each one's summary.
        channel: the column of 2-D ``samples`` to range.

    Returns:
        dict: ``method, chirps, estimates, delta_d_median, delta_d_ci95``
        (and the wall distances), ``sample_rate_hz, recording_s, speaker,
        mic, chirp, max_delta_d_m, gap_resolution_floor_m`` (and
        ``compare``).
    """
    x = _channel(samples, channel)
    if method not in _METHODS:
        raise ValueError(f"method: unknown method {method!r}: use gap, matched or dechirp")
    if not isinstance(compare, (bool, np.bool_)):
        raise TypeError(f"compare must be True or False, not {type(compare).__name__}")
    methods = list(_METHODS) if compare else [method]
    primary = methods.index(method)
    wn = None if wall_normal is None else _point("wall_normal", wall_normal)
    text = _chirpmap.range(
        x,
        float(sample_rate),
        _point("speaker", speaker),
        _point("mic", mic),
        wn,
        methods,
        primary,
        float(f_start),
        float(f_end),
        float(duration),
        float(speed_of_sound),
        None if max_delta_d is None else float(max_delta_d),
    )
    return json.loads(text)


@dataclass(frozen=True, eq=False)
class RecordingEchoes:
    """Echoes of a moving listener's recording.

    Attributes:
        echoes: ``(n, 8)`` float64 in the columns of echoes.csv, or ``(n, 9)``
            with ``sigma_m`` (the method's 1-σ Δd uncertainty, m) when the
            method gives one: ready for :func:`map_echoes`.
        chirps: chirps detected in the recording.
        chirps_without_pose: chirps skipped because the poses do not cover them.
        delta_d_rate: ``(n,)`` float64, each echo's rate of change of Δd
            (m/s) as ``"doppler"`` estimates it (NaN for the other methods):
            echoes.csv's ``delta_d_rate`` column. Not a column of ``echoes``,
            which :func:`map_echoes` reads by position.
    """

    echoes: np.ndarray
    chirps: int
    chirps_without_pose: int
    delta_d_rate: np.ndarray

    def __repr__(self) -> str:
        return (
            f"RecordingEchoes(echoes={len(self.echoes)}, chirps={self.chirps}, "
            f"chirps_without_pose={self.chirps_without_pose})"
        )


def echoes_from_recording(
    samples: Any,
    sample_rate: float,
    poses: Any,
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
    """Echoes of a moving listener's recording, for :func:`map_echoes`.

    The echoes ``chirpmap map --wav REC.wav --poses P.csv --speaker X,Y``
    extracts (and writes to echoes.csv): every chirp is detected, then one
    measurement is made every ``period_ms`` at the listener's pose, linearly
    interpolated between ``poses`` (paper §III.B's sampling period on a real
    recording).

    Args:
        samples: 1-D samples, or 2-D ``(n_samples, n_channels)`` with ``channel``.
        sample_rate: Hz.
        poses: ``(m, 3)`` array-like ``t, x, y`` (s, m), as :func:`synth`
            returns per listener and ``chirpmap synth --poses`` writes.
        speaker: speaker position ``(x, y)`` (m).
        method: ``"doppler"`` (Doppler-corrected for moving listeners, the
            default, as ``map --wav``'s; issue 11), ``"gap"`` (the paper's,
            uncorrected) or ``"dechirp"`` (uncorrected).
        period_ms: time between measurements (ms). Paper: 1, 10, 50.
        frame_ms: measurement frame length (ms); default: the method's.
        f_start, f_end, duration, speed_of_sound, max_delta_d: the chirp and
            medium, as for :func:`range`.
        channel: the column of 2-D ``samples``; also the echoes' listener id.
        pattern: the chirps' sweep directions, ``"down"``, ``"up"`` or
            ``"updown"`` (alternating, starting down); ``None``: every chirp
            from ``f_start`` to ``f_end`` (``map --wav --pattern``).
        echoes_per_frame: most echoes per frame, earliest first, each tracked
            across its chirp with its own Doppler correction (``"doppler"``
            only); ``None``: 8 for ``"doppler"``, 1 otherwise (the first
            reflection alone, the paper's §IV), as ``map --wav``.
        sweep: the chirps' shape, ``"linear"`` (the paper's),
            ``"exponential"`` or ``"hyperbolic"`` (``map --wav --sweep``).

    Returns:
        A :class:`RecordingEchoes`.
    """
    x = _channel(samples, channel)
    if not (isinstance(period_ms, (int, float, np.integer, np.floating)) and period_ms > 0):
        raise ValueError(f"period_ms: must be a number of milliseconds > 0, got {period_ms!r}")
    if frame_ms is not None and not (isinstance(frame_ms, (int, float, np.integer, np.floating)) and frame_ms > 0):
        raise ValueError(f"frame_ms: must be a number of milliseconds > 0, got {frame_ms!r}")
    p = np.ascontiguousarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must be an (m, 3) array t, x, y; got shape {p.shape}")
    if method not in _WAV_METHODS:
        raise ValueError(f"method: unknown method {method!r}: use doppler, gap or dechirp")
    if echoes_per_frame is not None:
        if isinstance(echoes_per_frame, bool) or not isinstance(echoes_per_frame, (int, np.integer)):
            raise TypeError(f"echoes_per_frame must be an int, not {type(echoes_per_frame).__name__}")
        if not 1 <= echoes_per_frame <= 64:
            raise ValueError(f"echoes_per_frame: must be in 1..=64, got {echoes_per_frame}")
    echoes, chirps, skipped, rates = _chirpmap.echoes_from_recording(
        x,
        float(sample_rate),
        p,
        _point("speaker", speaker),
        method,
        float(period_ms) / 1000.0,
        None if frame_ms is None else float(frame_ms) / 1000.0,
        int(channel),
        float(f_start),
        float(f_end),
        float(duration),
        float(speed_of_sound),
        None if max_delta_d is None else float(max_delta_d),
        pattern,
        None if echoes_per_frame is None else int(echoes_per_frame),
        "linear" if sweep is None else str(sweep),
    )
    return RecordingEchoes(echoes, chirps, skipped, rates)


#: Columns of the echoes.csv ``chirpmap range --echoes`` writes, the order of
#: :meth:`RoomEchoes.table`: the map's eight (:data:`ECHO_COLUMNS`), then the
#: chirp's index, the echo's rank by delay within it (1 = earliest), the
#: measured 3D path difference (m), the strength (dB re direct) and the plane
#: label (``"floor"``, ``"ceiling"``, ``"floor?"`` or ``""``).
ROOM_ECHO_COLUMNS: Tuple[str, ...] = ECHO_COLUMNS[:8] + (
    "chirp",
    "rank",
    "path_delta_m",
    "strength_db",
    "plane",
)


@dataclass(frozen=True, eq=False)
class RoomEchoes:
    """Every reflection of every chirp, as ``chirpmap range --echoes`` reports it.

    One row per echo, by chirp then delay, in the rows of its echoes.csv.

    Attributes:
        echoes: ``(n, 8)`` float64 in the columns of echoes.csv
            (:data:`ECHO_COLUMNS`): speaker and microphone in the map's plane,
            ``delta_d`` (the horizontal path difference a vertical reflector
            would give, m), ``weight`` (1, or 0 for a labelled floor or
            ceiling echo, which stays out of the map), ``t`` (the chirp's
            onset, s; 0 for an impulse response) and ``listener``. Ready for
            :func:`map_echoes`.
        chirp: ``(n,)`` int64, the chirp's index (from 0).
        rank: ``(n,)`` int64, rank by delay within the chirp (1 = earliest).
        path_delta_m: ``(n,)`` float64, the measured (3D) path difference (m).
        strength_db: ``(n,)`` float64, amplitude re the direct sound (dB).
        plane: ``(n,)`` str, ``"floor"``, ``"ceiling"``, ``"floor?"`` (the
            floor guessed at z = 0) or ``""``.
        chirp_onsets_s: ``(k,)`` float64, onsets of the chirps' direct
            sound (s); ``[0.0]`` for an impulse response.
        clusters: echoes found in at least half of the chirps, by path
            difference: dicts ``path_delta_m, delta_d_m, strength_db`` (medians),
            ``chirps`` and ``plane`` (None or a label), as in summary.json.
        echogram: ``(m, 2)`` float64 ``path_delta_m, level_db``: the median
            envelope over chirps re the direct peak (echogram.csv, unrounded).
        predicted: the floor's and ceiling's predicted echoes, dicts
            ``plane, path_delta_m`` (summary.json's ``predicted``).
        min_delta_d_m: smallest path difference searched (m): the ringing
            window, or a third of a millisecond with a calibration.
        max_delta_d_m: largest path difference searched (m).
        calibrated: whether a calibration gave the system response.
    """

    echoes: np.ndarray
    chirp: np.ndarray
    rank: np.ndarray
    path_delta_m: np.ndarray
    strength_db: np.ndarray
    plane: np.ndarray
    chirp_onsets_s: np.ndarray
    clusters: List[Dict[str, Any]]
    echogram: np.ndarray
    predicted: List[Dict[str, Any]]
    min_delta_d_m: float
    max_delta_d_m: float
    calibrated: bool

    def table(self) -> np.ndarray:
        """The rows of echoes.csv as a numpy structured array, one field per
        column of :data:`ROOM_ECHO_COLUMNS` (``listener``, ``chirp`` and
        ``rank`` int64, ``plane`` str, the others float64; unrounded)."""
        n = len(self.echoes)
        dtype = [(c, np.float64) for c in ECHO_COLUMNS[:7]] + [
            ("listener", np.int64),
            ("chirp", np.int64),
            ("rank", np.int64),
            ("path_delta_m", np.float64),
            ("strength_db", np.float64),
            ("plane", "U7"),
        ]
        out = np.zeros(n, dtype=dtype)
        for j, c in enumerate(ECHO_COLUMNS[:8]):
            out[c] = self.echoes[:, j]
        for c in ROOM_ECHO_COLUMNS[8:]:
            out[c] = getattr(self, c)
        return out

    def __repr__(self) -> str:
        return (
            f"RoomEchoes(echoes={len(self.echoes)}, chirps={len(self.chirp_onsets_s)}, "
            f"clusters={[round(c['path_delta_m'], 3) for c in self.clusters]})"
        )


_INPUTS = ("recording", "rir")


def room_echoes(
    samples: Any,
    sample_rate: float,
    speaker: Sequence[float],
    mic: Sequence[float],
    *,
    input: str = "recording",  # noqa: A002 - the CLI's --input
    max_echoes: int = 20,
    floor_z: Optional[float] = None,
    ceiling_z: Optional[float] = None,
    calibration: Any = None,
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
    """Every reflection of every chirp in a room (issue 10, item 1).

    The same as ``chirpmap range REC.wav --echoes K --speaker X,Y[,Z] --mic
    X,Y[,Z]`` (with ``--input rir`` for an impulse response) on a WAV holding
    these samples: the same echoes, clusters, echogram and predictions, bit
    for bit (echoes.csv and echogram.csv round what these hold).

    Per chirp the impulse response (matched filter for a linear sweep,
    Farina's inverse filter for an exponential one), then matching pursuit
    with the system response cut from the direct sound, or taken from
    ``calibration``, so that the loudspeaker's ringing is not taken for an
    echo. With heights, path differences are measured in 3D and projected
    for the 2D map; echoes matching the floor's or ceiling's image source
    are labelled and kept out of the map.

    Args:
        samples: 1-D samples, or 2-D ``(n_samples, n_channels)`` with
            ``channel`` (float, full scale ±1, converted to float32 as a WAV
            is read; or int16 / int32 PCM, scaled to ±1 as a WAV's).
        sample_rate: Hz.
        speaker: speaker position ``(x, y)`` or ``(x, y, z)`` (m).
        mic: microphone position ``(x, y)`` or ``(x, y, z)`` (m); heights
            for both or for neither.
        input: ``"recording"`` (chirps; the CLI's ``wav``) or ``"rir"`` (an
            impulse response whose time zero is the emission; the chirp
            arguments but ``speed_of_sound`` and ``max_delta_d`` are unused).
        max_echoes: most echoes per chirp (1 to 1000): the strongest,
            then ordered by delay.
        floor_z: floor height (m), below speaker and mic (needs heights).
        ceiling_z: ceiling height (m), above them (needs heights).
        calibration: samples of the direct sound alone, the same kind of
            input as ``samples`` at the same rate (1-D, or 2-D with
            ``channel``): its response models the loudspeaker.
        echo_threshold_db: weakest echo reported re the direct sound (dB, < 0).
        ringing_ms: length of the loudspeaker's ringing after the direct
            peak (ms); nothing closer is reported.
        echo_atom_ms: length of the system response after its peak matched
            to each echo (ms).
        plane_tolerance: an echo within this of a predicted floor or ceiling
            echo is labelled (m; the nearest one).
        f_start, f_end, duration, speed_of_sound, max_delta_d: the chirp and
            medium, as for :func:`range`. ``max_delta_d`` defaults to
            min(60, a·T/2) for a recording, and to 60 m or the response's
            length for an impulse response.
        sweep: ``"linear"`` (the paper's), ``"exponential"`` or ``"hyperbolic"``.
        channel: the column of 2-D ``samples`` (and ``calibration``).
        listener: listener id of the echoes; default ``channel``.

    Returns:
        A :class:`RoomEchoes`.

    Raises:
        ValueError: bad input; the message names the argument, as the CLI's
            names the flag.
    """
    if input not in _INPUTS:
        raise ValueError(f"input: {input!r} is not an input kind (recording or rir)")
    x = _channel(samples, channel)
    cal = None if calibration is None else _channel(calibration, channel, "calibration")
    (sx, sy, sz) = _point_2or3("speaker", speaker)
    (mx, my, mz) = _point_2or3("mic", mic)
    if (sz is None) != (mz is None):
        raise ValueError("speaker, mic: give heights for both (x, y, z), or for neither")
    heights = None if sz is None else (sz, mz)
    if isinstance(max_echoes, bool) or not isinstance(max_echoes, (int, np.integer)):
        raise TypeError(f"max_echoes must be an int, not {type(max_echoes).__name__}")
    if not 1 <= max_echoes <= 1000:
        raise ValueError(f"max_echoes: must be in 1..=1000, got {max_echoes}")
    lid = channel if listener is None else listener
    if isinstance(lid, bool) or not isinstance(lid, (int, np.integer)):
        raise TypeError(f"listener must be an int, not {type(lid).__name__}")
    if not 0 <= lid <= 2**32 - 1:
        raise ValueError(f"listener: must be between 0 and 2^32 - 1, got {lid}")
    d = _chirpmap.room_echoes(
        x,
        float(sample_rate),
        [sx, sy],
        [mx, my],
        heights,
        None if floor_z is None else float(floor_z),
        None if ceiling_z is None else float(ceiling_z),
        input,
        cal,
        int(max_echoes),
        float(echo_threshold_db),
        float(ringing_ms),
        float(echo_atom_ms),
        float(plane_tolerance),
        int(lid),
        float(f_start),
        float(f_end),
        float(duration),
        float(speed_of_sound),
        None if max_delta_d is None else float(max_delta_d),
        str(sweep),
    )
    d["plane"] = np.array(d["plane"], dtype="U7")
    return RoomEchoes(**d)


def _point_2or3(name: str, p: Sequence[float]) -> Tuple[float, float, Optional[float]]:
    """`(x, y)` or `(x, y, z)`, checked as the CLI checks `X,Y[,Z]`."""
    if isinstance(p, (str, bytes)):
        raise TypeError(f"{name} must be numbers (x, y) or (x, y, z), not a string")
    v = [float(c) for c in p]
    if len(v) not in (2, 3):
        raise ValueError(f"{name}: expected (x, y) or (x, y, z), got {len(v)} values")
    for c in v:
        if not (np.isfinite(c) and abs(c) <= _MAX_COORD_M):
            raise ValueError(f"{name}: {c} must be finite and within ±{_MAX_COORD_M} m")
    return v[0], v[1], (v[2] if len(v) == 3 else None)


def _channel(samples: Any, channel: int, what: str = "samples") -> np.ndarray:
    """One channel of ``what`` as contiguous float32 (as a WAV's samples are read)."""
    if isinstance(channel, bool) or not hasattr(channel, "__index__"):
        raise TypeError(f"channel must be an int, not {type(channel).__name__}")
    channel = operator.index(channel)
    if not 0 <= channel <= 2**32 - 1:
        raise ValueError(f"channel: must be a channel number from 0, got {channel}")
    x = np.asarray(samples)
    if np.iscomplexobj(x):
        # numpy would drop the imaginary part with only a warning.
        raise TypeError(f"{what} must be real, not complex")
    if x.ndim == 2:
        if x.shape[0] < x.shape[1]:
            # torchaudio's and librosa's (channels, frames) layout.
            raise ValueError(
                f"{what}: shape {x.shape} has fewer samples than channels; pass "
                f"(n_samples, n_channels), e.g. {what}.T"
            )
        if not 0 <= channel < x.shape[1]:
            raise ValueError(f"channel: {channel} is not a channel of {what} ({x.shape[1]} channels)")
        x = x[:, channel]
    elif x.ndim == 1:
        if channel != 0:
            raise ValueError(f"channel: {channel} is not a channel of 1-D {what} (one channel, 0)")
    else:
        raise ValueError(f"{what} must be 1-D or 2-D, got {x.ndim} dimensions")
    if x.size == 0:
        raise ValueError(f"{what}: empty (no samples)")
    if np.issubdtype(x.dtype, np.integer):
        # PCM as soundfile or scipy.io.wavfile return it: scaled to full
        # scale ±1 exactly as chirpmap's WAV reader scales the same file.
        if x.dtype == np.int16:
            return np.ascontiguousarray(x.astype(np.float32) / np.float32(32768.0))
        if x.dtype == np.int32:
            return np.ascontiguousarray((x.astype(np.float64) / 2147483648.0).astype(np.float32))
        raise TypeError(
            f"{what}: {x.dtype} is not a PCM format chirpmap reads (int16, int32); convert to float, full scale ±1"
        )
    return np.ascontiguousarray(x, dtype=np.float32)


#: Largest coordinate accepted (m), as the CLI's X,Y arguments.
_MAX_COORD_M = 1e6


def _point(name: str, p: Sequence[float]) -> List[float]:
    """`(x, y)` checked as the CLI checks an `X,Y` argument."""
    if isinstance(p, (str, bytes)):
        raise TypeError(f"{name} must be a pair of numbers (x, y), not a string")
    v = [float(c) for c in p]
    if len(v) != 2:
        raise ValueError(f"{name}: expected (x, y), got {len(v)} values")
    for c in v:
        if not (np.isfinite(c) and abs(c) <= _MAX_COORD_M):
            raise ValueError(f"{name}: {c} must be finite and within ±{_MAX_COORD_M} m")
    return v
