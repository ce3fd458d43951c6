"""prism beside the same model in PyTorch on one NVIDIA GPU, in one command (issues 35 and 45).

For a machine with the GPU, its driver and PyTorch, but no Rust toolchain and no network:

1. Unpacks the pack of scripts/peer/pack_for_gpu.sh (`prism.tar.xz`: prism's stripped release
   binary built with `--features vulkan`, kernels in SPIR-V, and the default build's,
   `prism-wgsl`, kernels in WGSL; the Vulkan loader's Debian packages) and points the Vulkan
   loader at the NVIDIA driver's ICD (printing what it found). A first short run of the SPIR-V
   build (the teacher's forward pass at 64 px) checks that it runs on the card; should it fail
   (it crashes on lavapipe), every later stage runs the WGSL build instead, and the report
   says so.
2. Times the PyTorch model (torch_backbone.py: `F.scaled_dot_product_attention`) at the paper
   backbone's shapes (width 768, 12 heads, 12 + 24 blocks, patch 8, no geometry parts) with
   bf16 autocast, TF32 and f32.
3. Times `prism bench --backend wgpu` on the same model through each attention path
   (`PRISM_ATTENTION`): `burn`, Burn's attention op (for training Burn decomposes it into
   matmul, softmax, matmul, the `unfused` path, so that path's training step is not timed
   twice); `unfused`, prism's matmul-softmax-matmul; `flash`, prism's flash kernels; each with
   the blocks in f32, f16 and bf16: the teacher's forward pass of one pair at 512 px (and the
   student's and the all-linear model's once per precision, on the `burn` path: linear
   attention takes none of the paths) and the teacher's training step at 256 px, median ms and
   peak memory.
4. Runs the paper config (`configs/paper.toml`, geometry included) through the flash kernels:
   the teacher's and the student's FPS at 512 px, and the teacher's training step at its own
   resolution, 512 px, one (source, target) pair per step, with its peak memory: the paper's
   model must train at 512 px on one 80 GB card (stored scores alone would take about 116 GB).
   Of the bench stages, only its training step runs the 3DGS renderer's backward kernel,
   which crashes through SPIR-V on Mesa 22.3's lavapipe once CubeCL's shared-memory bug is
   patched (a driver bug; BENCHMARKS): a run that fails on the SPIR-V build is repeated on the
   WGSL build.
5. Times the WGSL build on Burn's attention path in the first precision (its forward rows and
   its training step), beside the SPIR-V build's rows: which compiler is faster on the card.
6. Runs `prism tune attention` on wgpu at the backbone's training shapes (in the first
   precision): a block's attention through each kernel, with and without a gradient, and the
   memory it keeps for the backward pass; the kernels it finds fastest are what prism would
   take on this card once tuned (recorded in a cache folder of its own, so the other stages
   run the default). The dry run tunes on whatever wgpu adapter the machine has (lavapipe).
7. Optionally, `prism quickstart --backend wgpu`, timed, with its phase table.

The report names the commit the pack's binary was built from (the pack's build.json), and a
warning is printed when the repository it runs in is at another commit.

It writes the tables to OUT/gpu_compare.md, everything to OUT/gpu_compare.json and the
commands' output to OUT/log.txt. The stages run one after the other (never two at once: they
share the card), most wanted first (PyTorch bf16, the SPIR-V check, the paths in the first
precision, the paper config, the tune stage, the WGSL build, the other precisions, PyTorch
TF32 and f32, the quick start), each within what is left of --budget seconds (450 by default,
so that the whole command ends within 8 minutes); one stopped at the budget or failing is
reported and the next goes on. --dry-run does the same on the CPU at tiny shapes (PyTorch on
the CPU, prism on flex, where every path runs prism's fused CPU kernel) to check the whole flow
on a machine without a GPU.

usage (from the repository root):
    python3 scripts/peer/gpu_compare.py --pack gpu-pack --out OUT [--budget 450]
        [--paths burn,unfused,flash] [--precisions f32,f16,bf16] [--paper-precisions f32]
        [--no-paper] [--no-quickstart] [--iters 3] [--warmup 1] [--prism FILE] [--dry-run]
"""
import argparse
import dataclasses
import datetime
import glob
import importlib.metadata
import json
import lzma
import os
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from compare import CONFIG, backbone_shapes, run_command, run_prism, run_torch  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PAPER_CONFIG = os.path.join(REPO, "configs", "paper.toml")
LPIPS_WEIGHTS = os.path.join(REPO, "data", "lpips_alex.safetensors")
# Where NVIDIA's driver installs its Vulkan ICD manifest.
ICD_DIRS = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d",
            "/usr/local/nvidia/share/vulkan/icd.d", "/usr/local/nvidia/icd.d"]
