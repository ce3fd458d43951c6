//! Tests of the body model: files, skinning in f32 and in tensors, gradients.

use std::path::Path;

use burn::tensor::{Tensor, TensorData};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;

/// A small random model with SMPL-X's tree: enough to exercise every array.
pub(crate) fn random_model(num_vertices: usize, seed: u64) -> BodyModel {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let v = num_vertices;
    let mut normal = |s: f32| -> f32 {
        // Sum of uniforms: a cheap bell-shaped draw.
        (0..4).map(|_| rng.random_range(-1.0f32..1.0)).sum::<f32>() * 0.5 * s
    };
    let v_template: Vec<Vec3> = (0..v)
        .map(|_| Vec3::new(normal(0.3), normal(0.3) + 0.9, normal(0.3)))
        .collect();
    let shapedirs: Vec<f32> = (0..v * 3 * NUM_SHAPE_COEFFS)
        .map(|_| normal(0.02))
        .collect();
    let posedirs: Vec<f32> = (0..v * 3 * NUM_POSE_FEATURES)
        .map(|_| normal(0.005))
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 1);
    let faces: Vec<[u32; 3]> = (0..v)
        .map(|i| [i as u32, ((i + 1) % v) as u32, ((i + 7) % v) as u32])
        .collect();
    let mut weights = vec![0.0f32; v * NUM_JOINTS];
    for i in 0..v {
        let mut total = 0.0;
        for _ in 0..3 {
            let j = rng.random_range(0..NUM_JOINTS);
            let w = rng.random_range(0.1f32..1.0);
            weights[i * NUM_JOINTS + j] += w;
            total += w;
        }
        for w in &mut weights[i * NUM_JOINTS..(i + 1) * NUM_JOINTS] {
            *w /= total;
        }
    }
    let mut j_regressor = vec![0.0f32; NUM_JOINTS * v];
    for j in 0..NUM_JOINTS {
        for _ in 0..4 {
            j_regressor[j * v + rng.random_range(0..v)] += 0.25;
        }
    }
    BodyModel::from_arrays(BodyArrays {
        v_template,
        faces,
        shapedirs,
        posedirs,
        j_regressor,
        weights,
        parents: joints::smplx_parents(),
    })
    .unwrap()
}

fn random_params(rng: &mut ChaCha8Rng, scale: f32) -> BodyParams {
    let mut p = BodyParams::rest("test");
    for b in &mut p.betas {
        *b = rng.random_range(-1.5..1.5);
    }
    for e in &mut p.expression {
        *e = rng.random_range(-1.5..1.5);
    }
    for (j, r) in p.pose.iter_mut().enumerate() {
        if j % 7 == 3 {
            continue; // some joints stay at exactly zero
        }
        for x in r.iter_mut() {
            *x = rng.random_range(-scale..scale);
        }
    }
    p
}

fn tmp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("prism-body-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn npz_round_trip_is_exact() {
    let model = random_model(50, 1);
    let dir = tmp_dir("roundtrip");
    let path = dir.join("model.npz");
    model.save_npz(&path).unwrap();
    let back = BodyModel::load_npz(&path).unwrap();
    assert_eq!(back.name(), path.display().to_string());
    assert!(back.has_smplx_tree());
    assert_eq!(back.into_arrays(), model.into_arrays());
    // No temporary file is left behind.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    std::fs::remove_dir_all(dir).unwrap();
}

/// An array to write into a hand-made `.npz`.
enum Raw {
    F32(Vec<f32>),
    F64(Vec<f64>),
    U32(Vec<u32>),
    I64(Vec<i64>),
}

