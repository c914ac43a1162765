//! The synthetic world: a closed room of axis-aligned planes with
//! furniture-sized axis-aligned boxes, each face carrying its own texture.
//! Ray queries are the slab test (Kay & Kajiya 1986) in f32.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::texture::Texture;

/// An axis-aligned box, world frame, metres.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    /// Lower corner, m.
    pub min_m: [f32; 3],
    /// Upper corner, m.
    pub max_m: [f32; 3],
}

impl Aabb {
    /// The box between the corners `min_m` and `max_m`, m.
    pub fn new(min_m: [f32; 3], max_m: [f32; 3]) -> Self {
        Self { min_m, max_m }
    }
    /// True when the two boxes overlap (closed intervals).
    pub fn overlaps(&self, other: &Aabb) -> bool {
        (0..3).all(|a| self.min_m[a] <= other.max_m[a] && other.min_m[a] <= self.max_m[a])
    }
    /// This box grown by `margin_m` on every side.
    pub fn expanded(&self, margin_m: f32) -> Aabb {
        Aabb {
            min_m: self.min_m.map(|v| v - margin_m),
            max_m: self.max_m.map(|v| v + margin_m),
        }
    }
    /// Whether `p` (world, m) is strictly inside.
    pub fn contains(&self, p: [f32; 3]) -> bool {
        (0..3).all(|a| self.min_m[a] < p[a] && p[a] < self.max_m[a])
    }
}

/// The surfaces of a scene without their textures: what `scene.json` of
/// a rendered dataset holds, so that an evaluation can check estimated
/// landmarks and maps against the surfaces they lie on (world frame of the
/// ground truth, m).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneGeometry {
    /// The room; its inside faces are surfaces.
    pub room: Aabb,
    /// The boxes standing in it; their outside faces are surfaces.
    pub boxes: Vec<Aabb>,
}

/// How to build a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneConfig {
    /// Seed of the box placement and textures; the same seed gives the same scene.
    pub seed: u64,
    /// Inside of the room.
    pub room: Aabb,
    /// Region the boxes must stay out of (the trajectory with a margin).
    pub keep_clear: Aabb,
    /// Number of boxes to place (fewer if they do not fit).
    pub box_count: usize,
    /// Base texel edge, m.
    pub texel_m: f32,
}

/// One flat face: texture plus the plane coordinates of its corner.
#[derive(Debug, Clone)]
pub struct Surface {
    /// The face's texture.
    pub texture: Texture,
    /// World coordinates (along the face's u and v axes) of the texture's corner.
    pub origin_uv_m: [f32; 2],
    /// Brightness factor standing in for lighting (faces of a box differ).
    pub gain: f32,
}

/// Room + boxes + one surface per face.
///
/// Surface `6 * k + 2 * axis + side` is face (`axis`, `side`) of body `k`,
/// body 0 the room, body `k >= 1` box `k - 1`; side 0 is the face at the
/// lower coordinate. A face with normal along `axis` is parametrised by
/// world axes `u = (axis + 1) % 3` and `v = (axis + 2) % 3`.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The room (its inside faces are surfaces 0-5).
    pub room: Aabb,
    /// The boxes in the room.
    pub boxes: Vec<Aabb>,
    /// Every face, indexed as above.
    pub surfaces: Vec<Surface>,
}

/// What a ray hits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter at the hit, m (the distance for a unit direction).
    pub t_m: f32,
    /// Index of the surface hit in [`Scene::surfaces`].
    pub surface: usize,
    /// Axis of the face's normal: 0 x, 1 y, 2 z.
    pub axis: usize,
}

/// Lighting stand-in per face (axis, side): floors bright, ceilings dim,
/// walls in between and different from each other.
const FACE_GAIN: [[f32; 2]; 3] = [[0.88, 0.8], [0.84, 0.93], [0.72, 1.0]];

