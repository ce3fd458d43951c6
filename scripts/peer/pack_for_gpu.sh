#!/usr/bin/env bash
# Packs what scripts/peer/gpu_compare.py needs on a GPU machine that has no Rust toolchain and
# no network, into gpu-pack/ (ignored by git): prism built with --features vulkan in release
# mode (kernels compiled to SPIR-V, the path to the tensor cores), stripped and xz-compressed
# (prism.xz), and the Debian packages of the Vulkan loader (libvulkan1) and of libglvnd
# (libglvnd0, which NVIDIA's Vulkan driver library links to), with build.json naming the commit
# it was built from. The build has a target folder of its own (target/vulkan, or
# CARGO_TARGET_DIR), so that it leaves the default build's alone.
# Checks that the pack and the working tree (what a device call carries) fit in 64 MiB, then
# prints the command that runs the comparison there.
#
# --dry-run packs the release binary of the default build (target/release/prism, WGSL, built
# already) into target/gpu-pack-dry/ instead, without building: the flow and the sizes,
# checked on a machine without the time for the vulkan build; it then prints the command that
# runs the comparison's flow on the CPU from that pack (gpu_compare.py --dry-run).
#
# usage (from anywhere in the repository): scripts/peer/pack_for_gpu.sh [--dry-run]
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
packages=(libvulkan1 libglvnd0)
# What one device call may carry: the working tree and the pack together.
limit_mib=64

case "${1:-}" in
    --dry-run)
        dry_run=true
        pack=target/gpu-pack-dry
        binary="${CARGO_TARGET_DIR:-target}/release/prism"
        [ -x "$binary" ] || { echo "$binary: not built (cargo build --release)" >&2; exit 1; }
        what="the default build's release binary (WGSL): a dry run"
        ;;
    "")
        dry_run=false
        pack=gpu-pack
        export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-target/vulkan}"
        cargo build --release --features vulkan
        binary="$CARGO_TARGET_DIR/release/prism"
        what="stripped release binary, --features vulkan"
        ;;
    *)
        echo "usage: $0 [--dry-run]" >&2
        exit 2
        ;;
esac

mkdir -p "$pack"
strip -o "$pack/prism" "$binary"
xz -T0 -6 -f "$pack/prism"
echo "$pack/prism.xz: $(du -h "$pack/prism.xz" | cut -f1) ($what)"
# What the binary was built from, for gpu_compare.py's report: the commit, and whether the
# tree had changes not committed (the build then holds more than the commit says). A dry run
# packs a binary built earlier, from whatever the tree was then: it names no commit.
if ! $dry_run; then
    dirty=false
    [ -z "$(git status --porcelain)" ] || dirty=true
    printf '{"commit": "%s", "dirty": %s, "build": "%s", "date": "%s"}\n' \
        "$(git rev-parse HEAD)" "$dirty" "$what" "$(date -u +%Y-%m-%dT%H:%M:%SZ)"
else
    printf '{"note": "%s, built before packing: commit not known"}\n' "$what"
fi > "$pack/build.json"
echo "$pack/build.json: $(cat "$pack/build.json")"

rm -f "$pack"/*.deb
if ! (cd "$pack" && apt-get download "${packages[@]}"); then
    echo "apt-get download failed: refreshing the package lists (apt-get update) and retrying" >&2
    apt-get update
    (cd "$pack" && apt-get download "${packages[@]}")
fi
ls -l "$pack"

# The working tree a device call copies: tracked files and untracked ones git does not ignore.
tree_bytes=$(git ls-files -z --cached --others --exclude-standard \
    | xargs -0 stat -c %s 2>/dev/null | awk '{ s += $1 } END { print s + 0 }')
pack_bytes=$(du -sb "$pack" | cut -f1)
total_mib=$(( (tree_bytes + pack_bytes + 1048575) / 1048576 ))
echo "a device call carries ${total_mib} MiB: the working tree $(( tree_bytes / 1048576 )) MiB," \
    "$pack $(( pack_bytes / 1048576 )) MiB (at most ${limit_mib} MiB)"
if [ "$total_mib" -gt "$limit_mib" ]; then
    echo "too large for one device call: more than ${limit_mib} MiB" >&2
    exit 1
fi

if $dry_run; then
    echo
    echo "The comparison's flow on this CPU (a Python with PyTorch), from this pack:"
    echo "    python3 scripts/peer/gpu_compare.py --dry-run --pack $pack --out runs/gpu-compare-dry"
    exit 0
fi
cat <<EOF

On the GPU machine, from the repository root with $pack/ beside it (one command, within
8 minutes; PYTHONUNBUFFERED shows progress as it goes):
    PYTHONUNBUFFERED=1 python3 scripts/peer/gpu_compare.py --pack $pack --out OUT_DIR

Through a runner that copies the working tree to the GPU machine and brings \$OUT back: carry
["$pack"] (an ignored folder), timeout_s 600, command
    PYTHONUNBUFFERED=1 python3 scripts/peer/gpu_compare.py --pack $pack --out \$OUT
EOF
