"""The package's behaviour apart from the CLI: errors are ValueErrors with the
CLI's messages (never a panic), results own Rust's buffers, and long work
releases the GIL."""

from __future__ import annotations

import os
import pathlib
import signal
import sys
import threading
import time
import warnings

import numpy as np
import pytest

import chirpmap
from conftest import assert_main_thread_runs_during

GOOD = [0.0, 0.0, 1.0, 1.0, 2.0]


@pytest.mark.parametrize(
    "rows, message",
    [
        ([GOOD[:4] + [float("nan")]], "echoes[0]: `delta_d` = NaN is not finite"),
        ([GOOD, GOOD[:4] + [-2.0]], "echoes[1]: delta_d must be >= 0"),
        ([[1.0, 1.0, 1.0, 1.0, 2.0]], "echoes[0]: source and listener coincide"),
        ([GOOD + [-1.0]], "echoes[0]: invalid mapping parameter weight"),
        ([GOOD + [1.0, 0.0, 2.5]], "echoes[0]: `listener` = 2.5 must be a non-negative integer id"),
        ([[1e300, 0.0, 1.0, 1.0, 2.0]], "echoes[0]: source (1e300, 0) is beyond"),
        ([GOOD + [1.0, 0.0, 0.0, 0.0]], "`sigma_m` = 0 must be > 0"),
        ([GOOD[:4]], "echoes must have 5 to 9 columns"),
        (np.zeros((0, 5)), "no echoes to map"),
    ],
)
def test_bad_echoes_raise_value_error(rows, message):
    with pytest.raises(ValueError) as e:
        chirpmap.map_echoes(np.array(rows, dtype=float))
    assert message in str(e.value)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mapper": "best"}, '"best" is not a mapper (paper or evidence)'),
        ({"cell": 0.0}, "cell"),
        ({"keep_top": 1.5}, "keep_top"),
        ({"bounds": (1, 0, 0, 1)}, "xmin < xmax"),
        ({"bounds": (0, 0, 1)}, "bounds: expected (x_min, y_min, x_max, y_max)"),
        ({"bounds": (-1e5, -1e5, 1e5, 1e5), "cell": 0.01}, "more than the cap of"),
        ({"cell": 1e300}, "leaves fewer than 2 cells"),
        ({"mapper": "evidence", "evidence": {"angle_bins": 2}}, "evidence.angle_bins"),
        ({"mapper": "evidence", "evidence": {"no_such_key": 2}}, "no_such_key"),
        ({"sigma": -1.0, "mapper": "evidence"}, "`sigma_m` = -1 must be > 0"),
        ({"sigma": [0.1, 0.2, 0.3], "mapper": "evidence"}, "sigma: expected one number or 2 values (one per echo), got shape (3,)"),
        ({"sigma": [[0.1], [0.2]], "mapper": "evidence"}, "got shape (2, 1)"),
        # The other mapper's settings, refused rather than ignored.
        ({"sigma": 0.1}, "sigma: applies to mapper='evidence' only"),
        ({"evidence": {"min_support": 3}}, "evidence: applies to mapper='evidence' only"),
        ({"mapper": "evidence", "ellipse_points": 64}, "ellipse_points: applies to mapper='paper' only"),
        # Algorithm 1's thresholds, which the evidence mapper would ignore.
        ({"mapper": "evidence", "peak_radius": 3.0}, "peak_radius: applies to mapper='paper' only"),
        ({"mapper": "evidence", "keep_top": 0.2}, "keep_top: applies to mapper='paper' only"),
        ({"mapper": "evidence", "min_of_max": 0.1}, "min_of_max: applies to mapper='paper' only"),
    ],
)
def test_bad_parameters_raise_value_error(kwargs, message):
    with pytest.raises(ValueError) as e:
        chirpmap.map_echoes(np.array([GOOD, GOOD]), **kwargs)
    assert message in str(e.value)


