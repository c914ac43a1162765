//! Where the map's frame nodes were taken, so that a place mapped on
//! several passes already gets no more of them.
//!
//! A frame whose landmarks are mostly mapped adds no node
//! ([`super::config::AbsoluteConfig::frame_node_saturation`]), but that
//! rule needs recognition to have found the landmarks again: a corner
//! seen from a new angle, or too near the border for a descriptor, comes
//! back as a new track, and a frame full of new tracks adds a node (and
//! its landmarks) on every lap. A place is a cube of [`PLACE_SIZE_M`] of
//! the robot's corrected position and the direction the frame looks in
//! (the mean of its landmarks' directions: one of 8 headings of 45
//! degrees, or up, or down). A pass is one stay in a place: it starts when a frame node's
//! turn comes in a place other than the previous turn's. Once nodes were
//! taken in a place on a given number of passes, later passes add none:
//! a robot that keeps driving through the same room stops growing its map
//! whatever its speed, since a room has finitely many places.

use std::collections::HashMap;

use nalgebra::Vector3;

/// Edge of a place's cube, m. About the distance a camera moves before
/// its view of a room a few metres away changes by more than its
/// landmarks' depth uncertainty.
pub const PLACE_SIZE_M: f64 = 0.5;

/// One place: the cube of the position and the bin of the direction.
pub(super) type Place = ([i64; 3], u8);

/// The passes of one place that took nodes.
#[derive(Clone, Copy, Debug)]
struct Passes {
    /// Passes during which the place took a node.
    count: u16,
    /// The pass of the last node it took.
    last: u64,
}

/// Passes with nodes per place, and the pass the robot is on.
#[derive(Debug, Default)]
pub(super) struct NodePlaces {
    places: HashMap<Place, Passes>,
    /// The place of the last node's turn, and its pass number.
    current: Option<(Place, u64)>,
    /// Passes started.
    passes: u64,
}

impl NodePlaces {
    /// A frame node's turn at `position_m` looking along `direction` (any
    /// length; zero when it has none). Returns its place (None for a
    /// position that is not finite: no place, never full).
    pub(super) fn turn(
        &mut self,
        position_m: &Vector3<f64>,
        direction: &Vector3<f64>,
    ) -> Option<Place> {
        let place = place(position_m, direction)?;
        if self.current.map(|(p, _)| p) != Some(place) {
            self.passes += 1;
            self.current = Some((place, self.passes));
        }
        Some(place)
    }

    /// True when `place` took nodes on `passes` passes before this one.
    pub(super) fn is_full(&self, place: Place, passes: usize) -> bool {
        let this_pass = self.current.map_or(0, |(_, pass)| pass);
        self.places
            .get(&place)
            .is_some_and(|p| p.last != this_pass && p.count as usize >= passes)
    }

    /// Records a node taken in `place` on the current pass.
    pub(super) fn add_node(&mut self, place: Place) {
        let this_pass = self.current.map_or(0, |(_, pass)| pass);
        let entry = self
            .places
            .entry(place)
            .or_insert(Passes { count: 0, last: 0 });
        if entry.count == 0 || entry.last != this_pass {
            entry.count = entry.count.saturating_add(1);
            entry.last = this_pass;
        }
    }

    /// Places holding at least one node.
    pub(super) fn len(&self) -> usize {
        self.places.len()
    }
}

/// The place of a position and a direction; None for a position that is
/// not finite.
fn place(position_m: &Vector3<f64>, direction: &Vector3<f64>) -> Option<Place> {
    if !position_m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let cube = position_m.map(|v| (v / PLACE_SIZE_M).floor() as i64);
    Some(([cube.x, cube.y, cube.z], direction_bin(direction)))
}

