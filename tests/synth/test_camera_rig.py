"""Tests of voxnero/synth/camera_rig.py: Fibonacci lattices, look-at poses, intrinsics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from voxnero.cameras.rays import pixel_rays
from voxnero.synth.camera_rig import (
    GOLDEN_ANGLE,
    camera_rig,
    fibonacci_dirs,
    focal_from_fov,
    look_at_opencv,
    min_angles_deg,
    offset_lattice,
)

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def test_fibonacci_band_and_area_uniformity():
    d = fibonacci_dirs(96, (-20.0, 90.0))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    elev = np.degrees(np.arcsin(d[:, 2]))
    assert elev.min() > -20.0 and elev.max() < 90.0
    # area-uniform: equal steps in z; top view at ~83° for 96 views as in the dev scenes
    assert np.allclose(np.diff(d[:, 2]), -(1 + math.sin(math.radians(20))) / 96)
    assert elev.max() == pytest.approx(83.2, abs=0.1)
    az = np.arctan2(d[:, 1], d[:, 0])
    assert np.allclose(np.angle(np.exp(1j * (np.diff(az) - GOLDEN_ANGLE))), 0, atol=1e-12)


def test_look_at_is_a_proper_opencv_pose_without_roll():
    eyes = 4.0 * fibonacci_dirs(50)
    c2w = look_at_opencv(eyes)
    R = c2w[:, :3, :3]
    assert np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    fwd = R[:, :, 2]
    assert np.allclose(fwd, -eyes / 4.0)  # z forward, toward the origin
    assert np.allclose(R[:, 2, 0], 0.0, atol=1e-12)  # x (image right) is horizontal: no roll
    assert (R[:, 2, 1] < 0).all()  # y (image down) points downward in the world
    # straight down from above: still a valid pose
    top = look_at_opencv(np.array([[0.0, 0.0, 4.0]]))[0, :3, :3]
    assert np.allclose(top.T @ top, np.eye(3)) and np.allclose(top[:, 2], [0, 0, -1])


def test_principal_ray_hits_the_origin_and_fov_is_right():
    train, test, info = camera_rig(12, 4, 64, fov_deg=40.0, distance=4.0)
    assert len(train) == 12 and len(test) == 4
    f = train.K[0, 0, 0].item()
    assert f == pytest.approx(focal_from_fov(64, 40.0)) == pytest.approx(32 / math.tan(
        math.radians(20)))
    o, d = pixel_rays(train, torch.arange(12), torch.full((12, 2), 32.0))
    closest = o + (-(o * d).sum(-1, keepdim=True)) * d
    assert closest.norm(dim=-1).max() < 1e-5
    # the left and right image edges are 40° apart
    _, e = pixel_rays(train, torch.zeros(2, dtype=torch.long), torch.tensor([[0.0, 32], [64, 32]]))
    assert math.degrees(math.acos((e[0] * e[1]).sum().item())) == pytest.approx(40.0, abs=1e-3)
    assert info["min_angle_test_to_train_deg"] > 0


def test_offset_lattice_improves_on_a_naive_second_lattice():
    train = fibonacci_dirs(24)
    test, info = offset_lattice(8, train, (-20.0, 90.0), seed=0)
    naive = fibonacci_dirs(8)
    m = min_angles_deg(test, train).min()
    assert m == pytest.approx(info["min_angle_test_to_train_deg"])
    assert m > min_angles_deg(naive, train).min()
    assert m > 3.0


@pytest.mark.skipif(not (DATA / "sphere_gold").is_dir(), reason=f"dev scenes not in {DATA}")
def test_matches_the_dev_scene_train_poses():
    doc = json.loads((DATA / "sphere_gold" / "transforms_train.json").read_text())
    gl = np.array([f["transform_matrix"] for f in doc["frames"]])
    eyes = gl[:, :3, 3]
    phase = math.atan2(eyes[0, 1], eyes[0, 0])
    assert np.allclose(4.0 * fibonacci_dirs(96, phase=phase), eyes, atol=1e-9)
    cv = look_at_opencv(eyes)
    assert np.allclose(cv @ np.diag([1.0, -1.0, -1.0, 1.0]), gl, atol=1e-9)
