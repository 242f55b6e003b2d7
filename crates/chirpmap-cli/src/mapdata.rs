//! Maps as data (issue 13, item 5): every map a command draws is also written
//! as numbers, so it can be re-plotted or post-processed without chirpmap.
//!
//! - `map.npy`: the grid as a NumPy array (format version 1.0, NEP 1
//!   "A Simple File Format for NumPy Arrays", Kern 2007), `float32`,
//!   little-endian, C order, shape `(ny, nx)`; row `j` is the grid row at
//!   `y_min + j·cell` (row 0 = `y_min`, as [`chirpmap_core::Grid`] stores it),
//!   so `np.load("map.npy")[j, i]` is cell `(i, j)`. The world placement is in
//!   `summary.json`'s `grid` (`bounds`, `nx`, `ny`, `cell`).
//! - `map.pgm` + `map.yaml`: a ROS `map_server` occupancy map (binary PGM
//!   "P5", 8 bit; the YAML gives `image`, `resolution`, `origin`, `negate`,
//!   `occupied_thresh`, `free_thresh` as `map_server` reads them). Image rows
//!   run top = `y_max` to bottom = `y_min`, which is how `map_server` places
//!   an image whose `origin` is its lower-left corner.
//!
//! Functions return bytes (for `output::Staged::write`) or write a given path.

use anyhow::{Context, Result, bail};
use chirpmap_core::Grid;
use chirpmap_core::error::Num;
use std::fmt::Write as _;
#[cfg(test)]
use std::path::Path;

/// `occupied_thresh` written into `map.yaml`: cells with occupancy above it
/// are obstacles (the ROS `map_server` tutorial's value).
pub const OCCUPIED_THRESH: f64 = 0.65;
/// `free_thresh` written into `map.yaml`: cells with occupancy below it are
/// free (the ROS `map_server` tutorial's value).
pub const FREE_THRESH: f64 = 0.196;

/// How the grid's values become occupancy in `map.pgm`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapValues {
    /// Values are occupancy probabilities in `[0, 1]` (e.g. a probabilistic
    /// mapper's output); anything outside is an error.
    Probability,
    /// Values are non-negative evidence on any scale (e.g. Algorithm 1's
    /// accumulated weight); occupancy = value / max (all free when max = 0).
    Evidence,
}

fn check_shape(grid: &Grid) -> Result<()> {
    let spec = grid.spec;
    let n = spec.nx.checked_mul(spec.ny).context("grid size overflows")?;
    if n == 0 || grid.data.len() != n {
        bail!("grid data has {} values but the spec says {} × {}", grid.data.len(), spec.nx, spec.ny);
    }
    Ok(())
}

/// The NumPy v1.0 header for a little-endian float32 C-order array of
/// `shape`: magic, version, header length and the dict, padded with spaces
/// and a final newline so the data starts at a multiple of 64 bytes (NEP 1;
/// NumPy itself aligns to 64).
fn npy_header(shape: (usize, usize)) -> Result<Vec<u8>> {
    let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}", shape.0, shape.1);
    // 6 magic + 2 version + 2 length bytes precede the dict.
    let unpadded = 10 + dict.len() + 1;
    let total = unpadded.div_ceil(64) * 64;
    let header_len = u16::try_from(total - 10).context("npy header longer than 65535 bytes")?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"\x93NUMPY");
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&header_len.to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.resize(total - 1, b' ');
    out.push(b'\n');
    Ok(out)
}

/// `map.npy` bytes of `grid` (see the module docs for the layout): what
/// [`write_npy_to`] writes.
#[cfg(test)]
pub fn npy_bytes(grid: &Grid) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    write_npy_to(&mut out, grid)?;
    Ok(out)
}

/// Cells converted per write of [`write_npy_to`] (64 KiB of float32).
const NPY_CHUNK_CELLS: usize = 1 << 14;

