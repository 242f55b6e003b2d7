//! `chirpmap._chirpmap`: the compiled half of the Python package `chirpmap`
//! (issue 12). It calls the facade crate [`chirpmap`] and nothing else, so
//! Python gets the CLI's numbers bit for bit; the Python half
//! (`python/chirpmap/__init__.py`) turns arguments into the plain types
//! used here and wraps the results in documented dataclasses.
//!
//! Arrays leave without copies where Rust owns the buffer (a grid's
//! `Vec<f64>` becomes the `(ny, nx)` array's memory). Inputs are checked in
//! place (read-only borrows of contiguous numpy buffers) and copied once
//! for the work, which runs on a thread of its own while the calling thread
//! waits with the interpreter detached ([`interruptible`]): other Python
//! threads run meanwhile, and Ctrl-C raises `KeyboardInterrupt` at once.
//! Every failure is a `ValueError` carrying the facade's message; nothing
//! here panics on user data.
//!
//! `room_echoes` (issue 10, "every reflection") is `chirpmap range
//! --echoes`; its plain-Rust half, which assembles the facade's inputs as
//! the CLI does, is [`rooms`].

pub mod convert;
pub mod rooms;

use chirpmap::audio::Method;
use chirpmap::{ChirpSpec, MapOptions, MapResult, Point, RangeGeometry};
use convert::{SceneSource, error_text};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

fn value_error(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(python_names(msg.into()))
}

/// The CLI's flags in the library's messages ("check --f-start/--f-end/
/// --duration", "pass smaller --bounds or a larger --cell") as the Python
/// arguments they are here.
fn python_names(mut msg: String) -> String {
    const FLAGS: [(&str, &str); 15] = [
        ("--f-start", "f_start"),
        ("--f-end", "f_end"),
        ("--duration", "duration"),
        ("--max-delta-d", "max_delta_d"),
        ("--speed-of-sound", "speed_of_sound"),
        ("--bounds", "bounds"),
        ("--cell", "cell"),
        ("--channel", "channel"),
        ("--floor-z", "floor_z"),
        ("--ceiling-z", "ceiling_z"),
        ("--speaker", "speaker"),
        ("--mic", "mic"),
        ("--calibration", "calibration"),
        ("--sweep", "sweep"),
        ("--period-ms", "period_ms"),
    ];
    if msg.contains("--") {
        for (flag, arg) in FLAGS {
            msg = msg.replace(flag, arg);
        }
    }
    msg
}

/// The name of a call's worker thread ([`interruptible`]).
const WORKER_NAME: &str = "chirpmap-call";

/// How often a waiting call runs Python's signal handlers.
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// The threads of interrupted calls that may still be running. The next
/// call waits for them before it starts ([`wait_for_abandoned`]), so
/// interrupted work never piles up: each runs on all cores (rayon) and
/// holds its call's memory, which the caps bound per call, not per process.
/// Each thread is listed with the process that started it: a forked child
/// (`multiprocessing`'s default on Linux) inherits the list but not the
/// threads, which would never finish there.
static ABANDONED: std::sync::Mutex<Vec<(ProcessKey, std::thread::JoinHandle<()>)>> = std::sync::Mutex::new(Vec::new());

fn abandoned() -> std::sync::MutexGuard<'static, Vec<(ProcessKey, std::thread::JoinHandle<()>)>> {
    // The list stays valid whatever a holder did: a poisoned lock is taken as is.
    let mut list = ABANDONED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let me = process_key();
    if list.iter().any(|(key, _)| *key != me) {
        // A parent's threads: their handles are forgotten, not dropped
        // (dropping detaches a thread this process does not have).
        for entry in std::mem::take(&mut *list) {
            if entry.0 == me {
                list.push(entry);
            } else {
                std::mem::forget(entry);
            }
        }
    }
    list
}

/// This process's rayon pool, on which every call's work runs. Not rayon's
/// global pool: a forked child inherits a pool's memory but none of its
/// threads, so its first parallel step would wait forever (a
/// `multiprocessing.Pool` of seeds hung, whether or not the parent had
/// called chirpmap, since the global pool was built at import). A child
/// builds its own on its first call.
static POOL: std::sync::Mutex<Option<(ProcessKey, std::sync::Arc<rayon::ThreadPool>)>> = std::sync::Mutex::new(None);

