//! prism-losses' integration tests, as one test binary: the losses' gradients against finite
//! differences, the objective's terms, the point loss, and the metrics against the reference
//! pairs. One binary links the Burn stack once, and its tests share the two cores.

mod common;
mod gradients;
mod objective;
mod point_loss;
mod reference_metrics;
