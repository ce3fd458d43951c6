"""How far is a person from the source camera, judged from their silhouette's height alone?

Usage: python scripts/silhouette_distance.py DATASET [HEIGHT]   (numpy and Pillow; HEIGHT 1.80)

The measure of the point branch's `anchor_height` (crates/prism-model/src/geometry/points/
anchor.rs), here from the dataset's masks instead of a key on the background, and with the rays
through the rows' outer edges at the silhouette's mean column.

For each subject's frontal view (view 0) of a prism dataset: the foreground rows of the mask,
the rays through the top edge of the first row and the bottom edge of the last (at the
silhouette's mean column), and the distance D at which a segment of HEIGHT metres, normal to
their bisector b, spans that angle: D = HEIGHT / (2 tan(theta / 2)). The anchor of a pixel is
the distance along its ray to that plane, D / (d . b). Compared on the mask with the true
distance along each ray (depth/000.png, camera z in millimetres).
"""
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

HEIGHT = float(sys.argv[2]) if len(sys.argv) > 2 else 1.80


def rays(cam, xs, ys):
    k_inv = np.linalg.inv(np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]]))
    c2w = np.array(cam["c2w"]).reshape(4, 4)
    p = np.stack([xs, ys, np.ones_like(xs)], -1) @ k_inv.T
    d = p @ c2w[:3, :3].T
    return d / np.linalg.norm(d, axis=-1, keepdims=True), p


root = Path(sys.argv[1])
rows = []
for subject in sorted(p for p in root.iterdir() if (p / "cameras.json").exists()):
    cams = json.loads((subject / "cameras.json").read_text())
    cams = cams["views"] if isinstance(cams, dict) else cams
    cam = next(c for c in cams if c["index"] == 0)
    mask = np.asarray(Image.open(subject / "mask" / "000.png")).astype(np.float32) / 255.0
    if mask.ndim == 3:
        mask = mask[..., 0]
    depth = np.asarray(Image.open(subject / "depth" / "000.png")).astype(np.float64) / 1000.0
    h, w = mask.shape
    fg = mask > 0.5
    ys, xs = np.nonzero(fg)
    y0, y1 = ys.min(), ys.max()
    xc = xs.mean() + 0.5
    (d_top, d_bot), _ = rays(cam, np.array([xc, xc]), np.array([float(y0), float(y1) + 1.0]))
    theta = np.arccos(np.clip(d_top @ d_bot, -1, 1))
    dist = HEIGHT / (2 * np.tan(theta / 2))
    b = d_top + d_bot
    b /= np.linalg.norm(b)
    gy, gx = np.mgrid[0:h, 0:w]
    d, p = rays(cam, gx.ravel() + 0.5, gy.ravel() + 0.5)
    anchor = (dist / (d @ b)).reshape(h, w)
    # camera z to distance along the unit ray: t = z |K^-1 [x, y, 1]|
    t_true = (depth.ravel() * np.linalg.norm(p, axis=-1)).reshape(h, w)
    valid = fg & (depth > 0)
    err = anchor[valid] - t_true[valid]
    median_plane = np.abs(t_true[valid] - np.median(t_true[valid])).mean()
    rows.append((subject.name, y0, y1, float(np.median(t_true[valid])), float(np.median(anchor[valid])),
                 float(err.mean()), float(np.abs(err).mean()), float(median_plane)))

print(f"height {HEIGHT} m; {len(rows)} subjects")
print("subject | rows | true median t | anchor median | bias | mean |err| | own-median plane |err|")
for r in rows:
    print(f"{r[0]} | {r[1]}-{r[2]} | {r[3]:.3f} | {r[4]:.3f} | {100*r[5]:+.1f} cm | {100*r[6]:.1f} cm | {100*r[7]:.1f} cm")
a = np.array([r[3:] for r in rows])
print(f"mean: bias {100*a[:,2].mean():+.2f} cm, |bias| {100*np.abs(a[:,2]).mean():.2f} cm, "
      f"mean |err| {100*a[:,3].mean():.2f} cm, own-median plane {100*a[:,4].mean():.2f} cm, "
      f"true median t std {100*a[:,0].std():.2f} cm, corr(true, anchor) {np.corrcoef(a[:,0], a[:,1])[0,1]:.3f}")