/// A process: its id and the forks before it ([`FORKS`]).
type ProcessKey = (u32, u64);

fn process_key() -> ProcessKey {
    (std::process::id(), FORKS.load(std::sync::atomic::Ordering::Relaxed))
}

/// Forks seen by this process's line of descent (Python's
/// `os.register_at_fork` calls [`after_fork`] in each child): with the
/// process id, it names the process a pool belongs to even if a child got
/// the id of a dead ancestor that had built one.
static FORKS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Counts a fork; the package registers it with `os.register_at_fork`.
#[pyfunction]
fn after_fork() {
    FORKS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
}

fn pool() -> Result<std::sync::Arc<rayon::ThreadPool>, String> {
    let mut slot = POOL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let me = process_key();
    match slot.take() {
        Some((key, pool)) if key == me => {
            *slot = Some((key, pool.clone()));
            return Ok(pool);
        }
        // A parent's pool: forgotten, as its threads are not here to stop.
        Some(parent) => std::mem::forget(parent),
        None => {}
    }
    // rayon's threads named as such: unnamed, they would take the name of
    // the thread that starts the pool, a call's worker.
    let pool = rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("chirpmap-rayon-{i}"))
        .build()
        .map(std::sync::Arc::new)
        .map_err(|e| format!("cannot start chirpmap's threads: {e}"))?;
    *slot = Some((me, pool.clone()));
    Ok(pool)
}

/// Waits, interruptibly, until the work of every interrupted call has
/// ended, with a `RuntimeWarning` when there is any to wait for.
fn wait_for_abandoned(py: Python<'_>) -> PyResult<()> {
    let mut warned = false;
    loop {
        let running = {
            let mut list = abandoned();
            list.retain(|(_, h)| !h.is_finished());
            !list.is_empty()
        };
        if !running {
            return Ok(());
        }
        if !warned {
            let category = py.get_type::<pyo3::exceptions::PyRuntimeWarning>();
            let text =
                c"chirpmap: waiting for an interrupted call's work to end (it cannot stop early) before this call";
            PyErr::warn(py, category.as_any(), text, 1)?;
            warned = true;
        }
        py.detach(|| std::thread::sleep(SIGNAL_POLL));
        py.check_signals()?;
    }
}

/// Runs `work` on a thread of its own; this thread waits with the
/// interpreter detached and wakes every [`SIGNAL_POLL`] to run Python's
/// signal handlers (`Python::check_signals`). So Ctrl-C raises
/// `KeyboardInterrupt` within 50 ms: the pipeline has no points at which
/// it could check for signals itself (a call used to be uninterruptible
/// until it returned). The interrupted work runs on to its end in the
/// background and its result is dropped (it owns its inputs, and touches
/// no Python object and no file); the next call first waits for it. Waiting
/// costs nothing when no signal comes: the result is taken the moment it
/// is sent (a call costs ~0.1 ms more for the thread).
fn interruptible<T: Send + 'static>(
    py: Python<'_>,
    work: impl FnOnce() -> Result<T, String> + Send + 'static,
) -> PyResult<T> {
    use std::sync::mpsc::RecvTimeoutError;
    wait_for_abandoned(py)?;
    let pool = pool().map_err(PyRuntimeError::new_err)?;
    let (tx, mut rx) = std::sync::mpsc::sync_channel(1);
    let worker = std::thread::Builder::new()
        .name(WORKER_NAME.into())
        .spawn(move || {
            // The receiver is gone when the call was interrupted.
            let _ = tx.send(pool.install(work));
        })
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start a thread for the computation: {e}")))?;
    loop {
        // The receiver is moved in and out: a borrow of it is not `Send`.
        let (back, got) = py.detach(move || {
            let got = rx.recv_timeout(SIGNAL_POLL);
            (rx, got)
        });
        rx = back;
        match got {
            Ok(result) => return result.map_err(value_error),
            Err(RecvTimeoutError::Timeout) => {
                if let Err(e) = py.check_signals() {
                    abandoned().push((process_key(), worker));
                    return Err(e);
                }
            }
            Err(RecvTimeoutError::Disconnected) => {
                return Err(PyRuntimeError::new_err("chirpmap's computation stopped without a result (a panic)"));
            }
        }
    }
}

