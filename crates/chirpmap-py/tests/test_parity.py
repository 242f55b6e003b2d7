"""The Python results equal the CLI's bit for bit on the same inputs (issue 12,
part 3): the same seed gives the same echoes, highlights, scores and resolved
scene; the same echoes the same map; the same scene the same recording; the
same recording the same range summary. Floats are compared with `==` after
parsing the CLI's shortest round-trip text."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import chirpmap
from conftest import REPO, read_table, read_wav_f32, run_cli

ECHO_COLS = list(chirpmap.ECHO_COLUMNS[:8])
# Simulated (particle) echoes carry their Δd uncertainty in a ninth column.
SIM_ECHO_COLS = list(chirpmap.ECHO_COLUMNS[:9])
HIGHLIGHT_COLS = ["x", "y", "value"]
THREE_CIRCLES = REPO / "examples" / "three-circles"

# The three-circles scene of examples/, with its own seed, as TOML text and
# as the equivalent dict.
SCENE_TOML = """seed = 11

[source]
position = [0.0, 0.0]

[[obstacles]]
center = [-10.0, -20.0]
radius = 3.0

[[obstacles]]
center = [6.0, -26.0]
radius = 4.0

[[listeners]]
start = [-20.0, 10.0]
heading_deg = 0.0
speed = 10.0
"""
SCENE_DICT = {
    "seed": 11,
    "source": {"position": [0.0, 0.0]},
    "obstacles": [
        {"center": [-10.0, -20.0], "radius": 3.0},
        {"center": [6.0, -26.0], "radius": 4.0},
    ],
    "listeners": [{"start": [-20.0, 10.0], "heading_deg": 0.0, "speed": 10.0}],
}

# A static microphone 1.58 m from the speaker, a wall 6 m behind it (the
# examples/wall scene, shortened), rendered as 32-bit float so the WAV holds
# exactly the samples `synth` returns.
WALL_SCENE = """[chirp]
f_start = 10000.0
f_end = 200.0
duration = 0.5

[source]
position = [0.0, 0.0]

[[obstacles]]
vertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]
roughness = 0.0
absorption = 0.2

[[listeners]]
start = [1.5, 0.5]
speed = 0.0

