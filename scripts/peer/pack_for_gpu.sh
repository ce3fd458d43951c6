#!/usr/bin/env bash
# Packs what scripts/peer/gpu_compare.py needs on a GPU machine that has no Rust toolchain and
# no network, into gpu-pack/ (ignored by git): prism built with --features vulkan in release
# mode (kernels compiled to SPIR-V, the path to the tensor cores), stripped and xz-compressed
# (prism.xz), and the Debian packages of the Vulkan loader (libvulkan1) and of libglvnd
# (libglvnd0, which NVIDIA's Vulkan driver library links to).
# Then prints the command that runs the comparison there.
#
# usage (from anywhere in the repository): scripts/peer/pack_for_gpu.sh
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
pack=gpu-pack
packages=(libvulkan1 libglvnd0)

cargo build --release --features vulkan
mkdir -p "$pack"
strip -o "$pack/prism" target/release/prism
xz -T0 -6 -f "$pack/prism"
echo "$pack/prism.xz: $(du -h "$pack/prism.xz" | cut -f1) (stripped release binary, --features vulkan)"

rm -f "$pack"/*.deb
if ! (cd "$pack" && apt-get download "${packages[@]}"); then
    echo "apt-get download failed: refreshing the package lists (apt-get update) and retrying" >&2
    apt-get update
    (cd "$pack" && apt-get download "${packages[@]}")
fi
ls -l "$pack"

cat <<'EOF'

On the GPU machine, from the repository root with gpu-pack/ beside it (one command, under
8 minutes; PYTHONUNBUFFERED shows progress as it goes):
    PYTHONUNBUFFERED=1 python3 scripts/peer/gpu_compare.py --pack gpu-pack --out OUT_DIR

Through a runner that copies the working tree to the GPU machine and brings $OUT back: carry
["gpu-pack"] (an ignored folder), timeout_s 600, command
    PYTHONUNBUFFERED=1 python3 scripts/peer/gpu_compare.py --pack gpu-pack --out $OUT
EOF
