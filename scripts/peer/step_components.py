#!/usr/bin/env python3
"""Where a training step's wall time goes, by part of the model, from perf's call stacks.

    perf record -F 149 --call-graph dwarf,12288 -o perf.data prism bench \\
        --config configs/small.toml --models teacher --res 128 --iters 1 --warmup 0 \\
        --train-steps 40
    perf script -i perf.data --no-inline -F tid,time,ip,sym > stacks.txt
    python3 scripts/peer/step_components.py stacks.txt [--skip 0.3]

The binary has no frame pointers, so the stacks come from DWARF unwinding; `--no-inline` keeps
`perf script` to seconds (without it, its inline lookups ran for more than ten minutes).

The busy thread runs the step and never sleeps: while the other worker helps with a parallel
kernel, the busy thread works on its own share, and while the other waits, the busy thread is
the serial part. So its samples, counted by the part of the model on its stack, split the wall
time. A forward sample is named by the model code on its stack, a reverse-pass sample by the
autodiff step it is in. Stacks cut short by the unwinding's 12 KiB land in "unknown".
"""
import argparse
import collections
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from serial_share import busy_and_other, read  # noqa: E402

# Forward-pass parts, by a frame on the stack; the first match wins.
FORWARD = [
    ("forward: LPIPS loss", "lpips"),
    ("forward: point branch's splatting", "PointBranch::forward"),
    ("forward: point branch's DPT head", "DptHead"),
    ("forward: SMPL-X branch", "smplx"),
    ("forward: triplane sampling", "triplane"),
    ("forward: 3DGS head", "GaussianHead"),
    ("forward: splatting (3DGS head, or a point branch stack cut short)", "splat::"),
    ("forward: injection", "Injection"),
    ("forward: tokenizer", "Tokenizer"),
    ("forward: tokenizer", "patchify"),
    ("forward: transformer blocks", "PrismBlock"),
    ("forward: transformer blocks", "stages::"),
    ("forward: other losses", "prism_losses"),
    ("forward: batching", "prism_data"),
    ("forward: other model code", "prism_model"),
]

# Reverse-pass parts, by the autodiff step on the stack.
BACKWARD = [
    ("backward: attention", "SelfAttentionBackward"),
    ("backward: linear layers (matmul)", "MatmulBackward"),
    ("backward: convolutions (LPIPS, DPT)", "ConvBackward"),
    ("backward: splatting", "SplatBackward"),
    ("backward: triplane sampling", "TriplaneBackward"),
    ("backward: norms", "NormBackward"),
    ("backward: GELU", "gelu"),
    ("backward: reshapes (contiguous copies)", "ReshapeDim"),
    ("backward: slices", "float_slice"),
    ("backward: selects", "Select"),
]


def component(frames):
    if any("adamw" in f or "step_dyn" in f for f in frames):
        return "optimizer"
    if any("clip::" in f for f in frames):
        return "gradient clipping"
    if any("backward_impl" in f or "AutodiffServer::execute_steps" in f for f in frames):
        for name, needle in BACKWARD:
            if any(needle in f for f in frames):
                return name
        ops = [re.search(r"::(float_\w+)::", f) for f in frames if "burn_autodiff::ops" in f]
        ops = [m.group(1) for m in ops if m]
        return "backward: other Burn ops" + (f" ({ops[0]} ...)" if ops else "")
    for name, needle in FORWARD:
        if any(needle in f for f in frames):
            return name
    return "unknown (stack cut short)"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("stacks")
    parser.add_argument("--skip", type=float, default=0.3,
                        help="share of the run's start to leave out (default 0.3: loading, "
                             "the forward rows, the first steps' page faults)")
    parser.add_argument("--rows", type=int, default=25, help="table rows to print")
    args = parser.parse_args()
    samples = read(args.stacks)
    busy, _ = busy_and_other(samples, args.stacks)
    start, end = samples[busy][0][0], samples[busy][-1][0]
    cut = start + args.skip * (end - start)
    parts = collections.Counter(
        component(frames) for time, frames in samples[busy] if time >= cut and frames)
    total = sum(parts.values())
    print(f"busy thread {busy}: {total} samples over {end - cut:.1f} s\n")
    print("| part of the step | samples | share of the wall time |\n|---|---:|---:|")
    for name, n in parts.most_common(args.rows):
        print(f"| {name} | {n} | {100 * n / total:.1f}% |")


if __name__ == "__main__":
    main()
