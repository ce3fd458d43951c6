#!/usr/bin/env python3
"""How much of a 2-thread prism run one thread does alone, and in what.

    perf record -F 149 --call-graph dwarf,12288 -o perf.data prism bench \\
        --config configs/small.toml --models teacher --iters 1 --warmup 0 --train-steps 40
    perf script -i perf.data --no-inline -F tid,time,ip,sym > samples.txt
    python3 scripts/peer/serial_share.py samples.txt [--skip 0.35]

The binary keeps no frame pointers, so `perf record -g` gives unreliable stacks; DWARF
unwinding gives whole ones, and `--no-inline` keeps `perf script` to seconds.

Inside `prism_kernels::warm` rayon's idle worker loops in `sched_yield` instead of sleeping,
so it is sampled while it waits. A sample of the busy thread counts as serial when the other
worker's nearest sample (within 1 ms) is in that loop. Only the busy thread's samples with such
a neighbour can be judged (at 149 Hz about three in ten), so the share is taken of those: before
2026-12-05 it was taken of all the busy thread's samples, which understated it about 3.5-fold
(7.5% printed where 26% of the judged samples were serial). `--skip` leaves out the first part
of the run (loading, the first steps' page faults). Prints the serial share of the busy thread's
samples, by the kind of code that ran, and the leaf functions that took most of it.
"""
import argparse
import bisect
import collections

# Frames of a worker that waits for work.
WAITING = ("sched_yield", "yield_now", "__schedule", "futex")

# The kind of code a leaf function belongs to, first match wins.
KINDS = [
    (("burn_flex", "macerator"), "Burn's flex ops (element-wise, copies, reductions)"),
    (("memmove", "memcpy"), "memmove / memcpy"),
    (("memset",), "memset (zeroed buffers)"),
    (("gemm",), "gemm (products not split between the threads)"),
    (("prism_render",), "prism-render (rasteriser, triplane)"),
    (("prism_kernels",), "prism-kernels (norms, GELU, AdamW, attention)"),
    (("mi_", "alloc", "page"), "allocator and page faults"),
    (("exp", "log", "pow", "libm"), "libm"),
]


def read(path):
    """tid -> [(time, [frames, leaf first])] from `perf script -F tid,time,ip,sym`."""
    samples = collections.defaultdict(list)
    current = None
    for line in open(path):
        line = line.rstrip("\n")
        if not line.strip():
            current = None
        elif not line.startswith("\t"):
            # A sample's first line: the thread id (right-aligned, so perhaps indented) and
            # the time; its frames follow, one per line, each indented by a tab.
            tid, time = line.split()[:2]
            current = (float(time.rstrip(":")), [])
            samples[int(tid)].append(current)
        elif current is not None:
            parts = line.split(None, 1)
            current[1].append(parts[1] if len(parts) > 1 else "?")
    return samples


def waiting(frames):
    """Whether a sample's thread waits for work: a wait frame on its stack below (leafwards of)
    any rayon job it runs. With full (DWARF) stacks, a job the spinning worker picked up sits
    above its wait loop's frame, and is work."""
    for frame in frames:
        if "rayon_core::job" in frame and "execute" in frame:
            return False
        if any(w in frame for w in WAITING):
            return True
    return False


def busy_and_other(samples, path):
    """The two most sampled threads of `read`'s samples: the busy one (which waits least) and
    the other."""
    threads = sorted(samples, key=lambda t: -len(samples[t]))[:2]
    if len(threads) < 2:
        raise SystemExit(f"{path}: fewer than two threads were sampled")
    busy, other = sorted(threads, key=lambda t: sum(waiting(s[1]) for s in samples[t]))
    return busy, other


def kind(leaf):
    for needles, name in KINDS:
        if any(n in leaf for n in needles):
            return name
    return "other"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("samples")
    parser.add_argument("--skip", type=float, default=0.35,
                        help="share of the run's start to leave out (default 0.35)")
    args = parser.parse_args()
    samples = read(args.samples)
    busy, other = busy_and_other(samples, args.samples)
    start, end = samples[busy][0][0], samples[busy][-1][0]
    cut = start + args.skip * (end - start)
    other_times = [s[0] for s in samples[other]]
    total, judged, kinds, leaves = 0, 0, collections.Counter(), collections.Counter()
    for time, frames in samples[busy]:
        if time < cut or not frames:
            continue
        total += 1
        i = bisect.bisect_left(other_times, time)
        near = min((samples[other][j] for j in (i - 1, i) if 0 <= j < len(other_times)),
                   key=lambda s: abs(s[0] - time))
        if abs(near[0] - time) >= 0.001:
            continue
        judged += 1
        if waiting(near[1]) and not waiting(frames):
            kinds[kind(frames[0])] += 1
            leaves[frames[0][:100]] += 1
    serial = sum(kinds.values())
    print(f"busy thread {busy}: {total} samples, {judged} with a sample of the other thread "
          f"within 1 ms, {serial} of those while the other waited "
          f"({100 * serial / max(judged, 1):.1f}%)\n")
    print("| code | samples | share of the judged samples |\n|---|---:|---:|")
    for name, n in kinds.most_common():
        print(f"| {name} | {n} | {100 * n / max(judged, 1):.1f}% |")
    print("\nleaf functions:")
    for leaf, n in leaves.most_common(15):
        print(f"{n:7d}  {leaf}")


if __name__ == "__main__":
    main()
