//! Ray-cast renderer: one ray per pixel through the real camera model.
//!
//! The camera's distortion is handled once: [`Renderer::new`] unprojects
//! every pixel centre with [`CameraModel::unproject`] into a unit ray in the
//! camera frame (a look-up table). A frame then costs one rotation, one ray
//! query and one trilinear texture fetch per pixel, in f32, with no
//! allocation.

use nalgebra::{Isometry3, Vector2};

use super::scene::Scene;
use super::texture::hash3;
use crate::camera::CameraModel;

/// Image-formation effects on top of the geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Standard deviation of the additive pixel noise, grey levels (0 = off).
    pub noise_sigma_grey: f32,
    /// Fractional darkening at the image corners (cos^4-like falloff; 0 = off).
    pub vignette: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            noise_sigma_grey: 1.0,
            vignette: 0.25,
        }
    }
}

impl RenderOptions {
    /// No noise, no vignetting: the image is the scene's radiance only.
    pub const IDEAL: RenderOptions = RenderOptions {
        noise_sigma_grey: 0.0,
        vignette: 0.0,
    };
}

/// Per-pixel constants of a camera.
#[derive(Debug, Clone, Copy)]
struct PixelRay {
    /// Unit ray in the camera frame; zero where the model has no inverse.
    dir_cam: [f32; 3],
    /// Angle between this pixel's ray and its neighbours', rad.
    footprint_rad: f32,
    /// Brightness factor for vignetting.
    gain: f32,
}

/// A square block of pixels and the cone (camera frame) holding their rays.
#[derive(Debug, Clone, Copy)]
struct Tile {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
    axis_cam: [f32; 3],
    /// Largest angle between the axis and a ray of the tile, rad.
    half_angle_rad: f32,
}

/// Edge of a tile, pixels.
const TILE_PX: usize = 16;
/// Most boxes a scene may hold for the per-tile candidate lists.
pub const MAX_BOXES: usize = 64;

/// Renders one camera.
#[derive(Debug, Clone)]
pub struct Renderer {
    width: usize,
    height: usize,
    rays: Vec<PixelRay>,
    tiles: Vec<Tile>,
    options: RenderOptions,
}

fn unit_ray(model: &CameraModel, x: f64, y: f64) -> Option<[f64; 3]> {
    let r = model.unproject(&Vector2::new(x, y))?;
    let r = r.normalize();
    Some([r.x, r.y, r.z])
}

fn angle(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
        .clamp(-1.0, 1.0)
        .acos()
}

