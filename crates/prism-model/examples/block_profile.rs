//! Scratch profile of one block's parts on flex.
use burn::tensor::{Device, Distribution, Tensor};
use prism_model::{AttentionKind, PrismBlockConfig, fused_attention, linear_attention, FeatureMap};
use std::time::Instant;

fn time<F: FnMut() -> Tensor<3>>(name: &str, mut f: F) {
    for _ in 0..2 { let _ = f().into_data(); }
    let mut t: Vec<f64> = (0..7).map(|_| { let s = Instant::now(); let _ = f().into_data(); s.elapsed().as_secs_f64()*1e3 }).collect();
    t.sort_by(f64::total_cmp);
    println!("{name:<30} {:8.2} ms", t[3]);
}

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let (tokens, width, heads) = (args[0], args[1], args[2]);
    let device = Device::flex();
    let x = Tensor::<3>::random([1, tokens, width], Distribution::Normal(0.0, 1.0), &device);
    for kind in [AttentionKind::Full, AttentionKind::Linear] {
        let block = PrismBlockConfig::new(width, heads).with_attention(kind).init(&device);
        time(&format!("block {kind:?}"), || block.forward(x.clone()));
        time(&format!("attention {kind:?}"), || block.attention.forward(x.clone()));
        time("mlp", || block.mlp.forward(x.clone()));
        time("qkv linear", || block.attention.qkv.forward(x.clone()));
        time("project", || { let (q, _, _) = block.attention.project(x.clone()); q.reshape([1, tokens, width]) });
        let (q, k, v) = block.attention.project(x.clone());
        let dh = width / heads;
        time("attn core", || match kind {
            AttentionKind::Full => fused_attention(q.clone(), k.clone(), v.clone()).reshape([1, tokens, width]),
            AttentionKind::Linear => linear_attention(q.clone(), k.clone(), v.clone(), FeatureMap::Relu, 1e-6).reshape([1, tokens, width]),
        });
        let _ = dh;
        time("softmax decomposed", || prism_model::softmax_attention(q.clone(), k.clone(), v.clone()).reshape([1, tokens, width]));
        time("layernorm", || block.attention_norm.forward(x.clone()));
        time("out linear", || block.attention.out.forward(x.clone()));
    }
}
