//! Candidate quadrilaterals: 4-connected dark components of the eroded
//! mask; the convex hull of each one's row ends gives four extreme
//! vertices, which pick four sides; each side is a line fitted to the
//! boundary pixels along its middle, and must be straight there. Corners come out in image
//! pixels (pixel centres at integer coordinates), clockwise as seen on
//! screen, about a pixel from the true corners: refine.rs finishes them.

use nalgebra::Vector2;

use super::threshold::Mask;

/// Smallest side of a candidate, px; a tag's data cells are then 1 px.
pub const MIN_SIDE_PX: f64 = 10.0;
/// How far boundary pixels are taken to belong to a side when it is first
/// chosen, as a fraction of the side.
const SIDE_TOLERANCE: f64 = 0.06;
/// How far they may stray from the fitted side, px (pixel steps, noise,
/// and the bow lens distortion gives a long side).
const SIDE_TOLERANCE_MIN_PX: f64 = 1.5;
/// The middle of a side: from this fraction of it to one minus this.
const MIDDLE_FROM: f64 = 0.15;
/// Least share of the boundary pixels along a side's middle that must lie
/// on the fitted line.
const MIN_INLIER_SHARE: f64 = 0.85;

/// The outer boundary of a component as seen from the four sides: the
/// first and last pixel of each of its rows and of each of its columns
/// (pixel centres).
struct Outline {
    row_ends: Vec<Vector2<f64>>,
    column_ends: Vec<Vector2<f64>>,
}

/// Outlines of every component with at least `min_pixels` pixels.
fn component_outlines(mask: &Mask, min_pixels: usize) -> Vec<Outline> {
    let (w, h) = (mask.width, mask.height);
    // Union-find over runs of dark pixels: runs in successive rows that
    // overlap in x are 4-connected.
    struct Run {
        y: usize,
        x0: usize,
        x1: usize,
    }
    let mut runs: Vec<Run> = Vec::new();
    let mut row_start = vec![0usize; h + 1];
    for (y, start) in row_start.iter_mut().take(h).enumerate() {
        *start = runs.len();
        let mut x = 0;
        while x < w {
            if mask.at(x, y) {
                let x0 = x;
                while x < w && mask.at(x, y) {
                    x += 1;
                }
                runs.push(Run { y, x0, x1: x - 1 });
            } else {
                x += 1;
            }
        }
    }
    row_start[h] = runs.len();
    let mut parent: Vec<usize> = (0..runs.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for y in 1..h {
        let (mut a, a_end) = (row_start[y - 1], row_start[y]);
        let (mut b, b_end) = (row_start[y], row_start[y + 1]);
        while a < a_end && b < b_end {
            if runs[a].x0 <= runs[b].x1 && runs[b].x0 <= runs[a].x1 {
                let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                parent[ra.max(rb)] = ra.min(rb);
            }
            if runs[a].x1 < runs[b].x1 {
                a += 1;
            } else {
                b += 1;
            }
        }
    }
    // Runs of each component, in row order.
    let mut index_of_root = vec![usize::MAX; runs.len()];
    let mut members: Vec<Vec<usize>> = Vec::new();
    for i in 0..runs.len() {
        let r = root(&mut parent, i);
        if index_of_root[r] == usize::MAX {
            index_of_root[r] = members.len();
            members.push(Vec::new());
        }
        members[index_of_root[r]].push(i);
    }
    let mut outlines = Vec::new();
    for component in members {
        let pixels: usize = component.iter().map(|&i| runs[i].x1 - runs[i].x0 + 1).sum();
        if pixels < min_pixels {
            continue;
        }
        let x_min = component.iter().map(|&i| runs[i].x0).min().unwrap_or(0);
        let x_max = component.iter().map(|&i| runs[i].x1).max().unwrap_or(0);
        let mut columns = vec![(usize::MAX, 0usize); x_max - x_min + 1];
        let mut row_ends = Vec::new();
        let mut k = 0;
        while k < component.len() {
            let y = runs[component[k]].y;
            let (mut lo, mut hi) = (usize::MAX, 0);
            while k < component.len() && runs[component[k]].y == y {
                let run = &runs[component[k]];
                lo = lo.min(run.x0);
                hi = hi.max(run.x1);
                for column in &mut columns[run.x0 - x_min..=run.x1 - x_min] {
                    column.0 = column.0.min(y);
                    column.1 = column.1.max(y);
                }
                k += 1;
            }
            row_ends.push(Vector2::new(lo as f64, y as f64));
            row_ends.push(Vector2::new(hi as f64, y as f64));
        }
        let column_ends = columns
            .iter()
            .enumerate()
            .filter(|(_, c)| c.0 != usize::MAX)
            .flat_map(|(x, &(top, bottom))| {
                let x = (x + x_min) as f64;
                [Vector2::new(x, top as f64), Vector2::new(x, bottom as f64)]
            })
            .collect();
        outlines.push(Outline {
            row_ends,
            column_ends,
        });
    }
    outlines
}

fn cross(o: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x)
}