impl Renderer {
    /// Builds the ray table of `model` (every pixel centre unprojected).
    pub fn new(model: &CameraModel, options: RenderOptions) -> Self {
        let width = model.width() as usize;
        let height = model.height() as usize;
        let half_diag2 = (width * width + height * height) as f64 / 4.0;
        let mut rays = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let (xf, yf) = (x as f64, y as f64);
                let ray = match unit_ray(model, xf, yf) {
                    Some(centre) => {
                        let dx = unit_ray(model, xf + 1.0, yf)
                            .or_else(|| unit_ray(model, xf - 1.0, yf))
                            .map_or(0.0, |n| angle(&centre, &n));
                        let dy = unit_ray(model, xf, yf + 1.0)
                            .or_else(|| unit_ray(model, xf, yf - 1.0))
                            .map_or(0.0, |n| angle(&centre, &n));
                        let r2 = ((xf - width as f64 / 2.0).powi(2)
                            + (yf - height as f64 / 2.0).powi(2))
                            / half_diag2;
                        PixelRay {
                            dir_cam: centre.map(|c| c as f32),
                            footprint_rad: dx.max(dy) as f32,
                            gain: (1.0 - options.vignette as f64 * r2) as f32,
                        }
                    }
                    None => PixelRay {
                        dir_cam: [0.0; 3],
                        footprint_rad: 0.0,
                        gain: 0.0,
                    },
                };
                rays.push(ray);
            }
        }
        let tiles = make_tiles(&rays, width, height);
        Self {
            width,
            height,
            rays,
            tiles,
            options,
        }
    }

    /// Image width, px.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Image height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Renders the view of a camera at `T_world_cam` into `out` (row-major
    /// Mono8, `width * height`). `noise_seed` seeds the pixel noise, so a
    /// frame is a pure function of scene, pose and seed.
    #[allow(non_snake_case)]
    pub fn render_into(
        &self,
        scene: &Scene,
        T_world_cam: &Isometry3<f64>,
        noise_seed: u64,
        out: &mut [u8],
    ) {
        assert_eq!(out.len(), self.width * self.height, "output buffer size");
        let r = T_world_cam.rotation.to_rotation_matrix();
        let m = r.matrix();
        let rot: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)] as f32));
        let rotate = |c: [f32; 3]| -> [f32; 3] {
            [
                rot[0][0] * c[0] + rot[0][1] * c[1] + rot[0][2] * c[2],
                rot[1][0] * c[0] + rot[1][1] * c[1] + rot[1][2] * c[2],
                rot[2][0] * c[0] + rot[2][1] * c[1] + rot[2][2] * c[2],
            ]
        };
        let o = T_world_cam.translation.vector;
        let o = [o.x as f32, o.y as f32, o.z as f32];
        assert!(
            scene.room.contains(o),
            "camera at {o:?} is outside the room {:?}",
            scene.room
        );
        assert!(scene.boxes.len() <= MAX_BOXES, "at most {MAX_BOXES} boxes");
        // Bounding spheres of the boxes relative to the camera: a tile
        // tests only the boxes whose sphere meets its cone of rays.
        let mut spheres = [([0f32; 3], 0f32, 0f32); MAX_BOXES];
        for (k, sphere) in spheres.iter_mut().enumerate().take(scene.boxes.len()) {
            let (c, radius) = scene.box_sphere(k);
            let v = [c[0] - o[0], c[1] - o[1], c[2] - o[2]];
            let dist = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            *sphere = (v, dist, radius);
        }
        // Triangular noise (sum of two uniforms) has std 1/sqrt(6) per unit half-width.
        let noise_scale = self.options.noise_sigma_grey * 6f32.sqrt();
        let inv_2_24 = 1.0 / (1u32 << 24) as f32;
        let mut candidates = [0u16; MAX_BOXES];
        for tile in &self.tiles {
            let axis = rotate(tile.axis_cam);
            let mut count = 0;
            for (k, &(v, dist, radius)) in spheres.iter().enumerate().take(scene.boxes.len()) {
                let visible = if dist <= radius {
                    true
                } else {
                    let cos = (axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]) / dist;
                    let angle = cos.clamp(-1.0, 1.0).acos();
                    angle <= tile.half_angle_rad + (radius / dist).asin() + 1e-3
                };
                if visible {
                    candidates[count] = k as u16;
                    count += 1;
                }
            }
            let candidates = &candidates[..count];
            for y in tile.y0..tile.y1 {
                for x in tile.x0..tile.x1 {
                    let i = y * self.width + x;
                    let ray = &self.rays[i];
                    if ray.gain == 0.0 {
                        out[i] = 0;
                        continue;
                    }
                    let d = rotate(ray.dir_cam);
                    let mut value =
                        scene.shade_among(o, d, ray.footprint_rad, candidates) * ray.gain;
                    if noise_scale > 0.0 {
                        let h = hash3(i as u64, noise_seed, 0x5EED);
                        let u1 = (h >> 40) as f32 * inv_2_24;
                        let u2 = ((h >> 8) & 0xff_ffff) as f32 * inv_2_24;
                        value += noise_scale * (u1 + u2 - 1.0) * 0.5;
                    }
                    out[i] = (value + 0.5).clamp(0.0, 255.0) as u8;
                }
            }
        }
    }

    /// Convenience: a freshly allocated frame.
    #[allow(non_snake_case)]
    pub fn render(&self, scene: &Scene, T_world_cam: &Isometry3<f64>, noise_seed: u64) -> Vec<u8> {
        let mut out = vec![0u8; self.width * self.height];
        self.render_into(scene, T_world_cam, noise_seed, &mut out);
        out
    }
}

