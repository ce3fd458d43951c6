#!/usr/bin/env python3
"""Convert SMPL-X fits stored as pickles (THuman2.0 / 2.1 ``smplx_param.pkl``) into prism's
``body.json`` schema, so that ``prism data render`` moves them with their scans.

Input keys (numpy arrays of any leading batch shape of 1; missing optional keys are zero):

- ``betas`` (shape), ``expression``: the first 10 are kept (more are dropped with a warning);
- ``global_orient`` (3), ``body_pose`` (21 x 3), ``jaw_pose``, ``leye_pose``, ``reye_pose``
  (3 each): axis-angle, or rotation matrices (``[..., 3, 3]``), which are converted;
- ``left_hand_pose``, ``right_hand_pose``: 45 values (15 joints x 3), or PCA coefficients
  (e.g. 12), expanded with the model's ``hands_components{l,r}`` (needs ``--model`` to be a
  readable SMPL-X ``.npz``);
- ``transl`` (3, added to the posed body inside SMPL-X), ``scale`` and ``translation`` (the
  outer similarity of THuman's fits: ``scan = scale * (smplx + transl) + translation``).

Hand poses: the smplx package (``flat_hand_mean=False``, its default and what THuman's fits
used) adds the model's mean hand pose ``hands_mean{l,r}`` to the hand poses it is given, PCA or
not. ``--hand-mean add`` (the default) adds it here too, so that the pose in ``body.json`` is
the full rotation of each joint; ``--hand-mean none`` is for fits made with
``flat_hand_mean=True``.

Output (``body.json`` schema): ``model``, ``betas`` (10), ``pose`` (55 x 3, SMPL-X joint order:
global, 21 body, jaw, left eye, right eye, 15 left hand, 15 right hand), ``expression`` (10),
``scale``, ``transl`` with ``scan = scale * posed + transl``.

Usage:
    smplx_pkl_to_json.py --model SMPLX_NEUTRAL.npz IN.pkl OUT.json
    smplx_pkl_to_json.py --model SMPLX_NEUTRAL.npz --tree THuman2.1_smplx THuman2.1_Release
        (every SRC/NAME/smplx_param.pkl becomes DST/NAME/smplx.json)

Needs numpy only. Exit status 1 with one line per problem when a fit cannot be converted.
"""

import argparse
import json
import os
import pickle
import sys

import numpy as np

NUM_BETAS = 10
NUM_EXPRESSION = 10
NUM_BODY_JOINTS = 21
NUM_HAND_JOINTS = 15
KNOWN_KEYS = {
    "betas", "expression", "global_orient", "body_pose", "jaw_pose", "leye_pose",
    "reye_pose", "left_hand_pose", "right_hand_pose", "transl", "scale", "translation",
}


class FitError(Exception):
    """A fit that cannot be converted; the message names the file and the key."""


def load_pickle(path):
    """The fit's dictionary of numpy arrays."""
    try:
        with open(path, "rb") as f:
            try:
                data = pickle.load(f)
            except UnicodeDecodeError:
                f.seek(0)
                data = pickle.load(f, encoding="latin1")  # pickles written by Python 2
    except ModuleNotFoundError as e:
        raise FitError(
            f"{path}: the pickle needs the Python module '{e.name}' (tensors saved from "
            f"{e.name}?); re-save its values as numpy arrays"
        ) from None
    except (OSError, pickle.UnpicklingError, EOFError) as e:
        raise FitError(f"{path}: cannot read the pickle: {e}") from None
    if not isinstance(data, dict):
        raise FitError(f"{path}: expected a dictionary of arrays, found {type(data).__name__}")
    return data