impl Scene {
    /// A seeded room with boxes on the floor and along the walls, all
    /// outside `keep_clear`.
    pub fn generate(config: &SceneConfig) -> Scene {
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let room = config.room;
        let mut boxes: Vec<Aabb> = Vec::new();
        let mut attempts = 0;
        while boxes.len() < config.box_count && attempts < 2000 {
            attempts += 1;
            let size = [
                rng.gen_range(0.3..1.4f32),
                rng.gen_range(0.3..1.4f32),
                rng.gen_range(0.25..1.8f32),
            ];
            let mut min = [0f32; 3];
            for a in 0..2 {
                let lo = room.min_m[a] + 0.05;
                let hi = room.max_m[a] - 0.05 - size[a];
                if hi <= lo {
                    continue;
                }
                min[a] = rng.gen_range(lo..hi);
            }
            // On the floor, or now and then hanging on a wall (shelves).
            min[2] = if rng.gen_bool(0.8) {
                room.min_m[2]
            } else {
                rng.gen_range(room.min_m[2]..(room.max_m[2] - size[2]).max(room.min_m[2] + 0.01))
            };
            let candidate = Aabb::new(min, [min[0] + size[0], min[1] + size[1], min[2] + size[2]]);
            let inside_room = (0..3).all(|a| candidate.max_m[a] <= room.max_m[a]);
            if inside_room
                && !candidate.overlaps(&config.keep_clear)
                && !boxes.iter().any(|b| b.expanded(0.05).overlaps(&candidate))
            {
                boxes.push(candidate);
            }
        }
        let mut surfaces = Vec::with_capacity(6 * (boxes.len() + 1));
        for body in std::iter::once(&room).chain(boxes.iter()) {
            // axis and side name the face; they index more than FACE_GAIN.
            #[allow(clippy::needless_range_loop)]
            for axis in 0..3 {
                for side in 0..2 {
                    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
                    let w = body.max_m[ua] - body.min_m[ua];
                    let h = body.max_m[va] - body.min_m[va];
                    let gain = FACE_GAIN[axis][side] * rng.gen_range(0.92..1.08f32);
                    surfaces.push(Surface {
                        texture: Texture::generate(w, h, config.texel_m, rng.gen()),
                        origin_uv_m: [body.min_m[ua], body.min_m[va]],
                        gain,
                    });
                }
            }
        }
        Scene {
            room,
            boxes,
            surfaces,
        }
    }

    /// Its surfaces without the textures.
    pub fn geometry(&self) -> SceneGeometry {
        SceneGeometry {
            room: self.room,
            boxes: self.boxes.clone(),
        }
    }

    /// A scene from explicit parts with one flat grey per body (room,
    /// then each box) and unit gain: for geometry tests.
    pub fn flat(room: Aabb, boxes: Vec<Aabb>, greys: &[u8]) -> Scene {
        assert_eq!(greys.len(), boxes.len() + 1, "one grey per body");
        let surfaces = greys
            .iter()
            .flat_map(|&g| {
                (0..6).map(move |_| Surface {
                    texture: Texture::flat(g),
                    origin_uv_m: [0.0, 0.0],
                    gain: 1.0,
                })
            })
            .collect();
        Scene {
            room,
            boxes,
            surfaces,
        }
    }

    /// First surface hit by the ray `o + t d` from inside the room;
    /// `inv_d` is the componentwise reciprocal of `d`.
    #[inline]
    pub fn intersect(&self, o: [f32; 3], inv_d: [f32; 3]) -> Hit {
        let mut best = self.intersect_room(o, inv_d);
        for k in 0..self.boxes.len() {
            self.intersect_box(k, o, inv_d, &mut best);
        }
        best
    }

    /// Where the ray leaves the room: along each axis the plane ahead of it.
    #[inline]
    pub fn intersect_room(&self, o: [f32; 3], inv_d: [f32; 3]) -> Hit {
        let mut best = Hit {
            t_m: f32::INFINITY,
            surface: 0,
            axis: 0,
        };
        for a in 0..3 {
            let (plane, side) = if inv_d[a] > 0.0 {
                (self.room.max_m[a], 1)
            } else {
                (self.room.min_m[a], 0)
            };
            let t = (plane - o[a]) * inv_d[a];
            if t < best.t_m {
                best = Hit {
                    t_m: t,
                    surface: 2 * a + side,
                    axis: a,
                };
            }
        }
        best
    }

    /// Replaces `best` by box `k`'s entry point when the ray meets the box
    /// in front of `o` and before `best`.
    #[inline]
    pub fn intersect_box(&self, k: usize, o: [f32; 3], inv_d: [f32; 3], best: &mut Hit) {
        let b = &self.boxes[k];
        let mut t_near = f32::NEG_INFINITY;
        let mut t_far = best.t_m;
        let mut near_axis = 0;
        for a in 0..3 {
            let t1 = (b.min_m[a] - o[a]) * inv_d[a];
            let t2 = (b.max_m[a] - o[a]) * inv_d[a];
            let lo = t1.min(t2);
            let hi = t1.max(t2);
            if lo > t_near {
                t_near = lo;
                near_axis = a;
            }
            t_far = t_far.min(hi);
        }
        if t_near <= t_far && t_near > 0.0 {
            // Entering through the face met first: the low face when
            // travelling towards +axis.
            let side = if inv_d[near_axis] > 0.0 { 0 } else { 1 };
            *best = Hit {
                t_m: t_near,
                surface: 6 * (k + 1) + 2 * near_axis + side,
                axis: near_axis,
            };
        }
    }

