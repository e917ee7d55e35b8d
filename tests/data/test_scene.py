"""Normalisation maths, the default normalisation rules, compositing and Scene helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fixtures.cameras import look_at
from voxnero.cameras.cameras import Cameras
from voxnero.data.scene import (
    Normalisation,
    Scene,
    Split,
    check_camera,
    choose_normalisation,
    closest_point_to_axes,
    composite_linear,
    narrow_half_fov,
    normalisation_from_cameras,
)
from voxnero.errors import DataError

finite = st.floats(-100, 100, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(st.lists(finite, min_size=3, max_size=3), st.floats(0.01, 50),
       st.lists(finite, min_size=3, max_size=3))
def test_normalisation_round_trip(center, scale, p):
    n = Normalisation(np.array(center), scale)
    p = np.array(p)
    np.testing.assert_allclose(n.to_input(n.to_unit(p)), p, atol=1e-9 * (1 + abs(p).max()))
    np.testing.assert_allclose(n.to_unit(p), (p - np.array(center)) / scale)
    t = torch.from_numpy(np.stack([p, p]))
    np.testing.assert_allclose(n.to_unit(t).numpy()[0], n.to_unit(p), rtol=1e-12, atol=1e-12)
    assert Normalisation.from_dict(n.to_dict()).to_dict() == n.to_dict()


def test_normalisation_rejects_bad_values():
    for c, s in (([0, 0, 0], 0.0), ([0, 0, 0], -1.0), ([np.nan, 0, 0], 1.0)):
        with pytest.raises(DataError, match="invalid normalisation"):
            Normalisation(np.array(c, float), s)


def test_c2w_to_unit_moves_centre_only():
    n = Normalisation(np.array([1.0, 2.0, 3.0]), 2.0)
    c2w = np.eye(4)
    c2w[:3, 3] = [3.0, 2.0, 1.0]
    out = n.c2w_to_unit(c2w)
    np.testing.assert_allclose(out[:3, 3], [1.0, 0.0, -1.0])
    np.testing.assert_array_equal(out[:3, :3], np.eye(3))


def test_closest_point_to_axes_recovers_target():
    target = np.array([0.4, -1.0, 2.0])
    rng = np.random.default_rng(0)
    eyes = target + rng.normal(size=(7, 3)) * 3
    c2w = np.stack([look_at(e, target) for e in eyes])
    np.testing.assert_allclose(closest_point_to_axes(eyes, c2w[:, :3, 2]), target, atol=1e-9)
    # parallel axes: falls back to the mean of the origins
    o = np.array([[0, 0, 0], [1, 0, 0.0]])
    np.testing.assert_allclose(closest_point_to_axes(o, np.array([[0, 0, 1], [0, 0, 1.0]])),
                               o.mean(0))


def test_narrow_half_fov_closed_form():
    K = np.array([[100.0, 0, 30], [0, 80, 25], [0, 0, 1]])
    # min(30, 64-30)/100 = 0.30 vs min(25, 48-25)/80 = 0.2875 -> atan(0.2875)
    assert narrow_half_fov(K, 64, 48)[0] == pytest.approx(np.arctan(23 / 80))


def test_default_radius_is_the_largest_sphere_every_view_sees():
    """Project the chosen sphere's silhouette: inside every image, touching the tightest one."""
    target = np.array([0.2, 0.1, -0.3])
    rng = np.random.default_rng(1)
    w, h = 64, 48
    K = np.array([[70.0, 0, 30], [0, 66, 26], [0, 0, 1]])
    eyes = []
    for _ in range(6):
        v = rng.normal(size=3)
        eyes.append(target + v / np.linalg.norm(v) * rng.uniform(3, 6))
    c2w = np.stack([look_at(e, target) for e in eyes])
    Ks = np.repeat(K[None], 6, 0)
    center, r = normalisation_from_cameras(c2w, Ks, w, h)
    np.testing.assert_allclose(center, target, atol=1e-9)
    cams = Cameras(Ks, c2w, w, h)
    u = rng.normal(size=(20000, 3))
    pts = torch.from_numpy((target + r * u / np.linalg.norm(u, axis=1, keepdims=True))
                           .astype(np.float32))
    slack = []
    for i in range(6):
        uv, z = cams.project(pts, i)
        assert (z > 0).all()
        uv = uv.numpy()
        # distance of the silhouette to the nearest border, in pixels
        slack.append(min(uv[:, 0].min(), w - uv[:, 0].max(), uv[:, 1].min(), h - uv[:, 1].max()))
    assert min(slack) > -0.05  # inside every view (sampling tolerance)
    assert min(slack) < 0.3  # and touching the tightest one