/// The bin of a viewing direction (world frame, z up): one of 8 headings
/// of 45 degrees, or straight up or down (more than 60 degrees from the
/// horizon). Headings, not a cube map: a level camera looks along the
/// horizon, where a bin edge would split one view in two. 10 for a
/// direction that is zero or not finite.
fn direction_bin(d: &Vector3<f64>) -> u8 {
    let norm = d.norm();
    if !(norm > 0.0 && norm.is_finite()) {
        return 10;
    }
    if d.z.abs() > STEEP_SIN * norm {
        return 8 + u8::from(d.z < 0.0);
    }
    let heading = d.y.atan2(d.x).rem_euclid(std::f64::consts::TAU);
    ((heading / std::f64::consts::FRAC_PI_4) as u8).min(7)
}

/// Sine of the elevation above which a view is straight up or down.
const STEEP_SIN: f64 = 0.866;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn places_split_by_cube_and_by_direction() {
        let here = Vector3::new(0.1, 0.2, 0.3);
        let ahead = Vector3::new(1.0, 0.1, 0.2);
        let p = place(&here, &ahead).expect("finite");
        // Same cube, same direction bin (length does not matter).
        assert_eq!(
            place(&Vector3::new(0.49, 0.01, 0.01), &(3.0 * ahead)),
            Some(p)
        );
        // The next cube, or the same cube seen the other way, is another place.
        for (position, direction) in [
            (Vector3::new(0.6, 0.2, 0.3), ahead),
            (Vector3::new(-0.1, 0.2, 0.3), ahead),
            (here, -ahead),
            (here, Vector3::new(1.0, 1.1, 0.2)),
            (here, Vector3::zeros()),
        ] {
            assert_ne!(
                place(&position, &direction),
                Some(p),
                "{position:?} {direction:?}"
            );
        }
        assert_eq!(place(&Vector3::new(f64::NAN, 0.0, 0.0), &ahead), None);
    }

    #[test]
    fn a_place_is_full_after_its_passes_whatever_the_nodes_per_pass() {
        let mut places = NodePlaces::default();
        let (a, b) = (Vector3::new(0.1, 0.1, 0.1), Vector3::new(3.1, 0.1, 0.1));
        let ahead = Vector3::x();
        // Four passes through a, then b; each pass wants some nodes in a (a
        // slow first pass five), at most 2 passes per place.
        let mut taken = Vec::new();
        for wanted in [5, 1, 3, 2] {
            let mut took = 0;
            for k in 0..6 {
                let place_a = places.turn(&a, &ahead).expect("finite");
                if k < wanted && !places.is_full(place_a, 2) {
                    places.add_node(place_a);
                    took += 1;
                }
            }
            taken.push(took);
            let place_b = places.turn(&b, &ahead).expect("finite");
            places.add_node(place_b);
        }
        assert_eq!(taken, [5, 1, 0, 0]);
        assert_eq!(places.len(), 2);
        // b took a node on each of 4 passes, and the pass under way (the
        // last) never fills its own place.
        let place_b = places.turn(&b, &ahead).expect("finite");
        assert!(!places.is_full(place_b, 1));
        let _ = places.turn(&a, &ahead);
        let place_b = places.turn(&b, &ahead).expect("finite");
        assert!(places.is_full(place_b, 4) && !places.is_full(place_b, 5));
    }

    #[test]
    fn every_direction_has_one_of_10_bins_and_opposite_ones_differ() {
        let mut seen = std::collections::HashSet::new();
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..5000 {
            let d = Vector3::new(next(), next(), next());
            let bin = direction_bin(&d);
            assert!(bin < 10);
            assert_ne!(bin, direction_bin(&-d), "{d:?}");
            // A level view's bin does not depend on how far it dips.
            let level = Vector3::new(d.x, d.y, 0.0);
            for dip in [-0.3, 0.3] {
                assert_eq!(
                    direction_bin(&(level + dip * level.norm() * Vector3::z())),
                    direction_bin(&level)
                );
            }
            seen.insert(bin);
        }
        assert_eq!(seen.len(), 10);
        assert_eq!(direction_bin(&Vector3::zeros()), 10);
    }
}
