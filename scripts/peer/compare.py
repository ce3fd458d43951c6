"""Side-by-side CPU speed of prism's backbone and the same model in PyTorch, in one run.

Runs `prism bench --config scripts/peer/backbone.toml` and `scripts/peer/torch_backbone.py`
with the same shapes one after the other (never at the same time: the timings need the
cores to themselves) and prints a Markdown table of both times and prism / PyTorch.
`gpu_compare.py` runs the same two sides on a GPU, through the functions below.

usage (from the repository root, with a Python that has torch):
    python scripts/peer/compare.py [--prism target/release/prism] [--res 128,256]
        [--backend flex] [--threads 2] [--iters 10] [--train-steps 10] [--precision bf16]
        [--rounds 5] [--json out.json]

`--rounds N` runs the two sides in turn N times (prism, PyTorch, prism, PyTorch, ...) and
prints each side's median over the rounds, their ratio, and the lowest and highest of the
rounds' own ratios. A virtual machine's cores change speed between spells of minutes, so one
run of each side, minutes apart, can compare two different machines; taking turns puts both
sides in every spell.

`--precision bf16` runs prism's blocks with `--precision bf16` and PyTorch under bf16
autocast (`torch_backbone.py --dtype bf16`). `--threads N` gives both sides N threads:
PyTorch's intra-op threads, and prism's rayon pool (`RAYON_NUM_THREADS`).

Under the table it prints each side's CPU steal: the share of the machine's CPU time the
hypervisor ran something else while that side ran (Linux's /proc/stat). A ratio measured while
one side had a few percent of steal and the other none says more about the host than the code.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
CONFIG = os.path.join(HERE, "backbone.toml")
TORCH_BACKBONE = os.path.join(HERE, "torch_backbone.py")
TRAIN_RES = 128


def backbone_shapes(config):
    """The shapes of a prism config file that torch_backbone.py takes, as its flags."""
    with open(config, "rb") as f:
        toml = tomllib.load(f)
    model, distill = toml["model"], toml["distill"]
    blocks = model["stage_one_blocks"] + model["stage_three_blocks"]
    return ["--width", str(model["width"]), "--heads", str(model["heads"]),
            "--patch", str(model["patch_size"]), "--blocks", str(blocks),
            "--group", str(distill["group_size"]), "--mlp-ratio", str(model["mlp_ratio"])]


def cpu_times():
    """(total, steal) clock ticks of all CPUs from /proc/stat's aggregate line, or None."""
    try:
        with open("/proc/stat") as f:
            fields = [int(v) for v in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    return (sum(fields), fields[7]) if len(fields) == 8 else None


def steal_since(before):
    """The share of the CPU time stolen since the `cpu_times()` reading `before`, as "x.y%"."""
    after = cpu_times()
    if before is None or after is None or after[0] <= before[0]:
        return "n/a"
    return f"{100 * (after[1] - before[1]) / (after[0] - before[0]):.1f}%"


def run_command(cmd, env=None, timeout=None, log=None):
    """Runs `cmd` to its end (killed after `timeout` seconds) and returns its stdout. Its
    stderr goes to ours, and both to the open file `log` when given. Raises
    subprocess.CalledProcessError on a non-zero exit, subprocess.TimeoutExpired on a timeout."""
    if log:
        log.write(f"$ {' '.join(cmd)}\n")
        log.flush()
    try:
        done = subprocess.run(cmd, env=env, timeout=timeout, capture_output=True, text=True)
    except subprocess.TimeoutExpired as e:
        echo(e.stderr, log)
        raise
    echo(done.stderr, log)
    if log:
        log.write(done.stdout)
        log.flush()
    if done.returncode != 0:
        raise subprocess.CalledProcessError(done.returncode, cmd, done.stdout, done.stderr)
    return done.stdout


def echo(text, log):
    """Writes a command's stderr (bytes or text, possibly None) to ours and to `log`."""
    if isinstance(text, bytes):
        text = text.decode(errors="replace")
    if text:
        sys.stderr.write(text)
        if log:
            log.write(text)
            log.flush()


def run_prism(prism, config, res, backend, warmup, iters, train_steps, extra=(), env=None,
              timeout=None, log=None):
    """`prism bench` on `config` at the resolutions `res` ("128,256"): its JSON rows by
    (model, res), the training step's as ("train_step", res). The table it prints goes to our
    stderr (and `log`)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "bench.json")
        cmd = [prism, "bench", "--config", config, "--res", res, "--backend", backend,
               "--warmup", str(warmup), "--iters", str(iters), "--train-steps",
               str(train_steps), "--json", out, *extra]
        echo(run_command(cmd, env, timeout, log), None)
        with open(out) as f:
            rows = json.load(f)["rows"]
    return {(row["model"], row["res"]): row for row in rows}


def run_torch(shapes, res, threads, warmup, iters, train_res, train_steps, extra=(),
              timeout=None, log=None):
    """torch_backbone.py with the flags `shapes` at the resolutions `res` (which must include
    `train_res` for the training step): rows {"ms", "peak_mem_bytes"?} by (model, res), the
    training step's as ("train_step", train_res)."""
    cmd = [sys.executable, TORCH_BACKBONE, *shapes, "--res", res, "--threads", str(threads),
           "--warmup", str(warmup), "--iters", str(iters), "--train", "--train-res",
           str(train_res), "--train-steps", str(train_steps), *extra]
    rows = {}
    for line in run_command(cmd, timeout=timeout, log=log).splitlines():
        row = json.loads(line)
        rows[(row["model"], row["res"])] = row
        if "train_ms" in row:
            rows[("train_step", row["res"])] = {
                "ms": row["train_ms"], "peak_mem_bytes": row.get("train_peak_mem_bytes")}
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prism", default=os.path.join("target", "release", "prism"))
    ap.add_argument("--res", default="128,256")
    ap.add_argument("--backend", default="flex")
    ap.add_argument("--threads", type=int, default=2,
                    help="both sides' threads: PyTorch's intra-op threads, and prism's rayon "
                         "pool (RAYON_NUM_THREADS)")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--train-steps", type=int, default=10,
                    help="training steps on each side (the median after 2 warm-up steps)")
    ap.add_argument("--precision", choices=["f32", "bf16"], default="f32",
                    help="both sides' precision: f32, or prism's bf16 against bf16 autocast")
    ap.add_argument("--rounds", type=int, default=1,
                    help="run the two sides in turn this many times and compare the medians")
    ap.add_argument("--json", help="also write the rows (and each round's) to this file")
    args = ap.parse_args()
    if args.rounds < 1:
        sys.exit(f"--rounds {args.rounds}: at least 1")
    if not os.path.isfile(args.prism):
        sys.exit(f"{args.prism}: no such file (build it with `cargo build --release`)")
    prism_env = {**os.environ, "RAYON_NUM_THREADS": str(args.threads)}
    rounds = []
    for r in range(args.rounds):
        if args.rounds > 1:
            print(f"round {r + 1} of {args.rounds}", file=sys.stderr)
        before = cpu_times()
        prism = run_prism(args.prism, CONFIG, args.res, args.backend, args.warmup, args.iters,
                          args.train_steps, extra=["--precision", args.precision],
                          env=prism_env)
        prism_steal, before = steal_since(before), cpu_times()
        torch_rows = run_torch(backbone_shapes(CONFIG), args.res, args.threads, args.warmup,
                               args.iters, TRAIN_RES, args.train_steps,
                               extra=["--dtype", args.precision])
        rounds.append({"prism": prism, "torch": torch_rows,
                       "cpu_steal": {"prism": prism_steal, "torch": steal_since(before)}})
    per_round = [round_rows(r) for r in rounds]
    rows = table(per_round)
    steals = [f"prism {r['cpu_steal']['prism']}, PyTorch {r['cpu_steal']['torch']}"
              for r in rounds]
    print("CPU steal: " + "; ".join(steals))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"rows": rows, "cpu_steal": rounds[-1]["cpu_steal"],
                       "rounds": [{"rows": one, "cpu_steal": r["cpu_steal"]}
                                  for one, r in zip(per_round, rounds)]}, f, indent=1)


