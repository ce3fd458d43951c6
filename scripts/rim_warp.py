"""The true-depth warp with rim Gaussians: do Gaussians stretched back along their rays at the
source silhouette's edge fill the disoccluded region?

Usage: python scripts/rim_warp.py DATASET SUBJECTS VARIANTS   (numpy and Pillow)
  SUBJECTS  comma-separated subject folders, e.g. subject_0021,subject_0022,subject_0023
  VARIANTS  comma-separated BACK:SIGMA pairs in metres, e.g. 0:0,0.025:0.0167

The measure behind the 3DGS head's `gs_rim_depth` (crates/prism-model/src/heads/rim.rs), with
the dataset's depth instead of a model's. Every foreground pixel of the source view (view 0)
becomes a Gaussian at its true 3D point (depth/000.png), with its colour, opacity 0.99 and an
isotropic sigma of 0.3 source-pixel footprints (the true-depth warp of `prism evaluate`). The
pixels of the silhouette's rim (foreground with a background pixel among their four
neighbours) move BACK metres back along their rays and get SIGMA metres along them
(`gs_rim_depth = L` starts at BACK = L/2, SIGMA = L/3; 0:0 is the plain warp). The Gaussians are
splatted into views 1..100 like prism's renderer (the projected covariance plus 0.3 px^2,
alpha capped at 0.99, composited front to back by the centre's depth, over the white
background). Scores as `prism evaluate`'s: PSNR per view averaged per subject, then over
subjects; the disoccluded region by the same depth test (1 cm of slack, the farthest of the
four source pixels around the projection).
"""
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

SLACK = 0.01
WINDOW = 5  # pixels each side of a Gaussian's centre


def camera(c):
    k = np.array([[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1.0]])
    return k, np.array(c["c2w"])


def load(subject, i):
    rgb = np.asarray(Image.open(subject / "rgb" / f"{i:03}.png").convert("RGB")) / 255.0
    mask = np.asarray(Image.open(subject / "mask" / f"{i:03}.png")) / 255.0
    mask = mask[..., 0] if mask.ndim == 3 else mask
    depth = np.asarray(Image.open(subject / "depth" / f"{i:03}.png")).astype(np.float64) / 1000
    return rgb, mask, depth


def unproject(k, c2w, z):
    h, w = z.shape
    ys, xs = np.mgrid[0:h, 0:w]
    pix = np.stack([xs + 0.5, ys + 0.5, np.ones_like(z)], -1)
    cam = pix @ np.linalg.inv(k).T * z[..., None]
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


def to_camera(c2w, points):
    w2c = np.linalg.inv(c2w)
    return points @ w2c[:3, :3].T + w2c[:3, 3], w2c[:3, :3]


def disoccluded(source, target):
    (ks, ms, mask_s, depth_s), (kt, mt, mask_t, depth_t) = source, target
    cam, _ = to_camera(ms, unproject(kt, mt, depth_t))
    z = cam[..., 2]
    u, v = (cam @ ks.T)[..., 0] / z, (cam @ ks.T)[..., 1] / z
    h, w = mask_s.shape
    x0, y0 = np.floor(u - 0.5).astype(int), np.floor(v - 0.5).astype(int)
    farthest = np.full(u.shape, -np.inf)
    for dx, dy in [(0, 0), (1, 0), (0, 1), (1, 1)]:
        x, y = x0 + dx, y0 + dy
        inside = (x >= 0) & (y >= 0) & (x < w) & (y < h)
        xc, yc = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
        surface = inside & (mask_s[yc, xc] > 0.5) & (depth_s[yc, xc] > 0)
        farthest = np.where(surface, np.maximum(farthest, depth_s[yc, xc]), farthest)
    seen = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (z > 0) & (z <= farthest + SLACK)
    return (mask_t > 0.5) & (depth_t > 0) & ~seen