def array(fit, path, key, default=None):
    """``fit[key]`` as a float64 array, or ``default`` when absent."""
    if key not in fit or fit[key] is None:
        if default is None:
            raise FitError(f"{path}: missing key '{key}'")
        return np.asarray(default, dtype=np.float64)
    try:
        value = np.asarray(fit[key], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise FitError(f"{path}: '{key}' is not numeric: {e}") from None
    if not np.all(np.isfinite(value)):
        raise FitError(f"{path}: '{key}' holds values that are not finite")
    return value


def matrices_to_axis_angle(m):
    """Axis-angle vectors of rotation matrices ``[N, 3, 3]`` (angle in [0, pi])."""
    out = np.zeros((m.shape[0], 3))
    for i, r in enumerate(m):
        # The unit quaternion of r, from its largest component for accuracy.
        t = np.trace(r)
        if t > 0:
            s = 2.0 * np.sqrt(1.0 + t)
            q = np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s,
                          (r[1, 0] - r[0, 1]) / s])
        else:
            k = int(np.argmax(np.diag(r)))
            a, b = (k + 1) % 3, (k + 2) % 3
            s = 2.0 * np.sqrt(max(1.0 + r[k, k] - r[a, a] - r[b, b], 1e-12))
            q = np.zeros(4)
            q[0] = (r[b, a] - r[a, b]) / s
            q[1 + k] = 0.25 * s
            q[1 + a] = (r[a, k] + r[k, a]) / s
            q[1 + b] = (r[b, k] + r[k, b]) / s
        if q[0] < 0:
            q = -q
        v = np.linalg.norm(q[1:])
        angle = 2.0 * np.arctan2(v, q[0])
        out[i] = q[1:] / v * angle if v > 1e-12 else 2.0 * q[1:]
    return out


def joints(fit, path, key, count, required=False):
    """``count`` axis-angle rotations of ``fit[key]`` as ``[count, 3]``."""
    value = array(fit, path, key, None if required else np.zeros(count * 3))
    if value.size == count * 9:
        return matrices_to_axis_angle(value.reshape(count, 3, 3))
    if value.size != count * 3:
        raise FitError(
            f"{path}: '{key}' has {value.size} values, expected {count * 3} "
            f"({count} axis-angle rotations) or {count * 9} (rotation matrices)"
        )
    return value.reshape(count, 3)


def coefficients(fit, path, key, count, warnings):
    """The first ``count`` coefficients of ``fit[key]`` (zero-padded), warning when non-zero
    ones are dropped."""
    value = array(fit, path, key, np.zeros(count)).reshape(-1)
    if value.size > count:
        dropped = np.abs(value[count:]).max()
        if dropped > 0:
            warnings.append(
                f"{path}: '{key}' has {value.size} components; prism's body model uses "
                f"{count}, the others (largest |value| {dropped:.3g}) are dropped"
            )
        value = value[:count]
    return np.concatenate([value, np.zeros(count - value.size)])


class HandModel:
    """The hand PCA components and mean poses of an SMPL-X ``.npz``, read on first use."""

    def __init__(self, model):
        self.model = model
        self.arrays = None

    def get(self, key, why):
        if self.arrays is None:
            if not (self.model.endswith(".npz") and os.path.isfile(self.model)):
                raise FitError(
                    f"{why} needs the SMPL-X model file ('{key}'): pass --model "
                    f"PATH/SMPLX_NEUTRAL.npz (a readable .npz; got '{self.model}')"
                )
            with np.load(self.model, allow_pickle=False) as npz:
                self.arrays = {k: np.asarray(npz[k], dtype=np.float64) for k in npz.files
                               if k.startswith("hands_")}
        if key not in self.arrays:
            raise FitError(f"{self.model}: missing key '{key}' ({why})")
        return self.arrays[key]


def hand(fit, path, side, hands, hand_mean):
    """The 15 joint rotations of one hand: full or PCA, plus the model's mean if asked."""
    key = f"{side}_hand_pose"
    letter = side[0]
    value = array(fit, path, key, np.zeros(NUM_HAND_JOINTS * 3)).reshape(-1)
    if value.size == NUM_HAND_JOINTS * 9:
        pose = matrices_to_axis_angle(value.reshape(NUM_HAND_JOINTS, 3, 3)).reshape(-1)
    elif value.size == NUM_HAND_JOINTS * 3:
        pose = value
    elif 0 < value.size < NUM_HAND_JOINTS * 3:
        why = f"{path}: '{key}' has {value.size} PCA coefficients; expanding them"
        components = hands.get(f"hands_components{letter}", why)
        pose = value @ components[: value.size]
    else:
        raise FitError(
            f"{path}: '{key}' has {value.size} values, expected 45 (15 axis-angle joints) "
            f"or fewer PCA coefficients"
        )
    if hand_mean == "add":
        why = f"{path}: adding the mean hand pose (--hand-mean add; use --hand-mean none for fits made with flat_hand_mean=True)"
        pose = pose + hands.get(f"hands_mean{letter}", why).reshape(-1)
    return pose.reshape(NUM_HAND_JOINTS, 3)