[synth]
chirps = 5
gap_s = 0.5
snr_db = 20.0
noise_seed = 1
bits = "f32"
"""


def summary(d: Path) -> dict:
    return json.loads((d / "summary.json").read_text())


def check_map_files(d: Path, m: chirpmap.MapResult) -> None:
    """highlights.csv, the summary's grid and (where the CLI writes it)
    map.npy (float32) against a Python map."""
    hl = read_table(d / "highlights.csv", HIGHLIGHT_COLS)
    assert hl.shape == m.highlights.shape
    assert np.array_equal(hl, m.highlights)
    g = summary(d)["grid"]
    assert tuple(g["bounds"]) == m.bounds
    assert (g["ny"], g["nx"]) == m.grid.shape
    assert g["cell"] == m.cell
    npy = d / "map.npy"
    if npy.exists():
        assert np.array_equal(np.load(npy), m.grid.astype(np.float32))


@pytest.mark.parametrize("seed", [None, 3])
def test_simulate_default_scene_matches_cli(cli, tmp_path, seed):
    args = ["simulate", "--out", tmp_path / "sim"] + (["--seed", seed] if seed is not None else [])
    run_cli(cli, *args)
    run = chirpmap.simulate(seed=seed)
    d = tmp_path / "sim"
    echoes = read_table(d / "echoes.csv", SIM_ECHO_COLS)
    assert run.echoes.shape == echoes.shape and run.echoes.shape[1] == 9
    assert np.array_equal(run.echoes, echoes)
    check_map_files(d, run)
    s = summary(d)
    metrics = ("score_obstacle", "score_highlight", "surface_precision", "surface_recall", "surface_f1", "chamfer_m", "walls")
    assert run.scores == {k: s[k] for k in metrics}
    assert run.scores["score_obstacle"] is not None
    assert (run.seed, run.n_measurements, run.n_obstacles) == (s["seed"], s["n_measurements"], s["n_obstacles"])
    assert len(run.highlights) == s["n_highlights"]
    cli_scene = "".join(l for l in (d / "scene.toml").read_text().splitlines(True) if not l.startswith("#"))
    assert run.scene == cli_scene
    # The resolved scene replays the run.
    again = chirpmap.simulate(run.scene)
    assert np.array_equal(again.echoes, run.echoes) and again.scores == run.scores


def test_simulate_with_the_evidence_mapper_scores_as_the_cli(cli, tmp_path):
    """The evidence mapper's surface metrics (F1, Chamfer, walls), as
    summary.json holds them."""
    scene = tmp_path / "ev.toml"
    scene.write_text('[mapping]\nmapper = "evidence"\n')
    run_cli(cli, "simulate", scene, "--seed", 4, "--out", tmp_path / "sim")
    run = chirpmap.simulate({"mapping": {"mapper": "evidence"}}, seed=4)
    s = summary(tmp_path / "sim")
    check_map_files(tmp_path / "sim", run)
    keys = ("score_obstacle", "score_highlight", "surface_precision", "surface_recall", "surface_f1", "chamfer_m", "walls")
    assert run.scores == {k: s[k] for k in keys}
    assert run.scores["surface_f1"] > 0 and len(run.surfaces) > 0


def test_scene_as_path_text_and_dict_match_cli(cli, tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE_TOML)
    run_cli(cli, "simulate", path, "--out", tmp_path / "sim")
    cli_echoes = read_table(tmp_path / "sim" / "echoes.csv", SIM_ECHO_COLS)
    runs = [
        chirpmap.simulate(str(path)),
        chirpmap.simulate(path),
        chirpmap.simulate(SCENE_TOML),
        chirpmap.simulate(SCENE_DICT),
    ]
    for run in runs:
        assert len(run.echoes) > 0
        assert np.array_equal(run.echoes, cli_echoes)
        check_map_files(tmp_path / "sim", run)
        assert run.scores == runs[0].scores and run.scene == runs[0].scene
    # --seed overrides the scene's seed in both.
    run_cli(cli, "simulate", path, "--seed", 12, "--out", tmp_path / "sim12")
    run12 = chirpmap.simulate(SCENE_DICT, seed=12)
    assert np.array_equal(run12.echoes, read_table(tmp_path / "sim12" / "echoes.csv", SIM_ECHO_COLS))
    assert run12.seed == 12


@pytest.mark.parametrize(
    "cli_args, kwargs",
    [
        ([], {}),
        (
            ["--bounds", "-40,-40,40,40", "--cell", "0.2", "--keep-top", "0.2", "--peak-radius", "3"],
            {"bounds": (-40, -40, 40, 40), "cell": 0.2, "keep_top": 0.2, "peak_radius": 3.0},
        ),
        (["--min-of-max", "0.05"], {"min_of_max": 0.05}),
    ],
)
def test_map_echoes_matches_cli(cli, tmp_path, cli_args, kwargs):
    csv_path = THREE_CIRCLES / "echoes.csv"
    run_cli(cli, "map", "--echoes", csv_path, "--out", tmp_path / "map", *cli_args)
    echoes = read_table(csv_path, ECHO_COLS)
    m = chirpmap.map_echoes(echoes, **kwargs)
    check_map_files(tmp_path / "map", m)
    assert m.cells_updated == summary(tmp_path / "map")["cells_updated"]
    assert len(m.highlights) > 0 and m.surfaces == []
    # The five required columns alone: weight 1 (the CSV's default, and
    # every weight of this file), t and listener 0 (unused by this mapper).
    assert np.all(echoes[:, 5] == 1.0)
    m5 = chirpmap.map_echoes(echoes[:, :5], **kwargs)
    assert np.array_equal(m5.grid, m.grid) and np.array_equal(m5.highlights, m.highlights)


def test_simulated_echoes_remap_to_the_same_map(cli, tmp_path):
    """simulate's echoes, mapped on its world (`map --bounds` = the world),
    give simulate's own map: the same CLI and Python path both ways."""
    run = chirpmap.simulate(seed=5)
    m = chirpmap.map_echoes(run.echoes, bounds=run.bounds)
    assert np.array_equal(m.grid, run.grid) and np.array_equal(m.highlights, run.highlights)
    run_cli(cli, "simulate", "--seed", 5, "--out", tmp_path / "sim")
    b = ",".join(repr(v) for v in run.bounds)
    run_cli(cli, "map", "--echoes", tmp_path / "sim" / "echoes.csv", "--bounds", b, "--out", tmp_path / "map")
    check_map_files(tmp_path / "map", m)