def test_bad_scenes_raise_value_error(tmp_path):
    with pytest.raises(ValueError, match=r"scene dict: .*sede"):
        chirpmap.simulate({"sede": 3})
    with pytest.raises(ValueError, match=r"^scene: .*radius"):
        chirpmap.simulate("[[obstacles]]\ncenter = [0.0, -20.0]\nradius = -1.0\n")
    with pytest.raises(ValueError, match=r"cannot read scene no/such/scene\.toml: "):
        chirpmap.simulate("no/such/scene.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("seed = \n")
    with pytest.raises(ValueError, match=f"^{bad}: "):
        chirpmap.simulate(bad)
    # An endless stream is read up to the cap, not until memory runs out.
    if os.path.exists("/dev/zero"):
        with pytest.raises(ValueError, match=r"scene /dev/zero is too large"):
            chirpmap.simulate(pathlib.Path("/dev/zero"))
    with pytest.raises(ValueError, match="seed: must be between 0 and 2"):
        chirpmap.simulate(seed=-1)
    with pytest.raises(ValueError, match="scene dict"):
        chirpmap.simulate({"seed": float("nan")})
    with pytest.raises(TypeError):
        chirpmap.simulate(3.5)  # type: ignore[arg-type]


def test_bad_recordings_raise_value_error():
    fs = 48000.0
    silent = np.zeros(48000, dtype=np.float32)
    with pytest.raises(ValueError, match=r"the channel is silent"):
        chirpmap.range(silent, fs, (0, 0), (1, 0))
    noise = np.random.default_rng(1).standard_normal(48000).astype(np.float32)
    with pytest.raises(ValueError, match=r"speaker and mic are the same point"):
        chirpmap.range(noise, fs, (1, 0), (1, 0))
    with pytest.raises(ValueError, match=r"duration: the chirp \(2 s\) is longer than the recording"):
        chirpmap.range(noise, fs, (0, 0), (1, 0), duration=2.0)
    with pytest.raises(ValueError, match=r"speed_of_sound: must be between"):
        chirpmap.range(noise, fs, (0, 0), (1, 0), speed_of_sound=5.0)
    with pytest.raises(ValueError, match=r"max_delta_d: .* longer than a·T"):
        chirpmap.range(noise, fs, (0, 0), (1, 0), max_delta_d=1000.0)
    with pytest.raises(ValueError, match=r"method: unknown method 'fft'"):
        chirpmap.range(noise, fs, (0, 0), (1, 0), method="fft")
    with pytest.raises(ValueError, match=r"sample_rate"):
        chirpmap.range(noise, float("nan"), (0, 0), (1, 0))
    with pytest.raises(ValueError, match=r"the wall normal must be finite and not zero"):
        chirpmap.range(noise, fs, (0, 0), (1, 0), wall_normal=(0, 0))
    with pytest.raises(ValueError, match=r"speaker: nan must be finite and within"):
        chirpmap.range(noise, fs, (float("nan"), 0), (1, 0))
    with pytest.raises(ValueError, match=r"mic: expected \(x, y\), got 3 values"):
        chirpmap.range(noise, fs, (0, 0), (1, 0, 0))
    with pytest.raises(ValueError, match=r"channel: 2 is not a channel of samples \(2 channels\)"):
        chirpmap.range(np.zeros((10, 2)), fs, (0, 0), (1, 0), channel=2)


def test_review_findings_raise_value_error(tmp_path):
    """Session 20's review of the package: a NaN or infinite sample is named
    (it gave "no chirp found"), poses the CLI refuses are refused, a FIFO
    scene path is refused (opening it waited for a writer for good), and a
    scene given as text or a dict is capped before it is converted."""
    rec, rate, poses = chirpmap.synth({"synth": {"chirps": 2}})
    x = rec[:, 0].copy()
    x[1000] = np.nan
    with pytest.raises(ValueError, match=r"samples\[1000\] is NaN: samples must be finite"):
        chirpmap.range(x, rate, (-3, 10), (0, 0))
    with pytest.raises(ValueError, match=r"samples\[1000\] is NaN"):
        chirpmap.echoes_from_recording(x, rate, poses[0], (0, 0))
    with pytest.raises(ValueError, match=r"samples\[1000\] is NaN"):
        chirpmap.room_echoes(x, rate, (0, 0), (1, 0))
    x[1000] = np.inf
    with pytest.raises(ValueError, match=r"samples\[1000\] is inf"):
        chirpmap.room_echoes(x, rate, (0, 0), (1, 0), input="rir")
    fast = poses[0].copy()
    fast[:, 1:] *= 1000.0
    with pytest.raises(ValueError, match=r"the listener moves at .* at least the speed of sound"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, fast, (0, 0))
    far = poses[0].copy()
    far[-1, 1] += 1e300
    with pytest.raises(ValueError, match=r"is beyond ±1000000 m"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, far, (0, 0))
    ms = poses[0].copy()
    ms[:, 0] *= 1000.0
    with pytest.raises(ValueError, match=r"are the times in milliseconds\?"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, ms, (0, 0))
    if hasattr(os, "mkfifo"):
        fifo = tmp_path / "scene.fifo"
        os.mkfifo(fifo)
        with pytest.raises(ValueError, match=r"is a FIFO \(named pipe\)"):
            chirpmap.simulate(fifo)
    with pytest.raises(ValueError, match=r"^scene \(TOML text\): holds up to 4000003 values"):
        chirpmap.simulate("a = [" + "1," * 4_000_001 + "1]")
    with pytest.raises(ValueError, match=r"^scene dict \(as JSON\): holds up to"):
        chirpmap.simulate({"obstacles": [{"center": [0.0, 0.0], "radius": 1.0}] * 1_000_000})
    # An array where a table belongs was read field by field.
    with pytest.raises(ValueError, match=r"`mapping` must be a table"):
        chirpmap.simulate({"mapping": [0.5]})
    with pytest.raises(TypeError, match=r"evidence must be a dict"):
        chirpmap.map_echoes(np.array([GOOD, GOOD]), mapper="evidence", evidence=[1, 2])
    # Arguments named in their errors; numpy integers are integers.
    for kwargs, message in [
        ({"cell": None}, "cell must be a number, not NoneType"),
        ({"cell": "x"}, "cell must be a number, not str"),
        ({"bounds": 5}, "bounds must be (x_min, y_min, x_max, y_max), not int"),
        ({"bounds": "0,0,1,1"}, "bounds must be (x_min, y_min, x_max, y_max), not str"),
    ]:
        with pytest.raises(TypeError) as e:
            chirpmap.map_echoes(np.array([GOOD, GOOD]), **kwargs)
        assert message in str(e.value)
    assert chirpmap.simulate(seed=np.int64(3)).seed == 3
    with pytest.raises(TypeError, match=r"samples must be real, not complex"):
        chirpmap.range(rec[:, 0].astype(np.complex64), rate, (-3, 10), (0, 0))
    deep: dict = {}
    for _ in range(100_000):
        deep = {"a": deep}
    with pytest.raises(ValueError, match=r"scene dict: nested too deeply"):
        chirpmap.simulate(deep)
    # A scene file whose name is not UTF-8 is read (it raised UnicodeEncodeError).
    if os.name == "posix":
        odd = os.path.join(os.fsencode(tmp_path), b"sc\xff.toml")
        with open(odd, "w") as f:
            f.write("seed = 5\n[particles]\nper_tick = 360\n")
        assert chirpmap.simulate(pathlib.Path(os.fsdecode(odd))).seed == 5
    with pytest.raises(ValueError, match=r"channel: must be a channel number from 0, got -1"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, poses[0], (0, 0), channel=-1)
    with pytest.raises(ValueError, match=r"echoes_per_frame: must be in 1..=64, got 0"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, poses[0], (0, 0), echoes_per_frame=0)
    with pytest.raises(TypeError, match=r"echoes_per_frame must be an int, not bool"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, poses[0], (0, 0), echoes_per_frame=True)
    with pytest.raises(ValueError, match=r"echoes per frame: gap ranges one echo per frame"):
        chirpmap.echoes_from_recording(rec[:, 0], rate, poses[0], (0, 0), method="gap", echoes_per_frame=3)
    with pytest.raises(ValueError, match=r"max_delta_d: must be finite and > 0, got NaN"):
        chirpmap.room_echoes(rec[:, 0], rate, (0, 0), (1, 0), input="rir", max_delta_d=float("nan"))
    # Poses handed out as arrays are a second copy, counted against the cap
    # (this rendering passed at 3.4 GiB and peaked at 6.8).
    with pytest.raises(ValueError, match=r"the rendering and its poses as arrays would need about"):
        chirpmap.synth({"synth": {"pose_period_s": 1e-6, "chirps": 100}})


def test_results_own_rust_buffers_without_copies():
    run = chirpmap.simulate(seed=2)
    for a in (run.grid, run.echoes, run.highlights):
        # A numpy array wrapping Rust's Vec: it does not own its data, its
        # base is the Rust container (not another ndarray a copy would make).
        assert not a.flags.owndata and a.base is not None and not isinstance(a.base, np.ndarray)
        assert a.flags.c_contiguous and a.dtype == np.float64
    assert run.grid.shape == (1000, 1000)
    x0, x1, y0, y1 = run.extent
    assert (x0, y0, x1, y1) == run.bounds == (-50.0, -50.0, 50.0, 50.0)
    # Highlights are the grid's cells: row = y, column = x.
    for x, y, v in run.highlights:
        i, j = int((x - x0) / run.cell), int((y - y0) / run.cell)
        assert run.grid[j, i] == v


def test_synth_shapes_several_listeners():
    scene = {
        "source": {"position": [0.0, 0.0]},
        "listeners": [{"start": [1.0, 0.5], "speed": 0.0}, {"start": [-2.0, 0.5], "speed": 0.0}],
        "synth": {"chirps": 2, "gap_s": 0.2, "bits": "f32"},
    }
    samples, rate, poses = chirpmap.synth(scene)
    assert samples.shape[1] == 2 and samples.dtype == np.float32 and rate == 48000
    assert [p.shape[1] for p in poses] == [3, 3]
    assert not np.array_equal(samples[:, 0], samples[:, 1])
    # Each channel ranges like a mono recording of it.
    one = chirpmap.range(samples, rate, (0, 0), (-2.0, 0.5), channel=1)
    assert one == chirpmap.range(np.ascontiguousarray(samples[:, 1]), rate, (0, 0), (-2.0, 0.5))


def slow_echoes(seed: int, at_least_s: float, max_n: int):
    """Echoes whose map takes more than `at_least_s` on this machine (the
    mapper's speed changes between versions and machines): doubled until it
    does. Returns them, the map and the time it took."""
    rng = np.random.default_rng(seed)
    n = 20000
    while True:
        echoes = np.column_stack(
            [np.zeros(n), np.zeros(n), rng.uniform(-5, 5, n), np.full(n, 10.0), rng.uniform(12, 30, n)]
        )
        started = time.perf_counter()
        result = chirpmap.map_echoes(echoes, bounds=(-40, -40, 40, 40))
        once = time.perf_counter() - started
        if once > at_least_s or n >= max_n:
            break
        n *= 2
    assert once > at_least_s, f"the call took only {once:.4f} s with {n} echoes: too short to tell"
    return echoes, result, once


def test_mapping_releases_the_gil():
    """While one thread maps, the main thread runs Python. With the GIL held
    for the whole call it could run at most one switch interval (5 ms) of
    it; released, it runs throughout."""
    echoes, _, _ = slow_echoes(7, 0.1, 2_560_000)
    assert_main_thread_runs_during(lambda: chirpmap.map_echoes(echoes, bounds=(-40, -40, 40, 40)))


def chirpmap_threads() -> int:
    """Threads of this process named "chirpmap-call" (a call's worker)."""
    tasks = pathlib.Path("/proc/self/task")
    return sum((t / "comm").read_text().strip() == "chirpmap-call" for t in tasks.iterdir())


def interrupted_after(seconds: float, call) -> float:
    """Runs `call` with SIGINT sent after `seconds`; returns how long it took
    to raise KeyboardInterrupt."""
    timer = threading.Timer(seconds, os.kill, (os.getpid(), signal.SIGINT))
    started = time.perf_counter()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        call()
    took = time.perf_counter() - started
    timer.join()
    return took


def interrupted_once_waiting(call, give_up_s: float) -> list:
    """Runs `call` with SIGINT sent as soon as it warns that it waits for
    an interrupted call's work (or after `give_up_s` if it never does), and
    returns the warnings it gave. Sent after a fixed delay instead, the signal
    could land while the call still converted its arguments, before it
    reached the wait (the earlier work on both cores slows that down): at
    640 000 echoes the conversion took 0.07 s of a 0.1 s delay alone, and the
    test failed in about one run of three (CI of session 24)."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")

        def fire():
            deadline = time.perf_counter() + give_up_s
            while not seen and time.perf_counter() < deadline:
                time.sleep(0.002)
            os.kill(os.getpid(), signal.SIGINT)

        sender = threading.Thread(target=fire)
        sender.start()
        with pytest.raises(KeyboardInterrupt):
            call()
        sender.join()
    return [w for w in seen if issubclass(w.category, RuntimeWarning) and "interrupted call" in str(w.message)]


def test_ctrl_c_interrupts_a_call():
    """SIGINT during a call raises KeyboardInterrupt at once, not when the
    call returns (the pipeline has no points at which it checks for signals;
    the call waits for it on another thread and runs the signal handlers
    every 50 ms). The interrupted work runs on in the background; the next
    call waits for it (with a RuntimeWarning), so repeated interrupts do not
    pile up work, and that call's result is the full one."""
    echoes, expected, once = slow_echoes(11, 0.8, 5_120_000)
    slow = lambda: chirpmap.map_echoes(echoes, bounds=(-40, -40, 40, 40))  # noqa: E731
    took = interrupted_after(0.1, slow)
    assert took < 0.5 * once, f"KeyboardInterrupt came after {took:.3f} s; the whole call takes {once:.3f} s"
    # Interrupted again while waiting for the first call's work: no second worker starts.
    assert interrupted_once_waiting(slow, 0.5 * once), "the next call did not wait for the interrupted work"
    if sys.platform.startswith("linux"):
        assert chirpmap_threads() <= 1, f"{chirpmap_threads()} workers of interrupted calls run at once"
    with pytest.warns(RuntimeWarning, match="interrupted call"):
        again = chirpmap.map_echoes(echoes, bounds=(-40, -40, 40, 40))
    assert np.array_equal(again.grid, expected.grid)


def _forked_work(seed: int) -> tuple:
    """Work for a forked child: rayon's parallel steps in simulate and the
    evidence mapper (run in `test_calls_work_in_forked_children`)."""
    run = chirpmap.simulate({"particles": {"per_tick": 360}}, seed=seed)
    mapped = chirpmap.map_echoes(run.echoes, mapper="evidence")
    return len(run.echoes), mapped.grid.tobytes()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork is POSIX only")
def test_calls_work_in_forked_children():
    """multiprocessing's default on Linux forks: a child inherits the
    parent's thread pool's memory but not its threads. With rayon's global
    pool, built at import, every parallel call in a child waited forever.
    Children now build their own pool; their results are the parent's."""
    import multiprocessing

    expected = [_forked_work(s) for s in (1, 2)]
    with multiprocessing.get_context("fork").Pool(2) as workers:
        got = workers.map_async(_forked_work, [1, 2]).get(timeout=120)
    assert got == expected


def test_python_audit_findings(tmp_path):
    """Session 26's audit of the package as a researcher uses it: numpy
    values in dicts, (channels, frames) arrays, a channel of mono samples,
    hydra-style scene paths, strings for points, and compare flags."""
    # numpy scalars and arrays in a scene or evidence dict are numbers.
    a = chirpmap.simulate({"seed": np.int64(3), "particles": {"per_tick": np.int32(360)}})
    b = chirpmap.simulate({"seed": 3, "particles": {"per_tick": 360}})
    assert np.array_equal(a.grid, b.grid)
    rows = np.array([GOOD, GOOD])
    m1 = chirpmap.map_echoes(rows, mapper="evidence", evidence={"min_support": np.int64(4)})
    m2 = chirpmap.map_echoes(rows, mapper="evidence", evidence={"min_support": 4})
    assert np.array_equal(m1.grid, m2.grid)
    with pytest.raises(ValueError, match=r"scene dict: a value of type object is not a number"):
        chirpmap.simulate({"seed": object()})
    rec, rate, poses = chirpmap.synth({"synth": {"chirps": 2}})
    with pytest.raises(ValueError, match=r"samples: shape \(1, \d+\) has fewer samples than channels; .*samples\.T"):
        chirpmap.range(rec.T, rate, (-3, 10), (0, 0))
    with pytest.raises(ValueError, match=r"channel: 7 is not a channel of 1-D samples"):
        chirpmap.range(rec[:, 0], rate, (-3, 10), (0, 0), channel=7)
    with pytest.raises(TypeError, match=r"speaker must be a pair of numbers \(x, y\), not a string"):
        chirpmap.range(rec[:, 0], rate, "00", (0, 0))
    with pytest.raises(TypeError, match=r"compare must be True or False, not str"):
        chirpmap.range(rec[:, 0], rate, (-3, 10), (0, 0), compare="no")
    with pytest.raises(TypeError, match=r"echoes must be real, not complex"):
        chirpmap.map_echoes(np.array([GOOD, GOOD], dtype=complex))
    # The CLI's default method.
    assert chirpmap.range(rec[:, 0], rate, (-3, 10), (0, 0))["method"] == "gap"
    # Integers no TOML integer holds, named by key (JSON turned 2**64 into a float).
    for big in (2**63, 2**64, 2**70, -(2**63) - 1):
        with pytest.raises(ValueError, match=r"scene dict: `particles.per_tick` is -?\d+, beyond a TOML integer's range"):
            chirpmap.simulate({"particles": {"per_tick": big}})
    # One-line TOML text that mentions a .toml file is still text.
    assert chirpmap.simulate("seed = 3  # as in run.toml").seed == 3
    # A mono calibration with a stereo recording is named as the calibration.
    with pytest.raises(ValueError, match=r"channel: 1 is not a channel of 1-D calibration"):
        chirpmap.room_echoes(np.stack([rec[:, 0]] * 2, axis=1), rate, (0, 0), (1, 0), calibration=rec[:, 0], channel=1)
    # A missing scene file named with `=` is a missing file, not bad TOML.
    with pytest.raises(ValueError) as e:
        chirpmap.simulate(str(tmp_path / "runs" / "a=1.toml"))
    assert "a=1.toml" in str(e.value) and "invalid parameter scene" not in str(e.value)
    # Results compare by identity (their arrays have no single truth value) and hash.
    assert a == a and a != b and len({a, b}) == 2


def test_read_echoes_by_column_name(tmp_path):
    """echoes.csv read by its header's names: a `map --wav --method doppler`
    file's `delta_d_rate` is not `sigma_m` (np.loadtxt read it as such, and
    map_echoes gave another grid than `chirpmap map --echoes`)."""
    doppler = tmp_path / "echoes.csv"
    doppler.write_text(
        "source_x,source_y,listener_x,listener_y,delta_d,weight,t,listener,delta_d_rate\n"
        "0,0,1,1,2.5,1,0.01,0,0.41\n"
        "0,0,1.1,1,2.4,1,0.02,0,\n"
    )
    got = chirpmap.read_echoes(doppler)
    assert got.shape == (2, 9)
    assert np.array_equal(got[:, :8], [[0, 0, 1, 1, 2.5, 1, 0.01, 0], [0, 0, 1.1, 1, 2.4, 1, 0.02, 0]])
    assert np.isnan(got[:, 8]).all()
    positional = np.loadtxt(doppler, delimiter=",", skiprows=1, max_rows=1, ndmin=2)
    assert positional[0, 8] == 0.41  # what a positional reader takes for sigma_m
    # Columns in any order, empty cells and absent columns take defaults.
    shuffled = tmp_path / "shuffled.csv"
    shuffled.write_text("sigma_m,delta_d,listener_y,listener_x,source_y,source_x,extra\n0.02,2.5,1,1,0,0,x\n,2.4,1,1.1,0,0,y\n")
    got = chirpmap.read_echoes(str(shuffled))
    # Excel's "CSV UTF-8" byte-order mark, and bytes that are not UTF-8 in
    # a column left out, as the CLI reads them.
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + shuffled.read_bytes().replace(b",x\n", b",\xff\n"))
    assert np.array_equal(chirpmap.read_echoes(bom), got, equal_nan=True)
    assert np.array_equal(got[0], [0, 0, 1, 1, 2.5, 1, 0, 0, 0.02])
    assert np.array_equal(got[1, :8], [0, 0, 1.1, 1, 2.4, 1, 0, 0]) and np.isnan(got[1, 8])
    for text, message in [
        ("source_x,source_y,listener_x,listener_y\n0,0,1,1\n", r"bad.csv:1: missing column `delta_d`"),
        ("source_x,source_y,listener_x,listener_y,delta_d\n0,0,1,1,two\n", r"bad.csv:2: `delta_d` = 'two' is not a number"),
        ("source_x,source_y,listener_x,listener_y,delta_d\n0,0,1,1\n", r"bad.csv:2: 4 fields where the header has 5"),
        ("source_x,source_y,listener_x,listener_y,delta_d\n0,0,1,1,\n", r"bad.csv:2: missing value for `delta_d`"),
        ("delta_d,delta_d\n1,2\n", r"bad.csv:1: column `delta_d` appears twice"),
        ("", r"bad.csv:1: no header"),
        # Rust's number syntax, as the CLI reads: no `2_5` (Python's float() read 25).
        ("source_x,source_y,listener_x,listener_y,delta_d\n0,0,1,1,2_5\n", r"bad.csv:2: `delta_d` = '2_5' is not a number"),
        ("source_x,source_y,listener_x,listener_y,delta_d,sigma_m\n0,0,1,1,2,nan\n", r"bad.csv:2: `sigma_m` = 'nan' is not finite"),
    ]:
        bad = tmp_path / "bad.csv"
        bad.write_text(text)
        with pytest.raises(ValueError, match=message):
            chirpmap.read_echoes(bad)


