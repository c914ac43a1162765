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

/// Renders one camera.
#[derive(Debug, Clone)]
pub struct Renderer {
    width: usize,
    height: usize,
    rays: Vec<PixelRay>,
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
        Self {
            width,
            height,
            rays,
            options,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }
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
        let o = T_world_cam.translation.vector;
        let o = [o.x as f32, o.y as f32, o.z as f32];
        assert!(
            scene.room.contains(o),
            "camera at {o:?} is outside the room {:?}",
            scene.room
        );
        // Triangular noise (sum of two uniforms) has std 1/sqrt(6) per unit half-width.
        let noise_scale = self.options.noise_sigma_grey * 6f32.sqrt();
        let inv_2_24 = 1.0 / (1u32 << 24) as f32;
        for (i, (px, ray)) in out.iter_mut().zip(&self.rays).enumerate() {
            if ray.gain == 0.0 {
                *px = 0;
                continue;
            }
            let c = ray.dir_cam;
            let d = [
                rot[0][0] * c[0] + rot[0][1] * c[1] + rot[0][2] * c[2],
                rot[1][0] * c[0] + rot[1][1] * c[1] + rot[1][2] * c[2],
                rot[2][0] * c[0] + rot[2][1] * c[1] + rot[2][2] * c[2],
            ];
            let mut value = scene.shade(o, d, ray.footprint_rad) * ray.gain;
            if noise_scale > 0.0 {
                let h = hash3(i as u64, noise_seed, 0x5EED);
                let u1 = (h >> 40) as f32 * inv_2_24;
                let u2 = ((h >> 8) & 0xff_ffff) as f32 * inv_2_24;
                value += noise_scale * (u1 + u2 - 1.0) * 0.5;
            }
            *px = (value + 0.5).clamp(0.0, 255.0) as u8;
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