fn write_npz(path: &Path, arrays: &[(&str, Vec<u64>, Raw, bool)]) {
    use npyz::WriterBuilder;
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    for (key, shape, data, fortran) in arrays {
        let order = if *fortran {
            npyz::Order::Fortran
        } else {
            npyz::Order::C
        };
        zip.start_file(npz::npy_name(key), zip::write::SimpleFileOptions::default())
            .unwrap();
        macro_rules! put {
            ($t:ty, $v:expr) => {{
                let mut w = npyz::WriteOptions::<$t>::new()
                    .default_dtype()
                    .shape(shape)
                    .order(order)
                    .writer(&mut zip)
                    .begin_nd()
                    .unwrap();
                w.extend($v.iter().copied()).unwrap();
                w.finish().unwrap();
            }};
        }
        match data {
            Raw::F32(v) => put!(f32, v),
            Raw::F64(v) => put!(f64, v),
            Raw::U32(v) => put!(u32, v),
            Raw::I64(v) => put!(i64, v),
        }
    }
    zip.finish().unwrap();
}

/// Writes `model` the way the official SMPL-X v1.1 files are stored: float64, uint32 faces and
/// kintree (root parent 2^32 - 1), `shapedirs [V, 3, 400]`, weights in Fortran order.
fn write_smplx_like(model: &BodyModel, path: &Path) {
    let v = model.num_vertices();
    let mut shapedirs = vec![0.0f64; v * 3 * 400];
    for i in 0..v * 3 {
        for k in 0..10 {
            shapedirs[i * 400 + k] = model.shapedirs()[i * 20 + k] as f64;
            shapedirs[i * 400 + 300 + k] = model.shapedirs()[i * 20 + 10 + k] as f64;
        }
        for k in 10..300 {
            shapedirs[i * 400 + k] = 99.0; // components prism does not use
        }
    }
    // Fortran order of a [V, 55] array: element (i, j) at i + V j.
    let mut weights_f = vec![0.0f64; v * NUM_JOINTS];
    for i in 0..v {
        for j in 0..NUM_JOINTS {
            weights_f[i + v * j] = model.weights()[i * NUM_JOINTS + j] as f64;
        }
    }
    let mut kintree: Vec<u32> = model
        .parents()
        .iter()
        .map(|p| p.map_or(u32::MAX, |p| p as u32))
        .collect();
    kintree.extend(0..NUM_JOINTS as u32);
    let f64s = |x: &[f32]| Raw::F64(x.iter().map(|&a| a as f64).collect());
    let template: Vec<f32> = model
        .v_template()
        .iter()
        .flat_map(|p| p.to_array())
        .collect();
    write_npz(
        path,
        &[
            ("v_template", vec![v as u64, 3], f64s(&template), false),
            (
                "f",
                vec![model.faces().len() as u64, 3],
                Raw::U32(model.faces().iter().flatten().copied().collect()),
                false,
            ),
            (
                "shapedirs",
                vec![v as u64, 3, 400],
                Raw::F64(shapedirs),
                false,
            ),
            (
                "posedirs",
                vec![v as u64, 3, 486],
                f64s(model.posedirs()),
                false,
            ),
            (
                "J_regressor",
                vec![55, v as u64],
                f64s(model.j_regressor()),
                false,
            ),
            ("weights", vec![v as u64, 55], Raw::F64(weights_f), true),
            ("kintree_table", vec![2, 55], Raw::U32(kintree), false),
            ("hands_meanl", vec![45], Raw::F32(vec![0.0; 45]), false),
        ],
    );
}