/// Convex hull by Andrew's monotone chain, collinear points dropped.
fn convex_hull(mut points: Vec<Vector2<f64>>) -> Vec<Vector2<f64>> {
    points.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    points.dedup();
    if points.len() < 3 {
        return points;
    }
    let mut hull: Vec<Vector2<f64>> = Vec::with_capacity(2 * points.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Vector2<f64>>> = if pass == 0 {
            Box::new(points.iter())
        } else {
            Box::new(points.iter().rev())
        };
        for p in iter {
            while hull.len() >= start + 2
                && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(*p);
        }
        hull.pop();
    }
    hull
}

/// Distance of `p` from the line through `a` and `b`, signed.
fn line_distance(a: &Vector2<f64>, b: &Vector2<f64>, p: &Vector2<f64>) -> f64 {
    cross(a, b, p) / (b - a).norm().max(1e-12)
}

/// Indices into `hull` of four extreme vertices, in hull order.
fn extreme_four(hull: &[Vector2<f64>]) -> Option<[usize; 4]> {
    let n = hull.len();
    if n < 4 {
        return None;
    }
    let centroid = hull.iter().fold(Vector2::zeros(), |s, p| s + p) / n as f64;
    let farthest = |from: &Vector2<f64>| {
        (0..n).max_by(|&i, &j| {
            (hull[i] - from)
                .norm_squared()
                .total_cmp(&(hull[j] - from).norm_squared())
        })
    };
    let a = farthest(&centroid)?;
    let c = farthest(&hull[a])?;
    // The vertex farthest from the diagonal on each side of it.
    let arc = |from: usize, to: usize| {
        let len = (to + n - from) % n;
        (1..len).map(move |k| (from + k) % n)
    };
    let far_from = |from: usize, to: usize| {
        arc(from, to).max_by(|&i, &j| {
            line_distance(&hull[from], &hull[to], &hull[i])
                .abs()
                .total_cmp(&line_distance(&hull[from], &hull[to], &hull[j]).abs())
        })
    };
    let mut corners = [a, far_from(a, c)?, c, far_from(c, a)?];
    // Each corner again as the vertex farthest from its neighbours' chord:
    // fixes a first diagonal that was really a side.
    for _ in 0..2 {
        for k in 0..4 {
            let (prev, next) = (corners[(k + 3) % 4], corners[(k + 1) % 4]);
            corners[k] = far_from(prev, next)?;
        }
    }
    Some(corners)
}

