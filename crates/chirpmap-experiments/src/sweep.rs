//! Sweep definitions: a base scene, parameters to vary (each a path into the
//! scene and a list of values), runs per configuration and a master seed.

use crate::error::ExperimentError;
use chirpmap_core::Scene;
use serde::{Deserialize, Serialize};

/// A sweep file (TOML). Unknown keys are errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepDef {
    /// Name, used in titles.
    pub name: String,
    /// Free text describing the sweep.
    #[serde(default)]
    pub description: String,
    /// Runs per configuration.
    pub runs: u64,
    /// Master seed; run `i` uses stream `i` of it.
    pub seed: u64,
    /// Base scene (same schema as a scene file; omitted keys take defaults).
    #[serde(default)]
    pub base: toml::Table,
    /// Parameters varied over their cartesian product, first slowest.
    pub params: Vec<Param>,
}

/// One varied parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Param {
    /// Column name in runs.csv and summaries.
    pub name: String,
    /// Dotted path into the scene; `*` applies to every element of an array,
    /// a number selects one element (e.g. `listeners.*.spin_rate`).
    pub path: String,
    /// Values, any TOML value (numbers, tables, arrays of tables).
    pub values: Vec<toml::Value>,
    /// Labels shown for the values (default: the values themselves).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub labels: Vec<String>,
    /// Label of the value other configurations are compared with, run by run
    /// (paired differences in the summary).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<String>,
}

impl Param {
    /// Whether runs.csv gets a numeric `<name>_value` column beside the
    /// label: the values are numbers and have labels that hide them.
    pub fn has_value_column(&self) -> bool {
        !self.labels.is_empty() && (0..self.values.len()).all(|k| self.numeric_value(k).is_some())
    }
    /// Name of the numeric value column.
    pub fn value_column(&self) -> String {
        format!("{}_value", self.name)
    }
    /// Value `k` as a number, if it is one.
    pub fn numeric_value(&self, k: usize) -> Option<f64> {
        match self.values.get(k)? {
            toml::Value::Integer(i) => Some(*i as f64),
            toml::Value::Float(f) => Some(*f),
            _ => None,
        }
    }
    /// Label of value `k`: the given label, else the value itself (strings unquoted).
    pub fn label(&self, k: usize) -> String {
        self.labels.get(k).cloned().unwrap_or_else(|| match &self.values[k] {
            toml::Value::String(s) => s.clone(),
            v => v.to_string(),
        })
    }
}

/// One configuration: a resolved scene and the label of each parameter value.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Position in the plan (the `config` column of runs.csv).
    pub index: usize,
    /// Index into each parameter's values.
    pub choice: Vec<usize>,
    /// Label of each parameter's chosen value.
    pub labels: Vec<String>,
    /// The base scene with the chosen values applied.
    pub scene: Scene,
}

/// One run of one configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Job {
    /// Configuration index.
    pub config: usize,
    /// Run index, also the random stream of the master seed.
    pub run: u64,
}

/// As runs.csv's columns name it: `config C, run R`.
impl std::fmt::Display for Job {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "config {}, run {}", self.config, self.run)
    }
}

/// As `--shard` takes it: `I/N`.
impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// `--shard I/N`: shard `I` (0-based) of `N` takes every job whose position in
/// the plan is `I` modulo `N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Shard index, 0-based.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

impl Shard {
    /// The whole sweep as one shard.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Parses `I/N`, requiring `0 <= I < N`.
    pub fn parse(s: &str) -> Result<Self, ExperimentError> {
        let bad = || ExperimentError::InvalidSweep(format!("shard {s:?} must look like I/N with 0 <= I < N"));
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) =
            (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

/// An expanded sweep: every configuration validated before any work starts.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The sweep as defined.
    pub def: SweepDef,
    /// Every configuration of the cartesian product, in order (first parameter slowest).
    pub configs: Vec<Config>,
}

impl SweepDef {
    /// Parses a sweep file; errors quote a short excerpt of the offending
    /// line ([`chirpmap_core::error::toml_error`]).
    pub fn from_toml_str(text: &str) -> Result<Self, ExperimentError> {
        chirpmap_core::error::check_toml_values(text).map_err(ExperimentError::InvalidSweep)?;
        toml::from_str(text).map_err(|e| ExperimentError::InvalidSweep(chirpmap_core::error::toml_error(text, &e)))
    }

