//! `L_distill`: hidden-state distillation from the frozen teacher (paper Sec. 3.4).

use burn::tensor::Tensor;

/// `L_distill = (1/|S|) sum_{l in S} MSE(H_l^student, sg(H_l^teacher))`: the mean over the
/// chosen layers of the mean squared error between student and teacher hidden states (each
/// `[B, T, d]`). The teacher states are detached, so no gradient reaches the teacher.
/// Returns `[1]`.
///
/// # Panics
/// When the lists are empty or differ in length or shapes.
pub fn distill_loss(student: &[Tensor<3>], teacher: &[Tensor<3>]) -> Tensor<1> {
    assert!(!student.is_empty(), "L_distill: no layers");
    assert_eq!(
        student.len(),
        teacher.len(),
        "L_distill: layer counts differ"
    );
    let layers = student.len() as f64;
    student
        .iter()
        .zip(teacher)
        .map(|(s, t)| {
            assert_eq!(s.dims(), t.dims(), "L_distill: hidden-state shapes differ");
            let d = s.clone().sub(t.clone().detach());
            d.clone().mul(d).mean()
        })
        .reduce(|a, b| a.add(b))
        .expect("at least one layer")
        .div_scalar(layers)
}

/// A uniformly spaced set `S` of `count` layers out of `num_layers` (0-based, always ending at
/// the last layer): `num_layers * (i + 1) / count - 1` for `i = 0..count`.
/// E.g. 36 layers, 6 chosen: 5, 11, 17, 23, 29, 35.
/// Empty when `num_layers` or `count` is 0; `count` is capped at `num_layers`.
pub fn distill_layers(num_layers: usize, count: usize) -> Vec<usize> {
    let count = count.min(num_layers);
    (0..count)
        .map(|i| num_layers * (i + 1) / count - 1)
        .collect()
}

/// Student and teacher hidden states of the distilled layers, in the same order.
#[derive(Clone, Debug)]
pub struct DistillInputs {
    /// Student hidden states, each `[B, T, d]`.
    pub student: Vec<Tensor<3>>,
    /// Teacher hidden states (detached by [`distill_loss`]), each `[B, T, d]`.
    pub teacher: Vec<Tensor<3>>,
}