/// Least-squares line through `points` as (point on it, unit direction).
fn fit_line(points: &[Vector2<f64>]) -> Option<(Vector2<f64>, Vector2<f64>)> {
    if points.len() < 2 {
        return None;
    }
    let mean = points.iter().fold(Vector2::zeros(), |s, p| s + p) / points.len() as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in points {
        let d = p - mean;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    Some((mean, Vector2::new(angle.cos(), angle.sin())))
}

fn intersect(
    a: &(Vector2<f64>, Vector2<f64>),
    b: &(Vector2<f64>, Vector2<f64>),
) -> Option<Vector2<f64>> {
    let det = a.1.x * b.1.y - a.1.y * b.1.x;
    if det.abs() < 1e-9 {
        return None;
    }
    let d = b.0 - a.0;
    let t = (d.x * b.1.y - d.y * b.1.x) / det;
    Some(a.0 + a.1 * t)
}

/// The quadrilateral of one component's outline, its sides grown by
/// `grow_px` outward (to undo erosion and the half pixel between a
/// boundary pixel's centre and the boundary), clockwise as seen.
///
/// The hull's four extreme vertices only pick the sides: each side is a
/// line fitted to the boundary pixels along its middle, away from the
/// corners, which the saddle cut and the erosion round off; the corners
/// are where the lines meet.
fn quad_of_outline(outline: &Outline, grow_px: f64) -> Option<[Vector2<f64>; 4]> {
    let hull = convex_hull(outline.row_ends.clone());
    let idx = extreme_four(&hull)?;
    let rough: [Vector2<f64>; 4] = std::array::from_fn(|k| hull[idx[k]]);
    let centre = rough.iter().fold(Vector2::zeros(), |s, p| s + p) / 4.0;
    let boundary: Vec<&Vector2<f64>> = outline
        .row_ends
        .iter()
        .chain(&outline.column_ends)
        .collect();
    let mut lines = Vec::with_capacity(4);
    for k in 0..4 {
        let (a, b) = (rough[k], rough[(k + 1) % 4]);
        let side = (b - a).norm();
        if side < MIN_SIDE_PX - 2.0 * grow_px {
            return None;
        }
        let mut line = (a, (b - a) / side);
        // Twice: choose the middle of the side, fit, choose again about
        // the fitted line, fit again.
        for pass in 0..2 {
            let reach = if pass == 0 {
                (SIDE_TOLERANCE * side).max(2.0 * SIDE_TOLERANCE_MIN_PX)
            } else {
                SIDE_TOLERANCE_MIN_PX
            };
            let near: Vec<Vector2<f64>> = boundary
                .iter()
                .filter(|p| {
                    let t = (**p - a).dot(&line.1) / side;
                    (MIDDLE_FROM..=1.0 - MIDDLE_FROM).contains(&t)
                        && line_distance(&line.0, &(line.0 + line.1), p).abs() <= 0.25 * side
                })
                .map(|p| **p)
                .collect();
            let inliers: Vec<Vector2<f64>> = near
                .iter()
                .filter(|p| line_distance(&line.0, &(line.0 + line.1), p).abs() <= reach)
                .copied()
                .collect();
            // A straight side: nearly all of its middle on the line.
            if (inliers.len() as f64) < MIN_INLIER_SHARE * near.len() as f64
                || (inliers.len() as f64) < 0.3 * side
            {
                return None;
            }
            let (point, direction) = fit_line(&inliers)?;
            line = (point, direction * direction.dot(&(b - a)).signum());
        }
        // Push it outward, away from the quad's centre.
        let mut normal = Vector2::new(-line.1.y, line.1.x);
        if normal.dot(&(centre - line.0)) > 0.0 {
            normal = -normal;
        }
        lines.push((line.0 + normal * grow_px, line.1));
    }
    let mut quad = [Vector2::zeros(); 4];
    for k in 0..4 {
        quad[k] = intersect(&lines[(k + 3) % 4], &lines[k])?;
        // The lines must meet near the rounded corner they replace.
        let side = (rough[(k + 1) % 4] - rough[k]).norm();
        if (quad[k] - rough[k]).norm() > 0.2 * side + 2.0 * grow_px {
            return None;
        }
    }
    // Clockwise as seen (y down) is a positive shoelace sum.
    let twice_area: f64 = (0..4)
        .map(|k| {
            let (p, q) = (quad[k], quad[(k + 1) % 4]);
            p.x * q.y - q.x * p.y
        })
        .sum();
    if twice_area < 0.0 {
        quad.swap(1, 3);
    }
    Some(quad)
}

/// Every dark component of the eroded `mask` that is a quadrilateral with
/// sides of at least [`MIN_SIDE_PX`], its corners grown back by `grow_px`.
pub fn find_quads(mask: &Mask, grow_px: f64) -> Vec<[Vector2<f64>; 4]> {
    let min_pixels = (MIN_SIDE_PX * MIN_SIDE_PX * 0.25) as usize;
    component_outlines(mask, min_pixels)
        .iter()
        .filter_map(|outline| quad_of_outline(outline, grow_px))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask_of(w: usize, h: usize, dark: impl Fn(f64, f64) -> bool) -> Mask {
        Mask {
            width: w,
            height: h,
            dark: (0..w * h)
                .map(|i| dark((i % w) as f64, (i / w) as f64))
                .collect(),
        }
    }

    /// A rotated filled square and a ring-shaped one: both found, corners
    /// within a pixel; an L-shaped blob and a small square are not quads.
    #[test]
    fn squares_are_found_and_other_shapes_are_not() {
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let square = |x: f64, y: f64, cx: f64, cy: f64, half: f64| {
            let (dx, dy) = (x - cx, y - cy);
            (c * dx + s * dy).abs() < half && (-s * dx + c * dy).abs() < half
        };
        let mask = mask_of(200, 120, |x, y| {
            square(x, y, 40.0, 40.0, 20.0)
                || (square(x, y, 110.0, 50.0, 25.0) && !square(x, y, 110.0, 50.0, 15.0))
                || ((150.0..190.0).contains(&x) && (10.0..20.0).contains(&y))
                || ((150.0..160.0).contains(&x) && (10.0..50.0).contains(&y))
                || ((20.0..26.0).contains(&x) && (90.0..96.0).contains(&y))
        });
        let quads = find_quads(&mask, 0.5);
        assert_eq!(quads.len(), 2, "{quads:?}");
        for (quad, (cx, cy, half)) in quads.iter().zip([(40.0, 40.0, 20.0), (110.0, 50.0, 25.0)]) {
            for k in 0..4 {
                // Square corners are at half*(+-1, +-1) in the rotated frame.
                let found = quad.iter().any(|q| {
                    let (sx, sy) = ([1.0, 1.0, -1.0, -1.0][k], [1.0, -1.0, -1.0, 1.0][k]);
                    let corner =
                        Vector2::new(cx + half * (c * sx - s * sy), cy + half * (s * sx + c * sy));
                    (q - corner).norm() < 1.0
                });
                assert!(found, "corner {k} of {quad:?}");
            }
            // Clockwise as seen: the cross product of the first two sides
            // is positive with y down.
            assert!(cross(&quad[0], &quad[1], &quad[2]) > 0.0);
        }
    }
}