def convert(path, model, hands, hand_mean):
    """The ``body.json`` dictionary of the fit at ``path`` and the warnings about it."""
    fit = load_pickle(path)
    warnings = []
    unknown = sorted(str(k) for k in fit if k not in KNOWN_KEYS)
    if unknown:
        warnings.append(f"{path}: ignored keys: {', '.join(unknown)}")
    pose = np.concatenate([
        joints(fit, path, "global_orient", 1, required=True),
        joints(fit, path, "body_pose", NUM_BODY_JOINTS, required=True),
        joints(fit, path, "jaw_pose", 1),
        joints(fit, path, "leye_pose", 1),
        joints(fit, path, "reye_pose", 1),
        hand(fit, path, "left", hands, hand_mean),
        hand(fit, path, "right", hands, hand_mean),
    ])
    scale = array(fit, path, "scale", [1.0]).reshape(-1)
    if scale.size != 1 or not scale[0] > 0:
        raise FitError(f"{path}: 'scale' must be one positive number, found {scale.tolist()}")
    scale = float(scale[0])

    def vector3(key):
        value = array(fit, path, key, np.zeros(3)).reshape(-1)
        if value.size != 3:
            raise FitError(f"{path}: '{key}' has {value.size} values, expected 3")
        return value

    # scan = scale * (posed + transl) + translation = scale * posed + (scale * transl + translation)
    transl = scale * vector3("transl") + vector3("translation")
    return {
        "model": model,
        "betas": coefficients(fit, path, "betas", NUM_BETAS, warnings).tolist(),
        "pose": pose.tolist(),
        "expression": coefficients(fit, path, "expression", NUM_EXPRESSION, warnings).tolist(),
        "scale": scale,
        "transl": transl.tolist(),
    }, warnings


def write_json(path, value):
    """Writes ``value`` as JSON atomically (a temporary file renamed into place)."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    tmp = path + ".partial"
    with open(tmp, "w") as f:
        json.dump(value, f, indent=2)
        f.write("\n")
    os.replace(tmp, path)


def jobs(args):
    """The (pickle, json) pairs to convert."""
    if args.tree:
        src, dst = args.paths
        if not os.path.isdir(src):
            raise FitError(f"{src}: no such folder")
        pairs = []
        for name in sorted(os.listdir(src)):
            pkl = os.path.join(src, name, args.pickle_name)
            if os.path.isfile(pkl):
                pairs.append((pkl, os.path.join(dst, name, args.json_name)))
        if not pairs:
            raise FitError(f"{src}: no */{args.pickle_name} found")
        return pairs
    src, dst = args.paths
    return [(src, dst)]


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Convert SMPL-X pickles (THuman's smplx_param.pkl) to prism's body.json schema.")
    parser.add_argument("paths", nargs=2, metavar=("SRC", "DST"),
                        help="IN.pkl OUT.json, or with --tree the fits folder and the scans folder")
    parser.add_argument("--model", required=True,
                        help="the body model the fits refer to, recorded in the JSON: the SMPL-X "
                             ".npz path (read for PCA hands and the mean hand pose)")
    parser.add_argument("--hand-mean", choices=["add", "none"], default="add",
                        help="add the model's mean hand pose (smplx's flat_hand_mean=False, the "
                             "default) or not")
    parser.add_argument("--tree", action="store_true",
                        help="convert SRC/NAME/<pickle-name> into DST/NAME/<json-name> for every NAME")
    parser.add_argument("--pickle-name", default="smplx_param.pkl")
    parser.add_argument("--json-name", default="smplx.json")
    args = parser.parse_args(argv)

    hands = HandModel(args.model)
    failures = 0
    try:
        pairs = jobs(args)
    except FitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    for src, dst in pairs:
        try:
            body, warnings = convert(src, args.model, hands, args.hand_mean)
        except FitError as e:
            print(f"error: {e}", file=sys.stderr)
            failures += 1
            continue
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
        write_json(dst, body)
    print(f"{len(pairs) - failures} of {len(pairs)} fits converted", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