# Where a driver library named without a folder may lie besides the loader's cache.
DRIVER_LIB_DIRS = ["/usr/local/nvidia/lib64", "/usr/local/nvidia/lib",
                   "/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib"]
# The paper's A6000 figures, the targets of the paper config's rows.
PAPER_FPS = {"teacher": 8.8, "student": 24.0}
# PyTorch's precisions; the first, the reference of the ratios, is timed first.
TORCH_DTYPES = ["bf16", "tf32", "f32"]
# prism's attention paths (`PRISM_ATTENTION`), as the tables name them.
PATHS = {"burn": "Burn's attention op", "unfused": "prism unfused", "flash": "prism flash"}
# The pack's binaries by the compiler their kernels go through on a Vulkan adapter.
BUILDS = {"SPIR-V": "prism", "WGSL": "prism-wgsl"}
MIB = 1024 * 1024
# The card the paper config must train on at 512 px.
TARGET_CARD_BYTES = 80 * 1000 ** 3


@dataclasses.dataclass
class Plan:
    """What a run measures: the device, the shapes and the optional stages' arguments."""
    device: str            # PyTorch's device
    backend: str           # prism's backend
    forward_res: int       # forward rows' resolution
    train_res: int         # training step's resolution
    data_res: int          # resolution of the synthetic dataset the training step reads
    width: int
    heads: int
    stage_one: int
    stage_three: int
    group: int
    paper_res: int         # the paper config's rows' resolution (forward and training)
    quickstart: list       # arguments of `prism quickstart` besides --backend and --out
    budget: float          # default seconds for the whole run


GPU = Plan("cuda", "wgpu", 512, 256, 128, 768, 12, 12, 24, 6, 512, [], 450)
DRY = Plan("cpu", "flex", 64, 32, 32, 64, 2, 2, 4, 3, 64,
           ["--fast", "--teacher-steps", "2", "--student-steps", "2", "--eval-views", "2"], 900)


class Budget:
    """The seconds left of the whole run."""

    def __init__(self, seconds):
        self.end = time.monotonic() + seconds

    def left(self):
        return self.end - time.monotonic()


class Run:
    """The results, the log file and the budget of one run; `stage` runs each part."""

    def __init__(self, out, budget):
        self.out = out
        self.log = open(os.path.join(out, "log.txt"), "w")
        self.budget = budget
        self.stages = []

    def stage(self, name, fn, least=10):
        """Runs `fn(seconds_left)`, returning its result, or None when it failed, ran past the
        budget, or fewer than `least` seconds were left; records its time and outcome."""
        left = self.budget.left()
        record = {"stage": name, "seconds": 0.0, "error": None}
        self.stages.append(record)
        if left < least:
            record["error"] = f"skipped: {max(left, 0):.0f} s of the budget left"
            say(f"== {name}: {record['error']}")
            return None
        say(f"== {name} ({left:.0f} s of the budget left)")
        start = time.monotonic()
        try:
            return fn(left)
        except subprocess.TimeoutExpired:
            record["error"] = f"stopped at the budget, after {left:.0f} s"
        except subprocess.CalledProcessError as e:
            tail = (e.stderr or "").strip().splitlines()[-1:] or [""]
            record["error"] = f"{exit_reason(e.returncode)}: {tail[0]}".rstrip(": ")
        except (OSError, ValueError, KeyError) as e:
            record["error"] = f"{type(e).__name__}: {e}"
        finally:
            record["seconds"] = round(time.monotonic() - start, 1)
            if record["error"]:
                say(f"== {name}: {record['error']}")
        return None