/// Refuses a sample that is not finite or beyond ±10⁶ × full scale, naming
/// `what` and its index, as the CLI's WAV reader does: such a sample gave
/// "no chirp found" (a float64 beyond float32's range arrives as inf).
fn check_samples(x: &[f32], what: &str) -> PyResult<()> {
    let bad = x.iter().position(|v| !(v.is_finite() && f64::from(v.abs()) <= chirpmap::audio::error::MAX_FLOAT_SAMPLE));
    match bad {
        None => Ok(()),
        Some(i) => Err(value_error(format!(
            "{what}[{i}] is {}: samples must be finite and within ±{} (a float64 beyond float32's range becomes inf)",
            chirpmap::core::error::Num(f64::from(x[i])),
            chirpmap::core::error::Num(chirpmap::audio::error::MAX_FLOAT_SAMPLE)
        ))),
    }
}

/// A scene's payload as the wrapper sends it: text (TOML, or a dict's
/// JSON) or a path. A path is taken as the OS's bytes: taken as `str`, a
/// file name that is not UTF-8 raised `UnicodeEncodeError`.
enum Payload {
    Text(String),
    Path(std::path::PathBuf),
    Nothing,
}

fn read_payload(kind: &str, payload: &Bound<'_, PyAny>) -> PyResult<Payload> {
    Ok(match kind {
        "default" => Payload::Nothing,
        "path" => Payload::Path(payload.extract()?),
        _ => Payload::Text(payload.extract()?),
    })
}

fn scene_source<'a>(kind: &str, payload: &'a Payload) -> Result<SceneSource<'a>, String> {
    match (kind, payload) {
        ("default", _) => Ok(SceneSource::Default),
        ("toml", Payload::Text(t)) => Ok(SceneSource::Toml(t)),
        ("json", Payload::Text(t)) => Ok(SceneSource::Json(t)),
        ("path", Payload::Path(p)) => Ok(SceneSource::Path(p)),
        (other, _) => Err(format!("unknown scene kind {other:?}")),
    }
}

/// A row-major `rows × cols` table as a numpy array, moving the buffer.
fn table<'py>(py: Python<'py>, data: Vec<f64>, cols: usize) -> PyResult<Bound<'py, PyAny>> {
    let rows = data.len().checked_div(cols).unwrap_or(0);
    let arr = Array2::from_shape_vec((rows, cols), data).map_err(|e| value_error(e.to_string()))?;
    Ok(arr.into_pyarray(py).into_any())
}

/// The fields every map result has (see `MapResult` in `__init__.py`).
fn map_fields<'py>(py: Python<'py>, d: &Bound<'py, PyDict>, map: MapResult) -> PyResult<()> {
    let spec = map.grid.spec;
    let (x0, y0, x1, y1) = (spec.x_min_m, spec.y_min_m, spec.x_max_m(), spec.y_max_m());
    d.set_item("extent", (x0, x1, y0, y1))?;
    d.set_item("bounds", (x0, y0, x1, y1))?;
    d.set_item("cell", spec.cell_m)?;
    d.set_item("cells_updated", map.cells_updated)?;
    d.set_item("highlights", table(py, convert::highlights_to_rows(&map.highlights), 3)?)?;
    let surfaces = PyList::empty(py);
    for s in &map.surfaces {
        let (kind, [sx0, sy0, sx1, sy1], support, ambiguous) = convert::surface_fields(s);
        let row = PyDict::new(py);
        row.set_item("kind", kind)?;
        row.set_item("x0", sx0)?;
        row.set_item("y0", sy0)?;
        row.set_item("x1", sx1)?;
        row.set_item("y1", sy1)?;
        row.set_item("support", support)?;
        row.set_item("ambiguous", ambiguous)?;
        surfaces.append(row)?;
    }
    d.set_item("surfaces", surfaces)?;
    d.set_item("mapping", serde_json::to_string(&map.params).map_err(|e| value_error(e.to_string()))?)?;
    // Last: moves the grid's buffer into the array (rows = y).
    let grid = Array2::from_shape_vec((spec.ny, spec.nx), map.grid.data).map_err(|e| value_error(e.to_string()))?;
    d.set_item("grid", grid.into_pyarray(py))?;
    Ok(())
}

