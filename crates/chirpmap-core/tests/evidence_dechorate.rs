//! The evidence mapper on real measured echoes: the dEchorate room
//! (tests/data/dechorate/README.md). Each of the 10 rows gives, for each of
//! the four side walls, the manually annotated path difference; the 3D paths
//! are projected to the horizontal plane:
//! Δd_h = sqrt(d_r² − Δz²) − sqrt(d_d² − Δz²), d_d = direct_m,
//! d_r = direct_m + dd_annot_<plane>, Δz = src_z − mic_z
//! (a vertical wall's image source keeps its height, so both paths rise by Δz).

use chirpmap_core::metrics::{MetricParams, surface_metrics};
use chirpmap_core::{
    Echo, EvidenceParams, GridSpec, Obstacle, Point, Polygon, Shape, Surface, SurfaceKind, map_evidence,
};

const ROOM_X_M: f64 = 5.705;
const ROOM_Y_M: f64 = 5.965;
/// 1-σ of the annotated path differences (m): half a sample at 48 kHz.
const SIGMA_M: f64 = 0.5 * 345.844 / 48_000.0;

fn echoes() -> Vec<Echo> {
    let text = include_str!("data/dechorate/rirs_index.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name}"));
    let mut out = Vec::new();
    for (row, line) in lines.filter(|l| !l.trim().is_empty()).enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let num = |name: &str| f[col(name)].parse::<f64>().unwrap_or_else(|e| panic!("{name}: {e}"));
        let src = Point::new(num("src_x"), num("src_y"));
        let mic = Point::new(num("mic_x"), num("mic_y"));
        let dz = num("src_z") - num("mic_z");
        let d_d = num("direct_m");
        for plane in ["x0", "xL", "y0", "yL"] {
            let d_r = d_d + num(&format!("dd_annot_{plane}"));
            let dd_h = (d_r * d_r - dz * dz).sqrt() - (d_d * d_d - dz * dz).sqrt();
            // One microphone pose per row, in file order (the array's five
            // microphones, twice): consecutive rows are neighbouring poses.
            // σ: manual picking to about half a sample at 48 kHz (3.6 mm of path).
            let e = Echo::new(src, mic, dd_h, 1.0, row as f64, 0).and_then(|e| e.with_sigma_m(SIGMA_M));
            out.push(e.expect("valid echo"));
        }
    }
    out
}

fn room() -> Obstacle {
    let v = vec![
        Point::new(0.0, 0.0),
        Point::new(ROOM_X_M, 0.0),
        Point::new(ROOM_X_M, ROOM_Y_M),
        Point::new(0.0, ROOM_Y_M),
    ];
    Obstacle { shape: Shape::Polygon(Polygon::new(v).expect("valid room")), roughness: 0.0, absorption: 0.0 }
}

/// Offset (m) and angle (deg) of `s` against the infinite line through `a`, `b`.
fn line_error(s: &Surface, a: Point, b: Point) -> (f64, f64) {
    let dir = (b - a).normalized();
    let normal = Point::new(-dir.y, dir.x);
    let mid = (s.p0 + s.p1) * 0.5;
    let ang = (s.p1 - s.p0).normalized().dot(dir).abs().min(1.0).acos().to_degrees();
    ((mid - a).dot(normal).abs(), ang)
}

#[test]
fn dechorate_four_walls() {
    let echoes = echoes();
    assert_eq!(echoes.len(), 40);
    let spec = GridSpec::from_bounds([-2.0, -2.0, 8.0, 8.0], 0.05, u128::MAX).expect("grid");
    // The array is 27 cm long (9 cm across the source direction), so each
    // wall is observed over 3–14 cm: the default shortest line (0.5 m, to
    // tell walls from compact reflectors on a walk) would drop them all.
    let params = EvidenceParams { min_line_length_m: 0.0, ..EvidenceParams::default() };
    let map = map_evidence(&echoes, spec, &params).expect("evidence map");
    let truth = [room()];
    println!("dEchorate, 40 echoes (10 rows x 4 side walls): {} surfaces", map.surfaces.len());
    for s in &map.surfaces {
        println!(
            "  {:?} ({:.3}, {:.3})-({:.3}, {:.3}) support {} ambiguous {}",
            s.kind, s.p0.x, s.p0.y, s.p1.x, s.p1.y, s.support, s.ambiguous
        );
    }
    let lines: Vec<Surface> = map.surfaces.iter().filter(|s| s.kind == SurfaceKind::Line).copied().collect();
    // Each true wall against every reported line (the metric's own matching
    // needs the line's midpoint over the wall; the short observed segments
    // may sit off its end, so this takes the infinite lines).
    let walls = [
        ("x = 0", Point::new(0.0, 0.0), Point::new(0.0, 1.0)),
        ("x = 5.705", Point::new(ROOM_X_M, 0.0), Point::new(ROOM_X_M, 1.0)),
        ("y = 0", Point::new(0.0, 0.0), Point::new(1.0, 0.0)),
        ("y = 5.965", Point::new(0.0, ROOM_Y_M), Point::new(1.0, ROOM_Y_M)),
    ];
    let mut worst = (0.0f64, 0.0f64);
    let mut within_6cm_2deg = 0;
    for (name, a, b) in walls {
        let best = lines
            .iter()
            .map(|s| line_error(s, a, b))
            .filter(|&(_, ang)| ang <= 10.0)
            .min_by(|x, y| (x.0 + x.1.to_radians()).total_cmp(&(y.0 + y.1.to_radians())));
        println!("  wall {name}: best line offset/angle {best:.3?}");
        let (off, ang) = best.unwrap_or((f64::INFINITY, f64::INFINITY));
        worst = (worst.0.max(off), worst.1.max(ang));
        if off <= 0.06 && ang <= 2.0 {
            within_6cm_2deg += 1;
        }
    }
    let m = surface_metrics(&map.surfaces, &truth, None, &MetricParams::default());
    println!(
        "  worst wall: offset {:.3} m, angle {:.2} deg; walls within 6 cm and 2 deg: {within_6cm_2deg} of 4; precision {:.3}",
        worst.0, worst.1, m.precision
    );
    // All four walls are found as lines. The mics are collinear (one linear
    // array), so every wall is mirror-ambiguous and must be flagged.
    assert!(lines.len() >= 4);
    assert!(lines.iter().all(|s| s.ambiguous), "collinear microphones: every line is mirror-ambiguous");
    // Issue 9's target is four lines within 6 cm and 2°. These data cannot
    // support it: a least-squares fit of each wall's image source to the
    // annotated Δd (rms residual 0.1–4 mm) puts the walls at offsets of
    // 1.7, 4.2, 20.7 and 0.3 cm and angles of 4.1°, 3.4°, 0.5° and 2.0°
    // from the nominal box (x = 0, x = 5.705, y = 0, y = 5.965): the y = 0
    // annotations are 0.40 m shorter than the box geometry, and a 27 cm
    // array fixes angles only to a few degrees. Measured here: 4.0, 5.6,
    // 20.3, 1.7 cm and 3.8°, 3.1°, 0.4°, 2.2°. Asserted with a margin over
    // that, so a regression shows.
    assert!(worst.0 <= 0.25, "offset {}", worst.0);
    assert!(worst.1 <= 5.0, "angle {}", worst.1);
}
