//! EWA projection of one 3D Gaussian into a pinhole camera, and its exact derivative.
//!
//! Forward (Zwicker et al. 2001, as used by 3DGS):
//!
//! ```text
//! q  = rot / |rot|,  R = R(q),  s = exp(log_scale)
//! Σ  = R diag(s) diag(s) R^T                       (world covariance)
//! p  = W mean + t                                  (camera space, OpenCV axes)
//! J  = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]] (Jacobian of the perspective projection)
//! Σ' = J W Σ W^T J^T + 0.3 I                       (2D covariance, with the 0.3 px dilation)
//! (u, v) = (fx x/z + cx, fy y/z + cy),  conic = Σ'^-1,  opacity = sigmoid(logit)
//! ```
//!
//! As in 3DGS and gsplat, the `x/z` and `y/z` used inside `J` (not in `(u, v)`) are clamped to
//! 1.3 times the half field of view, so that Gaussians far outside the image do not blow up.

use glam::{Mat3, Vec3};

use super::view::View;
use super::{DILATION, EXTENT_SIGMAS, MAX_POWER, MIN_ALPHA, NEAR_PLANE};

/// One Gaussian as seen by one camera: everything the compositing needs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Projected {
    /// Projected centre, continuous pixel coordinates (pixel centres at `x + 0.5`).
    pub u: f32,
    /// Projected centre, continuous pixel coordinates.
    pub v: f32,
    /// Camera-space depth `z`.
    pub depth: f32,
    /// The inverse 2D covariance `[a, b, c]` of `[[a, b], [b, c]]`.
    pub conic: [f32; 3],
    /// `sigmoid(opacity_logit)`.
    pub opacity: f32,
    /// The largest `power` at which it is drawn: [`support_power`] of its opacity, worked out
    /// once here and read by every tile and row that bounds its drawing.
    pub support: f32,
    /// Half extents of the bounding box of the ellipse where the Gaussian can be drawn,
    /// `sqrt(2 P Σ'_xx)`, `sqrt(2 P Σ'_yy)` with `P` its `support`: the 3-sigma box,
    /// `3 sqrt(Σ'_xx)`, for all but faint Gaussians, whose alpha falls below 1/255 sooner.
    pub extent: [f32; 2],
}

/// The largest `power = d^T conic d / 2` at which a Gaussian of opacity `opacity` can still be
/// drawn: the 3-sigma limit, or sooner `ln(255 o)`, where its alpha `o exp(-power)` falls
/// below 1/255; widened by 0.01 so that bounds built on it keep every drawn pixel despite
/// rounding. At most 0.01 for a Gaussian too faint to draw anywhere.
pub fn support_power(opacity: f32) -> f32 {
    MAX_POWER.min((opacity / MIN_ALPHA).ln()) + 0.01
}

/// The half extent of the drawn support along an axis of variance `variance` (see
/// [`Projected::extent`]).
pub(super) fn half_extent(variance: f32, power: f32) -> f32 {
    if power >= MAX_POWER {
        EXTENT_SIGMAS * variance.sqrt()
    } else {
        (2.0 * power.max(0.0) * variance).sqrt()
    }
}

impl Projected {
    /// Inclusive pixel index ranges `[x0, x1] x [y0, y1]` whose centres lie in the bounding
    /// box of the drawn support ([`Projected::extent`]), clipped to a `width x height` image;
    /// `None` when empty.
    pub fn pixel_rect(&self, width: usize, height: usize) -> Option<[usize; 4]> {
        let x0 = (self.u - self.extent[0] - 0.5).ceil().max(0.0);
        let y0 = (self.v - self.extent[1] - 0.5).ceil().max(0.0);
        let x1 = (self.u + self.extent[0] - 0.5)
            .floor()
            .min(width as f32 - 1.0);
        let y1 = (self.v + self.extent[1] - 0.5)
            .floor()
            .min(height as f32 - 1.0);
        // Also rejects NaN.
        if x0 <= x1 && y0 <= y1 {
            Some([x0 as usize, y0 as usize, x1 as usize, y1 as usize])
        } else {
            None
        }
    }
}

/// The raw parameters of one Gaussian, as stored in the input tensors.
#[derive(Clone, Copy, Debug)]
pub struct Params {
    /// World-space centre.
    pub mean: [f32; 3],
    /// Natural log of the three axis scales (metres).
    pub log_scale: [f32; 3],
    /// Rotation quaternion `w, x, y, z` (any non-zero length).
    pub rotation: [f32; 4],
    /// Opacity before the sigmoid.
    pub opacity_logit: f32,
}

/// Gradients of a loss with respect to one Gaussian's raw parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ParamGrads {
    /// `dL/dmean`.
    pub mean: [f32; 3],
    /// `dL/dlog_scale`.
    pub log_scale: [f32; 3],
    /// `dL/drotation` (through the normalisation).
    pub rotation: [f32; 4],
    /// `dL/dopacity_logit`.
    pub opacity_logit: f32,
}