/// Writes `map.npy` of `grid` to `w` (see the module docs for the layout),
/// chunk by chunk: the 4 MB of a default map are never held at once (a
/// fresh buffer's page faults were 1 000 of a default `simulate`'s ~6 000).
/// Values are rounded to f32, the precision any plot needs; NaN and ±∞
/// pass through unchanged. A finite value beyond f32's range is an error
/// naming its cell (the first such cell): it would be written as ±∞ (echo
/// weights of 1e300), a map no reader can normalise.
/// On that error part of the file may have been written; the commands
/// stage their outputs, so it never lands.
pub fn write_npy_to(w: &mut impl std::io::Write, grid: &Grid) -> Result<()> {
    check_shape(grid)?;
    w.write_all(&npy_header((grid.spec.ny, grid.spec.nx))?)?;
    let mut buf = vec![0u8; NPY_CHUNK_CELLS.min(grid.data.len()) * 4];
    // Overflow is noted without a branch, so the loop over every cell (a
    // million in the default run) stays as straight as it was; the culprit
    // is looked up only then.
    let overflows = |v: f64| (v as f32).is_infinite() & v.is_finite();
    for (c, cells) in grid.data.chunks(NPY_CHUNK_CELLS).enumerate() {
        let dst = &mut buf[..cells.len() * 4];
        // On the CPU's widest vectors (pulp's runtime dispatch; the
        // conversion is exact IEEE rounding at every width).
        let overflow = pulp::Arch::new().dispatch(
            #[inline(always)]
            || {
                let mut overflow = false;
                for (dst, &v) in dst.chunks_exact_mut(4).zip(cells) {
                    overflow |= overflows(v);
                    dst.copy_from_slice(&(v as f32).to_le_bytes());
                }
                overflow
            },
        );
        if let Some(k) = overflow.then(|| cells.iter().position(|&v| overflows(v))).flatten() {
            let k = c * NPY_CHUNK_CELLS + k;
            let (i, j) = (k % grid.spec.nx, k / grid.spec.nx);
            bail!(
                "map.npy: cell ({i}, {j}) holds {}, beyond float32's range (±{}); scale the echoes' weights down",
                Num(grid.data[k]),
                Num(f64::from(f32::MAX))
            );
        }
        w.write_all(&buf[..cells.len() * 4])?;
    }
    Ok(())
}

/// Writes [`npy_bytes`] to `path` (the commands stage bytes instead).
#[cfg(test)]
pub fn write_npy(path: &Path, grid: &Grid) -> Result<()> {
    std::fs::write(path, npy_bytes(grid)?).with_context(|| format!("cannot write {}", path.display()))
}

/// Checks every cell under `values` and returns the divisor that maps it to
/// an occupancy in `[0, 1]` (`occupancy = value / divisor`), or an error
/// naming the first cell that does not fit the interpretation.
fn occupancy_divisor(grid: &Grid, values: MapValues) -> Result<f64> {
    let bad = |k: usize, v: f64, what: &str| {
        let (i, j) = (k % grid.spec.nx, k / grid.spec.nx);
        anyhow::anyhow!("cell ({i}, {j}) holds {v}, not {what}")
    };
    match values {
        MapValues::Probability => match grid.data.iter().position(|v| !(0.0..=1.0).contains(v)) {
            Some(k) => Err(bad(k, grid.data[k], "a probability in [0, 1]")),
            None => Ok(1.0),
        },
        MapValues::Evidence => {
            // One branch-free pass (it vectorises) for the maximum and whether
            // any value is negative, infinite or NaN; the culprit is looked
            // up only then.
            let ok = |v: f64| (0.0..=f64::MAX).contains(&v);
            // Eight independent lanes: one accumulator's select chain did not
            // vectorise (ros_map was ~5 % of the default run's CPU; issue 14).
            const LANES: usize = 8;
            let mut lanes = grid.data.chunks_exact(LANES);
            let (max, all_ok) = pulp::Arch::new().dispatch(
                #[inline(always)]
                || {
                    let (mut max, mut all_ok) = ([0.0f64; LANES], [true; LANES]);
                    for x in &mut lanes {
                        for k in 0..LANES {
                            max[k] = if x[k] > max[k] { x[k] } else { max[k] };
                            all_ok[k] &= ok(x[k]);
                        }
                    }
                    (max, all_ok)
                },
            );
            let (max, all_ok) = lanes
                .remainder()
                .iter()
                .chain(&max)
                .fold((0.0f64, all_ok.iter().all(|o| *o)), |(m, all), &v| (if v > m { v } else { m }, all & ok(v)));
            match grid.data.iter().position(|&v| !all_ok && !ok(v)) {
                Some(k) => Err(bad(k, grid.data[k], "finite non-negative evidence")),
                None => Ok(max),
            }
        }
    }
}

