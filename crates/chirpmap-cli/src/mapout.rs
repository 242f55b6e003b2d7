//! The files of a map, written alike by `simulate` and `map`: highlights,
//! surfaces, the grid as data (NumPy and ROS map_server), the figure, and
//! the summary's map fields.

use crate::mapdata::{MapValues, ros_map, write_npy_to};
use crate::output::Staged;
use crate::plot::{ColourMap, MapPlot, MapStyle, render_map_with};
use crate::tables::{highlights_csv, surfaces_csv};
use anyhow::{Context, Result};
use chirpmap::{Evaluation, Grid, MapResult, MapperKind};
use clap::ValueEnum;
use serde_json::{Value, json};

/// Figure file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum PlotFormat {
    /// Raster (PNG).
    #[default]
    Png,
    /// Vector (SVG), for papers.
    Svg,
}

impl PlotFormat {
    /// The map figure's file name.
    pub fn map(self) -> &'static str {
        self.pick("map.png", "map.svg")
    }
    /// The spectrum figure's file name.
    pub fn spectrum(self) -> &'static str {
        self.pick("spectrum.png", "spectrum.svg")
    }
    /// The spectrogram figure's file name.
    pub fn spectrogram(self) -> &'static str {
        self.pick("spectrogram.png", "spectrogram.svg")
    }
    fn pick(self, png: &'static str, svg: &'static str) -> &'static str {
        match self {
            Self::Png => png,
            Self::Svg => svg,
        }
    }
}

/// The files a map writes with `mapper`.
pub fn map_outputs(mapper: MapperKind, fmt: PlotFormat) -> Vec<&'static str> {
    let mut v = vec!["highlights.csv", "map.npy", "map.pgm", "map.yaml", fmt.map()];
    if mapper == MapperKind::Evidence {
        v.push("surfaces.csv");
    }
    v
}

/// Writes the map's files into `out` (declared by [`map_outputs`]). The
/// figure, the slowest of them, is drawn on a second thread while the data
/// files are built and written (issue 14: the whole default run ≤ 50 ms);
/// every file's bytes are the same as drawn one after the other.
pub fn write_map(out: &mut Staged, map: &MapResult, plot: &MapPlot, fmt: PlotFormat) -> Result<()> {
    let drawn: Vec<crate::plot::Surface> =
        map.surfaces.iter().map(|s| ((s.p0.x, s.p0.y), (s.p1.x, s.p1.y), s.ambiguous)).collect();
    let style = match map.params.mapper {
        MapperKind::Paper => MapStyle::default(),
        MapperKind::Evidence => {
            MapStyle { surfaces: &drawn, colour_map: ColourMap::default(), value_label: Some("log-odds of occupancy") }
        }
    };
    let (fig, shown) = (out.path(fmt.map())?, out.shown(fmt.map()));
    std::thread::scope(|scope| {
        let figure = scope.spawn(|| render_map_with(&fig, plot, &style));
        let data = write_map_data(out, map);
        let figure = figure.join().map_err(|_| anyhow::anyhow!("drawing {} failed", shown.display()))?;
        data.and(figure.with_context(|| format!("cannot write {}", shown.display())))
    })
}

/// The map's data files: highlights, `map.npy`, the ROS map and (evidence
/// mapper) `surfaces.csv`.
fn write_map_data(out: &mut Staged, map: &MapResult) -> Result<()> {
    out.write("highlights.csv", highlights_csv(&map.highlights))?;
    out.write_with("map.npy", |f| write_npy_to(f, &map.grid))?;
    let ros = match map.params.mapper {
        MapperKind::Paper => ros_map(&map.grid, MapValues::Evidence, "map.pgm")?,
        MapperKind::Evidence => {
            // Log-odds L → occupancy probability 1 / (1 + e^−L).
            let p =
                Grid { spec: map.grid.spec, data: map.grid.data.iter().map(|l| 1.0 / (1.0 + (-l).exp())).collect() };
            ros_map(&p, MapValues::Probability, "map.pgm")?
        }
    };
    out.write("map.pgm", ros.pgm)?;
    out.write("map.yaml", ros.yaml)?;
    if map.params.mapper == MapperKind::Evidence {
        out.write("surfaces.csv", surfaces_csv(&map.surfaces))?;
    }
    Ok(())
}

/// The summary fields of a map (and of its evaluation, with a scene).
pub fn map_summary(map: &MapResult, eval: Option<&Evaluation>) -> Value {
    let spec = map.spec();
    let mut s = json!({
        "mapper": map.params.mapper,
        "n_highlights": map.highlights.len(),
        "n_surfaces": map.surfaces.len(),
        "cells_updated": map.cells_updated,
        "grid": {
            "bounds": [spec.x_min_m, spec.y_min_m, spec.x_max_m(), spec.y_max_m()],
            "nx": spec.nx,
            "ny": spec.ny,
            "cell": spec.cell_m,
            "values": match map.params.mapper {
                MapperKind::Paper => "accumulated weight",
                MapperKind::Evidence => "log-odds of occupancy",
            },
        },
    });
    if let Some(e) = eval {
        s["score_obstacle"] = json!(e.scores.score_obstacle);
        s["score_highlight"] = json!(e.scores.score_highlight);
        let m = &e.surfaces;
        s["surface_precision"] = json!(m.precision);
        s["surface_recall"] = json!(m.recall);
        s["surface_f1"] = json!(m.f1);
        s["chamfer_m"] = json!(m.chamfer_m);
        s["walls"] = m
            .walls
            .iter()
            .map(
                |w| json!({"a": [w.a.x, w.a.y], "b": [w.b.x, w.b.y], "offset_m": w.offset_m, "angle_deg": w.angle_deg}),
            )
            .collect();
    }
    s
}

/// What every summary records about the run: the version and the command line.
pub fn provenance() -> Value {
    json!({
        "chirpmap_version": env!("CARGO_PKG_VERSION"),
        // `args_os`: `args` panics on an argument that is not UTF-8 (a file
        // name such as `sc\xff.toml`); such bytes are recorded as U+FFFD.
        "command_line": std::env::args_os().map(|a| a.to_string_lossy().into_owned()).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use chirpmap::{Echo, MapOptions, Point};

    /// A figure that cannot be written is named where it would have landed,
    /// not by the staging folder's path (gone by the time the user reads it).
    #[test]
    fn a_figure_that_cannot_be_written_is_named_where_it_lands() {
        let echo = Echo::new(Point::new(0.0, 0.0), Point::new(2.0, 0.0), 3.0, 1.0, 0.0, 0).unwrap();
        let map = chirpmap::map_echoes(&[echo], &[], &MapOptions::default()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out_dir = dir.path().join("out");
        let mut out = Staged::dir(&out_dir, "test", &map_outputs(MapperKind::Paper, PlotFormat::Png), &[]).unwrap();
        // A directory where the figure's file would be created.
        std::fs::create_dir(out.path("map.png").unwrap()).unwrap();
        let plot = MapPlot {
            title: "t".into(),
            grid: &map.grid,
            highlights: &map.highlights,
            sources: &[],
            listener_positions: &[],
            listener_radius_m: None,
            obstacles: &[],
        };
        let e = format!("{:#}", write_map(&mut out, &map, &plot, PlotFormat::Png).unwrap_err());
        let shown = out_dir.join("map.png");
        assert!(e.starts_with(&format!("cannot write {}: ", shown.display())), "{e}");
        assert!(!e.contains(".chirpmap-partial"), "{e}");
    }
}