def test_choose_normalisation_rules():
    c2w = np.stack([look_at(np.array(e, float), [0, 0, 0]) for e in
                    ([4, 0, 0], [0, 4, 0], [0.5, 0, 4], [-4, 0, 1])])
    K = np.repeat(np.array([[50.0, 0, 20], [0, 50, 20], [0, 0, 1]])[None], 4, 0)
    n, rec = choose_normalisation(c2w, K, 40, 40)
    assert rec["method"].startswith("cameras")
    np.testing.assert_allclose(n.center, 0, atol=1e-9)
    # all axes meet at the origin; the nearest camera is at distance 4 and the half FOV is
    # atan(20 / 50)
    assert n.scale == pytest.approx(4 * np.sin(np.arctan(20 / 50)))
    n, rec = choose_normalisation(c2w, K, 40, 40, bbox=[-1, -2, -3, 1, 2, 3])
    np.testing.assert_allclose(n.center, 0)
    assert n.scale == pytest.approx(np.sqrt(1 + 4 + 9)) and rec["bbox"] == [-1, -2, -3, 1, 2, 3]
    n, rec = choose_normalisation(c2w, K, 40, 40, radius=2.5, center=[1, 1, 1])
    assert n.scale == 2.5 and n.center.tolist() == [1, 1, 1] and "user" in rec["method"]
    pts = np.random.default_rng(0).uniform(-1, 1, (5000, 3)) + [5, 0, 0]
    pts[:10] = 1e6  # outliers are ignored by the percentiles
    n, rec = choose_normalisation(c2w, K, 40, 40, points=pts)
    np.testing.assert_allclose(n.center, [5, 0, 0], atol=0.05)
    assert n.scale == pytest.approx(1.1 * np.sqrt(3) * 0.96, rel=0.03)
    assert rec["method"].startswith("sparse points")
    with pytest.raises(DataError, match="bbox"):
        choose_normalisation(c2w, K, 40, 40, bbox=[1, 1, 1, 0, 0, 0])


def test_composite_linear():
    enc = np.zeros((1, 1, 3, 4), np.float32)
    enc[..., :3] = 1.0
    enc[0, 0, :, 3] = [1.0, 0.5, 0.0]
    lin, a = composite_linear(enc, white_bg=False)
    np.testing.assert_allclose(lin[0, 0, :, 0], [1.0, 0.5, 0.0])
    np.testing.assert_array_equal(a[0, 0], [1.0, 0.5, 0.0])
    enc[..., :3] = 0.0
    lin, _ = composite_linear(enc, white_bg=True)
    np.testing.assert_allclose(lin[0, 0, :, 1], [0.0, 0.5, 1.0])
    enc[..., 3] = 1.0
    assert composite_linear(enc, white_bg=True)[1] is None  # fully opaque -> no alpha
    lin, a = composite_linear(np.full((1, 1, 1, 3), 0.5, np.float32), False)
    assert a is None and lin[0, 0, 0, 0] == pytest.approx(0.21404114, abs=1e-6)


def test_scene_split_lookup_and_summary():
    cams = Cameras(torch.eye(3), torch.eye(4), 4, 3)
    sp = Split("train", torch.zeros(1, 3, 4, 3), cams, ["a"])
    assert (sp.n, sp.height, sp.width) == (1, 3, 4)
    sc = Scene(Path("/x"), "blender", {"train": sp}, Normalisation(np.zeros(3), 2.0),
               np.array([0, 0, 1.0]), meta={"normalisation": {"method": "test"}})
    assert sc.split("train") is sp
    with pytest.raises(DataError, match=r"split 'test' is not loaded \(have \['train'\]\)"):
        sc.split("test")
    s = sc.summary()
    assert "format      blender" in s and "train: 1 views, 4x3" in s and "scale=2.0000" in s


