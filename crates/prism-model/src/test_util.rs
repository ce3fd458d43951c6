//! Helpers shared by the unit tests.

use burn::module::Module;
use burn::tensor::{Device, Tensor};

/// The ndarray device (the backend every test must pass on).
pub(crate) fn ndarray() -> Device {
    prism_core::BackendKind::Ndarray
        .device()
        .expect("ndarray is compiled in")
}

/// The values of a tensor.
pub(crate) fn values<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.to_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32 data")
}

/// The largest absolute difference between two equally long slices.
pub(crate) fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len(), "lengths differ");
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Every float parameter of a module as (path, values), in visiting order.
pub(crate) fn parameters<M: Module>(module: &M) -> Vec<(String, Vec<f32>)> {
    crate::tools::info::named_parameters(module)
        .into_iter()
        .map(|(path, t)| (path, values(&t)))
        .collect()
}

/// Protocol-like views of `b` pairs at `h x w`: the frontal source camera and targets at
/// several yaw and pitch angles on the 2 m orbit, grey background.
pub(crate) fn views(b: usize, h: usize, w: usize) -> crate::Views {
    use prism_core::{Camera, Intrinsics};
    let k = Intrinsics::protocol_default(w as u32, h as u32);
    let centre = glam::Vec3::new(0.0, 0.9, 0.0);
    let source = vec![Camera::orbit(0.0, 0.0, 2.0, centre, k); b];
    let target = (0..b)
        .map(|i| {
            Camera::orbit(
                25.0 - 17.0 * i as f32,
                10.0 - 8.0 * i as f32,
                2.0,
                centre,
                k,
            )
        })
        .collect();
    crate::Views::new(source, target, [0.5, 0.5, 0.5])
}

/// A batch of `b` (source image, source rays, target rays) at `h x w`: a random image and the
/// rays of [`views`].
pub(crate) fn inputs(
    b: usize,
    h: usize,
    w: usize,
    device: &Device,
) -> ([Tensor<4>; 3], crate::Views) {
    use burn::tensor::Distribution;
    let views = views(b, h, w);
    device.seed(11);
    let image = Tensor::random([b, 3, h, w], Distribution::Uniform(0.0, 1.0), device);
    let source = prism_core::rays::plucker_rays(&views.source, device);
    let target = prism_core::rays::plucker_rays(&views.target, device);
    ([image, source, target], views)
}

/// The tiny config with the geometry switches set.
pub(crate) fn tiny_with(smplx: bool, points: bool, gs: bool) -> crate::PrismConfig {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/tiny.toml");
    let mut config = crate::load_config(path)
        .expect("tiny config")
        .model
        .paper_outputs();
    config.smplx_branch = smplx;
    config.point_branch = points;
    config.gs_head = gs;
    config
}