/// Simulates a scene, maps and scores it (`chirpmap simulate`).
#[pyfunction]
#[pyo3(signature = (scene_kind, scene_payload, seed=None))]
fn simulate<'py>(
    py: Python<'py>,
    scene_kind: &str,
    scene_payload: &Bound<'py, PyAny>,
    seed: Option<u64>,
) -> PyResult<Bound<'py, PyDict>> {
    let payload = read_payload(scene_kind, scene_payload)?;
    let kind = scene_kind.to_owned();
    if seed.is_some_and(|s| s > i64::MAX as u64) {
        return Err(value_error("seed: must be between 0 and 2^63 - 1 (scene.toml records it as a TOML integer)"));
    }
    let run = interruptible(py, move || {
        let (mut scene, _, name) = convert::load_scene(scene_source(&kind, &payload)?)?;
        if let Some(s) = seed {
            scene.seed = s;
        }
        let run = chirpmap::simulate(&scene).map_err(|e| format!("{name}: {}", error_text(&e)))?;
        // The surface metrics `chirpmap simulate` writes to summary.json.
        let eval = chirpmap::evaluate(&run.resolved.obstacles, &run.map, &run.output.echoes);
        Ok((run, eval))
    })?;
    let (run, eval) = run;
    let d = PyDict::new(py);
    let (rows, cols) = convert::echoes_to_rows(&run.output.echoes);
    d.set_item("echoes", table(py, rows, cols)?)?;
    let scores = PyDict::new(py);
    scores.set_item("score_obstacle", run.scores.score_obstacle)?;
    scores.set_item("score_highlight", run.scores.score_highlight)?;
    let m = &eval.surfaces;
    scores.set_item("surface_precision", m.precision)?;
    scores.set_item("surface_recall", m.recall)?;
    scores.set_item("surface_f1", m.f1)?;
    scores.set_item("chamfer_m", m.chamfer_m)?;
    let walls = PyList::empty(py);
    for w in &m.walls {
        let wall = PyDict::new(py);
        wall.set_item("a", [w.a.x, w.a.y])?;
        wall.set_item("b", [w.b.x, w.b.y])?;
        wall.set_item("offset_m", w.offset_m)?;
        wall.set_item("angle_deg", w.angle_deg)?;
        walls.append(wall)?;
    }
    scores.set_item("walls", walls)?;
    d.set_item("scores", scores)?;
    d.set_item("scene", run.resolved.scene.to_toml_string())?;
    d.set_item("seed", run.resolved.scene.seed)?;
    d.set_item("n_measurements", run.output.measurements.len())?;
    d.set_item("n_obstacles", run.resolved.obstacles.len())?;
    d.set_item("simulate_elapsed_s", run.simulate_elapsed_s)?;
    map_fields(py, &d, run.map)?;
    Ok(d)
}

/// Maps echoes (`chirpmap map --echoes`).
#[pyfunction]
#[pyo3(signature = (echoes, sigma, bounds, cell, keep_top, min_of_max, peak_radius, ellipse_points, mapper, evidence_json))]
#[allow(clippy::too_many_arguments)]
fn map_echoes<'py>(
    py: Python<'py>,
    echoes: PyReadonlyArray2<'py, f64>,
    sigma: Option<PyReadonlyArray1<'py, f64>>,
    bounds: Option<[f64; 4]>,
    cell: f64,
    keep_top: Option<f64>,
    min_of_max: Option<f64>,
    peak_radius: Option<f64>,
    ellipse_points: u32,
    mapper: &str,
    evidence_json: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    let cols = echoes.as_array().ncols();
    let data = echoes.as_slice().map_err(|_| value_error("echoes must be a C-contiguous array"))?;
    let sigma = match &sigma {
        Some(s) => Some(s.as_slice().map_err(|_| value_error("sigma must be a contiguous array"))?),
        None => None,
    };
    let params =
        convert::mapping_params(cell, keep_top, min_of_max, peak_radius, ellipse_points, mapper, evidence_json)
            .map_err(value_error)?;
    if sigma.is_some() && params.mapper == chirpmap::MapperKind::Paper {
        return Err(value_error(
            "sigma: applies to mapper='evidence' only (Algorithm 1 draws every echo one cell wide)",
        ));
    }
    // The rows become echoes here (detached, reading numpy's buffer in
    // place); the worker gets the echoes, not a copy of the rows.
    let echoes = py.detach(|| convert::echoes_from_rows(data, cols, sigma)).map_err(value_error)?;
    let map = interruptible(py, move || {
        let opts = MapOptions { params, bounds, ..MapOptions::default() };
        chirpmap::map_echoes(&echoes, &[], &opts).map_err(|e| error_text(&e))
    })?;
    let d = PyDict::new(py);
    map_fields(py, &d, map)?;
    Ok(d)
}