# --------------------------------------------------------------------------------------------
# check_camera: the per-frame checks every loader runs
# --------------------------------------------------------------------------------------------

def _good_camera() -> tuple[np.ndarray, np.ndarray]:
    """A pinhole 40x32 camera and a random rotation (QR of a Gaussian, det +1)."""
    q, r = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = q, (1.0, -2.0, 3.0)
    return np.array([[48.0, 0, 21.0], [0, 46.0, 15.5], [0, 0, 1]]), c2w


def test_check_camera_accepts_good_and_float32_cameras():
    K, c2w = _good_camera()
    check_camera(K, c2w, 40, 32, "frame 0", "t.json")
    check_camera(K.astype(np.float32), c2w.astype(np.float32), 40, 32, "frame 0", "t.json")
    check_camera(K, c2w[:3], 40, 32, "frame 0", "t.json")  # 3x4 poses have no last row


def _edit(K: np.ndarray, c2w: np.ndarray, defect: str) -> None:
    """Spoil one camera in place by ``defect``."""
    if defect == "scaled":
        c2w[:3, :3] *= 3
    elif defect == "sheared":
        c2w[0, 1] += 0.01
    elif defect == "singular":
        c2w[:3, :3] = 0
    elif defect == "mirror":
        c2w[:3, 0] *= -1
    elif defect == "transposed":
        c2w[:] = c2w.T.copy()
    elif defect == "nan_pose":
        c2w[1, 3] = np.nan
    elif defect == "zero_focal":
        K[0, 0] = 0
    elif defect == "negative_focal":
        K[1, 1] = -46
    elif defect == "inf_focal":
        K[0, 0] = np.inf
    elif defect == "pp_outside":
        K[0, 2] = 41.0
    elif defect == "pp_on_edge":
        K[1, 2] = 0.0
    elif defect == "not_pinhole":
        K[2] = (0, 0, 2)


@pytest.mark.parametrize("defect, words", [
    ("scaled", "not orthonormal"), ("sheared", "not orthonormal"), ("singular", "singular"),
    ("mirror", "mirror"), ("transposed", "transposed"), ("nan_pose", "non-finite"),
    ("zero_focal", "focal lengths"), ("negative_focal", "focal lengths"),
    ("inf_focal", "non-finite"), ("pp_outside", "principal point"),
    ("pp_on_edge", "principal point"), ("not_pinhole", "pinhole")])
def test_check_camera_refuses_each_defect_naming_file_and_frame(defect, words):
    K, c2w = _good_camera()
    _edit(K, c2w, defect)
    with pytest.raises(DataError) as e:
        check_camera(K, c2w, 40, 32, "frame 7 (./train/r_7)", "transforms_train.json")
    msg = str(e.value)
    assert msg.startswith("transforms_train.json: frame 7 (./train/r_7): ") and words in msg, msg
    assert e.value.fix


def test_check_camera_names_the_intrinsics_file_for_intrinsics():
    K, c2w = _good_camera()
    K[0, 0] = -1
    with pytest.raises(DataError, match="^cameras.txt: image 3"):
        check_camera(K, c2w, 40, 32, "image 3 (a.png)", "images.txt", intrinsics_path="cameras.txt")


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 2e-3))
def test_check_camera_tolerance_on_rotation_scale(e):
    """A rotation scaled by 1 + e passes iff (1 + e)^2 - 1 <= ORTHONORMAL_TOL."""
    from voxnero.data.scene import ORTHONORMAL_TOL

    K, c2w = _good_camera()
    c2w[:3, :3] *= 1 + e
    if (1 + e) ** 2 - 1 <= ORTHONORMAL_TOL * (1 - 1e-9):
        check_camera(K, c2w, 40, 32, "frame 0", "t.json")
    elif (1 + e) ** 2 - 1 > ORTHONORMAL_TOL * (1 + 1e-9):
        with pytest.raises(DataError, match="not orthonormal"):
            check_camera(K, c2w, 40, 32, "frame 0", "t.json")
