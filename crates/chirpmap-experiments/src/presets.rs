//! The paper's two experiments as built-in sweeps (§III.B Table I, §III.C
//! Table II; parameters in docs/parameters.md).

use crate::sweep::SweepDef;

/// Names of the built-in presets.
pub const PRESETS: [&str; 2] = ["table1", "table2"];

const SAMPLE_PARAM: &str = r#"
[[params]]
name = "sample"
path = "listeners.*.sampling"
values = [{ period_ms = 1.0 }, { period_ms = 10.0 }, { period_ms = 50.0 }, { random_ms = [10.0, 100.0] }]
labels = ["1 ms", "10 ms", "50 ms", "U(10,100) ms"]
"#;

fn table1() -> String {
    format!(
        r#"name = "table1"
description = "Paper Table I (single listener): n_obstacles {{1,2,3}} x spin_rate {{0, pi/4 rad/s}} x sample period {{1, 10, 50 ms, U(10,100) ms}}; run i has the same obstacles in every configuration."
runs = 100
seed = 1

[[params]]
name = "n_obstacles"
path = "random_obstacles.count"
values = [1, 2, 3]

[[params]]
name = "spin_rate"
path = "listeners.*.spin_rate"
values = [0.0, {spin}]
labels = ["0", "pi/4"]
baseline = "0"
{SAMPLE_PARAM}"#,
        spin = std::f64::consts::FRAC_PI_4
    )
}

/// Table II: Listener 1 relative to Listener 0 (docs/parameters.md, paper Fig. 5).
/// `l0` is Listener 0's start, heading +x; `path_len_m` the distance it covers.
fn table2(l0: [f64; 2], path_len_m: f64) -> String {
    let [x, y] = l0;
    let end_x = x + path_len_m;
    let mid_x = x + 0.5 * path_len_m;
    let l = |sx: f64, sy: f64, heading: f64| format!("{{ start = [{sx:?}, {sy:?}], heading_deg = {heading:?} }}");
    let base = l(x, y, 0.0);
    format!(
        r#"name = "table2"
description = "Paper Table II (two listeners, n_obstacles 3, spin 0): movement patterns of Fig. 5 against the single-listener baseline on the same runs, at each sample period. Listener 0 starts at ({x}, {y}) heading +x and covers {path_len_m:.3} m. (i) L1 +5 m in y; (ii) L1 starts at L0's end x, +5 m in y; (iii) L1 heads +y (away from the Source); (iv) both start at the centre of L0's path, opposite headings."
runs = 60
seed = 2

[base.random_obstacles]
count = 3

[[params]]
name = "pattern"
path = "listeners"
values = [
  [{base}],
  [{base}, {p1}],
  [{base}, {p2}],
  [{base}, {p3}],
  [{p4a}, {p4b}],
]
labels = ["single", "i", "ii", "iii", "iv"]
baseline = "single"
{SAMPLE_PARAM}"#,
        p1 = l(x, y + 5.0, 0.0),
        p2 = l(end_x, y + 5.0, 0.0),
        p3 = l(x, y, 90.0),
        p4a = l(mid_x, y, 0.0),
        p4b = l(mid_x, y, 180.0),
    )
}

/// The preset `name`, if there is one. Table II needs Listener 0's start and
/// path length, which depend on the simulator's duration.
pub fn preset(name: &str, l0_start: [f64; 2], l0_path_len_m: f64) -> Option<SweepDef> {
    let text = match name {
        "table1" => table1(),
        "table2" => table2(l0_start, l0_path_len_m),
        _ => return None,
    };
    // The presets are compiled in and covered by tests.
    SweepDef::from_toml_str(&text).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_expand_to_the_papers_grids() {
        let t1 = preset("table1", [-3.0, 10.0], 9.0).unwrap().plan(|_| Ok(())).unwrap();
        assert_eq!(t1.configs.len(), 24);
        assert_eq!(t1.jobs().len(), 2400);
        let c = &t1.configs[23];
        assert_eq!(c.scene.random_obstacles.count, 3);
        assert_eq!(c.scene.listeners[0].spin_rate, std::f64::consts::FRAC_PI_4);
        assert_eq!(c.scene.listeners[0].sampling.random_ms, Some([10.0, 100.0]));

        let t2 = preset("table2", [-3.0, 10.0], 9.0).unwrap().plan(|_| Ok(())).unwrap();
        assert_eq!(t2.configs.len(), 20);
        assert_eq!(t2.jobs().len(), 1200);
        let by = |pattern: &str, sample: &str| {
            t2.configs.iter().find(|c| c.labels == [pattern, sample]).unwrap().scene.clone()
        };
        let s = by("single", "50 ms");
        assert_eq!(s.listeners.len(), 1);
        assert_eq!(s.random_obstacles.count, 3);
        let ii = by("ii", "1 ms");
        assert_eq!(ii.listeners[1].start, [6.0, 15.0]);
        assert!(ii.listeners.iter().all(|l| l.sampling.period_ms == Some(1.0)));
        let iv = by("iv", "10 ms");
        assert_eq!((iv.listeners[0].start, iv.listeners[1].heading_deg), ([1.5, 10.0], 180.0));
        assert_eq!(by("iii", "10 ms").listeners[1].heading_deg, 90.0);
        assert!(preset("table3", [0.0, 0.0], 1.0).is_none());
    }
}
