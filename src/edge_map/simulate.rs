//! Simulated landmark observations for the edge map: a robot drives a
//! random route through a strip of city streets lined with landmarks, sees
//! those within range, and hands their body-frame positions with
//! depth-dependent, stereo-like covariances to the edge map. The result is
//! a map problem with ground truth; `rigslam map generate` writes it.
//!
//! The route wanders inside a strip `strip_blocks` blocks wide, mostly
//! forward, so streets are driven again (loop closures) while the map keeps
//! growing along the strip, as a vehicle mapping a district does.

use std::collections::HashMap;
use std::time::Instant;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::edge::{EdgeMap, LandmarkObservation};
use super::policy::EdgePolicy;
use super::problem::MapProblem;

/// Parameters of a simulated mapping run.
#[derive(Clone, Debug)]
pub struct CityOptions {
    /// Landmarks to create; the run stops when the last is created. The map
    /// keeps those connected to the reference (a few crowded-out ones may
    /// be missing from large runs).
    pub landmarks: usize,
    /// Side of a city block (street spacing), m.
    pub block_m: f64,
    /// Landmarks per metre of street (both sides together).
    pub landmarks_per_m: f64,
    /// Width of the strip the route stays in, blocks.
    pub strip_blocks: i64,
    /// Distance between frames, m.
    pub step_m: f64,
    /// Largest distance at which a landmark is observed, m.
    pub range_m: f64,
    /// At most this many (nearest) landmarks are observed per frame.
    pub max_visible: usize,
    /// Transverse standard deviation per metre of depth (pixel noise / focal).
    pub sigma_transverse_per_m: f64,
    /// Depth standard deviation per squared metre of depth (stereo).
    pub sigma_depth_per_m2: f64,
    /// Which landmark pairs of a frame become edges.
    pub policy: EdgePolicy,
    /// Seed of the route, landmarks and noise; the same seed gives the same run.
    pub seed: u64,
    /// Draw observation noise from the stated covariances (false: exact
    /// observations, same covariances).
    pub add_noise: bool,
}

impl Default for CityOptions {
    fn default() -> Self {
        Self {
            landmarks: 1000,
            block_m: 40.0,
            landmarks_per_m: 1.0,
            strip_blocks: 3,
            step_m: 2.0,
            range_m: 15.0,
            max_visible: 30,
            sigma_transverse_per_m: 0.002,
            sigma_depth_per_m2: 0.001,
            policy: EdgePolicy::KNearest(4),
            seed: 0,
            add_noise: true,
        }
    }
}

/// A simulated map: the fused problem and the true landmark positions.
pub struct SimulatedMap {
    /// The fused edges, ready to solve.
    pub problem: MapProblem,
    /// True positions by id, world frame, m (of the frame for a frame
    /// node).
    pub truth_m: Vec<Vector3<f64>>,
    /// Which ids are frame nodes ([`EdgePolicy::FrameNodes`]), not
    /// landmarks.
    pub frame_node: Vec<bool>,
    /// Frames driven.
    pub frames: usize,
    /// Observations (or frame-landmark pairs) fused into edges.
    pub measurements: usize,
    /// Wall time spent choosing pairs and fusing edges (eq. 41-43), ms.
    pub fuse_ms: f64,
}

impl SimulatedMap {
    /// True positions relative to the reference landmark (what the solve
    /// recovers: the reference sits at the origin).
    pub fn truth_relative_m(&self) -> Vec<Vector3<f64>> {
        let r = self.truth_m[self.problem.reference as usize];
        self.truth_m.iter().map(|p| p - r).collect()
    }
}

