"""prism's backbone written in PyTorch, to time beside `prism bench` on the same CPU or GPU.

The model mirrors prism-model's backbone with the geometry parts off: the tokenizer
(`Linear_inp([2I - 1, P_s])`, `Linear_tar(P_t)`, LayerNorm on the joined sequence), pre-norm
blocks (LayerNorm, attention with a per-head RMSNorm on queries and keys, LayerNorm, GELU MLP),
no biases anywhere, and the NVS head (LayerNorm, Linear, sigmoid) on the target tokens.
Full attention is `F.scaled_dot_product_attention`, what a PyTorch user reaches for; linear
attention is the ReLU kernel with its normaliser, computed right to left.

Prints one JSON object per line: {"model", "res", "ms", "train_ms"?}. `ms` is the median
inference forward of one (source, target) pair; `train_ms` (with --train) the median of
forward + MSE + backward + AdamW.

--device cuda runs on the GPU (each timed run between two `torch.cuda.synchronize()`) and adds
`peak_mem_bytes` (and `train_peak_mem_bytes`): `torch.cuda.max_memory_allocated()` over the
row's runs. --dtype: f32 (the default), tf32 (f32 tensors, TF32 matrix products on CUDA) or
bf16 (`torch.autocast` to bfloat16 around the forward pass and the loss; weights, gradients and
AdamW stay f32).
"""
import argparse
import contextlib
import json
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