/// Cuts the image into tiles and finds each tile's cone of rays.
fn make_tiles(rays: &[PixelRay], width: usize, height: usize) -> Vec<Tile> {
    let mut tiles = Vec::new();
    for y0 in (0..height).step_by(TILE_PX) {
        for x0 in (0..width).step_by(TILE_PX) {
            let (x1, y1) = ((x0 + TILE_PX).min(width), (y0 + TILE_PX).min(height));
            let valid = || {
                (y0..y1)
                    .flat_map(move |y| (x0..x1).map(move |x| y * width + x))
                    .map(|i| &rays[i])
                    .filter(|r| r.gain != 0.0)
            };
            let mut sum = [0f64; 3];
            for r in valid() {
                for (total, d) in sum.iter_mut().zip(r.dir_cam) {
                    *total += d as f64;
                }
            }
            let norm = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
            let axis = if norm > 0.0 {
                sum.map(|c| (c / norm) as f32)
            } else {
                [0.0, 0.0, 1.0]
            };
            let half_angle_rad = valid()
                .map(|r| {
                    let d = r.dir_cam;
                    (axis[0] * d[0] + axis[1] * d[1] + axis[2] * d[2])
                        .clamp(-1.0, 1.0)
                        .acos()
                })
                .fold(0.0f32, f32::max);
            tiles.push(Tile {
                x0,
                y0,
                x1,
                y1,
                axis_cam: axis,
                half_angle_rad,
            });
        }
    }
    tiles
}