def test_sample_arrays_are_checked_by_kind():
    """Empty samples, integer types no WAV holds, and measurement periods
    that are not positive milliseconds are refused, each named."""
    rec, rate, poses = chirpmap.synth({"synth": {"chirps": 2}})
    with pytest.raises(ValueError, match=r"samples: empty \(no samples\)"):
        chirpmap.room_echoes(np.zeros(0), rate, (0, 0), (1, 0), input="rir")
    with pytest.raises(TypeError, match=r"samples: int64 is not a PCM format chirpmap reads \(int16, int32\)"):
        chirpmap.range(np.zeros(100_000, dtype=np.int64), rate, (-3, 10), (0, 0))
    for kwargs, message in [
        ({"period_ms": -1}, r"period_ms: must be a number of milliseconds > 0, got -1"),
        ({"period_ms": float("nan")}, r"period_ms: must be a number of milliseconds > 0, got nan"),
        ({"frame_ms": 0}, r"frame_ms: must be a number of milliseconds > 0, got 0"),
    ]:
        with pytest.raises(ValueError, match=message):
            chirpmap.echoes_from_recording(rec[:, 0], rate, poses[0], (0, 0), **kwargs)
    # int16 PCM is the float recording's samples, quantised: ranged alike.
    pcm = np.clip(np.round(rec[:, 0].astype(np.float64) * 32768), -32768, 32767).astype(np.int16)
    a = chirpmap.range(pcm, rate, (-3, 10), (0, 0))
    b = chirpmap.range(pcm.astype(np.float32) / np.float32(32768), rate, (-3, 10), (0, 0))
    assert a == b