/// Runs the simulated mapping drive and fuses its edges.
pub fn simulate_city(options: &CityOptions) -> SimulatedMap {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut truth: Vec<Vector3<f64>> = Vec::with_capacity(options.landmarks);
    let mut frame_node: Vec<bool> = Vec::with_capacity(options.landmarks);
    let mut landmarks = 0usize;
    let cell_m = options.range_m;
    let mut grid: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
    let mut segments_done: HashMap<((i64, i64), (i64, i64)), ()> = HashMap::new();
    let mut map = EdgeMap::new();
    let (mut frames, mut measurements, mut fuse_ms) = (0usize, 0usize, 0.0);
    let mut node = (0i64, 0i64);
    let mut heading = (1i64, 0i64);
    let per_segment = (options.block_m * options.landmarks_per_m).round().max(1.0) as usize;
    let mut observations: Vec<LandmarkObservation> = Vec::new();
    let mut candidates: Vec<(f64, u32)> = Vec::new();
    let mut positions_body: Vec<Vector3<f64>> = Vec::new();
    // Drive until every landmark exists and the last segment was driven.
    while landmarks < options.landmarks {
        // Choose the next street at this intersection.
        let choices: Vec<((i64, i64), f64)> = [(1, 0), (0, 1), (0, -1), (-1, 0)]
            .into_iter()
            .filter(|d| *d != (-heading.0, -heading.1))
            .filter(|d| (0..=options.strip_blocks).contains(&(node.1 + d.1)))
            .map(|d| {
                (
                    d,
                    if d.0 == 1 {
                        3.0
                    } else if d.0 == -1 {
                        0.7
                    } else {
                        1.0
                    },
                )
            })
            .collect();
        let total: f64 = choices.iter().map(|c| c.1).sum();
        let mut pick = rng.gen_range(0.0..total);
        let mut next_dir = choices[0].0;
        for (d, w) in &choices {
            if pick < *w {
                next_dir = *d;
                break;
            }
            pick -= w;
        }
        heading = next_dir;
        let next = (node.0 + heading.0, node.1 + heading.1);
        let key = (node.min(next), node.max(next));
        let a = Vector3::new(node.0 as f64, node.1 as f64, 0.0) * options.block_m;
        let b = Vector3::new(next.0 as f64, next.1 as f64, 0.0) * options.block_m;
        let along = (b - a).normalize();
        let side = Vector3::new(-along.y, along.x, 0.0);
        if segments_done.insert(key, ()).is_none() {
            for k in 0..per_segment {
                if landmarks >= options.landmarks {
                    break;
                }
                let s = rng.gen_range(0.1..0.9) * options.block_m;
                let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
                let p = a
                    + along * s
                    + side * sign * rng.gen_range(4.0..10.0)
                    + Vector3::new(0.0, 0.0, rng.gen_range(0.0..8.0));
                let id = truth.len() as u32;
                grid.entry(((p.x / cell_m).floor() as i64, (p.y / cell_m).floor() as i64))
                    .or_default()
                    .push(id);
                truth.push(p);
                frame_node.push(false);
                landmarks += 1;
            }
        }
        // Frames along the segment.
        let yaw = along.y.atan2(along.x);
        let rotation = *Rotation3::from_axis_angle(&Vector3::z_axis(), yaw).matrix();
        let steps = (options.block_m / options.step_m).round() as usize;
        for step in 0..steps {
            let c = a + along * (step as f64 * options.step_m) + Vector3::new(0.0, 0.0, 1.5);
            candidates.clear();
            let (cx, cy) = ((c.x / cell_m).floor() as i64, (c.y / cell_m).floor() as i64);
            for gx in cx - 1..=cx + 1 {
                for gy in cy - 1..=cy + 1 {
                    for &id in grid.get(&(gx, gy)).map(Vec::as_slice).unwrap_or(&[]) {
                        let d = (truth[id as usize] - c).norm();
                        if d <= options.range_m {
                            candidates.push((d, id));
                        }
                    }
                }
            }
            if candidates.len() > options.max_visible {
                candidates
                    .select_nth_unstable_by(options.max_visible - 1, |x, y| x.0.total_cmp(&y.0));
                candidates.truncate(options.max_visible);
            }
            candidates.sort_unstable_by_key(|c| c.1);
            observations.clear();
            for &(depth, id) in &candidates {
                let p_body = rotation.transpose() * (truth[id as usize] - c);
                let ray = p_body / depth;
                let sigma_t = options.sigma_transverse_per_m * depth;
                let sigma_d = options.sigma_depth_per_m2 * depth * depth;
                let frame = ray_frame(&ray);
                let cov = frame
                    * Matrix3::from_diagonal(&Vector3::new(
                        sigma_d * sigma_d,
                        sigma_t * sigma_t,
                        sigma_t * sigma_t,
                    ))
                    * frame.transpose();
                let noise = frame
                    * Vector3::new(
                        sigma_d * {
                            let z: f64 = StandardNormal.sample(&mut rng);
                            z
                        },
                        sigma_t * {
                            let z: f64 = StandardNormal.sample(&mut rng);
                            z
                        },
                        sigma_t * {
                            let z: f64 = StandardNormal.sample(&mut rng);
                            z
                        },
                    );
                let noise: Vector3<f64> = if options.add_noise {
                    noise
                } else {
                    Vector3::zeros()
                };
                observations.push(LandmarkObservation {
                    id,
                    p_body_m: p_body + noise,
                    cov_body_m2: cov,
                });
            }
            let t = Instant::now();
            positions_body.clear();
            positions_body.extend(observations.iter().map(|o| o.p_body_m));
            match options.policy {
                EdgePolicy::FrameNodes { every } => {
                    if frames % every == 0 && !observations.is_empty() {
                        let node = truth.len() as u32;
                        truth.push(c);
                        frame_node.push(true);
                        map.add_frame_node(&rotation, node, &observations);
                        measurements += observations.len();
                    }
                }
                _ => {
                    let pairs = options.policy.pairs(&positions_body);
                    map.add_frame(&rotation, &observations, &pairs);
                    measurements += pairs.len();
                }
            }
            fuse_ms += t.elapsed().as_secs_f64() * 1e3;
            frames += 1;
        }
        node = next;
    }
    map.reserve_landmarks(truth.len() as u32);
    // A landmark crowded out of every frame's nearest `max_visible` has no
    // edge; keep the part of the map connected to the reference.
    let (problem, kept) = MapProblem::from_edge_map(&map, 0).reference_component();
    SimulatedMap {
        problem,
        truth_m: kept.iter().map(|&old| truth[old as usize]).collect(),
        frame_node: kept.iter().map(|&old| frame_node[old as usize]).collect(),
        frames,
        measurements,
        fuse_ms,
    }
}

/// Orthonormal frame whose first column is the unit ray.
fn ray_frame(ray: &Vector3<f64>) -> Matrix3<f64> {
    let helper = if ray.z.abs() < 0.9 {
        Vector3::z()
    } else {
        Vector3::x()
    };
    let u = ray.cross(&helper).normalize();
    let v = ray.cross(&u);
    Matrix3::from_columns(&[*ray, u, v])
}
