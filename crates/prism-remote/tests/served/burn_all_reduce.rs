//! Where Burn 0.22's distributed operations stop, shown on the smallest program: two served
//! devices on two `prism serve` servers, and `burn::tensor::distributed::all_reduce` over them.
//!
//! Burn's remote client refuses a collective whose devices live on different servers
//! (burn-remote 0.22.1, `src/client/runner.rs`, line 182: "cross-peer all_reduce is not
//! supported yet"), and the CPU backends have no collective at all (burn-flex 0.22.1,
//! `src/ops/transaction.rs` line 11 takes the default of burn-backend 0.22.1,
//! `src/backend/distributed/ops.rs` line 121, a default that panics). This is why prism's
//! trainer sums the gradients with Burn's server-to-server transfers instead (see the README,
//! "Training on several machines"). When a Burn release lifts the limit, this test fails:
//! then the trainer should switch to `all_reduce`.

use std::panic::{AssertUnwindSafe, catch_unwind};

use crate::common::served_device;
use burn::tensor::Tensor;
use burn::tensor::distributed::{ReduceOperation, all_reduce};

#[test]
fn burn_cannot_all_reduce_across_two_servers() {
    let (a, b) = (served_device(), served_device());
    let x = Tensor::<1>::from_floats([1.0, 2.0], &a);
    // Read back, so that the collective runs even where the remote backend queues operations
    // (Burn's fusion, in the GPU build).
    let refused = catch_unwind(AssertUnwindSafe(|| {
        all_reduce(x, ReduceOperation::Sum, vec![a.clone(), b.clone()])
            .resolve()
            .into_data()
    }));
    let message = match refused {
        Ok(_) => panic!("Burn all-reduced across servers: switch the trainer to all_reduce"),
        Err(payload) => payload
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default(),
    };
    assert!(
        message.contains("cross-peer all_reduce is not supported yet"),
        "{message}"
    );
}
