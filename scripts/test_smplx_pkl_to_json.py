"""Tests of smplx_pkl_to_json.py on pickles written here (needs numpy):
``python3 scripts/test_smplx_pkl_to_json.py``."""

import contextlib
import io
import json
import os
import pickle
import sys
import tempfile
import unittest

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import smplx_pkl_to_json as conv  # noqa: E402


def rodrigues(r):
    """Rotation matrix of axis-angle ``r`` (reference for the matrix input)."""
    theta = np.linalg.norm(r)
    if theta < 1e-12:
        return np.eye(3)
    k = r / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def read_json(path):
    with open(path) as f:
        return json.load(f)


def thuman_fit(rng, hand_size=45):
    """A fit with THuman's keys, batch dimension 1, float32 like the release."""
    f = lambda *s: rng.normal(scale=0.3, size=(1,) + s).astype(np.float32)  # noqa: E731
    return {
        "betas": f(10), "global_orient": f(3), "body_pose": f(63), "jaw_pose": f(3),
        "leye_pose": f(3), "reye_pose": f(3), "left_hand_pose": f(hand_size),
        "right_hand_pose": f(hand_size), "expression": f(10),
        "scale": np.array([0.9], dtype=np.float32),
        "translation": np.array([0.1, -0.2, 0.3], dtype=np.float32),
    }


class ConvertTest(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.root = self.dir.name
        self.rng = np.random.default_rng(0)

    def tearDown(self):
        self.dir.cleanup()

    def pickle(self, fit, name="smplx_param.pkl"):
        path = os.path.join(self.root, name)
        with open(path, "wb") as f:
            pickle.dump(fit, f)
        return path

    def model_npz(self):
        """A stand-in for SMPLX_NEUTRAL.npz with the hand keys only."""
        q, _ = np.linalg.qr(self.rng.normal(size=(45, 45)))
        arrays = {"hands_componentsl": q, "hands_componentsr": q[::-1],
                  "hands_meanl": self.rng.normal(size=45), "hands_meanr": self.rng.normal(size=45)}
        path = os.path.join(self.root, "SMPLX_TEST.npz")
        np.savez(path, **arrays)
        return path, arrays

    def run_main(self, *argv):
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = conv.main(list(argv))
        return code, err.getvalue()

    def test_full_hands_pose_order_and_similarity(self):
        fit = thuman_fit(self.rng)
        fit["transl"] = np.array([[0.01, 0.02, 0.03]])
        # Body pose as rotation matrices: converted back to the same axis-angle.
        axis_angles = fit["body_pose"].reshape(21, 3)
        fit["body_pose"] = np.stack([rodrigues(r) for r in axis_angles])[None]
        src = self.pickle(fit)
        dst = os.path.join(self.root, "out", "smplx.json")
        code, err = self.run_main("--model", "procedural:0", "--hand-mean", "none", src, dst)
        self.assertEqual(code, 0, err)
        body = read_json(dst)
        self.assertEqual(body["model"], "procedural:0")
        pose = np.array(body["pose"])
        self.assertEqual(pose.shape, (55, 3))
        np.testing.assert_allclose(pose[0], fit["global_orient"][0], atol=1e-6)
        np.testing.assert_allclose(pose[1:22], axis_angles, atol=1e-5)
        np.testing.assert_allclose(pose[22], fit["jaw_pose"][0], atol=1e-6)
        np.testing.assert_allclose(pose[24], fit["reye_pose"][0], atol=1e-6)
        np.testing.assert_allclose(pose[25:40].reshape(-1), fit["left_hand_pose"][0], atol=1e-6)
        np.testing.assert_allclose(pose[40:].reshape(-1), fit["right_hand_pose"][0], atol=1e-6)
        # scan = 0.9 * (posed + transl) + translation.
        self.assertAlmostEqual(body["scale"], 0.9, places=6)
        np.testing.assert_allclose(body["transl"], [0.109, -0.182, 0.327], atol=1e-6)
        self.assertEqual(len(body["betas"]), 10)
        self.assertEqual(len(body["expression"]), 10)
        self.assertFalse(os.path.exists(dst + ".partial"))

    def test_pca_hands_are_expanded_with_the_model_and_its_mean(self):
        npz, arrays = self.model_npz()
        fit = thuman_fit(self.rng, hand_size=12)
        src = self.pickle(fit)
        dst = os.path.join(self.root, "smplx.json")
        code, err = self.run_main("--model", npz, src, dst)
        self.assertEqual(code, 0, err)
        pose = np.array(read_json(dst)["pose"])
        left = fit["left_hand_pose"][0] @ arrays["hands_componentsl"][:12] + arrays["hands_meanl"]
        right = fit["right_hand_pose"][0] @ arrays["hands_componentsr"][:12] + arrays["hands_meanr"]
        np.testing.assert_allclose(pose[25:40].reshape(-1), left, atol=1e-6)
        np.testing.assert_allclose(pose[40:].reshape(-1), right, atol=1e-6)

    def test_pca_without_the_model_file_is_a_clear_error(self):
        src = self.pickle(thuman_fit(self.rng, hand_size=12))
        dst = os.path.join(self.root, "smplx.json")
        code, err = self.run_main("--model", "SMPLX_NEUTRAL.npz", "--hand-mean", "none", src, dst)
        self.assertEqual(code, 1)
        self.assertIn("'left_hand_pose' has 12 PCA coefficients", err)
        self.assertIn("--model", err)
        self.assertFalse(os.path.exists(dst))

    def test_tree_mode_warnings_and_bad_files(self):
        fits = os.path.join(self.root, "THuman2.1_smplx")
        scans = os.path.join(self.root, "THuman2.1_Release")
        for name in ["0000", "0001", "0002"]:
            os.makedirs(os.path.join(fits, name))
        fit = thuman_fit(self.rng)
        fit["betas"] = np.concatenate([fit["betas"], np.ones((1, 6))], axis=1)
        fit["gender"] = "neutral"
        with open(os.path.join(fits, "0000", "smplx_param.pkl"), "wb") as f:
            pickle.dump(fit, f)
        del fit["body_pose"]
        with open(os.path.join(fits, "0001", "smplx_param.pkl"), "wb") as f:
            pickle.dump(fit, f)
        with open(os.path.join(fits, "0002", "smplx_param.pkl"), "wb") as f:
            f.write(b"not a pickle")
        code, err = self.run_main("--model", "procedural:0", "--hand-mean", "none", "--tree",
                                  fits, scans)
        self.assertEqual(code, 1)
        self.assertIn("'betas' has 16 components", err)
        self.assertIn("ignored keys: gender", err)
        self.assertIn("0001/smplx_param.pkl: missing key 'body_pose'", err)
        self.assertIn("0002/smplx_param.pkl: cannot read the pickle", err)
        self.assertIn("1 of 3 fits converted", err)
        self.assertTrue(os.path.isfile(os.path.join(scans, "0000", "smplx.json")))
        self.assertFalse(os.path.exists(os.path.join(scans, "0001")))

    def test_matrix_conversion_near_pi(self):
        for r in [np.array([np.pi - 1e-4, 0, 0]), np.array([0.0, 2.0, 2.0]), np.zeros(3)]:
            got = conv.matrices_to_axis_angle(rodrigues(r)[None])[0]
            np.testing.assert_allclose(rodrigues(got), rodrigues(r), atol=1e-7)


if __name__ == "__main__":
    unittest.main()