def round_rows(one):
    """One round's rows, `{"what", "res", "prism_ms", "torch_ms", "ratio"}`, for the keys both
    sides timed, in the table's order."""
    prism, torch_rows = one["prism"], one["torch"]
    keys = sorted((k for k in prism if k in torch_rows),
                  key=lambda k: (k[0] == "train_step", k[1], k[0]))
    return [{"what": k[0], "res": k[1], "prism_ms": prism[k]["ms"],
             "torch_ms": torch_rows[k]["ms"], "ratio": prism[k]["ms"] / torch_rows[k]["ms"]}
            for k in keys]


def table(per_round):
    """Prints the Markdown table of the rounds' rows (each round's from `round_rows`) and returns
    its rows: each side's median over the rounds and their ratio; with several rounds, also the
    lowest and highest of the rounds' own ratios (`ratio_min`, `ratio_max`)."""
    several = len(per_round) > 1
    head = "| what | res | prism ms | PyTorch ms | prism / PyTorch |"
    rule = "|---|---|---|---|---|"
    if several:
        head += f" rounds' ratios ({len(per_round)}) |"
        rule += "---|"
    print(head)
    print(rule)
    # Each row's values over the rounds, by (what, res), in the first round's order.
    by_key = {}
    for one in per_round:
        for row in one:
            by_key.setdefault((row["what"], row["res"]), []).append(row)
    rows = []
    for (what, res), timed in by_key.items():
        ours = statistics.median(r["prism_ms"] for r in timed)
        theirs = statistics.median(r["torch_ms"] for r in timed)
        row = {"what": what, "res": res, "prism_ms": ours, "torch_ms": theirs,
               "ratio": ours / theirs}
        line = f"| {what} | {res} | {ours:.1f} | {theirs:.1f} | {row['ratio']:.2f}x |"
        if several:
            ratios = [r["ratio"] for r in timed]
            row["ratio_min"], row["ratio_max"] = min(ratios), max(ratios)
            line += f" {row['ratio_min']:.2f}x to {row['ratio_max']:.2f}x |"
        rows.append(row)
        print(line)
    return rows


if __name__ == "__main__":
    main()
