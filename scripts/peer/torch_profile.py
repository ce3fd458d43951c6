"""Where PyTorch's time goes in the comparison backbone: `torch.profiler` over forward passes of
`torch_backbone.py`'s model on the CPU, printed as a table of self CPU time per op, the PyTorch
side of BENCHMARKS' per-op tables (prism's side is `perf record` of `prism bench`).

usage (from the repository root, with a Python that has torch):
    python scripts/peer/torch_profile.py [--model teacher] [--res 256] [--dtype bf16]
        [--iters 20] [--threads 2] [--rows 15] [--train]

With --train it profiles the model's training step instead (forward, MSE, backward and AdamW,
as `torch_backbone.py --train` times the teacher's).
"""
import argparse
import os
import sys

import torch
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import torch_backbone as tb  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=["teacher", "student", "linear"], default="teacher")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--dtype", choices=["f32", "bf16"], default="f32")
    ap.add_argument("--iters", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rows", type=int, default=15)
    ap.add_argument("--train", action="store_true", help="profile the training step")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    width, heads, patch, blocks, group, mlp = 256, 4, 8, 6, 6, 4
    model = tb.Backbone(width, heads, patch, blocks, mlp)
    for block, kind in zip(model.blocks, tb.kinds(a.model, blocks, group)):
        block.attention.kind = kind
    dev = tb.Device("cpu", a.dtype)
    image = torch.rand(1, 3, a.res, a.res)
    rays = [torch.randn(1, 6, a.res, a.res) for _ in range(2)]

    def forward():
        with torch.inference_mode(), dev.autocast():
            model(image, *rays)

    target = torch.rand(1, 3, a.res, a.res)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-5)

    def step():
        opt.zero_grad(set_to_none=True)
        with dev.autocast():
            loss = torch.nn.functional.mse_loss(model(image, *rays), target)
        loss.backward()
        opt.step()

    run = step if a.train else forward
    for _ in range(3):
        run()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(a.iters):
            run()
    total = sum(e.self_cpu_time_total for e in prof.key_averages())
    print(f"{a.model} {a.res} px {a.dtype}: {total / 1e3 / a.iters:.1f} ms of self CPU time a {'step' if a.train else 'forward'}")
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=a.rows))


if __name__ == "__main__":
    main()
