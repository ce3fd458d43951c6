//! The objective: LPIPS-weighted image terms, SMPL-X and distillation losses, the weighted
//! total, absent terms, the config's defaults and serialisation.

use crate::common;

use burn::tensor::Tensor;
use common::{host, ndarray, tensor, uniform};
use prism_losses::{
    LossError, LossInputs, LossWeights, Lpips, Objective, PointInputs, SmplxInputs, SmplxParams,
    distill_layers, distill_loss, mse_loss, point_loss, smplx_loss,
};

fn scalar(t: &Tensor<1>) -> f64 {
    f64::from(t.clone().into_scalar::<f32>())
}

fn params(seed: u64, batch: usize, device: &burn::tensor::Device) -> SmplxParams {
    SmplxParams::from_joint_pose(
        tensor(uniform(seed, batch * 10, -1.0, 1.0), [batch, 10], device),
        tensor(
            uniform(seed + 1, batch * 165, -1.0, 1.0),
            [batch, 55, 3],
            device,
        ),
        tensor(
            uniform(seed + 2, batch * 10, -1.0, 1.0),
            [batch, 10],
            device,
        ),
        tensor(uniform(seed + 3, batch * 3, -1.0, 1.0), [batch, 3], device),
    )
}

/// Sum of squared differences of one subject's four parameter groups, on the host.
fn subject_sse(a: &SmplxParams, b: &SmplxParams, subject: usize) -> f64 {
    let groups = |p: &SmplxParams| [p.beta.clone(), p.theta.clone(), p.psi.clone(), p.pi.clone()];
    groups(a)
        .into_iter()
        .zip(groups(b))
        .map(|(x, y)| {
            let [_, n] = x.dims();
            let (x, y) = (host(x), host(y));
            (subject * n..(subject + 1) * n)
                .map(|i| (f64::from(x[i]) - f64::from(y[i])).powi(2))
                .sum::<f64>()
        })
        .sum()
}

#[test]
fn smplx_loss_averages_summed_squared_errors_over_pairs_with_fits_counting_zero_without() {
    let device = ndarray();
    let (pred, gt) = (params(1, 3, &device), params(10, 3, &device));
    let sse: Vec<f64> = (0..3).map(|b| subject_sse(&pred, &gt, b)).collect();
    let all = scalar(&smplx_loss(&pred, &gt, None));
    assert!((all - sse.iter().sum::<f64>() / 3.0).abs() < 1e-4 * all);
    let mask = Tensor::<1>::from_floats([1.0, 0.0, 1.0], &device);
    let fitted = scalar(&smplx_loss(&pred, &gt, Some(mask)));
    assert!((fitted - (sse[0] + sse[2]) / 3.0).abs() < 1e-4 * fitted);
    let none = Tensor::<1>::zeros([3], &device);
    assert_eq!(scalar(&smplx_loss(&pred, &gt, Some(none))), 0.0);
}

#[test]
fn distill_loss_is_the_mean_layer_mse_and_leaves_the_teacher_alone() {
    let ad = ndarray().autodiff();
    let shape = [2, 5, 4];
    let student: Vec<Tensor<3>> = (0..3)
        .map(|l| tensor(uniform(l, 40, -1.0, 1.0), shape, &ad).require_grad())
        .collect();
    let teacher: Vec<Tensor<3>> = (0..3)
        .map(|l| tensor(uniform(l + 50, 40, -1.0, 1.0), shape, &ad).require_grad())
        .collect();
    let loss = distill_loss(&student, &teacher);
    let expected: f64 = student
        .iter()
        .zip(&teacher)
        .map(|(s, t)| {
            let (s, t) = (host(s.clone()), host(t.clone()));
            s.iter()
                .zip(&t)
                .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
                .sum::<f64>()
                / 40.0
        })
        .sum::<f64>()
        / 3.0;
    assert!((scalar(&loss) - expected).abs() < 1e-6);
    let grads = loss.backward();
    assert!(student[0].grad(&grads).is_some());
    assert!(
        teacher.iter().all(|t| t.grad(&grads).is_none()),
        "the teacher got a gradient"
    );
    assert_eq!(distill_layers(36, 6), vec![5, 11, 17, 23, 29, 35]);
    assert_eq!(distill_layers(4, 8), vec![0, 1, 2, 3]);
    assert!(distill_layers(0, 3).is_empty());
}

#[test]
fn loss_weights_default_to_the_paper_and_round_trip_through_json() {
    let w = LossWeights::new();
    assert_eq!(
        (
            w.nvs,
            w.gs,
            w.pts,
            w.smplx,
            w.distill,
            w.lpips,
            w.confidence_alpha,
            w.gs_opacity
        ),
        (1.0, 1.0, 100.0, 1.0, 1.0, 1.0, 0.2, 0.0)
    );
    let json = serde_json::to_string(&w.clone().with_pts(50.0)).unwrap();
    let back: LossWeights = serde_json::from_str(&json).unwrap();
    assert_eq!(back, w.with_pts(50.0));
}