def test_evidence_mapper_matches_cli(cli, tmp_path):
    """The evidence mapper via a scene's [mapping] (which every CLI version
    reads), explicit bounds so the scene's obstacles do not widen the grid."""
    scene = tmp_path / "evidence.toml"
    scene.write_text('[mapping]\nmapper = "evidence"\n\n[mapping.evidence]\nmin_support = 6\n')
    csv_path = THREE_CIRCLES / "echoes.csv"
    run_cli(
        cli, "map", "--echoes", csv_path, "--scene", scene, "--bounds", "-40,-35,40,35", "--out", tmp_path / "map"
    )
    echoes = read_table(csv_path, ECHO_COLS)
    m = chirpmap.map_echoes(echoes, mapper="evidence", bounds=(-40, -35, 40, 35), evidence={"min_support": 6})
    check_map_files(tmp_path / "map", m)
    assert len(m.surfaces) > 0
    assert m.mapping["mapper"] == "evidence" and m.mapping["evidence"]["min_support"] == 6
    surfaces_csv = tmp_path / "map" / "surfaces.csv"
    if surfaces_csv.exists():
        cols = ["x0", "y0", "x1", "y1", "support"]
        got = read_table(surfaces_csv, cols)
        want = np.array([[s[c] for c in cols] for s in m.surfaces], dtype=float)
        points = np.array([s["kind"] == "point" for s in m.surfaces])
        want[points, 2:4] = np.nan  # the CSV leaves a point's x1, y1 empty
        assert np.array_equal(got, want, equal_nan=True)


def test_synth_matches_cli_wav_and_poses(cli, tmp_path):
    scene = tmp_path / "wall.toml"
    scene.write_text(WALL_SCENE)
    run_cli(cli, "synth", scene, "--out", tmp_path / "rec.wav", "--poses", tmp_path / "poses.csv")
    samples, rate, poses = chirpmap.synth(scene)
    assert rate == 48000 and samples.dtype == np.float32
    wav = read_wav_f32(tmp_path / "rec.wav")
    assert samples.shape == wav.shape == (int(5.5 * 48000), 1)
    assert np.array_equal(samples, wav)
    cli_poses = read_table(tmp_path / "poses.csv", ["t", "x", "y"])
    assert len(poses) == 1 and poses[0].shape == cli_poses.shape
    # The CLI writes poses with 6 decimals.
    rounded = np.array([[float(f"{v:.6f}") for v in row] for row in poses[0]])
    assert np.array_equal(rounded, cli_poses)


@pytest.mark.parametrize(
    "cli_args, kwargs",
    [
        # Both defaults (the paper's gap method).
        ([], {}),
        (["--method", "matched"], {"method": "matched"}),
        (["--method", "gap", "--wall-normal", "0,-1"], {"method": "gap", "wall_normal": (0, -1)}),
        (["--method", "dechirp", "--compare", "--max-delta-d", "30"], {"method": "dechirp", "compare": True, "max_delta_d": 30.0}),
    ],
)
def test_range_matches_cli_summary(cli, tmp_path, cli_args, kwargs):
    scene = tmp_path / "wall.toml"
    scene.write_text(WALL_SCENE)
    run_cli(cli, "synth", scene, "--out", tmp_path / "rec.wav")
    run_cli(cli, "range", tmp_path / "rec.wav", "--speaker", "0,0", "--mic", "1.5,0.5", "--out", tmp_path / "r", *cli_args)
    samples, rate, _ = chirpmap.synth(WALL_SCENE)
    got = chirpmap.range(samples, rate, (0, 0), (1.5, 0.5), **kwargs)
    want = summary(tmp_path / "r")
    # What describes the file or the run rather than the recording.
    file_keys = {"wav", "clipped_samples", "elapsed_s", "run"}
    assert set(want) - set(got) <= file_keys, set(want) - set(got)
    assert got == {k: v for k, v in want.items() if k not in file_keys}
    assert got["chirps"] == 5 and got["estimates"] > 0
    # 1-D input and float64 input (converted to float32, as a WAV is read) agree.
    assert chirpmap.range(samples[:, 0].astype(np.float64), rate, (0, 0), (1.5, 0.5), **kwargs) == got


# A listener walking at 1 m/s past a speaker 6 m in front of a wall
# (examples/moving-wall, fewer chirps), as 32-bit float.
MOVING_WALL_SCENE = """[chirp]
f_start = 10000.0
f_end = 200.0
duration = 0.25

[source]
position = [0.0, 0.0]

[[obstacles]]
vertices = [[-30.0, -6.0], [-30.0, -6.3], [30.0, -6.3], [30.0, -6.0]]
roughness = 0.0
absorption = 0.2

[[listeners]]
start = [-10.0, 3.0]
heading_deg = 0.0
speed = 1.0

[synth]
chirps = 12
gap_s = 0.25
snr_db = 20.0
bits = "f32"
"""