/// Renders what the scene's listeners record (`chirpmap synth`): samples
/// `(n_samples, n_listeners)` float32, the sample rate (Hz) and per
/// listener an `(m, 3)` array of poses `t, x, y`.
#[pyfunction]
fn synth<'py>(
    py: Python<'py>,
    scene_kind: &str,
    scene_payload: &Bound<'py, PyAny>,
) -> PyResult<(Bound<'py, PyAny>, u32, Bound<'py, PyList>)> {
    let payload = read_payload(scene_kind, scene_payload)?;
    let kind = scene_kind.to_owned();
    let (samples, rate, poses) = interruptible(py, move || {
        let (scene, cfg, name) = convert::load_scene(scene_source(&kind, &payload)?)?;
        // The poses are handed out as (m, 3) arrays, built while the
        // rendering's own poses are alive: counted twice against the
        // cap (a scene just under it peaked at twice its estimate).
        let (_, poses_per_listener) = chirpmap::audio::synth::synth_lengths(&scene, &cfg);
        let copy = scene.listeners.len() as f64 * poses_per_listener * 24.0;
        chirpmap::audio::error::check_memory(
            || format!("{name}: the rendering and its poses as arrays"),
            (chirpmap::audio::synth::synth_memory_bytes(&scene, &cfg) + copy) as u128,
            "fewer chirps, a lower sample rate or a longer pose_period_s",
        )
        .map_err(|e| e.to_string())?;
        let syn = chirpmap::synth(&scene, &cfg).map_err(|e| format!("{name}: {}", error_text(&e)))?;
        let n_listeners = syn.channels.len();
        let n = syn.channels.first().map_or(0, Vec::len);
        if syn.channels.iter().any(|c| c.len() != n) {
            return Err(format!("{name}: the listeners' channels differ in length"));
        }
        let mut channels = syn.channels;
        let samples = if n_listeners == 1 {
            // One listener: the channel's buffer itself, as an (n, 1) array.
            Array2::from_shape_vec((n, 1), channels.pop().unwrap_or_default())
        } else {
            // Several: one buffer (L, n), handed out transposed (a view).
            let mut flat = Vec::with_capacity(n * n_listeners);
            for c in channels {
                flat.extend(c);
            }
            Array2::from_shape_vec((n_listeners, n), flat).map(Array2::reversed_axes)
        }
        .map_err(|e| e.to_string())?;
        let poses: Vec<Vec<f64>> =
            syn.poses.iter().map(|p| p.iter().flat_map(|&(t, q)| [t, q.x, q.y]).collect()).collect();
        Ok((samples, syn.sample_rate_hz, poses))
    })?;
    let pose_list = PyList::empty(py);
    for p in poses {
        pose_list.append(table(py, p, 3)?)?;
    }
    Ok((samples.into_pyarray(py).into_any(), rate, pose_list))
}

