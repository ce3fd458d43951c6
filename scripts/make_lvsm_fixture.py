#!/usr/bin/env python3
"""Makes the test fixture of `prism convert lvsm`: a tiny decoder-only LVSM with random
weights, its inputs and its outputs.

The model below is written for this project after the *layout* of the published LVSM
decoder-only scene model (class `Images2LatentScene`): the same parameter names and shapes in
its state dict, the same computation. It is not a copy of that code. What it computes:

- source pixels `[2 I - 1, o x d, d]` (9 channels), target pixels `[o x d, d]` (6 channels);
  Plücker rays from the cameras: `d = normalize(R_c2w K^-1 [x + 0.5, y + 0.5, 1])`, `o` the
  camera centre (OpenCV cameras);
- patchify `b c (hh ph) (ww pw) -> b (hh ww) (ph pw c)`, then `Linear` without bias
  (`image_tokenizer.1`, `target_pose_tokenizer.1`);
- the sequence `[source tokens, target tokens]`, a LayerNorm without bias
  (`transformer_input_layernorm`);
- `n_layer` pre-norm blocks `x + fc(attn(norm1(x)))`, `x + mlp(norm2(x))`: LayerNorms without
  bias, `attn.to_qkv` `[3d, d]` (q, k, v chunks, heads `(nh dh)`), RMSNorm (eps 1e-5, one gain
  of size `d_head`) on q and k (`attn.q_norm`, `attn.k_norm`), softmax attention with scale
  `1 / sqrt(d_head)`, `attn.fc` `[d, d]`, MLP `mlp.mlp.0` `[4d, d]`, exact GELU, `mlp.mlp.2`
  `[d, 4d]`; no biases anywhere;
- the target tokens through `image_token_decoder`: LayerNorm without bias (`.0`), Linear
  `[3 p^2, d]` (`.1`), sigmoid, unpatchify.

Outputs (in the folder given, default `crates/prism-model/tests/fixtures`):

- `lvsm_tiny.pt`: `{"model": state_dict}` as `torch.save` writes it (with one extra tensor
  under `loss_computer.` as the real checkpoints carry the perceptual loss's network, which the
  converter must skip);
- `lvsm_tiny_io.safetensors`: `source_image [B, 3, H, W]` in [0, 1], the LVSM-ordered Plücker
  maps `source_plucker`, `target_plucker` `[B, 6, H, W]` (`o x d, d`), `source_c2w`,
  `target_c2w` `[B, 4, 4]`, `fxfycxcy [4]`, and LVSM's prediction `render [B, 3, H, W]`.

Run with PyTorch, safetensors and numpy installed:

    python3 scripts/make_lvsm_fixture.py [OUT_DIR]

CI does not need PyTorch: the Rust tests read the committed files.
"""

import math
import os
import sys

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from safetensors.torch import save_file

# The fixture's model: small, but every part as in the published model.
WIDTH = 32
HEAD_DIM = 16
PATCH = 8
LAYERS = 4
MLP_RATIO = 4
# Images of the fixture's forward pass.
BATCH = 2
SIZE = 32
# Larger than LVSM's init (0.02) so that the prediction varies across pixels.
WEIGHT_STD = 0.25
SEED = 16


class RmsNorm(nn.Module):
    def __init__(self, dim, eps=1e-5):
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(dim))

    def forward(self, x):
        return x * torch.rsqrt(x.pow(2).mean(-1, keepdim=True) + self.eps) * self.weight


class Attention(nn.Module):
    def __init__(self, dim, head_dim):
        super().__init__()
        self.head_dim = head_dim
        self.to_qkv = nn.Linear(dim, 3 * dim, bias=False)
        self.fc = nn.Linear(dim, dim, bias=False)
        self.q_norm = RmsNorm(head_dim)
        self.k_norm = RmsNorm(head_dim)

    def forward(self, x):
        b, t, d = x.shape
        heads = d // self.head_dim
        q, k, v = self.to_qkv(x).chunk(3, dim=-1)
        # [b, t, heads, dh] -> [b, heads, t, dh]
        q, k, v = (y.reshape(b, t, heads, self.head_dim) for y in (q, k, v))
        q, k = self.q_norm(q), self.k_norm(k)
        q, k, v = (y.transpose(1, 2) for y in (q, k, v))
        scores = q @ k.transpose(-1, -2) / math.sqrt(self.head_dim)
        out = scores.softmax(-1) @ v
        return self.fc(out.transpose(1, 2).reshape(b, t, d))


class Mlp(nn.Module):
    def __init__(self, dim, ratio):
        super().__init__()
        self.mlp = nn.Sequential(
            nn.Linear(dim, ratio * dim, bias=False),
            nn.GELU(),
            nn.Linear(ratio * dim, dim, bias=False),
        )

    def forward(self, x):
        return self.mlp(x)


class Block(nn.Module):
    def __init__(self, dim, head_dim, ratio):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, bias=False)
        self.attn = Attention(dim, head_dim)
        self.norm2 = nn.LayerNorm(dim, bias=False)
        self.mlp = Mlp(dim, ratio)

    def forward(self, x):
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


