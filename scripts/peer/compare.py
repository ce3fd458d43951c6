"""Side-by-side CPU speed of prism's backbone and the same model in PyTorch, in one run.

Runs `prism bench --config scripts/peer/backbone.toml` and `scripts/peer/torch_backbone.py`
with the same shapes one after the other (never at the same time: the timings need the
cores to themselves) and prints a Markdown table of both times and prism / PyTorch.

usage (from the repository root, with a Python that has torch):
    python scripts/peer/compare.py [--prism target/release/prism] [--res 128,256]
        [--backend flex] [--threads 2] [--iters 10] [--train-steps 10] [--json out.json]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
CONFIG = os.path.join(HERE, "backbone.toml")
# The shapes of backbone.toml, passed to the PyTorch side.
SHAPES = ["--width", "256", "--heads", "4", "--patch", "8", "--blocks", "6", "--group", "6"]
TRAIN_RES = 128


def run_prism(args):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "bench.json")
        cmd = [args.prism, "bench", "--config", CONFIG, "--res", args.res,
               "--backend", args.backend, "--warmup", str(args.warmup),
               "--iters", str(args.iters), "--train-steps", str(args.train_steps), "--json", out]
        subprocess.run(cmd, check=True, stdout=sys.stderr)
        with open(out) as f:
            rows = json.load(f)["rows"]
    times = {}
    for row in rows:
        key = ("train_step", row["res"]) if row["model"] == "train_step" else (row["model"], row["res"])
        times[key] = row["ms"]
    return times


def run_torch(args):
    cmd = [sys.executable, os.path.join(HERE, "torch_backbone.py"), *SHAPES, "--res", args.res,
           "--threads", str(args.threads), "--warmup", str(args.warmup), "--iters",
           str(args.iters), "--train", "--train-res", str(TRAIN_RES), "--train-steps",
           str(args.train_steps)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    times = {}
    for line in out.splitlines():
        row = json.loads(line)
        times[(row["model"], row["res"])] = row["ms"]
        if "train_ms" in row:
            times[("train_step", row["res"])] = row["train_ms"]
    return times


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prism", default=os.path.join("target", "release", "prism"))
    ap.add_argument("--res", default="128,256")
    ap.add_argument("--backend", default="flex")
    ap.add_argument("--threads", type=int, default=2, help="PyTorch's intra-op threads")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--train-steps", type=int, default=10,
                    help="training steps on each side (the median after 2 warm-up steps)")
    ap.add_argument("--json", help="also write the rows to this file")
    args = ap.parse_args()
    if not os.path.isfile(args.prism):
        sys.exit(f"{args.prism}: no such file (build it with `cargo build --release`)")
    prism = run_prism(args)
    torch_times = run_torch(args)
    rows = []
    print("| what | res | prism ms | PyTorch ms | prism / PyTorch |")
    print("|---|---|---|---|---|")
    for key in sorted(prism, key=lambda k: (k[0] == "train_step", k[1], k[0])):
        if key not in torch_times:
            continue
        ours, theirs = prism[key], torch_times[key]
        rows.append({"what": key[0], "res": key[1], "prism_ms": ours, "torch_ms": theirs,
                     "ratio": ours / theirs})
        print(f"| {key[0]} | {key[1]} | {ours:.1f} | {theirs:.1f} | {ours / theirs:.2f}x |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