/// Gradients of a loss with respect to one [`Projected`] Gaussian (summed over its pixels).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProjectedGrads {
    /// `dL/du`, `dL/dv`.
    pub uv: [f32; 2],
    /// `dL/dz` from the depth channel only (the projection adds its own part).
    pub depth: f32,
    /// `dL/d[a, b, c]` with `power = a dx^2 / 2 + b dx dy + c dy^2 / 2`.
    pub conic: [f32; 3],
    /// `dL/dopacity` (after the sigmoid).
    pub opacity: f32,
}

/// Everything of the projection that the backward pass reuses.
struct Intermediates {
    quat: [f32; 4],
    quat_norm: f32,
    rot: Mat3,
    scale: Vec3,
    cov3: Mat3,
    cam: Vec3,
    /// Rows of `M = J W`.
    m: [Vec3; 2],
    /// `x/z`, `y/z` after clamping, and whether each was clamped.
    ratio: [f32; 2],
    clamped: [bool; 2],
    cov2: [f32; 3],
    conic: [f32; 3],
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// `R(q)` of a unit quaternion `w, x, y, z`.
fn rotation_matrix(q: [f32; 4]) -> Mat3 {
    let [w, x, y, z] = q;
    Mat3::from_cols(
        Vec3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ),
        Vec3::new(
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ),
        Vec3::new(
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
    )
}

fn intermediates(p: &Params, view: &View) -> Option<Intermediates> {
    let cam = view.rotation * Vec3::from(p.mean) + view.translation;
    // Also rejects NaN.
    if cam.z.is_nan() || cam.z < NEAR_PLANE {
        return None;
    }
    let [w, x, y, z] = p.rotation;
    let quat_norm = (w * w + x * x + y * y + z * z).sqrt();
    if quat_norm.is_nan() || quat_norm <= 1e-12 {
        return None;
    }
    let quat = [w / quat_norm, x / quat_norm, y / quat_norm, z / quat_norm];
    let rot = rotation_matrix(quat);
    let scale = Vec3::from(p.log_scale).exp();
    let rs = Mat3::from_cols(
        rot.x_axis * scale.x,
        rot.y_axis * scale.y,
        rot.z_axis * scale.z,
    );
    let cov3 = rs * rs.transpose();

    let rz = 1.0 / cam.z;
    let raw = [cam.x * rz, cam.y * rz];
    let lim = view.ratio_limits();
    let mut ratio = [0.0; 2];
    let mut clamped = [false; 2];
    for k in 0..2 {
        ratio[k] = raw[k].clamp(lim[k][0], lim[k][1]);
        clamped[k] = ratio[k] != raw[k];
    }
    let j0 = Vec3::new(view.fx * rz, 0.0, -view.fx * ratio[0] * rz);
    let j1 = Vec3::new(0.0, view.fy * rz, -view.fy * ratio[1] * rz);
    let wt = view.rotation.transpose();
    let m = [wt * j0, wt * j1];
    let s0 = cov3 * m[0];
    let s1 = cov3 * m[1];
    let cov2 = [
        m[0].dot(s0) + DILATION,
        m[0].dot(s1),
        m[1].dot(s1) + DILATION,
    ];
    let det = cov2[0] * cov2[2] - cov2[1] * cov2[1];
    if det.is_nan() || det <= 0.0 {
        return None;
    }
    let conic = [cov2[2] / det, -cov2[1] / det, cov2[0] / det];
    Some(Intermediates {
        quat,
        quat_norm,
        rot,
        scale,
        cov3,
        cam,
        m,
        ratio,
        clamped,
        cov2,
        conic,
    })
}

/// Projects one Gaussian; `None` when it is behind the near plane or degenerate.
pub fn project(p: &Params, view: &View) -> Option<Projected> {
    let it = intermediates(p, view)?;
    let rz = 1.0 / it.cam.z;
    let opacity = sigmoid(p.opacity_logit);
    let support = support_power(opacity);
    Some(Projected {
        u: view.fx * it.cam.x * rz + view.cx,
        v: view.fy * it.cam.y * rz + view.cy,
        depth: it.cam.z,
        conic: it.conic,
        opacity,
        support,
        extent: [
            half_extent(it.cov2[0], support),
            half_extent(it.cov2[2], support),
        ],
    })
}

/// The chain rule through [`project`]: from the gradients of the projected quantities to those
/// of the raw parameters. Returns zeros for a Gaussian that [`project`] culls.
pub fn project_backward(p: &Params, view: &View, g: &ProjectedGrads) -> ParamGrads {
    let Some(it) = intermediates(p, view) else {
        return ParamGrads::default();
    };
    let (fx, fy) = (view.fx, view.fy);
    let rz = 1.0 / it.cam.z;
    let rz2 = rz * rz;

    // conic = Σ'^-1  =>  dL/dΣ' = -Q G_Q Q, with G_Q the gradient of the full symmetric matrix
    // (the off-diagonal `b` appears twice in it, hence the half).
    let [a, b, c] = it.conic;
    let (ga, gb, gc) = (g.conic[0], 0.5 * g.conic[1], g.conic[2]);
    let qg = [
        a * ga + b * gb,
        a * gb + b * gc,
        b * ga + c * gb,
        b * gb + c * gc,
    ];
    let gs00 = -(qg[0] * a + qg[1] * b);
    let gs01 = -(qg[0] * b + qg[1] * c);
    let gs11 = -(qg[2] * b + qg[3] * c);

    // Σ' = M Σ M^T + 0.3 I.
    let (m0, m1) = (it.m[0], it.m[1]);
    let s0 = it.cov3 * m0;
    let s1 = it.cov3 * m1;
    let g_cov3 =
        gs00 * outer(m0, m0) + gs01 * (outer(m0, m1) + outer(m1, m0)) + gs11 * outer(m1, m1);
    let g_m0 = 2.0 * (gs00 * s0 + gs01 * s1);
    let g_m1 = 2.0 * (gs01 * s0 + gs11 * s1);
    // M rows are W^T j_k.
    let g_j0 = view.rotation * g_m0;
    let g_j1 = view.rotation * g_m1;

    // J -> camera-space point.
    let mut g_cam = Vec3::ZERO;
    g_cam.z += -fx * rz2 * g_j0.x - fy * rz2 * g_j1.y;
    for (k, (f, gj)) in [(fx, g_j0.z), (fy, g_j1.z)].into_iter().enumerate() {
        if it.clamped[k] {
            // J_k2 = -f lim / z.
            g_cam.z += f * it.ratio[k] * rz2 * gj;
        } else {
            // J_k2 = -f x / z^2.
            g_cam[k] += -f * rz2 * gj;
            g_cam.z += 2.0 * f * it.cam[k] * rz2 * rz * gj;
        }
    }
    // (u, v) and the depth channel.
    g_cam.x += fx * rz * g.uv[0];
    g_cam.y += fy * rz * g.uv[1];
    g_cam.z += -fx * it.cam.x * rz2 * g.uv[0] - fy * it.cam.y * rz2 * g.uv[1] + g.depth;
    let g_mean = view.rotation.transpose() * g_cam;

    // Σ = (R S)(R S)^T.
    let rs = Mat3::from_cols(
        it.rot.x_axis * it.scale.x,
        it.rot.y_axis * it.scale.y,
        it.rot.z_axis * it.scale.z,
    );
    let g_rs = 2.0 * g_cov3 * rs;
    let g_scale = Vec3::new(
        it.rot.x_axis.dot(g_rs.x_axis),
        it.rot.y_axis.dot(g_rs.y_axis),
        it.rot.z_axis.dot(g_rs.z_axis),
    );
    let g_rot = Mat3::from_cols(
        g_rs.x_axis * it.scale.x,
        g_rs.y_axis * it.scale.y,
        g_rs.z_axis * it.scale.z,
    );
    let g_quat_unit = quat_backward(it.quat, &g_rot);
    // q̂ = q / |q|  =>  dL/dq = (g - q̂ (q̂ . g)) / |q|.
    let dot: f32 = (0..4).map(|k| it.quat[k] * g_quat_unit[k]).sum();
    let g_quat = std::array::from_fn(|k| (g_quat_unit[k] - it.quat[k] * dot) / it.quat_norm);

    let opacity = sigmoid(p.opacity_logit);
    ParamGrads {
        mean: g_mean.to_array(),
        log_scale: (g_scale * it.scale).to_array(),
        rotation: g_quat,
        opacity_logit: g.opacity * opacity * (1.0 - opacity),
    }
}

fn outer(a: Vec3, b: Vec3) -> Mat3 {
    Mat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// `dL/dq` of a unit quaternion from `dL/dR` (`R_ij` is row `i`, column `j`).
fn quat_backward(q: [f32; 4], g: &Mat3) -> [f32; 4] {
    let [w, x, y, z] = q;
    let r = |i: usize, j: usize| g.col(j)[i];
    let dw =
        2.0 * (-z * r(0, 1) + y * r(0, 2) + z * r(1, 0) - x * r(1, 2) - y * r(2, 0) + x * r(2, 1));
    let dx = 2.0
        * (y * r(0, 1) + z * r(0, 2) + y * r(1, 0) - 2.0 * x * r(1, 1) - w * r(1, 2)
            + z * r(2, 0)
            + w * r(2, 1)
            - 2.0 * x * r(2, 2));
    let dy = 2.0
        * (-2.0 * y * r(0, 0) + x * r(0, 1) + w * r(0, 2) + x * r(1, 0) + z * r(1, 2)
            - w * r(2, 0)
            + z * r(2, 1)
            - 2.0 * y * r(2, 2));
    let dz = 2.0
        * (-2.0 * z * r(0, 0) - w * r(0, 1) + x * r(0, 2) + w * r(1, 0) - 2.0 * z * r(1, 1)
            + y * r(1, 2)
            + x * r(2, 0)
            + y * r(2, 1));
    [dw, dx, dy, dz]
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_core::{Camera, Intrinsics};

    fn view() -> View {
        let k = Intrinsics {
            fx: 40.0,
            fy: 44.0,
            cx: 20.0,
            cy: 18.0,
            width: 40,
            height: 36,
        };
        View::new(&Camera::orbit(10.0, -5.0, 3.0, Vec3::new(0.1, 0.2, 0.0), k))
    }

    fn params() -> Params {
        Params {
            mean: [0.15, 0.1, 0.05],
            log_scale: [-1.5, -2.0, -1.2],
            rotation: [0.8, 0.3, -0.4, 0.2],
            opacity_logit: 0.4,
        }
    }

    /// A scalar function of the projection with known weights, to check the chain rule.
    fn objective(p: &Params, v: &View, w: &ProjectedGrads) -> f64 {
        let q = project(p, v).unwrap();
        (q.u * w.uv[0]
            + q.v * w.uv[1]
            + q.depth * w.depth
            + q.conic[0] * w.conic[0]
            + q.conic[1] * w.conic[1]
            + q.conic[2] * w.conic[2]
            + q.opacity * w.opacity) as f64
    }

    #[test]
    fn projection_backward_matches_finite_differences() {
        check_projection_backward(params());
    }

    #[test]
    fn projection_backward_matches_finite_differences_outside_the_guard_band() {
        // Far to the side and below the image: both ratios x/z, y/z are clamped in J.
        let v = view();
        let mut p = params();
        let cam = Vec3::new(2.5, 2.2, 2.0);
        p.mean = (v.rotation.transpose() * (cam - v.translation)).to_array();
        let lim = v.ratio_limits();
        assert!(cam.x / cam.z > lim[0][1] && cam.y / cam.z > lim[1][1]);
        check_projection_backward(p);
    }

    /// Checks each projected quantity's chain rule on its own, so that a small part (such as
    /// the conic's dependence on depth) is not hidden behind a large one.
    fn check_projection_backward(p: Params) {
        let v = view();
        let weights = [
            ProjectedGrads {
                uv: [0.3, -0.7],
                ..Default::default()
            },
            ProjectedGrads {
                depth: 0.9,
                opacity: 0.5,
                ..Default::default()
            },
            ProjectedGrads {
                conic: [20.0, -35.0, 12.0],
                ..Default::default()
            },
        ];
        for w in &weights {
            let g = project_backward(&p, &v, w);
            let analytic: Vec<f32> = g
                .mean
                .iter()
                .chain(&g.log_scale)
                .chain(&g.rotation)
                .chain([&g.opacity_logit])
                .copied()
                .collect();
            let scale = analytic.iter().fold(0.0f32, |m, a| m.max(a.abs()));
            for (k, &an) in analytic.iter().enumerate() {
                let h = 1e-3;
                let shifted = |d: f32| {
                    let mut q = p;
                    match k {
                        0..3 => q.mean[k] += d,
                        3..6 => q.log_scale[k - 3] += d,
                        6..10 => q.rotation[k - 6] += d,
                        _ => q.opacity_logit += d,
                    }
                    objective(&q, &v, w)
                };
                let fd = ((shifted(h) - shifted(-h)) / (2.0 * h as f64)) as f32;
                let tol = 1e-2 * fd.abs().max(an.abs()).max(1e-2 * scale);
                assert!(
                    (fd - an).abs() < tol,
                    "param {k}: fd {fd} analytic {an} ({w:?})"
                );
            }
        }
    }

    #[test]
    fn gaussians_behind_the_camera_are_culled() {
        let mut p = params();
        // The orbit camera sits at distance 3 looking at the centre: put the mean behind it.
        let cam = Camera::orbit(
            10.0,
            -5.0,
            3.0,
            Vec3::new(0.1, 0.2, 0.0),
            Intrinsics::protocol_default(4, 4),
        );
        p.mean = (cam.center() + (cam.center() - Vec3::new(0.1, 0.2, 0.0))).to_array();
        assert!(project(&p, &view()).is_none());
        assert_eq!(
            project_backward(&p, &view(), &ProjectedGrads::default()),
            ParamGrads::default()
        );
    }
}