/// Ranges a recording (`chirpmap range`): the summary as JSON text, the
/// keys of range's summary.json.
#[pyfunction]
#[pyo3(signature = (samples, sample_rate, speaker, mic, wall_normal, methods, primary, f_start, f_end, duration, speed_of_sound, max_delta_d))]
#[allow(clippy::too_many_arguments)]
fn range(
    py: Python<'_>,
    samples: PyReadonlyArray1<'_, f32>,
    sample_rate: f64,
    speaker: [f64; 2],
    mic: [f64; 2],
    wall_normal: Option<[f64; 2]>,
    methods: Vec<String>,
    primary: usize,
    f_start: f64,
    f_end: f64,
    duration: f64,
    speed_of_sound: f64,
    max_delta_d: Option<f64>,
) -> PyResult<String> {
    let methods: Vec<Method> = methods
        .iter()
        .map(|m| m.parse())
        .collect::<Result<_, String>>()
        .map_err(|e| value_error(format!("method: {e}")))?;
    if !(sample_rate.is_finite() && sample_rate > 0.0) {
        return Err(value_error(format!("sample_rate: must be finite and > 0 Hz, got {sample_rate}")));
    }
    let geom = RangeGeometry {
        speaker: Point::new(speaker[0], speaker[1]),
        mic: Point::new(mic[0], mic[1]),
        wall_normal: wall_normal.map(|[x, y]| Point::new(x, y)),
    };
    let chirp = ChirpSpec {
        f_start_hz: f_start,
        f_end_hz: f_end,
        duration_s: duration,
        speed_of_sound_mps: speed_of_sound,
        max_delta_d_m: max_delta_d,
        kind: chirpmap::core::scene::SweepKind::Linear,
    };
    let x = samples.as_slice().map_err(|_| value_error("samples must be a contiguous array"))?;
    check_samples(x, "samples")?;
    let x = x.to_vec();
    interruptible(py, move || {
        geom.validate().map_err(|e| error_text(&e))?;
        let prep = chirpmap::prepare(x, sample_rate, &chirp).map_err(|e| error_text(&e))?;
        let report = chirpmap::range(&prep, &methods, &geom).map_err(|e| error_text(&e))?;
        let summary = report.summary(&prep, &chirp, &geom, primary);
        serde_json::to_string(&summary).map_err(|e| e.to_string())
    })
}

/// What [`echoes_from_recording`] returns: the echoes' table, the chirps
/// detected, those skipped for want of a pose, and each echo's Δḋ (m/s).
type RecordingTuple<'py> = (Bound<'py, PyAny>, usize, usize, Bound<'py, PyArray1<f64>>);

