//! Runs jobs on a thread pool and hands finished rows to the caller (which
//! streams them to runs.csv) in completion order.

use crate::error::ExperimentError;
use crate::runs::{RunMetrics, RunRow};
use crate::sweep::{Job, Plan};
use chirpmap_core::Scene;
use rayon::prelude::*;
use std::sync::mpsc;
use std::time::Instant;

/// Runs `jobs` with `threads` workers. `run_one(scene, run_index)` must be
/// deterministic in its arguments. `on_row` sees every finished run; the first
/// error (from a run or from `on_row`) stops the sweep after in-flight runs.
pub fn execute(
    plan: &Plan,
    jobs: &[Job],
    threads: usize,
    run_one: impl Fn(&Scene, u64) -> Result<RunMetrics, String> + Sync,
    mut on_row: impl FnMut(RunRow) -> Result<(), ExperimentError>,
) -> Result<(), ExperimentError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .map_err(|e| ExperimentError::InvalidSweep(format!("cannot start {threads} threads: {e}")))?;
    let (tx, rx) = mpsc::channel::<Result<RunRow, ExperimentError>>();
    let stop = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|scope| {
        let stop = &stop;
        let run_one = &run_one;
        scope.spawn(move || {
            pool.install(|| {
                jobs.par_iter().with_max_len(1).for_each_with(tx, |tx, job| {
                    if stop.load(std::sync::atomic::Ordering::Relaxed) {
                        return;
                    }
                    let config = &plan.configs[job.config];
                    let started = Instant::now();
                    let result = run_one(&config.scene, job.run)
                        .map(|metrics| RunRow {
                            job: *job,
                            labels: config.labels.clone(),
                            seed: plan.def.seed,
                            metrics,
                            elapsed_s: started.elapsed().as_secs_f64(),
                        })
                        .map_err(|msg| ExperimentError::RunFailed { config: job.config, run: job.run, msg });
                    let _ = tx.send(result);
                });
            });
        });
        let mut first_err = None;
        for msg in rx {
            let res = msg.and_then(&mut on_row);
            if let Err(e) = res
                && first_err.is_none()
            {
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
                first_err = Some(e);
            }
        }
        first_err.map_or(Ok(()), Err)
    })
}