/// Grey level of occupancy `p` for `map_server` with `negate: 0`, which reads
/// a pixel `g` as occupancy `(255 − g) / 255`: black = occupied, white = free.
/// `round` without the libm call (the x86-64 baseline has no rounding
/// instruction): for `x` in [0, 255], `x − trunc(x)` is exact, so this is
/// `x.round()` bit for bit, ties away from zero included.
fn grey_of(p: f64) -> u8 {
    let x = (255.0 * (1.0 - p)).clamp(0.0, 255.0);
    let whole = x as u8;
    if x - f64::from(whole) >= 0.5 { whole + 1 } else { whole }
}

/// `grey_of(v / divisor)` for each value of `row`, written so the loop
/// vectorises (the plain loop's saturating `as u8` and branches kept it
/// scalar). For the finite quotients `ros_map` passes (every cell is checked
/// first) it is `grey_of` bit for bit: `x + 2⁵² − 2⁵²` rounds `x` ∈ [0, 255]
/// to an integer exactly, one step down when it rounded up gives `trunc(x)`,
/// and the integer's value sits in the low bits of `g + 2⁵²`.
#[inline(always)]
fn grey_row(dst: &mut [u8], row: &[f64], divisor: f64) {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    for (d, &v) in dst.iter_mut().zip(row) {
        let x = 255.0 * (1.0 - v / divisor);
        let x = if x > 255.0 { 255.0 } else { x };
        let x = if x > 0.0 { x } else { 0.0 };
        let t = (x + TWO_52) - TWO_52;
        let whole = if t > x { t - 1.0 } else { t };
        let g = if x - whole >= 0.5 { whole + 1.0 } else { whole };
        *d = (g + TWO_52).to_bits() as u8;
    }
}

/// A ROS `map_server` map: the PGM image and its YAML description.
#[derive(Debug, Clone, PartialEq)]
pub struct RosMap {
    /// Binary PGM (P5), `nx` × `ny`, top row = `y_max`.
    pub pgm: Vec<u8>,
    /// `map.yaml` text naming `image`.
    pub yaml: String,
}

/// Builds the ROS map of `grid`; `image` is the PGM's file name as the YAML
/// refers to it (relative to the YAML file, e.g. `"map.pgm"`).
pub fn ros_map(grid: &Grid, values: MapValues, image: &str) -> Result<RosMap> {
    check_shape(grid)?;
    let spec = grid.spec;
    let divisor = occupancy_divisor(grid, values)?;
    let mut pgm = format!("P5\n{} {}\n255\n", spec.nx, spec.ny).into_bytes();
    let header = pgm.len();
    pgm.resize(header + grid.data.len(), 0);
    // Rows top (y_max) first; plain slice loops, which vectorise (issue 14),
    // compiled for the CPU's widest vectors (pulp's runtime dispatch; the
    // arithmetic is exact IEEE at every width, so the bytes are the same).
    let rows = pgm[header..].chunks_exact_mut(spec.nx).zip(grid.data.chunks_exact(spec.nx).rev());
    pulp::Arch::new().dispatch(
        #[inline(always)]
        || {
            for (dst, row) in rows {
                if divisor > 0.0 {
                    grey_row(dst, row, divisor);
                } else {
                    dst.fill(grey_of(0.0));
                }
            }
        },
    );
    let mut yaml = String::new();
    // Debug formatting keeps a decimal point ("-50.0"), so YAML reads floats.
    let _ = writeln!(yaml, "image: {image}");
    let _ = writeln!(yaml, "resolution: {:?}", spec.cell_m);
    let _ = writeln!(yaml, "origin: [{:?}, {:?}, 0.0]", spec.x_min_m, spec.y_min_m);
    let _ = writeln!(yaml, "negate: 0");
    let _ = writeln!(yaml, "occupied_thresh: {OCCUPIED_THRESH:?}");
    let _ = writeln!(yaml, "free_thresh: {FREE_THRESH:?}");
    Ok(RosMap { pgm, yaml })
}