/// Echoes of a moving listener's recording (`chirpmap map --wav`): the
/// echoes as an `(n, 8)` or `(n, 9)` table (with `sigma_m`), the chirps
/// detected, those skipped for want of a pose, and the path-difference
/// rates (NaN where the method gives none).
#[pyfunction]
#[pyo3(signature = (samples, sample_rate, poses, speaker, method, period_s, frame_s, listener, f_start, f_end, duration, speed_of_sound, max_delta_d, pattern=None, echoes_per_frame=None, sweep=None))]
#[allow(clippy::too_many_arguments)]
fn echoes_from_recording<'py>(
    py: Python<'py>,
    samples: PyReadonlyArray1<'py, f32>,
    sample_rate: f64,
    poses: PyReadonlyArray2<'py, f64>,
    speaker: [f64; 2],
    method: &str,
    period_s: f64,
    frame_s: Option<f64>,
    listener: u32,
    f_start: f64,
    f_end: f64,
    duration: f64,
    speed_of_sound: f64,
    max_delta_d: Option<f64>,
    pattern: Option<&str>,
    echoes_per_frame: Option<usize>,
    sweep: Option<&str>,
) -> PyResult<RecordingTuple<'py>> {
    let kind = sweep.map(rooms::parse_sweep).transpose().map_err(value_error)?.unwrap_or_default();
    let method: chirpmap::audio::doppler::WavMethod =
        method.parse().map_err(|e| value_error(format!("method: {e}")))?;
    let pattern: Option<chirpmap::audio::synth::ChirpPattern> =
        pattern.map(str::parse).transpose().map_err(|e| value_error(format!("pattern: {e}")))?;
    if !(sample_rate.is_finite() && sample_rate > 0.0) {
        return Err(value_error(format!("sample_rate: must be finite and > 0 Hz, got {sample_rate}")));
    }
    if poses.as_array().ncols() != 3 {
        return Err(value_error(format!("poses must be (m, 3): t, x, y; got {} columns", poses.as_array().ncols())));
    }
    let rows: Vec<(f64, Point)> = poses.as_array().rows().into_iter().map(|r| (r[0], Point::new(r[1], r[2]))).collect();
    let chirp = ChirpSpec {
        f_start_hz: f_start,
        f_end_hz: f_end,
        duration_s: duration,
        speed_of_sound_mps: speed_of_sound,
        max_delta_d_m: max_delta_d,
        kind,
    };
    let opts = chirpmap::audio::doppler::MovingOptions {
        method,
        pattern,
        period_s,
        frame_s,
        speaker: Point::new(speaker[0], speaker[1]),
        listener_id: listener,
        echoes_per_frame: echoes_per_frame.unwrap_or(method.default_echoes_per_frame()),
    };
    let x = samples.as_slice().map_err(|_| value_error("samples must be a contiguous array"))?;
    check_samples(x, "samples")?;
    let x = x.to_vec();
    let got = interruptible(py, move || {
        let track = chirpmap::PoseTrack::new(rows).map_err(|e| format!("poses: {}", error_text(&e)))?;
        // As `map --wav`: the doppler method ranges any sweep through its
        // inverse, and the prepared channel does not depend on the shape
        // (only its template, unused there); the others need a linear one.
        let linear = ChirpSpec { kind: chirpmap::core::scene::SweepKind::Linear, ..chirp };
        let for_prep = if method == chirpmap::audio::doppler::WavMethod::Doppler { &linear } else { &chirp };
        let prep = chirpmap::prepare(x, sample_rate, for_prep).map_err(|e| error_text(&e))?;
        chirpmap::RecordingEchoes::from_moving(&prep, &chirp, &track, &opts).map_err(|e| error_text(&e))
    })?;
    let (rows, cols) = convert::echoes_to_rows(&got.echoes);
    // NaN where the method gives no rate (echoes.csv leaves the cell empty).
    let rates: Vec<f64> = got.delta_d_rates_mps.iter().map(|r| r.unwrap_or(f64::NAN)).collect();
    Ok((table(py, rows, cols)?, got.chirps, got.chirps_without_pose, rates.into_pyarray(py)))
}