@pytest.mark.parametrize(
    "method, sweep",
    [("gap", "linear"), ("dechirp", "linear"), ("doppler", "linear"), ("doppler", "hyperbolic")],
)
def test_echoes_from_recording_match_cli_map_wav(cli, tmp_path, method, sweep):
    scene = tmp_path / "moving.toml"
    scene.write_text(MOVING_WALL_SCENE.replace("[chirp]\n", f'[chirp]\nkind = "{sweep}"\n'))
    wav, poses_csv = tmp_path / "rec.wav", tmp_path / "poses.csv"
    run_cli(cli, "synth", scene, "--out", wav, "--poses", poses_csv)
    run_cli(
        cli, "map", "--wav", wav, "--poses", poses_csv, "--speaker", "0,0", "--duration", "0.25",
        "--method", method, "--sweep", sweep, "--out", tmp_path / "map",
    )
    # The CLI read the WAV and the poses file; so does Python.
    samples = read_wav_f32(wav)
    poses = read_table(poses_csv, ["t", "x", "y"])
    got = chirpmap.echoes_from_recording(samples, 48000, poses, (0, 0), method=method, duration=0.25, sweep=sweep)
    assert got.chirps == 12 and got.chirps_without_pose == 0 and len(got.echoes) > 0
    header = (tmp_path / "map" / "echoes.csv").read_text().splitlines()[0].split(",")
    want = read_table(tmp_path / "map" / "echoes.csv", header)
    if method == "doppler":
        # The CLI also writes each echo's delta_d_rate, its track's Doppler fit.
        assert header[-1] == "delta_d_rate"
        assert np.array_equal(got.delta_d_rate, want[:, -1], equal_nan=True)
        assert not np.isnan(got.delta_d_rate).all()
        want = want[:, :-1]
    else:
        assert np.isnan(got.delta_d_rate).all() and len(got.delta_d_rate) == len(got.echoes)
    assert got.echoes.shape == want.shape
    assert np.array_equal(got.echoes, want, equal_nan=True)
    # Mapped with the defaults, the CLI's map; the file read back by column
    # name maps the same (a positional reader took delta_d_rate for sigma_m).
    check_map_files(tmp_path / "map", chirpmap.map_echoes(got.echoes))
    read = chirpmap.read_echoes(tmp_path / "map" / "echoes.csv")
    check_map_files(tmp_path / "map", chirpmap.map_echoes(read))
    for mapper in ("paper", "evidence"):
        a, b = chirpmap.map_echoes(read, mapper=mapper), chirpmap.map_echoes(got.echoes, mapper=mapper)
        assert np.array_equal(a.grid, b.grid) and a.surfaces == b.surfaces


@pytest.mark.parametrize("bits", ["16", "32"])
def test_range_of_pcm_arrays_matches_cli(cli, tmp_path, bits):
    """Integer PCM as soundfile or scipy.io.wavfile return it (int16, int32)
    is scaled as chirpmap's WAV reader scales the same file: int32 arrays
    were refused (beyond ±10⁶), int16 ones ranged unscaled."""
    import struct

    scene = tmp_path / "wall.toml"
    scene.write_text(WALL_SCENE.replace('bits = "f32"', f'bits = "{bits}"'))
    wav = tmp_path / "rec.wav"
    run_cli(cli, "synth", scene, "--out", wav)
    run_cli(cli, "range", wav, "--speaker", "0,0", "--mic", "1.5,0.5", "--out", tmp_path / "r")
    # The RIFF chunks read here (Python's wave module refuses the
    # extensible format chirpmap writes for 32 bits).
    data, pos, chunks = wav.read_bytes(), 12, {}
    while pos + 8 <= len(data):
        tag, size = data[pos : pos + 4], struct.unpack("<I", data[pos + 4 : pos + 8])[0]
        chunks[tag] = data[pos + 8 : pos + 8 + size]
        pos += 8 + size + (size & 1)
    channels, rate = struct.unpack("<HI", chunks[b"fmt "][2:8])
    assert struct.unpack("<H", chunks[b"fmt "][14:16])[0] == int(bits)
    dtype = {"16": np.int16, "32": np.int32}[bits]
    pcm = np.frombuffer(chunks[b"data"], dtype=np.dtype(dtype).newbyteorder("<")).astype(dtype).reshape(-1, channels)
    got = chirpmap.range(pcm, rate, (0, 0), (1.5, 0.5))
    want = summary(tmp_path / "r")
    file_keys = {"wav", "clipped_samples", "elapsed_s", "run"}
    assert got == {k: v for k, v in want.items() if k not in file_keys}
    assert got["estimates"] > 0