def test_errors_name_python_arguments_not_cli_flags():
    """The library's messages name the CLI's flags ("check --f-start/--f-end/
    --duration"); Python's name the arguments."""
    noise = np.random.default_rng(2).standard_normal(96000).astype(np.float32) * 0.01
    with pytest.raises(ValueError) as e:
        chirpmap.range(noise, 48000.0, (0, 0), (1, 0))
    assert "no chirp found" in str(e.value) and "f_start/f_end/duration" in str(e.value)
    assert "--" not in str(e.value), str(e.value)
    with pytest.raises(ValueError) as e:
        chirpmap.map_echoes(np.array([GOOD, GOOD]), bounds=(-1e5, -1e5, 1e5, 1e5), cell=0.01)
    assert "smaller bounds or a larger cell" in str(e.value) and "--" not in str(e.value), str(e.value)


def test_the_worked_example_runs(tmp_path):
    """examples/python/plot_map.py, which the README calls the worked
    example, runs to its figure (it crashed once `scores` held the surface
    metrics' list of walls)."""
    pytest.importorskip("matplotlib")
    import subprocess

    script = pathlib.Path(__file__).resolve().parents[3] / "examples" / "python" / "plot_map.py"
    out = tmp_path / "plot.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    p = subprocess.run([sys.executable, str(script), str(out)], capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert out.stat().st_size > 10_000