    /// Serialises the sweep back to TOML (written into the output directory).
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot serialise sweep: {e}\n"))
    }

    /// Expands the cartesian product and checks each configuration's scene.
    /// `validate` gets every resolved scene (e.g. the simulator's own checks).
    pub fn plan(&self, validate: impl Fn(&Scene) -> Result<(), String>) -> Result<Plan, ExperimentError> {
        let err = |m: String| ExperimentError::InvalidSweep(m);
        if self.runs == 0 || self.runs > MAX_RUNS {
            return Err(err(format!("runs must be in 1..={MAX_RUNS}, got {}", self.runs)));
        }
        if self.params.is_empty() {
            return Err(err("no parameters to vary (params is empty)".into()));
        }
        for (k, p) in self.params.iter().enumerate() {
            // Two parameters of one name would share a runs.csv column.
            if self.params[..k].iter().any(|q| q.name == p.name) {
                return Err(err(format!("parameter {:?} is given twice (params[{k}]); names must differ", p.name)));
            }
            if p.values.is_empty() {
                return Err(err(format!("parameter {:?} has no values (empty grid)", p.name)));
            }
            if !p.labels.is_empty() && p.labels.len() != p.values.len() {
                return Err(err(format!(
                    "parameter {:?}: {} labels for {} values",
                    p.name,
                    p.labels.len(),
                    p.values.len()
                )));
            }
            if let Some(b) = &p.baseline
                && !(0..p.values.len()).any(|k| &p.label(k) == b)
            {
                return Err(err(format!("parameter {:?}: baseline {b:?} is not one of its labels", p.name)));
            }
            let taken = |n: &str| crate::runs::RESERVED_COLUMNS.contains(&n);
            if taken(&p.name)
                || (p.has_value_column()
                    && (taken(&p.value_column()) || self.params.iter().any(|q| q.name == p.value_column())))
                || p.name.contains(',')
                || p.name.is_empty()
            {
                return Err(err(format!("parameter name {:?} is reserved or not a valid column", p.name)));
            }
        }
        let n_configs = self
            .params
            .iter()
            .try_fold(1usize, |n, p| n.checked_mul(p.values.len()))
            .filter(|&n| n <= MAX_CONFIGS)
            .ok_or_else(|| {
                err(format!("more than {MAX_CONFIGS} configurations (the product of the values' counts)"))
            })?;
        self.check_size(n_configs)?;
        chirpmap_core::scene::check_scene_tables(&self.base).map_err(|m| err(format!("base scene: {m}")))?;
        // The `toml` crate puts the key on a line of its own: one line.
        let one_line = |e: toml::de::Error| {
            chirpmap_core::error::short_message(&e.to_string().split_whitespace().collect::<Vec<_>>().join(" "))
        };
        let mut configs = Vec::with_capacity(n_configs);
        for index in 0..n_configs {
            let mut rem = index;
            let mut choice = vec![0; self.params.len()];
            for (k, p) in self.params.iter().enumerate().rev() {
                choice[k] = rem % p.values.len();
                rem /= p.values.len();
            }
            let mut value = toml::Value::Table(self.base.clone());
            // Start from the fully defaulted base so paths into defaults exist.
            let base: Scene = value.clone().try_into().map_err(|e| err(format!("base scene: {e}")))?;
            value = toml::Value::try_from(&base).map_err(|e| err(format!("base scene: {e}")))?;
            for (p, &c) in self.params.iter().zip(&choice) {
                set_path(&mut value, &p.path, &p.values[c])
                    .map_err(|m| err(format!("parameter {:?} (path {:?}): {m}", p.name, p.path)))?;
            }
            if let toml::Value::Table(t) = &value {
                chirpmap_core::scene::check_scene_tables(t).map_err(|m| err(format!("configuration {index}: {m}")))?;
            }
            let mut scene: Scene =
                value.try_into().map_err(|e| err(format!("configuration {index}: {}", one_line(e))))?;
            scene.seed = self.seed;
            let labels: Vec<String> = self.params.iter().zip(&choice).map(|(p, &c)| p.label(c)).collect();
            scene.validate().map_err(|e| err(format!("configuration {index} ({}): {e}", labels.join(", "))))?;
            validate(&scene).map_err(|m| err(format!("configuration {index} ({}): {m}", labels.join(", "))))?;
            configs.push(Config { index, choice, labels, scene });
        }
        Ok(Plan { def: self.clone(), configs })
    }
}