def splat(means, covariances, colours, k, c2w, h, w):
    cam, rot = to_camera(c2w, means)
    x, y, z = cam.T
    fx, fy = k[0, 0], k[1, 1]
    u, v = fx * x / z + k[0, 2], fy * y / z + k[1, 2]
    jac = np.zeros((len(z), 2, 3))
    jac[:, 0, 0], jac[:, 0, 2] = fx / z, -fx * x / z**2
    jac[:, 1, 1], jac[:, 1, 2] = fy / z, -fy * y / z**2
    m = jac @ rot
    cov = m @ covariances @ m.transpose(0, 2, 1) + 0.3 * np.eye(2)
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    ca, cb, cc = cov[:, 1, 1] / det, -cov[:, 0, 1] / det, cov[:, 0, 0] / det
    ox, oy = (o.ravel() for o in np.meshgrid(np.arange(-WINDOW, WINDOW + 1), np.arange(-WINDOW, WINDOW + 1)))
    px = np.floor(u).astype(int)[:, None] + ox
    py = np.floor(v).astype(int)[:, None] + oy
    dx, dy = px + 0.5 - u[:, None], py + 0.5 - v[:, None]
    power = ca[:, None] * dx * dx + 2 * cb[:, None] * dx * dy + cc[:, None] * dy * dy
    alpha = np.minimum(0.99 * np.exp(-0.5 * power), 0.99)
    keep = (alpha > 1 / 255) & (px >= 0) & (py >= 0) & (px < w) & (py < h) & (z[:, None] > 0)
    gaussian = np.broadcast_to(np.arange(len(z))[:, None], alpha.shape)[keep]
    pixel, alpha = (py * w + px)[keep], alpha[keep]
    order = np.lexsort((z[gaussian], pixel))
    pixel, alpha, gaussian = pixel[order], alpha[order], gaussian[order]
    # Front to back within each pixel: the transmittance before each Gaussian.
    log_t = np.log1p(-alpha)
    total = np.cumsum(log_t)
    first = np.r_[True, pixel[1:] != pixel[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(len(pixel)), 0))
    weight = alpha * np.exp(total - log_t - (total[start] - log_t[start]))
    image, coverage = np.zeros((h * w, 3)), np.zeros(h * w)
    np.add.at(image, pixel, weight[:, None] * colours[gaussian])
    np.add.at(coverage, pixel, weight)
    return (image + (1 - coverage)[:, None]).reshape(h, w, 3)


def psnr(mse):
    return 10 * np.log10(1 / max(mse, 1e-12))


def main():
    root, subjects = Path(sys.argv[1]), sys.argv[2].split(",")
    variants = [tuple(float(x) for x in v.split(":")) for v in sys.argv[3].split(",")]
    scores = {v: ([], []) for v in variants}
    for name in subjects:
        subject = root / name
        cams = {c["index"]: c for c in json.loads((subject / "cameras.json").read_text())}
        ks, ms = camera(cams[0])
        rgb_s, mask_s, depth_s = load(subject, 0)
        h, w = mask_s.shape
        fg = (mask_s > 0.5) & (depth_s > 0)
        inner = fg.copy()
        inner[1:-1, 1:-1] = fg[1:-1, 1:-1] & fg[:-2, 1:-1] & fg[2:, 1:-1] & fg[1:-1, :-2] & fg[1:-1, 2:]
        rim = (fg & ~inner)[fg]
        points, colours = unproject(ks, ms, depth_s)[fg], rgb_s[fg]
        rays = points - ms[:3, 3]
        distance = np.linalg.norm(rays, axis=1)
        rays /= distance[:, None]
        sigma = 0.3 * distance / ks[0, 0]
        gaussians = {}
        for back, along in variants:
            means = points + (rim * back)[:, None] * rays
            stretch = np.where(rim, np.maximum(along**2 - sigma**2, 0), 0)
            cov = sigma[:, None, None] ** 2 * np.eye(3) + stretch[:, None, None] * rays[:, :, None] * rays[:, None, :]
            gaussians[(back, along)] = (means, cov)
        per_view = {v: ([], []) for v in variants}
        for i in range(1, 101):
            kt, mt = camera(cams[i])
            rgb_t, mask_t, depth_t = load(subject, i)
            region = disoccluded((ks, ms, mask_s, depth_s), (kt, mt, mask_t, depth_t))
            for v in variants:
                error = (splat(*gaussians[v], colours, kt, mt, h, w) - rgb_t) ** 2
                per_view[v][0].append(psnr(error.mean()))
                if region.any():
                    per_view[v][1].append(psnr(error[region].mean()))
        for v in variants:
            for k in range(2):
                scores[v][k].append(np.mean(per_view[v][k]))
    for (back, along), (overall, region) in scores.items():
        print(f"back {back} m, sigma along the ray {along} m: PSNR {np.mean(overall):.3f} dB, disoccluded region {np.mean(region):.3f} dB")


if __name__ == "__main__":
    main()