def exit_reason(returncode):
    """A failed command's exit status in words: `exit status 1`, or the signal that killed it
    (`killed by SIGSEGV`)."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exit status {returncode}"


def say(text):
    print(text, file=sys.stderr, flush=True)


def set_keys(text, values, source):
    """`text` (a TOML file's) with the `key = value` lines of `values` ({section: {key: value}})
    replaced; every key must be present in its section of `source`."""
    section, lines, done = None, [], set()
    for line in text.splitlines():
        header = re.match(r"\s*\[(\w+)\]", line)
        key = re.match(r"(\w+)\s*=", line)
        if header:
            section = header.group(1)
        elif key and key.group(1) in values.get(section, {}):
            line = f"{key.group(1)} = {values[section][key.group(1)]}"
            done.add((section, key.group(1)))
        lines.append(line)
    missing = [f"[{s}] {k}" for s, keys in values.items() for k in keys if (s, k) not in done]
    if missing:
        raise ValueError(f"{source}: no line for {', '.join(missing)}")
    return "\n".join(lines) + "\n"


def backbone_config(plan, path):
    """Writes backbone.toml at the plan's shapes to `path`: the model at the training step's
    resolution (the forward rows take theirs from --res), a small synthetic dataset (4
    people, 1 held out) and one validation view."""
    with open(CONFIG) as f:
        text = f.read()
    values = {
        "model": {"width": plan.width, "heads": plan.heads, "stage_one_blocks": plan.stage_one,
                  "stage_three_blocks": plan.stage_three, "resolution": plan.train_res},
        "distill": {"group_size": plan.group},
        "train": {"validation_views": 1},
        "data": {"subjects": 4, "test_fraction": 0.25, "resolution": plan.data_res},
    }
    header = f"# Written by gpu_compare.py from {os.path.basename(CONFIG)}: {values}\n"
    with open(path, "w") as f:
        f.write(header + set_keys(text, values, CONFIG))
    return path


def paper_config(plan, path):
    """Writes the paper config to `path` with its training step cut to what the memory figure
    needs: one (source, target) pair per step (the scores a pair would store, 12 heads x 36
    blocks x 8192^2 floats, are the 116 GB), at plan.paper_res, on a synthetic dataset of
    two people (one held out) rendered without supersampling (its speed, not its looks,
    matters here), one validation view."""
    with open(PAPER_CONFIG) as f:
        text = f.read()
    values = {
        "model": {"resolution": plan.paper_res},
        "train": {"batch_size": 1, "targets_per_sample": 1, "validation_views": 1,
                  "data_workers": 2},
        "data": {"subjects": 2, "test_fraction": 0.5, "resolution": plan.paper_res,
                 "supersample": 1},
    }
    header = f"# Written by gpu_compare.py from {os.path.basename(PAPER_CONFIG)}: {values}\n"
    with open(path, "w") as f:
        f.write(header + set_keys(text, values, PAPER_CONFIG))
    return path


def unpack_prism(pack, work):
    """The pack's binaries (`prism.tar.xz`), extracted into `work`: {compiler: path}."""
    packed = os.path.join(pack, "prism.tar.xz")
    if not os.path.isfile(packed):
        raise SystemExit(f"{packed}: no such file (make the pack with "
                         "scripts/peer/pack_for_gpu.sh, or pass --prism)")
    with lzma.open(packed) as src, tarfile.open(fileobj=src, mode="r|") as tar:
        tar.extractall(work, filter="data")
    binaries = {}
    for build, name in BUILDS.items():
        binaries[build] = os.path.join(work, name)
        if not os.path.isfile(binaries[build]):
            raise SystemExit(f"{packed}: no {name} in it (make the pack again with "
                             "scripts/peer/pack_for_gpu.sh)")
        say(f"prism: {name} ({build}) unpacked to {binaries[build]} "
            f"({os.path.getsize(binaries[build]) / MIB:.0f} MiB)")
    return binaries


def check_build(run, plan, binaries, config, env):
    """The build the prism stages run: the SPIR-V one when a first short run of it (the
    teacher's forward pass at 64 px) succeeds, else the WGSL one. Returns (build, failure):
    how the SPIR-V build's run failed, or None."""
    if "WGSL" not in binaries:
        return next(iter(binaries)), None
    rows = run.stage("prism SPIR-V build, first run", lambda left: run_prism(
        binaries["SPIR-V"], config, "64", plan.backend, 0, 1, 0, ["--models", "teacher"], env,
        timeout=min(left, 180), log=run.log))
    if rows is not None:
        return "SPIR-V", None
    failure = run.stages[-1]["error"]
    say(f"prism: the SPIR-V build failed its first run ({failure}): the WGSL build takes over")
    return "WGSL", failure


def describe_compiler(build, failure):
    """One sentence naming the build prism's stages ran, for the report."""
    if failure:
        return (f"prism's stages ran the WGSL build: the SPIR-V build failed its first run "
                f"({failure})")
    if build == "SPIR-V":
        return "prism's stages ran the SPIR-V build, but for the rows marked WGSL"
    return "prism's stages ran the binary passed with --prism"


def pack_build(pack, prism_arg):
    """What the pack's binary was built from, as pack_for_gpu.sh wrote it (`build.json`: the
    commit, whether the tree had uncommitted changes, the build and the date), or a note
    saying it is not known (a binary passed with --prism, or a pack without the file).
    Printed, with a warning when the repository here is at another commit."""
    if prism_arg:
        build = {"note": f"--prism {prism_arg}: not from a pack, commit not known"}
    else:
        try:
            with open(os.path.join(pack, "build.json")) as f:
                build = json.load(f)
        except (OSError, ValueError) as e:
            build = {"note": f"{pack}/build.json not readable ({e}): commit not known"}
    say(f"prism: {describe_build(build)}")
    try:
        head = subprocess.run(["git", "-C", REPO, "rev-parse", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return build
    if build.get("commit") and build["commit"] != head:
        say(f"WARNING: the pack was built from {build['commit'][:12]}, the repository here is at "
            f"{head[:12]}: run scripts/peer/pack_for_gpu.sh again")
    return build


def describe_build(build):
    """One line naming the binary's commit and build, for the log and the report."""
    if "commit" not in build:
        return build.get("note", "commit not known")
    dirty = " with uncommitted changes" if build.get("dirty") else ""
    return (f"built from commit {build['commit'][:12]}{dirty}, {build.get('build', '?')}, "
            f"{build.get('date', '?')}")


def known_libraries():
    """The loader cache's library names and paths (`ldconfig -p`), empty without ldconfig."""
    try:
        listing = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    except OSError:
        return {}
    found = {}
    for line in listing.splitlines():
        m = re.match(r"\s*(\S+) .*=> (\S+)", line)
        if m:
            found.setdefault(m.group(1), m.group(2))
    return found


def extract_debs(pack, work):
    """Extracts the pack's .deb files (dpkg-deb -x) into work/vulkan; returns the folders
    that hold their shared libraries."""
    debs = sorted(glob.glob(os.path.join(pack, "*.deb")))
    if not debs:
        return []
    if not shutil.which("dpkg-deb"):
        say(f"vulkan: no dpkg-deb here to unpack {', '.join(debs)}: using the system's loader")
        return []
    root = os.path.join(work, "vulkan")
    for deb in debs:
        subprocess.run(["dpkg-deb", "-x", deb, root], check=True)
        say(f"vulkan: extracted {os.path.basename(deb)}")
    dirs = sorted({os.path.dirname(p) for p in glob.glob(os.path.join(root, "**", "lib*.so*"),
                                                         recursive=True)})
    return dirs


def find_icd():
    """The NVIDIA Vulkan ICD manifests in the usual folders."""
    return sorted(p for d in ICD_DIRS for p in glob.glob(os.path.join(d, "nvidia*.json")))


def resolve_driver(name, cache):
    """The path of the ICD's library `name` (absolute, in the loader cache, or in one of
    DRIVER_LIB_DIRS), or None."""
    if os.path.isabs(name):
        return name if os.path.exists(name) else None
    if name in cache:
        return cache[name]
    for d in DRIVER_LIB_DIRS:
        if os.path.exists(os.path.join(d, name)):
            return os.path.join(d, name)
    return None


def vulkan_env(pack, work):
    """The environment of prism's GPU runs: the pack's Vulkan loader on LD_LIBRARY_PATH, the
    NVIDIA ICD in VK_ICD_FILENAMES / VK_DRIVER_FILES, the driver library's folder on the path
    when the loader cache lacks it. Returns (env, notes): what was found, also printed."""
    env = dict(os.environ)
    env.setdefault("XDG_RUNTIME_DIR", tempfile.gettempdir())
    notes = {}
    cache = known_libraries()
    lib_dirs = extract_debs(pack, work)
    notes["system_loader"] = cache.get("libvulkan.so.1")
    notes["pack_library_dirs"] = lib_dirs
    icds = find_icd()
    notes["icd_manifests"] = icds
    if icds:
        env["VK_ICD_FILENAMES"] = env["VK_DRIVER_FILES"] = icds[0]
        with open(icds[0]) as f:
            library = json.load(f).get("ICD", {}).get("library_path", "")
        path = resolve_driver(library, cache)
        notes["icd_library"] = {"name": library, "path": path}
        if path and library not in cache and os.path.dirname(path) not in lib_dirs:
            lib_dirs.append(os.path.dirname(path))
    if lib_dirs:
        env["LD_LIBRARY_PATH"] = ":".join(lib_dirs + [env.get("LD_LIBRARY_PATH", "")]).rstrip(":")
    notes["missing_driver_dependencies"] = missing_dependencies(
        notes.get("icd_library", {}).get("path"), env)
    say("vulkan: loader " + (f"from the pack ({', '.join(lib_dirs)})" if lib_dirs else
                             f"of the system ({notes['system_loader']})"
                             if notes["system_loader"] else "NOT FOUND (no .deb in the pack)"))
    say("vulkan: ICD " + (f"{icds[0]} -> {notes['icd_library']}" if icds else
                          f"NOT FOUND under {', '.join(ICD_DIRS)}"))
    if notes["missing_driver_dependencies"]:
        say(f"vulkan: the driver library lacks {notes['missing_driver_dependencies']}")
    return env, notes


def missing_dependencies(library, env):
    """The shared libraries `ldd` cannot find for `library` in `env` (empty without one)."""
    if not library or not shutil.which("ldd"):
        return []
    listing = subprocess.run(["ldd", library], env=env, capture_output=True, text=True).stdout
    return [line.split()[0] for line in listing.splitlines() if "not found" in line]


def gpu_name():
    """The card, its driver and memory as nvidia-smi reports them, or None without one."""
    if not shutil.which("nvidia-smi"):
        return None
    query = ["nvidia-smi", "--query-gpu=name,driver_version,memory.total",
             "--format=csv,noheader"]
    return subprocess.run(query, capture_output=True, text=True).stdout.strip() or None


def measure_torch(run, plan, args, shapes, dtypes):
    """The PyTorch rows of `dtypes`: {dtype: {(model, res): row}}."""
    threads = os.cpu_count() if plan.device == "cuda" else 2
    results = {}
    for dtype in dtypes:
        rows = run.stage(f"PyTorch {plan.device} {dtype}", lambda left, d=dtype: run_torch(
            shapes, f"{plan.forward_res},{plan.train_res}", threads, args.warmup, args.iters,
            plan.train_res, args.train_steps, ["--device", plan.device, "--dtype", d],
            timeout=left, log=run.log))
        results[dtype] = rows or {}
    return results


def with_path(env, path):
    """`env` with PRISM_ATTENTION set to `path`."""
    return dict(env, PRISM_ATTENTION=path)


def measure_prism(run, plan, args, build, prism, config, env, precision, paths):
    """The rows of the prism binary `prism` (of the compiler `build`) with the blocks in
    `precision`, one `prism bench` per attention path of `paths`:
    {"build path precision": {(model, res): row}}. The teacher's forward pass on every path,
    the student and the all-linear model on `burn`'s; the training step on every path but
    `burn`'s (which trains through `unfused`'s ops) unless `burn` is the only one."""
    results = {}
    for path in paths:
        models = "teacher,student,linear" if path == "burn" else "teacher"
        train = 0 if path == "burn" and len(paths) > 1 else args.train_steps
        extra = ["--models", models, "--precision", precision]
        rows = run.stage(f"prism {build} {plan.backend} {path} {precision}",
                         lambda left, e=extra, t=train, p=path: run_prism(
                             prism, config, str(plan.forward_res), plan.backend, args.warmup,
                             args.iters, t, e, with_path(env, p), timeout=left, log=run.log))
        results[f"{build} {path} {precision}"] = rows or {}
    return results


def measure_paper(run, plan, args, build, binaries, config, env):
    """The paper config through the flash kernels, per precision of --paper-precisions: the
    teacher's and the student's forward pass and the teacher's training step, all at
    plan.paper_res: {"precision build": {(model, res): row}}. Of the bench stages, only this
    one runs the 3DGS renderer's backward kernel, which crashes through SPIR-V on Mesa 22.3's
    lavapipe (a driver bug; BENCHMARKS): a precision that fails on the SPIR-V build is run again
    on the WGSL build (a run stopped at the budget leaves too little for it, and the repeat is
    skipped)."""
    results = {}
    for precision in args.paper_precisions.split(","):
        extra = ["--models", "teacher,student", "--precision", precision]
        for name in [build, "WGSL"] if build == "SPIR-V" else [build]:
            rows = run.stage(f"paper config, prism {name} {plan.backend} flash {precision}",
                             lambda left, e=extra, b=binaries[name]: run_prism(
                                 b, config, str(plan.paper_res), plan.backend, args.warmup,
                                 args.iters, args.paper_train_steps, e,
                                 with_path(env, "flash"), timeout=left, log=run.log), least=30)
            results[f"{precision} {name}"] = rows or {}
            if rows is not None:
                break
    return results


def measure_tune(run, plan, args, prism, config, env, precision, work):
    """`prism tune attention` on wgpu (a GPU's, or lavapipe in a dry run) at the backbone's
    training shapes in `precision`, recorded in a cache folder of its own: the record it
    writes (each kernel's ms, the bytes it keeps for the backward pass, the fastest of each),
    or None when it did not finish."""
    cache = os.path.join(work, "tune-cache")
    cmd = [prism, "tune", "attention", "--backend", "wgpu", "--config", config,
           "--res", str(plan.train_res), "--precision", precision,
           "--warmup", str(args.warmup), "--iters", str(max(args.iters, 5))]

    def go(left):
        run_command(cmd, dict(env, PRISM_CACHE_DIR=cache), left, run.log)
        records = glob.glob(os.path.join(cache, "attention", "*.json"))
        if len(records) != 1:
            raise ValueError(f"{len(records)} records in {cache}/attention")
        with open(records[0]) as f:
            return dict(json.load(f), command=" ".join(cmd))

    return run.stage(f"prism tune attention {precision}", go)


def measure_quickstart(run, plan, prism, env, work):
    """`prism quickstart` on the plan's backend, timed: its wall seconds, its tables and its
    phase timings (OUT/quickstart_phases.json), or None when it did not finish."""
    out = os.path.join(work, "quickstart")
    cmd = [prism, "quickstart", "--backend", plan.backend, "--quiet", "--out", out,
           *plan.quickstart]

    def go(left):
        start = time.monotonic()
        tables = run_command(cmd, env, left, run.log)
        seconds = time.monotonic() - start
        with open(os.path.join(out, "phases.json")) as f:
            phases = json.load(f)
        shutil.copy(os.path.join(out, "phases.json"),
                    os.path.join(run.out, "quickstart_phases.json"))
        return {"command": " ".join(cmd), "wall_seconds": seconds, "tables": tables,
                "phases": phases}

    return run.stage(f"prism quickstart --backend {plan.backend}", go, least=60)


def cell(row, key, scale=1.0, digits=1):
    value = (row or {}).get(key)
    return "-" if value is None else f"{value / scale:.{digits}f}"


def ratio(row, base, key="ms"):
    """`row`'s `key` over `base`'s, as `1.23x`, or `-`."""
    ours, theirs = (row or {}).get(key), (base or {}).get(key)
    return f"{ours / theirs:.2f}x" if ours and theirs else "-"


def torch_table(plan, torch_rows):
    """Markdown table of the PyTorch rows: median ms and peak memory."""
    f, t = plan.forward_res, plan.train_res
    lines = [f"| PyTorch | teacher {f} px ms | student {f} px ms | all-linear {f} px ms | "
             f"training step {t} px ms | training peak MiB |", "|---|" + "---:|" * 5]
    for dtype, rows in torch_rows.items():
        step = rows.get(("train_step", t))
        lines.append(f"| {dtype} | " + " | ".join(
            [cell(rows.get((m, f)), "ms") for m in ("teacher", "student", "linear")]
            + [cell(step, "ms"), cell(step, "peak_mem_bytes", MIB, 0)]) + " |")
    return "\n".join(lines) + "\n"


def prism_table(plan, torch_rows, prism_rows):
    """Markdown table of prism's rows, one per (build, attention path, block precision): median
    ms, the ratio to PyTorch bf16, and peak memory (the memory pools' reservation)."""
    f, t = plan.forward_res, plan.train_res
    base = torch_rows.get("bf16", {})
    lines = [f"| kernels | attention | blocks | teacher {f} px ms | / PyTorch bf16 | "
             f"student {f} px ms | all-linear {f} px ms | forward peak MiB | "
             f"training step {t} px ms | "
             "/ PyTorch bf16 | training peak MiB |", "|---|---|---|" + "---:|" * 8]
    for name, rows in prism_rows.items():
        build, path, precision = name.split(" ")
        teacher, step = rows.get(("teacher", f)), rows.get(("train_step", t))
        lines.append(f"| {build} | {PATHS[path]} | {precision} | " + " | ".join([
            cell(teacher, "ms"), ratio(teacher, base.get(("teacher", f))),
            cell(rows.get(("student", f)), "ms"), cell(rows.get(("linear", f)), "ms"),
            cell(teacher, "peak_mem_bytes", MIB, 0), cell(step, "ms"),
            ratio(step, base.get(("train_step", t))),
            cell(step, "peak_mem_bytes", MIB, 0)]) + " |")
    return ("\n".join(lines) + "\n\nPeak memory: PyTorch's `torch.cuda.max_memory_allocated()`; "
            "prism's `peak_mem` (on a GPU its memory pools' reservation over the run, an upper "
            "bound of what is in use; on the CPU the heap's peak). `burn`'s training step is "
            "`unfused`'s (Burn decomposes its op under autodiff).\n")


def paper_table(plan, paper_rows):
    """Markdown table of the paper config through the flash kernels: the FPS beside the
    paper's A6000 figures, and the training step's time and peak memory."""
    res = plan.paper_res
    lines = [f"| paper config, flash attention, blocks in | kernels | teacher {res} px FPS | "
             f"student {res} px FPS | training step {res} px s | training peak GiB | "
             "fits 80 GB |", "|---|---|" + "---:|" * 5]
    for name, rows in paper_rows.items():
        precision, build = name.split(" ")
        step = rows.get(("train_step", res)) or {}
        peak = step.get("peak_mem_bytes")
        fits = "-" if peak is None else ("yes" if peak <= TARGET_CARD_BYTES else "no")
        lines.append(f"| {precision} | {build} | " + " | ".join([
            cell(rows.get(("teacher", res)), "fps", digits=2),
            cell(rows.get(("student", res)), "fps", digits=2),
            cell(step, "ms", 1000, 2), cell(step, "peak_mem_bytes", 1024 ** 3, 1), fits])
            + " |")
    targets = ", ".join(f"{m} {fps} FPS" for m, fps in PAPER_FPS.items())
    return ("\n".join(lines) + f"\n\nThe paper (A6000): {targets}. The training step is one "
            "(source, target) pair (geometry, 3DGS and LPIPS included, AdamW); its peak is "
            "prism's `peak_mem` over the whole short run (on a GPU the memory pools' "
            "reservation).\n")


def tune_table(record):
    """Markdown table of `prism tune attention`'s record: each kernel's ms and the memory it
    keeps for the backward pass, and the choice."""
    shape = record["shape"]
    lines = [f"`prism tune attention` on {record['adapter']['name']}: {shape['batch']} pair x "
             f"{shape['heads']} heads x {shape['tokens']} tokens x head width "
             f"{shape['head_dim']}, {shape['precision']}.\n",
             "| mode | kernel | ms | kept for the gradient MiB |", "|---|---|---:|---:|"]
    for mode in ("inference", "training"):
        for time in record[mode]:
            lines.append(f"| {mode} | {PATHS.get(time['kernel'], time['kernel'])} | "
                         f"{time['ms']:.3f} | {cell(time, 'kept_bytes', MIB, 2)} |")
    choice = record["choice"]
    return ("\n".join(lines) + f"\n\nFastest: inference {choice['inference']}, training "
            f"{choice['training']}.\n")


def json_rows(results):
    """{(model, res): row} maps as lists, for the JSON file."""
    return {name: [dict(row, model=k[0], res=k[1]) for k, row in rows.items()]
            for name, rows in results.items()}


def report(run, plan, context, torch_rows, prism_rows, paper_rows, tune, quickstart):
    """Prints the Markdown report and writes it and the JSON into the output folder."""
    parts = [f"# prism and PyTorch on {context['gpu'] or plan.device} ({context['date']})\n",
             f"Command: `{context['command']}`. Backbone: width {plan.width}, {plan.heads} "
             f"heads, {plan.stage_one} + {plan.stage_three} blocks, patch 8, no geometry "
             f"parts; PyTorch {context['torch']}; prism {describe_build(context['build'])}. "
             f"{describe_compiler(context['compiler'], context['spirv_failure'])}.\n",
             torch_table(plan, torch_rows), prism_table(plan, torch_rows, prism_rows)]
    if paper_rows is not None:
        parts.append(paper_table(plan, paper_rows))
    if tune:
        parts.append(tune_table(tune))
    if quickstart:
        parts.append(f"`{quickstart['command']}`: {quickstart['wall_seconds']:.0f} s\n\n"
                     f"```\n{quickstart['tables'].strip()}\n```\n")
    stages = ["| stage | s | outcome |", "|---|---:|---|"]
    stages += [f"| {s['stage']} | {s['seconds']} | {s['error'] or 'ok'} |" for s in run.stages]
    parts.append("\n".join(stages) + "\n")
    markdown = "\n".join(parts)
    print(markdown)
    with open(os.path.join(run.out, "gpu_compare.md"), "w") as f:
        f.write(markdown)
    data = dict(context, plan=dataclasses.asdict(plan), torch=json_rows(torch_rows),
                prism=json_rows(prism_rows), paper=json_rows(paper_rows or {}), tune=tune,
                quickstart=quickstart, stages=run.stages)
    with open(os.path.join(run.out, "gpu_compare.json"), "w") as f:
        json.dump(data, f, indent=1)
    say(f"wrote {run.out}/gpu_compare.md, gpu_compare.json, log.txt")


def torch_version():
    """The installed PyTorch's version; exits with a clear message without one."""
    try:
        return importlib.metadata.version("torch")
    except importlib.metadata.PackageNotFoundError:
        raise SystemExit(f"{sys.executable} has no PyTorch: run this script with a Python "
                         "that has it") from None


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pack", default="gpu-pack",
                    help="folder of prism.tar.xz and the Vulkan loader's .deb files")
    ap.add_argument("--prism", help="a prism binary to use instead of the pack's (the WGSL "
                    "build's stage is then skipped)")
    ap.add_argument("--out", default=os.path.join("runs", "gpu-compare"),
                    help="folder of gpu_compare.md, gpu_compare.json and log.txt")
    ap.add_argument("--budget", type=float,
                    help="seconds for everything [default: 450; 900 with --dry-run]")
    ap.add_argument("--warmup", type=int, default=1, help="untimed runs before timing")
    ap.add_argument("--iters", type=int, default=3, help="timed runs (the median is reported)")
    ap.add_argument("--train-steps", type=int, default=4,
                    help="training steps on each side (the median of those after 2 warm-up "
                    "steps)")
    ap.add_argument("--paths", default="burn,unfused,flash",
                    help="prism's attention paths (PRISM_ATTENTION) to time (comma-separated)")
    ap.add_argument("--precisions", default="f32,f16,bf16",
                    help="prism's block precisions to time (comma-separated; the first is "
                    "timed before the paper config, the others after)")
    ap.add_argument("--paper-precisions", default="f32",
                    help="block precisions of the paper config's rows (comma-separated)")
    ap.add_argument("--paper-train-steps", type=int, default=3,
                    help="the paper config's training steps (at least 3: the median of those "
                    "after 2 warm-up steps)")
    ap.add_argument("--no-paper", dest="paper", action="store_false",
                    help="skip the paper config's FPS rows")
    ap.add_argument("--no-quickstart", dest="quickstart", action="store_false",
                    help="skip the timed quick start")
    ap.add_argument("--dry-run", action="store_true",
                    help="the whole flow on the CPU at tiny shapes (PyTorch on the CPU, flex)")
    args = ap.parse_args()
    unknown = set(args.paths.split(",")) - set(PATHS)
    if unknown:
        ap.error(f"--paths: {', '.join(sorted(unknown))} not among {', '.join(PATHS)}")
    return args


def main():
    args = parse_args()
    plan = DRY if args.dry_run else GPU
    os.makedirs(args.out, exist_ok=True)
    run = Run(args.out, Budget(args.budget or plan.budget))
    context = {"command": " ".join([os.path.basename(sys.executable), *sys.argv]),
               "date": datetime.datetime.now().isoformat(timespec="seconds"),
               "gpu": gpu_name(), "torch": torch_version()}
    say(f"card: {context['gpu'] or 'no nvidia-smi'}; PyTorch {context['torch']}")
    with tempfile.TemporaryDirectory(prefix="gpu-compare-") as work:
        binaries = {"--prism": args.prism} if args.prism else unpack_prism(args.pack, work)
        context["build"] = pack_build(args.pack, args.prism)
        env, context["vulkan"] = vulkan_env(args.pack, work)
        env["PRISM_CACHE_DIR"] = os.path.join(work, "cache")
        if os.path.isfile(LPIPS_WEIGHTS):
            env["PRISM_LPIPS_WEIGHTS"] = LPIPS_WEIGHTS
        config = backbone_config(plan, os.path.join(work, "backbone.toml"))
        shapes = backbone_shapes(config)
        first, *others = args.precisions.split(",")
        paths = args.paths.split(",")
        torch_rows = measure_torch(run, plan, args, shapes, TORCH_DTYPES[:1])
        build, context["spirv_failure"] = check_build(run, plan, binaries, config, env)
        context["compiler"], prism = build, binaries[build]
        prism_rows = measure_prism(run, plan, args, build, prism, config, env, first, paths)
        paper_rows = None
        if args.paper:
            paper = paper_config(plan, os.path.join(work, "paper.toml"))
            paper_rows = measure_paper(run, plan, args, build, binaries, paper, env)
        tune = measure_tune(run, plan, args, prism, config, env, first, work)
        if build == "SPIR-V":
            prism_rows.update(measure_prism(run, plan, args, "WGSL", binaries["WGSL"], config,
                                            env, first, ["burn"]))
        for precision in others:
            prism_rows.update(measure_prism(run, plan, args, build, prism, config, env,
                                            precision, paths))
        torch_rows.update(measure_torch(run, plan, args, shapes, TORCH_DTYPES[1:]))
        quickstart = measure_quickstart(run, plan, prism, env, work) if args.quickstart else None
        report(run, plan, context, torch_rows, prism_rows, paper_rows, tune, quickstart)


if __name__ == "__main__":
    main()