/// Most runs per configuration: the paper uses 100; 10⁶ is already weeks of
/// simulation. `--runs 18446744073709551615` panicked (issue 8, item 8).
pub const MAX_RUNS: u64 = 1_000_000;
/// Most configurations of one sweep (each holds a scene).
pub const MAX_CONFIGS: usize = 100_000;
/// Most runs of a whole sweep (configurations × runs).
pub const MAX_JOBS: u64 = 10_000_000;
/// Cap on the estimated memory of a sweep's runs table (bytes).
pub const RUNS_MEMORY_CAP_BYTES: u64 = 2 << 30;

impl SweepDef {
    /// Estimated peak memory (bytes) of the runs table of a sweep of
    /// `n_configs` configurations: per run, the job lists (plan, shard and
    /// to-do: 3 × 16 bytes), the row twice (the resume map and the sorted
    /// copy: 2 × (96 bytes + 24 per label + the labels' text, with 50 %
    /// map overhead)) and its CSV line (~100 bytes + labels). Measured rows
    /// of the paper's tables are about 60 bytes of CSV, so this is generous.
    pub fn runs_memory_bytes(&self, n_configs: usize) -> u128 {
        let labels: usize =
            self.params.iter().map(|p| 24 + (0..p.values.len()).map(|k| p.label(k).len()).max().unwrap_or(0)).sum();
        let per_row = 3 * 16 + 3 * (96 + labels) + 100 + labels;
        u128::from(self.runs) * n_configs as u128 * per_row as u128
    }

    /// Bounds the total runs and their memory before anything is expanded,
    /// allocated or written (sweep.toml included).
    fn check_size(&self, n_configs: usize) -> Result<(), ExperimentError> {
        let jobs = u128::from(self.runs) * n_configs as u128;
        if jobs > u128::from(MAX_JOBS) {
            return Err(ExperimentError::InvalidSweep(format!(
                "{n_configs} configurations × {} runs = {jobs} runs, more than the cap of {MAX_JOBS}; lower --runs",
                self.runs
            )));
        }
        let bytes = self.runs_memory_bytes(n_configs);
        if bytes > u128::from(RUNS_MEMORY_CAP_BYTES) {
            return Err(ExperimentError::InvalidSweep(format!(
                "the table of {jobs} runs would need about {bytes} bytes of memory, more than the cap of \
                 {RUNS_MEMORY_CAP_BYTES} bytes; lower --runs"
            )));
        }
        Ok(())
    }
}

impl Plan {
    /// Every job in plan order (configuration-major).
    pub fn jobs(&self) -> Vec<Job> {
        self.configs.iter().flat_map(|c| (0..self.def.runs).map(move |run| Job { config: c.index, run })).collect()
    }

    /// The jobs of one shard.
    pub fn shard_jobs(&self, shard: Shard) -> Vec<Job> {
        self.jobs().into_iter().enumerate().filter(|(k, _)| k % shard.count == shard.index).map(|(_, j)| j).collect()
    }
}