def to_patches(x, p):
    """[B, C, H, W] -> [B, (H/p)(W/p), p*p*C], pixel-major inside a patch, channels last."""
    b, c, h, w = x.shape
    x = x.reshape(b, c, h // p, p, w // p, p).permute(0, 2, 4, 3, 5, 1)
    return x.reshape(b, (h // p) * (w // p), p * p * c)


def from_patches(t, c, h, w, p):
    """Inverse of to_patches."""
    b = t.shape[0]
    t = t.reshape(b, h // p, w // p, p, p, c).permute(0, 5, 1, 3, 2, 4)
    return t.reshape(b, c, h, w)


class HeadNorm(nn.Module):
    """RMSNorm over the last dimension with one gain vector."""

    def __init__(self, dim, eps=1e-5):
        super().__init__()
        self.gain = nn.Parameter(torch.ones(dim))
        self.eps = eps

    def forward(self, x):
        return x * torch.rsqrt(x.square().mean(-1, keepdim=True) + self.eps) * self.gain


class Attention(nn.Module):
    def __init__(self, width, heads, eps=1e-6):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(width, 3 * width, bias=False)
        self.q_norm = HeadNorm(width // heads)
        self.k_norm = HeadNorm(width // heads)
        self.out = nn.Linear(width, width, bias=False)
        self.kind = "full"
        self.eps = eps

    def forward(self, x):
        b, t, d = x.shape
        q, k, v = self.qkv(x).reshape(b, t, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        q, k = self.q_norm(q), self.k_norm(k)
        if self.kind == "full":
            y = F.scaled_dot_product_attention(q, k, v)
        else:
            q, k = F.relu(q), F.relu(k)
            kv = k.transpose(2, 3) @ v
            normaliser = (q * k.sum(2, keepdim=True)).sum(3, keepdim=True)
            y = (q @ kv) / (normaliser + self.eps)
        return self.out(y.transpose(1, 2).reshape(b, t, d))


class Block(nn.Module):
    def __init__(self, width, heads, mlp_ratio):
        super().__init__()
        self.attention_norm = nn.LayerNorm(width, bias=False)
        self.attention = Attention(width, heads)
        self.mlp_norm = nn.LayerNorm(width, bias=False)
        self.fc_in = nn.Linear(width, mlp_ratio * width, bias=False)
        self.fc_out = nn.Linear(mlp_ratio * width, width, bias=False)

    def forward(self, x):
        x = x + self.attention(self.attention_norm(x))
        return x + self.fc_out(F.gelu(self.fc_in(self.mlp_norm(x))))


class Backbone(nn.Module):
    def __init__(self, width, heads, patch, blocks, mlp_ratio):
        super().__init__()
        self.patch = patch
        self.source = nn.Linear(9 * patch * patch, width, bias=False)
        self.target = nn.Linear(6 * patch * patch, width, bias=False)
        self.norm = nn.LayerNorm(width, bias=False)
        self.blocks = nn.ModuleList(Block(width, heads, mlp_ratio) for _ in range(blocks))
        self.head_norm = nn.LayerNorm(width, bias=False)
        self.head = nn.Linear(width, 3 * patch * patch, bias=False)

    def forward(self, image, source_rays, target_rays):
        _, _, h, w = image.shape
        p = self.patch
        x = self.source(to_patches(torch.cat([image * 2 - 1, source_rays], 1), p))
        q = self.target(to_patches(target_rays, p))
        tokens = self.norm(torch.cat([x, q], 1))
        for block in self.blocks:
            tokens = block(tokens)
        y = self.head(self.head_norm(tokens[:, x.shape[1]:]))
        return from_patches(torch.sigmoid(y), 3, h, w, p)


def kinds(model_name, blocks, group):
    """Attention kind per block: teacher all full, linear all linear, student the last block
    of each distillation group full (the end of prism's progressive schedule)."""
    if model_name == "teacher":
        return ["full"] * blocks
    if model_name == "linear":
        return ["linear"] * blocks
    return ["full" if i % group == group - 1 else "linear" for i in range(blocks)]


def median_ms(fn, warmup, iters, sync=lambda: None):
    """Median wall time of `fn` in ms after `warmup` untimed runs; `sync` waits for the device
    before and after each timed run."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(iters):
        sync()
        start = time.perf_counter()
        fn()
        sync()
        times.append((time.perf_counter() - start) * 1e3)
    return sorted(times)[len(times) // 2]


class Device:
    """Where and in which precision the model runs: the autocast context, the device's
    synchronisation and its peak-memory counter (CUDA only)."""

    def __init__(self, name, dtype):
        self.name = name
        self.cuda = name == "cuda"
        if self.cuda and not torch.cuda.is_available():
            raise SystemExit("--device cuda: PyTorch sees no CUDA device")
        self.dtype = dtype
        if self.cuda:
            torch.backends.cuda.matmul.allow_tf32 = dtype == "tf32"
            torch.backends.cudnn.allow_tf32 = dtype == "tf32"

    def autocast(self):
        if self.dtype == "bf16":
            return torch.autocast(self.name, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def sync(self):
        if self.cuda:
            torch.cuda.synchronize()

    def reset_peak(self):
        if self.cuda:
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()

    def peak(self, row, key):
        """Adds the peak memory since `reset_peak` to `row` as `key` (CUDA only)."""
        if self.cuda:
            row[key] = torch.cuda.max_memory_allocated()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--heads", type=int, default=4)
    ap.add_argument("--patch", type=int, default=8)
    ap.add_argument("--blocks", type=int, default=6)
    ap.add_argument("--group", type=int, default=6)
    ap.add_argument("--mlp-ratio", type=int, default=4)
    ap.add_argument("--res", default="128,256")
    ap.add_argument("--models", default="teacher,student,linear")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--train", action="store_true", help="also time the teacher's training step")
    ap.add_argument("--train-res", type=int, default=128, help="resolution of the training step")
    ap.add_argument("--train-steps", type=int, default=6)
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    ap.add_argument("--dtype", choices=["f32", "tf32", "bf16"], default="f32")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    dev = Device(a.device, a.dtype)
    model = Backbone(a.width, a.heads, a.patch, a.blocks, a.mlp_ratio).to(a.device)
    for res in (int(r) for r in a.res.split(",")):
        image = torch.rand(1, 3, res, res, device=a.device)
        source_rays = torch.randn(1, 6, res, res, device=a.device)
        target_rays = torch.randn(1, 6, res, res, device=a.device)
        target = torch.rand(1, 3, res, res, device=a.device)
        for name in a.models.split(","):
            for block, kind in zip(model.blocks, kinds(name, a.blocks, a.group)):
                block.attention.kind = kind

            def forward():
                with torch.inference_mode(), dev.autocast():
                    model(image, source_rays, target_rays)

            dev.reset_peak()
            row = {"model": name, "res": res,
                   "ms": median_ms(forward, a.warmup, a.iters, dev.sync)}
            dev.peak(row, "peak_mem_bytes")
            if a.train and name == "teacher" and res == a.train_res:
                opt = torch.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-5)

                def step():
                    opt.zero_grad(set_to_none=True)
                    with dev.autocast():
                        loss = F.mse_loss(model(image, source_rays, target_rays), target)
                    loss.backward()
                    opt.step()

                dev.reset_peak()
                row["train_ms"] = median_ms(step, 2, a.train_steps, dev.sync)
                dev.peak(row, "train_peak_mem_bytes")
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