/// Writes `pgm_path` and, beside it, the YAML with the same stem
/// (`map.pgm` → `map.yaml`) (the commands stage bytes instead).
#[cfg(test)]
pub fn write_ros_map(pgm_path: &Path, grid: &Grid, values: MapValues) -> Result<()> {
    let image = pgm_path
        .file_name()
        .and_then(|n| n.to_str())
        .with_context(|| format!("{} has no UTF-8 file name", pgm_path.display()))?;
    let map = ros_map(grid, values, image)?;
    let yaml_path = pgm_path.with_extension("yaml");
    std::fs::write(pgm_path, &map.pgm).with_context(|| format!("cannot write {}", pgm_path.display()))?;
    std::fs::write(&yaml_path, &map.yaml).with_context(|| format!("cannot write {}", yaml_path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use chirpmap_core::GridSpec;
    use proptest::prelude::*;

    fn grid(nx: usize, ny: usize, data: Vec<f64>) -> Grid {
        Grid { spec: GridSpec { x_min_m: -2.5, y_min_m: 1.0, cell_m: 0.5, nx, ny }, data }
    }

    /// Independent NPY reader (NEP 1): checks magic, version, alignment and
    /// the dict, returns the shape and the values.
    fn read_npy(b: &[u8]) -> ((usize, usize), Vec<f32>) {
        assert_eq!(&b[..6], b"\x93NUMPY");
        assert_eq!(&b[6..8], &[1, 0]);
        let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hl) % 64, 0, "data must start 64-byte aligned");
        let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
        assert!(header.ends_with('\n'));
        assert!(header.contains("'descr': '<f4'") && header.contains("'fortran_order': False"), "{header}");
        let shape = header.split("'shape': (").nth(1).unwrap().split(')').next().unwrap();
        let dims: Vec<usize> = shape.split(',').map(|s| s.trim().parse().unwrap()).collect();
        let data: Vec<f32> =
            b[10 + hl..].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        assert_eq!(b[10 + hl..].len() % 4, 0);
        ((dims[0], dims[1]), data)
    }

    #[test]
    fn npy_is_rows_of_y_with_row_zero_at_y_min() {
        // 3 wide, 2 tall: cell (i, j) holds 10·j + i.
        let g = grid(3, 2, vec![0.0, 1.0, 2.0, 10.0, 11.0, 12.0]);
        let (shape, data) = read_npy(&npy_bytes(&g).unwrap());
        assert_eq!(shape, (2, 3));
        assert_eq!(data, vec![0.0, 1.0, 2.0, 10.0, 11.0, 12.0]);
        // The dict is spelled as NumPy writes it (key order, spacing, trailing comma).
        let b = npy_bytes(&g).unwrap();
        assert!(b.starts_with(b"\x93NUMPY\x01\x00\x76\x00{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"));
    }

    /// A finite value that f32 cannot hold is refused, naming the cell; it
    /// was written as +inf (exit 0). f32::MAX itself and NaN still pass.
    #[test]
    fn a_value_beyond_f32_is_an_error_naming_its_cell() {
        let e = npy_bytes(&grid(3, 2, vec![0.0, 1.0, 2.0, 3.0, 1e300, 5.0])).unwrap_err().to_string();
        assert!(e.contains("cell (1, 1) holds 1e300") && e.contains("float32"), "{e}");
        let e = npy_bytes(&grid(2, 1, vec![-1e39, 0.0])).unwrap_err().to_string();
        assert!(e.contains("cell (0, 0) holds -1e39"), "{e}");
        let (_, data) = read_npy(&npy_bytes(&grid(2, 1, vec![f64::from(f32::MAX), f64::NAN])).unwrap());
        assert_eq!(data[0], f32::MAX);
        assert!(data[1].is_nan());
    }

    #[test]
    fn shape_mismatch_is_an_error_not_a_panic() {
        assert!(npy_bytes(&grid(3, 2, vec![0.0; 5])).is_err());
        assert!(ros_map(&grid(0, 2, vec![]), MapValues::Evidence, "m.pgm").is_err());
    }

    #[test]
    fn pgm_top_row_is_y_max_and_black_is_occupied() {
        // Row j = 0 (y_min) certainly free, row j = 1 (y_max) certainly occupied.
        let g = grid(2, 2, vec![0.0, 0.0, 1.0, 1.0]);
        let m = ros_map(&g, MapValues::Probability, "map.pgm").unwrap();
        let header = b"P5\n2 2\n255\n";
        assert_eq!(&m.pgm[..header.len()], header);
        assert_eq!(&m.pgm[header.len()..], &[0, 0, 255, 255]);
        assert_eq!(
            m.yaml,
            "image: map.pgm\nresolution: 0.5\norigin: [-2.5, 1.0, 0.0]\nnegate: 0\n\
             occupied_thresh: 0.65\nfree_thresh: 0.196\n"
        );
    }

    #[test]
    fn evidence_is_normalised_by_its_max_and_checked() {
        let g = grid(2, 1, vec![2.0, 4.0]);
        let m = ros_map(&g, MapValues::Evidence, "map.pgm").unwrap();
        // 2/4 → 255·0.5 = 127.5 → 128; 4/4 → 0.
        assert_eq!(&m.pgm[m.pgm.len() - 2..], &[128, 0]);
        assert!(ros_map(&grid(2, 1, vec![0.0, 0.0]), MapValues::Evidence, "m").unwrap().pgm.ends_with(&[255, 255]));
        let e = ros_map(&grid(2, 1, vec![1.0, -1.0]), MapValues::Evidence, "m").unwrap_err();
        assert!(e.to_string().contains("cell (1, 0)"), "{e}");
        assert!(ros_map(&grid(2, 1, vec![0.5, f64::NAN]), MapValues::Evidence, "m").is_err());
        let e = ros_map(&grid(3, 1, vec![0.5, 2.0, f64::INFINITY]), MapValues::Evidence, "m").unwrap_err();
        assert!(e.to_string().contains("cell (2, 0)"), "{e}");
        assert!(ros_map(&grid(2, 1, vec![0.5, 1.5]), MapValues::Probability, "m").is_err());
        assert!(ros_map(&grid(2, 1, vec![0.5, 1.5]), MapValues::Evidence, "m").is_ok());
    }

    #[test]
    fn writers_put_files_where_asked() {
        let dir = tempfile::tempdir().unwrap();
        let g = grid(3, 2, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
        write_npy(&dir.path().join("map.npy"), &g).unwrap();
        write_ros_map(&dir.path().join("map.pgm"), &g, MapValues::Evidence).unwrap();
        assert_eq!(std::fs::read(dir.path().join("map.npy")).unwrap(), npy_bytes(&g).unwrap());
        let yaml = std::fs::read_to_string(dir.path().join("map.yaml")).unwrap();
        assert!(yaml.starts_with("image: map.pgm\n"), "{yaml}");
    }

    /// Cross-check with NumPy itself when python3 with numpy is installed;
    /// skipped (with a note) otherwise.
    #[test]
    fn numpy_reads_the_file_back() {
        let have_numpy = std::process::Command::new("python3")
            .args(["-c", "import numpy"])
            .output()
            .is_ok_and(|o| o.status.success());
        if !have_numpy {
            eprintln!("skipped: python3 with numpy not found");
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.npy");
        let g = grid(4, 3, (0..12).map(|k| f64::from(k) * 0.25 - 1.0).collect());
        write_npy(&path, &g).unwrap();
        let script = "import numpy as np, sys\n\
                      a = np.load(sys.argv[1])\n\
                      assert a.dtype == np.float32 and a.shape == (3, 4), (a.dtype, a.shape)\n\
                      print(' '.join(repr(float(v)) for v in a[2, :]), float(a[0, 1]))";
        let out = std::process::Command::new("python3").args(["-c", script]).arg(&path).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        // Row 2 (the top, y_max) is cells 8..12; a[0, 1] is cell (1, 0).
        assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), "1.0 1.25 1.5 1.75 -0.75");
    }

    proptest! {
        /// The libm-free rounding equals `f64::round` (the oracle), ties and
        /// the clamped ends included.
        #[test]
        fn grey_of_rounds_as_f64_round(p in prop_oneof![-0.1f64..1.1, (0u32..=510).prop_map(|h| 1.0 - f64::from(h) / 510.0)]) {
            let oracle = (255.0 * (1.0 - p)).round().clamp(0.0, 255.0) as u8;
            prop_assert_eq!(grey_of(p), oracle);
        }

        /// The eight-lane maximum and check of evidence values give what one
        /// fold over the cells gives (the code before issue 14's change): the
        /// same divisor, or an error naming the same first bad cell.
        #[test]
        fn evidence_divisor_is_the_single_fold(data in proptest::collection::vec(prop_oneof![
            -5.0f64..5.0, 0.0f64..100.0, Just(f64::NAN), Just(f64::INFINITY), Just(f64::NEG_INFINITY),
            Just(-0.0), Just(0.0), Just(f64::MAX)
        ], 1..40)) {
            let ok = |v: f64| (0.0..=f64::MAX).contains(&v);
            let (max, all_ok) = data.iter().fold((0.0f64, true), |(m, all), &v| (if v > m { v } else { m }, all & ok(v)));
            let want = match data.iter().position(|&v| !all_ok && !ok(v)) {
                Some(k) => Err(format!("cell ({k}, 0) holds")),
                None => Ok(max.to_bits()),
            };
            let g = grid(data.len(), 1, data);
            let got = occupancy_divisor(&g, MapValues::Evidence).map(f64::to_bits).map_err(|e| e.to_string());
            match (&want, &got) {
                (Err(w), Err(g)) => prop_assert!(g.starts_with(w.as_str()), "{} vs {}", g, w),
                _ => prop_assert_eq!(&got, &want),
            }
        }

        /// The vectorised row is `grey_of` of each quotient, over the whole
        /// range of finite values (clamped ends and exact half steps included).
        #[test]
        fn grey_row_is_grey_of_per_cell(row in proptest::collection::vec(prop_oneof![
            -1e3f64..1e3, (0u32..=1020).prop_map(|h| f64::from(h) / 4.0), Just(0.0), Just(f64::MAX)
        ], 0..40), divisor in prop_oneof![0.01f64..1e3, Just(255.0), Just(1.0)]) {
            let mut got = vec![0u8; row.len()];
            grey_row(&mut got, &row, divisor);
            let want: Vec<u8> = row.iter().map(|v| grey_of(v / divisor)).collect();
            prop_assert_eq!(got, want);
        }

        #[test]
        fn npy_round_trips_any_grid(nx in 1usize..40, ny in 1usize..40, seed in any::<u64>()) {
            let data: Vec<f64> = (0..nx * ny)
                .map(|k| ((k as u64).wrapping_mul(6364136223846793005).wrapping_add(seed) >> 11) as f64 * 1e-9)
                .collect();
            let g = grid(nx, ny, data.clone());
            let (shape, back) = read_npy(&npy_bytes(&g).unwrap());
            prop_assert_eq!(shape, (ny, nx));
            for (a, b) in back.iter().zip(&data) {
                prop_assert_eq!(*a, *b as f32);
            }
        }

        #[test]
        fn pgm_matches_a_naive_per_cell_oracle(nx in 1usize..20, ny in 1usize..20, scale in 0.1f64..100.0) {
            let data: Vec<f64> = (0..nx * ny).map(|k| ((k * 37) % 11) as f64 * scale).collect();
            let g = grid(nx, ny, data);
            let m = ros_map(&g, MapValues::Evidence, "m.pgm").unwrap();
            let max = g.max();
            let head = format!("P5\n{nx} {ny}\n255\n").len();
            for r in 0..ny {
                for i in 0..nx {
                    let j = ny - 1 - r;
                    let p = if max > 0.0 { g.get(i, j) / max } else { 0.0 };
                    let want = (255.0 * (1.0 - p)).round() as u8;
                    prop_assert_eq!(m.pgm[head + r * nx + i], want);
                    // map_server's reading of the grey level gives back the occupancy.
                    prop_assert!(((255.0 - f64::from(want)) / 255.0 - p).abs() <= 0.5 / 255.0 + 1e-12);
                }
            }
        }
    }
}