/// Sets `path` (dotted; `*` = every array element; numbers index arrays) in
/// `root` to `value`. The last segment may create a table key.
fn set_path(root: &mut toml::Value, path: &str, value: &toml::Value) -> Result<(), String> {
    let segs: Vec<&str> = path.split('.').collect();
    if segs.iter().any(|s| s.is_empty()) {
        return Err("empty path segment".into());
    }
    fn go(node: &mut toml::Value, segs: &[&str], value: &toml::Value) -> Result<(), String> {
        let (head, rest) = (segs[0], &segs[1..]);
        match node {
            toml::Value::Array(items) => {
                let targets: Vec<usize> = if head == "*" {
                    (0..items.len()).collect()
                } else {
                    let i: usize = head.parse().map_err(|_| format!("{head:?} is not an array index"))?;
                    if i >= items.len() {
                        return Err(format!("index {i} out of range (array has {} elements)", items.len()));
                    }
                    vec![i]
                };
                for i in targets {
                    if rest.is_empty() {
                        items[i] = value.clone();
                    } else {
                        go(&mut items[i], rest, value)?;
                    }
                }
                Ok(())
            }
            toml::Value::Table(t) => {
                if rest.is_empty() {
                    t.insert(head.to_string(), value.clone());
                    Ok(())
                } else {
                    let child = t.get_mut(head).ok_or_else(|| format!("no key {head:?} in the scene"))?;
                    go(child, rest, value)
                }
            }
            _ => Err(format!("cannot descend into {head:?}: not a table or array")),
        }
    }
    go(root, &segs, value)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn def(text: &str) -> SweepDef {
        SweepDef::from_toml_str(text).unwrap()
    }

    const SMALL: &str = r#"
name = "t"
runs = 3
seed = 9
[[params]]
name = "n_obstacles"
path = "random_obstacles.count"
values = [1, 2]
[[params]]
name = "sample"
path = "listeners.*.sampling"
values = [{ period_ms = 1.0 }, { random_ms = [10.0, 100.0] }]
labels = ["1 ms", "U(10,100) ms"]
"#;

    #[test]
    fn expands_cartesian_product_first_param_slowest() {
        let plan = def(SMALL).plan(|_| Ok(())).unwrap();
        assert_eq!(plan.configs.len(), 4);
        assert_eq!(plan.configs[1].labels, vec!["1", "U(10,100) ms"]);
        assert_eq!(plan.configs[2].scene.random_obstacles.count, 2);
        assert_eq!(plan.configs[3].scene.listeners[0].sampling.random_ms, Some([10.0, 100.0]));
        assert_eq!(plan.configs[3].scene.listeners[0].sampling.period_ms, None);
        assert!(plan.configs.iter().all(|c| c.scene.seed == 9));
        assert_eq!(plan.jobs().len(), 12);
    }

    #[test]
    fn shards_partition_the_jobs() {
        let plan = def(SMALL).plan(|_| Ok(())).unwrap();
        let mut all: Vec<Job> = (0..5).flat_map(|i| plan.shard_jobs(Shard { index: i, count: 5 })).collect();
        all.sort();
        let mut want = plan.jobs();
        want.sort();
        assert_eq!(all, want);
        assert!(Shard::parse("5/5").is_err() && Shard::parse("x").is_err() && Shard::parse("0/0").is_err());
        assert_eq!(Shard::parse("2/4").unwrap(), Shard { index: 2, count: 4 });
    }

    #[test]
    fn bad_sweeps_are_rejected_before_work() {
        let cases = [
            (SMALL.replace("values = [1, 2]", "values = []"), "empty grid"),
            (SMALL.replace("random_obstacles.count", "random_obstacles.cuont"), "cuont"),
            (SMALL.replace("listeners.*.sampling", "listeners.7.sampling"), "out of range"),
            (SMALL.replace("runs = 3", "runs = 0"), "runs must be"),
            (SMALL.replace("values = [1, 2]", "values = [\"x\", 2]"), "configuration 0"),
            (SMALL.replace("labels = [\"1 ms\", \"U(10,100) ms\"]", "labels = [\"1 ms\"]"), "labels"),
        ];
        for (text, want) in cases {
            let e = def(&text).plan(|_| Ok(())).unwrap_err().to_string();
            assert!(e.contains(want), "{e:?} lacks {want:?}");
        }
        assert!(SweepDef::from_toml_str("name = 1").is_err());
        let e = def(SMALL).plan(|_| Err("nope".into())).unwrap_err().to_string();
        assert!(e.contains("nope"));
    }
}