/// Reference rendering of a pixel region with `n x n` rays per pixel,
/// unprojected on the fly (slow; no noise, no vignetting): the mean
/// radiance per pixel, i.e. the area coverage of each surface. Used to
/// check geometry to sub-pixel precision.
#[allow(non_snake_case)]
pub fn render_supersampled(
    model: &CameraModel,
    scene: &Scene,
    T_world_cam: &Isometry3<f64>,
    region: (usize, usize, usize, usize),
    n: usize,
) -> Vec<f32> {
    let (x0, y0, w, h) = region;
    let r = T_world_cam.rotation;
    let o = T_world_cam.translation.vector;
    let o = [o.x as f32, o.y as f32, o.z as f32];
    let mut out = Vec::with_capacity(w * h);
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let mut sum = 0.0;
            for sy in 0..n {
                for sx in 0..n {
                    let px = x as f64 - 0.5 + (sx as f64 + 0.5) / n as f64;
                    let py = y as f64 - 0.5 + (sy as f64 + 0.5) / n as f64;
                    let c = model
                        .unproject(&Vector2::new(px, py))
                        .expect("test regions lie where the model inverts");
                    let d = r * c.normalize();
                    sum += scene.shade(o, [d.x as f32, d.y as f32, d.z as f32], 0.0);
                }
            }
            out.push(sum / (n * n) as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::euroc::euroc_cam0;
    use crate::simulate::scene::{Aabb, SceneConfig};
    use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

    /// Camera at `position` looking along world +x, image x to world -y,
    /// image y to world -z.
    #[allow(non_snake_case)]
    fn looking_along_x(position: Vector3<f64>, yaw_rad: f64) -> Isometry3<f64> {
        let R_world_cam = Matrix3::new(
            0.0, 0.0, 1.0, //
            -1.0, 0.0, 0.0, //
            0.0, -1.0, 0.0,
        );
        let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad)
            * UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(R_world_cam));
        Isometry3::from_parts(Translation3::from(position), r)
    }

    fn textured_scene(seed: u64) -> Scene {
        Scene::generate(&SceneConfig {
            seed,
            room: Aabb::new([-3.5, -3.2, 0.0], [3.5, 3.2, 3.0]),
            keep_clear: Aabb::new([-1.5, -1.5, 0.6], [1.5, 1.5, 2.0]),
            box_count: 10,
            texel_m: 0.005,
        })
    }

    #[test]
    fn tile_culling_matches_testing_every_box() {
        let cam = euroc_cam0();
        let renderer = Renderer::new(&cam.model, RenderOptions::IDEAL);
        let scene = textured_scene(11);
        for (k, yaw) in [0.0, 1.3, 2.6, -2.0, -0.7].into_iter().enumerate() {
            let pose = looking_along_x(Vector3::new(0.3 * k as f64 - 0.6, 0.2, 1.2), yaw);
            let fast = renderer.render(&scene, &pose, 0);
            let o = pose.translation.vector.map(|v| v as f32);
            let mut differing = 0;
            for (i, ray) in renderer.rays.iter().enumerate() {
                if ray.gain == 0.0 {
                    continue;
                }
                let d = pose.rotation * Vector3::from(ray.dir_cam.map(|c| c as f64));
                let d = [d.x as f32, d.y as f32, d.z as f32];
                let full = scene.shade([o.x, o.y, o.z], d, ray.footprint_rad);
                let full = (full + 0.5).clamp(0.0, 255.0) as u8;
                differing += (full.abs_diff(fast[i]) > 1) as usize;
            }
            assert_eq!(differing, 0, "pose {k}");
        }
    }

    #[test]
    fn same_seed_same_image_other_seed_differs() {
        let cam = euroc_cam0();
        let renderer = Renderer::new(&cam.model, RenderOptions::default());
        let pose = looking_along_x(Vector3::new(0.0, 0.0, 1.4), 0.4);
        let a = renderer.render(&textured_scene(1), &pose, 9);
        let b = renderer.render(&textured_scene(1), &pose, 9);
        let c = renderer.render(&textured_scene(2), &pose, 9);
        let d = renderer.render(&textured_scene(1), &pose, 10);
        assert!(a == b);
        assert!(a != c);
        // The noise seed alone changes pixels, by about the noise level.
        let changed = a.iter().zip(&d).filter(|(x, y)| x != y).count();
        assert!(changed > a.len() / 4, "{changed}");
    }

    /// Smallest eigenvalue of the 5x5 structure tensor (Shi & Tomasi 1994)
    /// at every pixel, central-difference gradients.
    fn min_eigen(img: &[u8], w: usize, h: usize) -> Vec<f32> {
        let at = |x: usize, y: usize| img[y * w + x] as f32;
        let mut gx = vec![0f32; w * h];
        let mut gy = vec![0f32; w * h];
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                gx[y * w + x] = 0.5 * (at(x + 1, y) - at(x - 1, y));
                gy[y * w + x] = 0.5 * (at(x, y + 1) - at(x, y - 1));
            }
        }
        let mut out = vec![0f32; w * h];
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let (mut a, mut b, mut c) = (0f32, 0f32, 0f32);
                for dy in 0..5 {
                    for dx in 0..5 {
                        let i = (y + dy - 2) * w + x + dx - 2;
                        a += gx[i] * gx[i];
                        b += gx[i] * gy[i];
                        c += gy[i] * gy[i];
                    }
                }
                out[y * w + x] = 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt();
            }
        }
        out
    }

    /// Cells of an 8 x 6 grid holding a pixel whose Shi-Tomasi response
    /// passes `threshold` (a corner of ~60 grey levels of contrast over a
    /// few pixels scores several thousand).
    fn cells_with_corners(img: &[u8], w: usize, h: usize, threshold: f32) -> usize {
        let response = min_eigen(img, w, h);
        let (nx, ny) = (8, 6);
        let mut count = 0;
        for cy in 0..ny {
            for cx in 0..nx {
                let found = (cy * h / ny..(cy + 1) * h / ny).any(|y| {
                    (cx * w / nx..(cx + 1) * w / nx).any(|x| response[y * w + x] > threshold)
                });
                count += found as usize;
            }
        }
        count
    }

    #[test]
    fn textures_give_corners_everywhere() {
        let cam = euroc_cam0();
        let renderer = Renderer::new(&cam.model, RenderOptions::default());
        let scene = textured_scene(4);
        let (w, h) = (renderer.width(), renderer.height());
        let threshold = 2000.0;
        for (k, yaw) in [0.0, 1.57, 3.0, -1.57, 0.8].into_iter().enumerate() {
            let pose = looking_along_x(Vector3::new(0.5, -0.4, 1.3), yaw);
            let img = renderer.render(&scene, &pose, k as u64);
            let cells = cells_with_corners(&img, w, h, threshold);
            assert!(
                cells >= 45,
                "view {k}: only {cells} of 48 cells have corners"
            );
        }
        // The detector is not trivially satisfied: a flat room has none.
        let flat = Scene::flat(
            Aabb::new([-3.0, -3.0, 0.0], [3.0, 3.0, 3.0]),
            vec![],
            &[120],
        );
        let img = Renderer::new(&cam.model, RenderOptions::IDEAL).render(
            &flat,
            &looking_along_x(Vector3::new(0.0, 0.0, 1.3), 0.3),
            0,
        );
        // Only the room's own corners and edges are left.
        assert!(cells_with_corners(&img, w, h, threshold) <= 6);
    }

    /// Least-squares quadratic a + b s + c s^2 through (s, value) pairs.
    fn fit_quadratic(points: &[(f64, f64)]) -> [f64; 3] {
        let mut ata = nalgebra::Matrix3::<f64>::zeros();
        let mut atb = nalgebra::Vector3::<f64>::zeros();
        for &(s, v) in points {
            let row = nalgebra::Vector3::new(1.0, s, s * s);
            ata += row * row.transpose();
            atb += row * v;
        }
        let c = ata.lu().solve(&atb).expect("well-posed fit");
        [c[0], c[1], c[2]]
    }

    #[test]
    fn rendered_box_corner_lands_where_the_model_projects_it() {
        // A bright box (200) against a dark room (50), camera looking along
        // +x at the box's front face x = 2; its top-left corner in the image
        // is P = (2, 1, 2.2), with only the front face and background around.
        // Render 16 x 16 rays per pixel around it, read each edge's sub-pixel
        // position from the coverage (the face's share of a column or row),
        // and compare with CameraModel::project of points on the 3-D edges;
        // the corner is the crossing of quadratic fits to both edges.
        let cam = euroc_cam0();
        let room = Aabb::new([-5.0, -5.0, 0.0], [5.0, 5.0, 3.0]);
        let b = Aabb::new([2.0, 0.2, 1.7], [2.5, 1.0, 2.2]);
        let scene = Scene::flat(room, vec![b], &[50, 200]);
        let pose = looking_along_x(Vector3::new(0.0, 0.0, 1.5), 0.0);
        let project = |p: Vector3<f64>| {
            cam.model
                .project(&(pose.inverse() * nalgebra::Point3::from(p)).coords)
                .expect("in front")
        };
        let corner_px = project(Vector3::new(2.0, 1.0, 2.2));
        let half = 20usize;
        let (x0, y0) = (
            corner_px.x.round() as usize - half,
            corner_px.y.round() as usize - half,
        );
        let n = 2 * half;
        let img = render_supersampled(&cam.model, &scene, &pose, (x0, y0, n, n), 16);
        let coverage = |x: usize, y: usize| ((img[y * n + x] - 50.0) / 150.0) as f64;
        // Top edge: in each column right of the corner the face fills the
        // bottom of the region, from the edge down.
        let mut top = Vec::new();
        let mut worst_edge_err = 0.0f64;
        let cx_local = corner_px.x - x0 as f64;
        let cy_local = corner_px.y - y0 as f64;
        for x in (cx_local.ceil() as usize + 3)..n {
            let filled: f64 = (0..n).map(|y| coverage(x, y)).sum();
            let edge_y = (y0 + n) as f64 - 0.5 - filled;
            let px = (x0 + x) as f64;
            // Model: the point of the 3-D top edge (2, y, 2.2) imaged in
            // column px, found by bisection on y.
            let (mut lo, mut hi) = (0.2, 1.0);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if project(Vector3::new(2.0, mid, 2.2)).x < px {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            let model_y = project(Vector3::new(2.0, 0.5 * (lo + hi), 2.2)).y;
            worst_edge_err = worst_edge_err.max((edge_y - model_y).abs());
            top.push((px, edge_y));
        }
        // Left edge: in each row below the corner the face fills the right.
        let mut left = Vec::new();
        for y in (cy_local.ceil() as usize + 3)..n {
            let filled: f64 = (0..n).map(|x| coverage(x, y)).sum();
            let edge_x = (x0 + n) as f64 - 0.5 - filled;
            let py = (y0 + y) as f64;
            let (mut lo, mut hi) = (1.7, 2.2);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if project(Vector3::new(2.0, 1.0, mid)).y < py {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            let model_x = project(Vector3::new(2.0, 1.0, 0.5 * (lo + hi))).x;
            worst_edge_err = worst_edge_err.max((edge_x - model_x).abs());
            left.push((py, edge_x));
        }
        // Corner: y = f(x) on the top edge, x = g(y) on the left edge.
        let f = fit_quadratic(&top);
        let g = fit_quadratic(&left);
        let (mut x, mut y) = (corner_px.x + 3.0, corner_px.y - 3.0);
        for _ in 0..50 {
            y = f[0] + f[1] * x + f[2] * x * x;
            x = g[0] + g[1] * y + g[2] * y * y;
        }
        let corner_err = ((x - corner_px.x).powi(2) + (y - corner_px.y).powi(2)).sqrt();
        println!(
            "corner projected at ({:.3}, {:.3}), found at ({x:.3}, {y:.3}): {corner_err:.3} px; worst edge point {worst_edge_err:.3} px over {} points",
            corner_px.x,
            corner_px.y,
            top.len() + left.len()
        );
        assert!(top.len() >= 10 && left.len() >= 10);
        assert!(worst_edge_err < 0.1, "edge error {worst_edge_err} px");
        assert!(corner_err < 0.5, "corner error {corner_err} px");
    }
}
