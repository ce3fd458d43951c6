#!/usr/bin/env python3
"""Interleaved A/B timing of prism builds on a noisy host.

    python3 scripts/peer/ab.py ROUNDS BUILD_A BUILD_B [...] -- BENCH_ARGS

Runs `BUILD bench BENCH_ARGS --json F` for every build in turn, ROUNDS times, so that a slow
spell of the host falls on every build alike. Prints, per bench row, each build's median over
the rounds and the last build's ratio to the first (of the medians, and of the fastest runs),
then every run's time, and each build's median CPU steal (the hypervisor's share of the CPU
time while its rows were timed, `cpu_steal` of the bench JSON; builds before it have none).
Refuses builds whose files are the same bytes: two checkouts built into one target folder can
leave one commit's binary under both names (BENCHMARKS.md, issue 43's "The main job and a
clean CI on a fresh model 167 Xeon"), and timing a build against itself shows only noise.
"""
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile


def main():
    if "--" not in sys.argv or len(sys.argv) < 4:
        sys.exit(__doc__)
    split = sys.argv.index("--")
    rounds, builds, args = int(sys.argv[1]), sys.argv[2:split], sys.argv[split + 1:]
    check_distinct(builds)
    times, steal = {}, {}
    for _ in range(rounds):
        for build in builds:
            with tempfile.NamedTemporaryFile(suffix=".json") as f:
                subprocess.run([build, "bench", *args, "--json", f.name], check=True,
                               capture_output=True)
                for row in json.load(open(f.name))["rows"]:
                    times.setdefault((row["model"], row["res"]), {}).setdefault(build, []).append(row["ms"])
                    if row.get("cpu_steal") is not None:
                        steal.setdefault(build, []).append(row["cpu_steal"])
    print("| row | " + " | ".join(builds) + " | last / first (medians) | last / first (fastest) |")
    print("|---|" + "---:|" * (len(builds) + 2))
    for (model, res), runs in times.items():
        medians = [statistics.median(runs[b]) for b in builds]
        fastest = min(runs[builds[-1]]) / min(runs[builds[0]])
        print(f"| {model} {res} | " + " | ".join(f"{m:.1f}" for m in medians)
              + f" | {medians[-1] / medians[0]:.2f}x | {fastest:.2f}x |")
    for (model, res), runs in times.items():
        print(model, res, {b: [round(t, 1) for t in runs[b]] for b in builds})
    print("CPU steal (median of the rows): " + ", ".join(
        f"{b} {100 * statistics.median(steal[b]):.1f}%" if b in steal
        else f"{b} n/a" for b in builds))


def check_distinct(builds):
    """Exits naming any two builds whose files hold the same bytes."""
    seen = {}
    for build in builds:
        if not os.path.isfile(build):
            sys.exit(f"{build}: no such file (a prism binary is expected)")
        with open(build, "rb") as f:
            digest = hashlib.file_digest(f, "sha256").hexdigest()
        if digest in seen:
            sys.exit(f"{seen[digest]} and {build} are the same binary (sha256 {digest[:16]}...): "
                     "build each commit into a target folder of its own")
        seen[digest] = build


if __name__ == "__main__":
    main()