#[test]
fn smplx_v11_layout_with_float64_and_uint32_loads() {
    let model = random_model(20, 2);
    let dir = tmp_dir("v11");
    let path = dir.join("SMPLX_NEUTRAL.npz");
    write_smplx_like(&model, &path);
    let back = BodyModel::load_npz(&path).unwrap();
    // float64 -> f32 conversion is exact for values that came from f32.
    assert_eq!(back.into_arrays(), model.into_arrays());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn missing_or_misshapen_keys_are_named_with_their_shapes() {
    let model = random_model(12, 3);
    let dir = tmp_dir("bad");
    let template: Vec<f32> = model
        .v_template()
        .iter()
        .flat_map(|p| p.to_array())
        .collect();
    let faces = Raw::I64(model.faces().iter().flatten().map(|&i| i as i64).collect());
    let path = dir.join("bad.npz");
    write_npz(
        &path,
        &[
            ("v_template", vec![12, 3], Raw::F32(template.clone()), false),
            ("f", vec![12, 3], faces, false),
            (
                "shapedirs",
                vec![12, 3, 20],
                Raw::F32(model.shapedirs().to_vec()),
                false,
            ),
            (
                "posedirs",
                vec![12, 3, 207],
                Raw::F32(vec![0.0; 12 * 3 * 207]),
                false,
            ),
        ],
    );
    let msg = BodyModel::load_npz(&path).unwrap_err().to_string();
    assert!(msg.contains("bad.npz"), "{msg}");
    assert!(msg.contains("`posedirs`"), "{msg}");
    assert!(
        msg.contains("[12, 3, 207]") && msg.contains("[12, 3, 486]"),
        "{msg}"
    );

    write_npz(
        &path,
        &[("v_template", vec![12, 3], Raw::F32(template.clone()), false)],
    );
    let msg = BodyModel::load_npz(&path).unwrap_err().to_string();
    assert!(
        msg.contains("missing key `f`") && msg.contains("[F, 3]"),
        "{msg}"
    );

    write_npz(
        &path,
        &[("v_template", vec![4, 9], Raw::F32(template), false)],
    );
    let msg = BodyModel::load_npz(&path).unwrap_err().to_string();
    assert!(
        msg.contains("`v_template` has shape [4, 9], expected [V, 3]"),
        "{msg}"
    );

    let msg = BodyModel::load_npz(dir.join("nope.npz"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("nope.npz"), "{msg}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn rest_pose_at_zero_parameters_is_the_template() {
    let model = random_model(30, 4);
    let posed = model.pose(&BodyParams::rest("test"));
    for (p, t) in posed.vertices.iter().zip(model.v_template()) {
        assert!((*p - *t).length() < 1e-6);
    }
    for (j, r) in posed.joints.iter().zip(model.rest_joints()) {
        assert!((*j - r).length() < 1e-6);
    }
}

#[test]
fn scale_and_translation_map_the_posed_body_to_the_world() {
    let model = random_model(30, 5);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut p = random_params(&mut rng, 0.5);
    let base = model.pose(&p);
    p.scale = 1.3;
    p.transl = [0.1, -0.2, 0.3];
    let world = model.pose(&p);
    for (a, b) in base.vertices.iter().zip(&world.vertices) {
        assert!((1.3 * *a + Vec3::new(0.1, -0.2, 0.3) - *b).length() < 1e-5);
    }
    // Skinning transforms reproduce the vertices of a rigidly weighted point.
    let v0 = world.skin_point(base.shaped[0], &[(0, 1.0)]);
    let expected = world.skinning_transforms[0].transform_point3(base.shaped[0]);
    assert!((v0 - expected).length() < 1e-6);
}

fn tensor_inputs(
    params: &[BodyParams],
    device: &burn::tensor::Device,
) -> (Tensor<2>, Tensor<3>, Tensor<2>) {
    let b = params.len();
    let betas: Vec<f32> = params.iter().flat_map(|p| p.betas).collect();
    let expr: Vec<f32> = params.iter().flat_map(|p| p.expression).collect();
    let pose: Vec<f32> = params
        .iter()
        .flat_map(|p| p.pose.iter().flatten().copied().collect::<Vec<_>>())
        .collect();
    (
        Tensor::from_data(TensorData::new(betas, [b, NUM_BETAS]), device),
        Tensor::from_data(TensorData::new(pose, [b, NUM_JOINTS, 3]), device),
        Tensor::from_data(TensorData::new(expr, [b, NUM_EXPRESSION]), device),
    )
}

fn check_tensor_matches_f32(device: burn::tensor::Device) {
    let model = random_model(64, 6);
    let layer = BodyLayer::new(&model, &device);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let params: Vec<BodyParams> = (0..3).map(|_| random_params(&mut rng, 0.8)).collect();
    let (betas, pose, expr) = tensor_inputs(&params, &device);
    let out = layer.forward(betas, pose, expr);
    assert_eq!(out.vertices.dims(), [3, 64, 3]);
    let verts = out.vertices.into_data().try_into_vec::<f32>().unwrap();
    let joints = out.joints.into_data().try_into_vec::<f32>().unwrap();
    let mut worst = 0.0f32;
    for (b, p) in params.iter().enumerate() {
        let posed = model.lbs(&p.betas, &p.pose, &p.expression);
        for (i, v) in posed.vertices.iter().enumerate() {
            for d in 0..3 {
                worst = worst.max((verts[(b * 64 + i) * 3 + d] - v[d]).abs());
            }
        }
        for (j, v) in posed.joints.iter().enumerate() {
            for d in 0..3 {
                worst = worst.max((joints[(b * NUM_JOINTS + j) * 3 + d] - v[d]).abs());
            }
        }
    }
    assert!(worst < 1e-5, "largest difference {worst}");
}

#[test]
fn tensor_skinning_matches_f32_on_ndarray() {
    check_tensor_matches_f32(prism_core::BackendKind::Ndarray.device().unwrap());
}

#[test]
fn tensor_skinning_matches_f32_on_flex() {
    check_tensor_matches_f32(prism_core::BackendKind::Flex.device().unwrap());
}

/// The rest joints' root is the posed joints' root, to the bit, whatever the pose; the other
/// joints move with it.
#[test]
fn rest_joints_root_is_the_posed_root() {
    let device = prism_core::BackendKind::Flex.device().unwrap();
    let model = random_model(64, 6);
    let layer = BodyLayer::new(&model, &device);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let params: Vec<BodyParams> = (0..3).map(|_| random_params(&mut rng, 0.8)).collect();
    let (betas, pose, expr) = tensor_inputs(&params, &device);
    let rest = layer.rest_joints(betas.clone(), expr.clone());
    let posed = layer.forward(betas, pose, expr).joints;
    let values = |t: Tensor<3>| t.into_data().try_into_vec::<f32>().unwrap();
    let (rest, posed) = (values(rest), values(posed));
    for b in 0..3 {
        let row = |v: &[f32], j: usize| v[(b * NUM_JOINTS + j) * 3..][..3].to_vec();
        assert_eq!(row(&rest, 0), row(&posed, 0), "root of body {b}");
        let moved = (1..NUM_JOINTS)
            .filter(|&j| row(&rest, j) != row(&posed, j))
            .count();
        assert!(
            moved > NUM_JOINTS / 2,
            "body {b}: only {moved} joints posed"
        );
    }
}

#[test]
fn tensor_gradients_match_finite_differences() {
    let device = prism_core::BackendKind::Ndarray.autodiff_device().unwrap();
    let model = random_model(24, 7);
    let layer = BodyLayer::new(&model, &device);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // One sample with random parameters, one at exactly zero (the zero-angle case).
    let mut params = vec![random_params(&mut rng, 0.7), BodyParams::rest("test")];
    params[1].betas[0] = 0.3;
    let probe_v: Vec<f32> = (0..2 * 24 * 3)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let probe_j: Vec<f32> = (0..2 * NUM_JOINTS * 3)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    // The scalar L = <probe_v, vertices> + <probe_j, joints> as a function of the parameters.
    let loss_f32 = |ps: &[BodyParams]| -> f64 {
        let mut total = 0.0f64;
        for (b, p) in ps.iter().enumerate() {
            let posed = model.lbs(&p.betas, &p.pose, &p.expression);
            for (i, v) in posed.vertices.iter().enumerate() {
                for d in 0..3 {
                    total += f64::from(probe_v[(b * 24 + i) * 3 + d]) * f64::from(v[d]);
                }
            }
            for (j, v) in posed.joints.iter().enumerate() {
                for d in 0..3 {
                    total += f64::from(probe_j[(b * NUM_JOINTS + j) * 3 + d]) * f64::from(v[d]);
                }
            }
        }
        total
    };
    let (betas, pose, expr) = tensor_inputs(&params, &device);
    let (betas, pose, expr) = (
        betas.require_grad(),
        pose.require_grad(),
        expr.require_grad(),
    );
    let out = layer.forward(betas.clone(), pose.clone(), expr.clone());
    let pv = Tensor::<3>::from_data(TensorData::new(probe_v.clone(), [2, 24, 3]), &device);
    let pj = Tensor::<3>::from_data(
        TensorData::new(probe_j.clone(), [2, NUM_JOINTS, 3]),
        &device,
    );
    let loss = (out.vertices * pv).sum() + (out.joints * pj).sum();
    let grads = loss.backward();
    let g_pose = pose
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let g_betas = betas
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let g_expr = expr
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    assert!(
        g_pose
            .iter()
            .chain(&g_betas)
            .chain(&g_expr)
            .all(|g| g.is_finite())
    );

    let eps = 1e-2f32;
    let check = |analytic: f32, set: &dyn Fn(&mut BodyParams, f32), b: usize, what: String| {
        let mut plus = params.clone();
        set(&mut plus[b], eps);
        let mut minus = params.clone();
        set(&mut minus[b], -eps);
        let numeric = ((loss_f32(&plus) - loss_f32(&minus)) / (2.0 * f64::from(eps))) as f32;
        let tol = 2e-3 + 1e-2 * numeric.abs();
        assert!(
            (analytic - numeric).abs() < tol,
            "{what}: analytic {analytic} vs numeric {numeric}"
        );
    };
    for b in 0..2 {
        for j in [0usize, 1, 3, 9, 16, 18, 20, 22, 26, 38, 53] {
            for d in 0..3 {
                let g = g_pose[(b * NUM_JOINTS + j) * 3 + d];
                check(
                    g,
                    &|p: &mut BodyParams, e| p.pose[j][d] += e,
                    b,
                    format!("pose[{b}][{j}][{d}]"),
                );
            }
        }
        for k in [0usize, 4, 9] {
            check(
                g_betas[b * 10 + k],
                &|p: &mut BodyParams, e| p.betas[k] += e,
                b,
                format!("beta[{b}][{k}]"),
            );
            check(
                g_expr[b * 10 + k],
                &|p: &mut BodyParams, e| p.expression[k] += e,
                b,
                format!("psi[{b}][{k}]"),
            );
        }
    }
}

#[test]
fn rodrigues_tensor_matches_f32_and_is_smooth_at_zero() {
    let device = prism_core::BackendKind::Ndarray.autodiff_device().unwrap();
    let rs = [
        [0.0f32, 0.0, 0.0],
        [1e-5, -2e-5, 1e-5],
        [0.01, 0.02, -0.015],
        [0.5, -1.0, 2.0],
        [3.0, 0.1, 0.0],
    ];
    let data: Vec<f32> = rs.iter().flatten().copied().collect();
    let r = Tensor::<2>::from_data(TensorData::new(data, [rs.len(), 3]), &device).require_grad();
    let m = rodrigues(r.clone());
    let values = m.clone().into_data().try_into_vec::<f32>().unwrap();
    for (i, x) in rs.iter().enumerate() {
        let reference = rotation::axis_angle_to_matrix(Vec3::from_array(*x));
        for row in 0..3 {
            for col in 0..3 {
                assert!((values[i * 9 + row * 3 + col] - reference.col(col)[row]).abs() < 1e-6);
            }
        }
    }
    // d(sum R)/dr at r = 0: R ~ I + [r]_x, whose entries sum to zero for every r; the
    // derivative of the off-diagonal entries is finite and here exactly zero.
    let grads = m.sum().backward();
    let g = r
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    assert!(g.iter().all(|x| x.is_finite()));
    assert!(g[..3].iter().all(|x| x.abs() < 1e-6));
}