/// Every reflection of every chirp (`chirpmap range --echoes`, issue 10):
/// a dict with the echoes for the map (`(n, 8)`, the echoes.csv columns),
/// the columns `range --echoes` adds (`chirp`, `rank`, `path_delta_m`,
/// `strength_db`, `plane`), the chirps' onsets, the clusters, the
/// echogram `(m, 2)` and the predicted floor/ceiling echoes.
#[pyfunction]
#[pyo3(signature = (samples, sample_rate, speaker, mic, heights, floor_z, ceiling_z, input, calibration, max_echoes, echo_threshold_db, ringing_ms, echo_atom_ms, plane_tolerance, listener, f_start, f_end, duration, speed_of_sound, max_delta_d, sweep))]
#[allow(clippy::too_many_arguments)]
fn room_echoes<'py>(
    py: Python<'py>,
    samples: PyReadonlyArray1<'py, f32>,
    sample_rate: f64,
    speaker: [f64; 2],
    mic: [f64; 2],
    heights: Option<(f64, f64)>,
    floor_z: Option<f64>,
    ceiling_z: Option<f64>,
    input: &str,
    calibration: Option<PyReadonlyArray1<'py, f32>>,
    max_echoes: usize,
    echo_threshold_db: f64,
    ringing_ms: f64,
    echo_atom_ms: f64,
    plane_tolerance: f64,
    listener: u32,
    f_start: f64,
    f_end: f64,
    duration: f64,
    speed_of_sound: f64,
    max_delta_d: Option<f64>,
    sweep: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let input: rooms::Input = input.parse().map_err(value_error)?;
    let kind = rooms::parse_sweep(sweep).map_err(value_error)?;
    let geom = rooms::geometry(speaker, mic, heights, floor_z, ceiling_z).map_err(value_error)?;
    let opts = rooms::echo_options(max_echoes, echo_threshold_db, ringing_ms, echo_atom_ms, plane_tolerance)
        .map_err(value_error)?;
    let chirp = ChirpSpec {
        f_start_hz: f_start,
        f_end_hz: f_end,
        duration_s: duration,
        speed_of_sound_mps: speed_of_sound,
        max_delta_d_m: max_delta_d,
        kind,
    };
    let x = samples.as_slice().map_err(|_| value_error("samples must be a contiguous array"))?;
    check_samples(x, "samples")?;
    let cal = match &calibration {
        Some(c) => Some(c.as_slice().map_err(|_| value_error("calibration must be a contiguous array"))?),
        None => None,
    };
    if let Some(c) = cal {
        check_samples(c, "calibration")?;
    }
    let (x, cal) = (x.to_vec(), cal.map(<[f32]>::to_vec));
    let (report, echoes) = interruptible(py, move || {
        let report = rooms::room_report(x, sample_rate, input, &chirp, &geom, opts, cal)?;
        let echoes = report.map_echoes(&geom, listener).map_err(|e| error_text(&e))?;
        Ok((report, echoes))
    })?;
    let d = PyDict::new(py);
    let (rows, cols) = convert::echoes_to_rows(&echoes);
    d.set_item("echoes", table(py, rows, cols)?)?;
    let (chirps, ranks, path_delta_m, strength_db, planes) = rooms::room_columns(&report);
    d.set_item("chirp", chirps.into_pyarray(py))?;
    d.set_item("rank", ranks.into_pyarray(py))?;
    d.set_item("path_delta_m", path_delta_m.into_pyarray(py))?;
    d.set_item("strength_db", strength_db.into_pyarray(py))?;
    d.set_item("plane", planes)?;
    let onsets: Bound<'py, PyArray1<f64>> = report.chirp_onsets_s.into_pyarray(py);
    d.set_item("chirp_onsets_s", onsets)?;
    let clusters = PyList::empty(py);
    for c in &report.clusters {
        let row = PyDict::new(py);
        row.set_item("path_delta_m", c.path_delta_m)?;
        row.set_item("delta_d_m", c.delta_d_m)?;
        row.set_item("strength_db", c.strength_db)?;
        row.set_item("chirps", c.chirps)?;
        row.set_item("plane", c.plane)?;
        clusters.append(row)?;
    }
    d.set_item("clusters", clusters)?;
    let gram: Vec<f64> = report.echogram.iter().flat_map(|&(pd, db)| [pd, db]).collect();
    d.set_item("echogram", table(py, gram, 2)?)?;
    let predicted = PyList::empty(py);
    for &(plane, pd) in &report.predicted {
        let row = PyDict::new(py);
        row.set_item("plane", plane)?;
        row.set_item("path_delta_m", pd)?;
        predicted.append(row)?;
    }
    d.set_item("predicted", predicted)?;
    d.set_item("min_delta_d_m", report.min_delta_d_m)?;
    d.set_item("max_delta_d_m", report.max_delta_d_m)?;
    d.set_item("calibrated", report.calibrated)?;
    Ok(d)
}

/// The facade's defaults of `room_echoes`' keywords ([`chirpmap::EchoOptions::default`]),
/// which the Python signature repeats (a test compares them).
#[pyfunction]
fn room_echo_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let o = chirpmap::EchoOptions::default();
    let d = PyDict::new(py);
    d.set_item("max_echoes", o.max_echoes)?;
    d.set_item("echo_threshold_db", o.threshold_db)?;
    d.set_item("ringing_ms", o.ringing_s * 1e3)?;
    d.set_item("echo_atom_ms", o.echo_atom_s * 1e3)?;
    d.set_item("plane_tolerance", o.plane_tolerance_m)?;
    Ok(d)
}

/// The compiled part of `chirpmap`; use the functions of the `chirpmap`
/// package, which document their arguments and results.
#[pymodule]
fn _chirpmap(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(map_echoes, m)?)?;
    m.add_function(wrap_pyfunction!(synth, m)?)?;
    m.add_function(wrap_pyfunction!(range, m)?)?;
    m.add_function(wrap_pyfunction!(echoes_from_recording, m)?)?;
    m.add_function(wrap_pyfunction!(room_echoes, m)?)?;
    m.add_function(wrap_pyfunction!(room_echo_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(after_fork, m)?)?;
    Ok(())
}