    /// Grey level seen along the unit ray `d` from `o`, for a pixel whose
    /// rays spread by `footprint_rad` (radians per pixel), testing every box.
    #[inline]
    pub fn shade(&self, o: [f32; 3], d: [f32; 3], footprint_rad: f32) -> f32 {
        let inv_d = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let hit = self.intersect(o, inv_d);
        self.radiance(o, d, hit, footprint_rad)
    }

    /// As [`Scene::shade`], testing only the boxes listed in `candidates`
    /// (those that may lie in the pixel's direction).
    #[inline]
    pub fn shade_among(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        footprint_rad: f32,
        candidates: &[u16],
    ) -> f32 {
        let inv_d = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let mut hit = self.intersect_room(o, inv_d);
        for &k in candidates {
            self.intersect_box(k as usize, o, inv_d, &mut hit);
        }
        self.radiance(o, d, hit, footprint_rad)
    }

    #[inline]
    fn radiance(&self, o: [f32; 3], d: [f32; 3], hit: Hit, footprint_rad: f32) -> f32 {
        let surface = &self.surfaces[hit.surface];
        let (ua, va) = ((hit.axis + 1) % 3, (hit.axis + 2) % 3);
        let u = o[ua] + hit.t_m * d[ua] - surface.origin_uv_m[0];
        let v = o[va] + hit.t_m * d[va] - surface.origin_uv_m[1];
        // Footprint on the plane: distance times angle, stretched by the
        // obliquity 1 / |cos|.
        let cos = d[hit.axis].abs().max(0.05);
        let footprint_m = hit.t_m * footprint_rad / cos;
        surface.texture.sample(u, v, footprint_m) * surface.gain
    }

    /// Centre and radius of box `k`'s bounding sphere.
    pub fn box_sphere(&self, k: usize) -> ([f32; 3], f32) {
        let b = &self.boxes[k];
        let c: [f32; 3] = std::array::from_fn(|a| 0.5 * (b.min_m[a] + b.max_m[a]));
        let r2: f32 = (0..3)
            .map(|a| (0.5 * (b.max_m[a] - b.min_m[a])).powi(2))
            .sum();
        (c, r2.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: [f32; 3]) -> [f32; 3] {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / n)
    }

    #[test]
    fn ray_hits_nearest_face() {
        let room = Aabb::new([-3.0, -3.0, 0.0], [3.0, 3.0, 3.0]);
        let b = Aabb::new([1.0, -0.5, 0.0], [2.0, 0.5, 1.0]);
        let scene = Scene::flat(room, vec![b], &[10, 200]);
        let o = [0.0, 0.0, 0.5];
        // Straight along +x: the box's low-x face at 1 m.
        let d = unit([1.0, 0.0, 0.0]);
        let hit = scene.intersect(o, d.map(|c| 1.0 / c));
        assert_eq!(hit.surface, 6);
        assert!((hit.t_m - 1.0).abs() < 1e-6);
        // Along -x: the room's low-x wall at 3 m.
        let hit = scene.intersect(o, [-1.0f32, 0.0, 0.0].map(|c| 1.0 / c));
        assert_eq!(hit.surface, 0);
        assert!((hit.t_m - 3.0).abs() < 1e-6);
        // Up at 45 degrees over the box: the ceiling at 2.5 / sin(45).
        let d = unit([1.0, 0.0, 1.0]);
        let hit = scene.intersect(o, d.map(|c| 1.0 / c));
        assert_eq!(hit.surface, 5);
        assert!((hit.t_m - 2.5 * 2f32.sqrt()).abs() < 1e-5);
    }

    #[test]
    fn generated_boxes_avoid_the_keep_clear_region() {
        let config = SceneConfig {
            seed: 5,
            room: Aabb::new([-4.0, -4.0, 0.0], [4.0, 4.0, 3.0]),
            keep_clear: Aabb::new([-2.0, -2.0, 0.6], [2.0, 2.0, 2.0]),
            box_count: 12,
            texel_m: 0.02,
        };
        let scene = Scene::generate(&config);
        assert!(scene.boxes.len() >= 8, "placed {}", scene.boxes.len());
        for b in &scene.boxes {
            assert!(!b.overlaps(&config.keep_clear));
        }
        assert_eq!(scene.surfaces.len(), 6 * (scene.boxes.len() + 1));
    }
}