#[test]
fn objective_total_is_the_weighted_sum_of_the_reported_terms() {
    let device = ndarray();
    let lpips = Lpips::load_default(None, &device).unwrap();
    let weights = LossWeights::new()
        .with_gs(0.5)
        .with_lpips(0.7)
        .with_smplx(2.0);
    let objective = Objective::new(weights.clone(), Some(lpips)).unwrap();
    let img = |seed| {
        tensor(
            uniform(seed, 2 * 3 * 32 * 32, 0.0, 1.0),
            [2, 3, 32, 32],
            &device,
        )
    };
    let (b, h, w) = (2, 8, 8);
    let n = b * h * w;
    let pts = PointInputs {
        points: tensor(uniform(30, 3 * n, -1.0, 1.0), [b, 3, h, w], &device),
        points_gt: tensor(uniform(31, 3 * n, -1.0, 1.0), [b, 3, h, w], &device),
        confidence: tensor(uniform(32, n, 1.0, 2.0), [b, 1, h, w], &device),
        mask: tensor(uniform(33, n, 0.0, 1.0), [b, 1, h, w], &device),
    };
    let smplx = SmplxInputs {
        pred: params(40, 2, &device),
        gt: params(50, 2, &device),
        has_fit: None,
    };
    let inputs = LossInputs::new()
        .with_target(img(2))
        .with_nvs(img(1))
        .with_gs(img(3))
        .with_pts(pts.clone())
        .with_smplx(smplx.clone());
    let terms = objective.forward(inputs).unwrap();
    assert_eq!(
        terms.names(),
        vec![
            "nvs_mse",
            "nvs_lpips",
            "gs_mse",
            "gs_lpips",
            "pts",
            "smplx",
            "total"
        ]
    );
    assert!(terms.get("distill").is_none());
    let v = |name: &str| scalar(terms.get(name).unwrap());
    // Each term equals the standalone function.
    assert!((v("nvs_mse") - scalar(&mse_loss(img(1), img(2)))).abs() < 1e-7);
    let lp = Lpips::load_default(None, &device).unwrap();
    assert!((v("gs_lpips") - scalar(&lp.forward(img(3), img(2)).mean())).abs() < 1e-6);
    let pl = point_loss(pts.points, pts.points_gt, pts.confidence, pts.mask, 0.2).total();
    assert!((v("pts") - scalar(&pl)).abs() < 1e-6);
    assert!((v("smplx") - scalar(&smplx_loss(&smplx.pred, &smplx.gt, None))).abs() < 1e-4);
    let expected = (v("nvs_mse") + 0.7 * v("nvs_lpips"))
        + 0.5 * (v("gs_mse") + 0.7 * v("gs_lpips"))
        + 100.0 * v("pts")
        + 2.0 * v("smplx");
    assert!(
        (v("total") - expected).abs() < 1e-4 * expected,
        "{} vs {expected}",
        v("total")
    );
    let logged = terms.values();
    assert_eq!(logged.len(), 7);
    assert_eq!(logged.last().unwrap().0, "total");
    for (name, value) in logged {
        assert!(
            (value - v(name)).abs() < 1e-6 * v(name).abs().max(1.0),
            "{name}"
        );
    }
}

#[test]
fn objective_skips_zero_weights_and_reports_what_is_missing() {
    let device = ndarray();
    let no_lpips = LossWeights::new().with_lpips(0.0);
    let objective = Objective::new(no_lpips, None).unwrap();
    let img = |seed| {
        tensor(
            uniform(seed, 3 * 16 * 16, 0.0, 1.0),
            [1, 3, 16, 16],
            &device,
        )
    };
    let terms = objective
        .forward(LossInputs::new().with_target(img(2)).with_nvs(img(1)))
        .unwrap();
    assert_eq!(terms.names(), vec!["nvs_mse", "total"]);
    assert!((scalar(&terms.total) - scalar(&mse_loss(img(1), img(2)))).abs() < 1e-7);

    assert!(matches!(
        Objective::new(LossWeights::new(), None),
        Err(LossError::LpipsRequired(_))
    ));
    assert!(matches!(
        objective.forward(LossInputs::new()),
        Err(LossError::NoTerms)
    ));
    assert!(matches!(
        objective.forward(LossInputs::new().with_nvs(img(1))),
        Err(LossError::NoTarget)
    ));
    let student = vec![Tensor::<3>::ones([1, 2, 2], &device)];
    let teacher = vec![Tensor::<3>::zeros([1, 2, 2], &device)];
    let only_distill =
        Objective::new(LossWeights::new().with_distill(0.0).with_lpips(0.0), None).unwrap();
    let result = only_distill.forward(LossInputs::new().with_distill(student, teacher));
    assert!(
        matches!(result, Err(LossError::NoTerms)),
        "a zero-weight term is not computed"
    );
}

#[test]
fn lpips_refuses_a_file_that_is_not_its_weights() {
    let device = ndarray();
    let json =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/reference.json");
    let err = Lpips::load(&json, &device).unwrap_err();
    assert!(matches!(err, LossError::WeightsInvalid { .. }), "{err}");
    assert!(err.to_string().contains("reference.json"));
    let err = Lpips::load(std::path::Path::new("/nonexistent.safetensors"), &device).unwrap_err();
    assert!(err.to_string().contains("/nonexistent.safetensors"));
}
