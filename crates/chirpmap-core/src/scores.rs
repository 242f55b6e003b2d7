//! The evaluation metrics of paper §III.A (definitions in docs/architecture.md, "Scores").

use crate::geometry::{Obstacle, Point};

/// 1/d capped at 1 (d = 0 scores 1).
fn inverse_capped(d: f64) -> f64 {
    if d <= 1.0 { 1.0 } else { 1.0 / d }
}

fn nearest_obstacle(obstacles: &[Obstacle], p: Point) -> Option<(usize, f64)> {
    obstacles.iter().enumerate().map(|(k, o)| (k, o.surface_distance(p))).min_by(|a, b| a.1.total_cmp(&b.1))
}

/// False-negative score: each highlight is assigned to its nearest obstacle
/// (by surface distance); each obstacle scores min(1, 1/d) for the closest
/// highlight assigned to it, 0 with none. Mean over obstacles; `None` when the
/// scene has no obstacles.
pub fn score_obstacle(obstacles: &[Obstacle], highlights: &[Point]) -> Option<f64> {
    if obstacles.is_empty() {
        return None;
    }
    let mut best = vec![f64::INFINITY; obstacles.len()];
    for &h in highlights {
        if let Some((k, d)) = nearest_obstacle(obstacles, h) {
            best[k] = best[k].min(d);
        }
    }
    let total: f64 = best.iter().map(|&d| if d.is_finite() { inverse_capped(d) } else { 0.0 }).sum();
    Some(total / obstacles.len() as f64)
}

/// False-positive score: each highlight scores min(1, 1/d) with d its distance
/// to the nearest obstacle surface. Mean over highlights, 0 with none; `None`
/// when the scene has no obstacles.
pub fn score_highlight(obstacles: &[Obstacle], highlights: &[Point]) -> Option<f64> {
    if obstacles.is_empty() {
        return None;
    }
    if highlights.is_empty() {
        return Some(0.0);
    }
    let total: f64 =
        highlights.iter().filter_map(|&h| nearest_obstacle(obstacles, h)).map(|(_, d)| inverse_capped(d)).sum();
    Some(total / highlights.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Circle, Shape};

    fn circle(x: f64, y: f64, r: f64) -> Obstacle {
        Obstacle { shape: Shape::Circle(Circle::new(Point::new(x, y), r).unwrap()), roughness: 0.1, absorption: 0.2 }
    }

    #[test]
    fn hand_computed_scores() {
        // Obstacle A: circle r=1 at (0,0); obstacle B: circle r=1 at (20,0).
        let obs = [circle(0.0, 0.0, 1.0), circle(20.0, 0.0, 1.0)];
        // h1 at (0,1.5): 0.5 m from A → 1. h2 at (5,0): 4 m from A, 14 m from B → A, 1/4.
        // h3 at (10,0): 9 m from A and B; tie → first (A), 1/9.
        let hs = [Point::new(0.0, 1.5), Point::new(5.0, 0.0), Point::new(10.0, 0.0)];
        // Obstacles: A's closest assigned is 0.5 → 1; B has none → 0. Mean 0.5.
        assert!((score_obstacle(&obs, &hs).unwrap() - 0.5).abs() < 1e-12);
        // Highlights: (1 + 1/4 + 1/9)/3.
        let want = (1.0 + 0.25 + 1.0 / 9.0) / 3.0;
        assert!((score_highlight(&obs, &hs).unwrap() - want).abs() < 1e-12);
        // Add a highlight 3 m outside B: B scores 1/3.
        let hs2 = [hs[0], hs[1], hs[2], Point::new(24.0, 0.0)];
        assert!((score_obstacle(&obs, &hs2).unwrap() - (1.0 + 1.0 / 3.0) / 2.0).abs() < 1e-12);
    }

    #[test]
    fn inside_an_obstacle_counts_distance_to_surface() {
        let obs = [circle(0.0, 0.0, 5.0)];
        // At the centre: 5 m from the surface.
        assert!((score_highlight(&obs, &[Point::new(0.0, 0.0)]).unwrap() - 0.2).abs() < 1e-12);
    }

    #[test]
    fn empty_cases() {
        let obs = [circle(0.0, 0.0, 1.0)];
        assert_eq!(score_obstacle(&obs, &[]), Some(0.0));
        assert_eq!(score_highlight(&obs, &[]), Some(0.0));
        assert_eq!(score_obstacle(&[], &[Point::new(0.0, 0.0)]), None);
    }
}