def patchify(x, p):
    b, c, h, w = x.shape
    x = x.reshape(b, c, h // p, p, w // p, p)
    # b hh ww ph pw c
    x = x.permute(0, 2, 4, 3, 5, 1)
    return x.reshape(b, (h // p) * (w // p), p * p * c)


def unpatchify(x, c, h, w, p):
    b = x.shape[0]
    x = x.reshape(b, h // p, w // p, p, p, c)
    x = x.permute(0, 5, 1, 3, 2, 4)
    return x.reshape(b, c, h, w)


class TinyLvsm(nn.Module):
    def __init__(self):
        super().__init__()
        d, p = WIDTH, PATCH
        # Index 0 of the published Sequential is a parameter-free rearrangement.
        self.image_tokenizer = nn.Sequential(nn.Identity(), nn.Linear(9 * p * p, d, bias=False))
        self.target_pose_tokenizer = nn.Sequential(
            nn.Identity(), nn.Linear(6 * p * p, d, bias=False)
        )
        self.transformer_blocks = nn.ModuleList(
            [Block(d, HEAD_DIM, MLP_RATIO) for _ in range(LAYERS)]
        )
        self.transformer_input_layernorm = nn.LayerNorm(d, bias=False)
        self.image_token_decoder = nn.Sequential(
            nn.LayerNorm(d, bias=False), nn.Linear(d, 3 * p * p, bias=False), nn.Sigmoid()
        )

    def forward(self, image, source_plucker, target_plucker):
        b, _, h, w = image.shape
        src = torch.cat([image * 2.0 - 1.0, source_plucker], dim=1)
        x = self.image_tokenizer[1](patchify(src, PATCH))
        q = self.target_pose_tokenizer[1](patchify(target_plucker, PATCH))
        tokens = self.transformer_input_layernorm(torch.cat([x, q], dim=1))
        for block in self.transformer_blocks:
            tokens = block(tokens)
        target = tokens[:, x.shape[1] :]
        return unpatchify(self.image_token_decoder(target), 3, h, w, PATCH)


def plucker(c2w, fxfycxcy, h, w):
    """LVSM-ordered Plücker map `[o x d, d]`, `[B, 6, H, W]`, of OpenCV cameras."""
    fx, fy, cx, cy = fxfycxcy
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    cam = torch.stack([(xs + 0.5 - cx) / fx, (ys + 0.5 - cy) / fy, torch.ones_like(xs)], -1)
    out = []
    for m in c2w:
        d = cam.reshape(-1, 3) @ m[:3, :3].T
        d = d / d.norm(dim=-1, keepdim=True)
        o = m[:3, 3].expand_as(d)
        pl = torch.cat([torch.cross(o, d, dim=-1), d], dim=-1)
        out.append(pl.T.reshape(6, h, w))
    return torch.stack(out).float()


def look_at_c2w(eye, target):
    """OpenCV camera-to-world (x right, y down, z forward) at `eye` looking at `target`, Y up."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, -1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return torch.tensor(m, dtype=torch.float64)


def orbit(yaw_deg, pitch_deg, radius=2.0):
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    eye = [
        radius * math.cos(pitch) * math.sin(yaw),
        1.0 + radius * math.sin(pitch),
        radius * math.cos(pitch) * math.cos(yaw),
    ]
    return look_at_c2w(eye, [0.0, 1.0, 0.0])


def main():
    out_dir = sys.argv[1] if len(sys.argv) > 1 else "crates/prism-model/tests/fixtures"
    os.makedirs(out_dir, exist_ok=True)
    torch.manual_seed(SEED)
    model = TinyLvsm()
    with torch.no_grad():
        for name, param in model.named_parameters():
            if "norm" in name:
                # Gains around 1, not all 1, so that a misplaced gain shows.
                param.copy_(1.0 + 0.2 * torch.randn_like(param))
            else:
                param.normal_(0.0, WEIGHT_STD)
    model.eval()

    fxfycxcy = torch.tensor([SIZE, SIZE, SIZE / 2, SIZE / 2], dtype=torch.float64)
    source_c2w = torch.stack([orbit(0, 0), orbit(5, -3)])
    target_c2w = torch.stack([orbit(25, 10), orbit(-20, -15)])
    source_plucker = plucker(source_c2w, fxfycxcy, SIZE, SIZE)
    target_plucker = plucker(target_c2w, fxfycxcy, SIZE, SIZE)
    image = torch.rand(BATCH, 3, SIZE, SIZE)
    with torch.no_grad():
        render = model(image, source_plucker, target_plucker)
    spread = (render.max() - render.min()).item()
    assert spread > 0.3, f"the prediction hardly varies across pixels ({spread})"

    state = {k: v.contiguous() for k, v in model.state_dict().items()}
    # The published checkpoints also hold the perceptual loss's network; one stand-in tensor.
    state["loss_computer.perceptual.vgg.features.0.weight"] = torch.zeros(2, 3, 3, 3)
    torch.save({"model": state, "step": 0}, os.path.join(out_dir, "lvsm_tiny.pt"))
    save_file(
        {
            "source_image": image.contiguous(),
            "source_plucker": source_plucker.contiguous(),
            "target_plucker": target_plucker.contiguous(),
            "source_c2w": source_c2w.float().contiguous(),
            "target_c2w": target_c2w.float().contiguous(),
            "fxfycxcy": fxfycxcy.float().contiguous(),
            "render": render.contiguous(),
        },
        os.path.join(out_dir, "lvsm_tiny_io.safetensors"),
    )
    print(
        f"wrote {out_dir}: {sum(p.numel() for p in model.parameters())} parameters, "
        f"render range {render.min().item():.3f}..{render.max().item():.3f}"
    )


if __name__ == "__main__":
    main()
