//! Helpers shared by the splatting tests.

use std::sync::{Mutex, MutexGuard};

use burn::tensor::{Device, Tensor, TensorData};
use glam::{Mat4, Vec3};
use prism_core::{BackendKind, Camera, Intrinsics};
use prism_render::splat::Gaussians;

/// The ndarray device the acceptance tests run on.
pub fn device() -> Device {
    BackendKind::Ndarray.device().unwrap()
}

/// Host values of `B x N` Gaussians, easy to perturb.
#[derive(Clone, Debug)]
pub struct Scene {
    pub batch: usize,
    pub count: usize,
    pub channels: usize,
    pub means: Vec<f32>,
    pub log_scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub opacity_logits: Vec<f32>,
    pub features: Vec<f32>,
}

impl Scene {
    pub fn new(batch: usize, channels: usize) -> Self {
        Self {
            batch,
            count: 0,
            channels,
            means: vec![],
            log_scales: vec![],
            rotations: vec![],
            opacity_logits: vec![],
            features: vec![],
        }
    }

    /// Appends one Gaussian (to a batch of 1).
    pub fn push(
        &mut self,
        mean: [f32; 3],
        log_scale: [f32; 3],
        rotation: [f32; 4],
        opacity: f32,
        features: &[f32],
    ) {
        assert_eq!(self.batch, 1);
        assert_eq!(features.len(), self.channels);
        self.count += 1;
        self.means.extend(mean);
        self.log_scales.extend(log_scale);
        self.rotations.extend(rotation);
        self.opacity_logits.push((opacity / (1.0 - opacity)).ln());
        self.features.extend(features);
    }

    pub fn tensors(&self, device: &Device) -> Gaussians {
        let (b, n) = (self.batch, self.count);
        let t = |v: &Vec<f32>, last: usize| {
            Tensor::<3>::from_data(TensorData::new(v.clone(), [b, n, last]), device)
        };
        Gaussians {
            means: t(&self.means, 3),
            log_scales: t(&self.log_scales, 3),
            rotations: t(&self.rotations, 4),
            opacity_logits: t(&self.opacity_logits, 1),
            features: t(&self.features, self.channels),
        }
    }

    /// The parameter vectors in the order of [`Gaussians`]' fields, mutable.
    pub fn kinds_mut(&mut self) -> [(&'static str, &mut Vec<f32>); 5] {
        [
            ("means", &mut self.means),
            ("log_scales", &mut self.log_scales),
            ("rotations", &mut self.rotations),
            ("opacity_logits", &mut self.opacity_logits),
            ("features", &mut self.features),
        ]
    }
}

/// A camera at the world origin looking along +z (the camera frame is the world frame).
pub fn axis_camera(f: f32, cx: f32, cy: f32, width: u32, height: u32) -> Camera {
    Camera::new(
        Intrinsics {
            fx: f,
            fy: f,
            cx,
            cy,
            width,
            height,
        },
        Mat4::IDENTITY,
    )
}

/// A general camera: orbiting a point, so that the world-to-camera rotation is not trivial.
pub fn orbit_camera(width: u32, height: u32, f: f32, yaw: f32, pitch: f32) -> Camera {
    let k = Intrinsics {
        fx: f,
        fy: f * 1.05,
        cx: width as f32 / 2.0 + 0.7,
        cy: height as f32 / 2.0 - 0.4,
        width,
        height,
    };
    Camera::orbit(yaw, pitch, 2.5, Vec3::new(0.1, 0.9, -0.05), k)
}

/// `g` with every parameter tracked by autodiff (on an autodiff device).
pub fn tracked(g: Gaussians) -> Gaussians {
    Gaussians {
        means: g.means.require_grad(),
        log_scales: g.log_scales.require_grad(),
        rotations: g.rotations.require_grad(),
        opacity_logits: g.opacity_logits.require_grad(),
        features: g.features.require_grad(),
    }
}

/// A tensor's values on the host.
pub fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

/// The GPU tests one at a time, on the one wgpu device they share.
pub fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The wgpu device when an adapter answers, else `None` (a panic under `PRISM_REQUIRE_WGPU`).
pub fn wgpu() -> Option<Device> {
    let works = std::panic::catch_unwind(|| {
        let device = BackendKind::Wgpu.device().ok()?;
        let sum = Tensor::<1>::from_floats([1.0, 2.0], &device)
            .sum()
            .into_scalar::<f32>();
        (sum == 3.0).then_some(device)
    });
    match works {
        Ok(Some(device)) => Some(device),
        _ if std::env::var_os("PRISM_REQUIRE_WGPU").is_some() => {
            panic!("PRISM_REQUIRE_WGPU is set but no wgpu adapter works (install Mesa's lavapipe)")
        }
        _ => {
            eprintln!("skipped: no wgpu adapter (install mesa-vulkan-drivers for lavapipe)");
            None
        }
    }
}
