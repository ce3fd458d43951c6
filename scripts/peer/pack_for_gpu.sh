#!/usr/bin/env bash
# Packs what scripts/peer/gpu_compare.py needs on a GPU machine that has no Rust toolchain and
# no network, into gpu-pack/ (ignored by git): prism's release binary built twice, with
# --features vulkan (`prism`: kernels compiled to SPIR-V, the path to the tensor cores) and
# without (`prism-wgsl`: the default build, kernels in WGSL), stripped and xz-compressed
# together (prism.tar.xz: the two share most of their code, so the second adds about a
# third); the Debian packages of the Vulkan loader (libvulkan1) and of libglvnd (libglvnd0,
# which NVIDIA's Vulkan driver library links to); build.json naming the commit they were built
# from. The WGSL build is the comparison's fallback should the SPIR-V one fail on the card
# (it crashes on lavapipe), and its row answers which of the two compilers is faster there.
# The vulkan build has a target folder of its own (target/vulkan, or $CARGO_TARGET_DIR/vulkan),
# so that it leaves the default build's alone.
# Checks that the pack and the working tree (what a device call carries) fit in 64 MiB, then
# prints the command that runs the comparison there.
#
# --dry-run packs the release binary of the default build (target/release/prism, WGSL, built
# already) under both names into target/gpu-pack-dry/ instead, without building: the flow and
# the sizes, checked on a machine without the time for the vulkan build; it then prints the
# command that runs the comparison's flow on the CPU from that pack (gpu_compare.py --dry-run).
#
# usage (from anywhere in the repository): scripts/peer/pack_for_gpu.sh [--dry-run]
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
packages=(libvulkan1 libglvnd0)
# What one device call may carry: the working tree and the pack together.
limit_mib=64

target_dir="${CARGO_TARGET_DIR:-target}"
wgsl_binary="$target_dir/release/prism"
case "${1:-}" in
    --dry-run)
        dry_run=true
        pack=target/gpu-pack-dry
        if [ ! -x "$wgsl_binary" ]; then
            echo "$wgsl_binary: not built (cargo build --release)" >&2
            exit 1
        fi
        spirv_binary="$wgsl_binary"
        what="the default build's release binary (WGSL) under both names: a dry run"
        ;;
    "")
        dry_run=false
        pack=gpu-pack
        cargo build --release
        CARGO_TARGET_DIR="$target_dir/vulkan" cargo build --release --features vulkan
        spirv_binary="$target_dir/vulkan/release/prism"
        what="stripped release binaries: prism --features vulkan, prism-wgsl the default build"
        ;;
    *)
        echo "usage: $0 [--dry-run]" >&2
        exit 2
        ;;
esac

mkdir -p "$pack"
rm -f "$pack"/prism.xz "$pack"/prism.tar.xz
staging=$(mktemp -d)
trap 'rm -rf "$staging"' EXIT
strip -o "$staging/prism" "$spirv_binary"
if [ "$spirv_binary" = "$wgsl_binary" ]; then
    ln "$staging/prism" "$staging/prism-wgsl"  # tar stores a hard link once
else
    strip -o "$staging/prism-wgsl" "$wgsl_binary"
fi
# One xz stream with a dictionary larger than a binary, so that the second binary is coded
# as matches into the first; single-threaded, as threads would cut the stream into blocks.
tar -C "$staging" -cf - prism prism-wgsl \
    | xz -T1 --lzma2=preset=9e,dict=448MiB > "$pack/prism.tar.xz"
echo "$pack/prism.tar.xz: $(du -h "$pack/prism.tar.xz" | cut -f1) ($what)"
# What the binaries were built from, for gpu_compare.py's report: the commit, and whether the
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
