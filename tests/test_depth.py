"""Depth images of the simulated lab: geometry, Kinect v2 noise, culling, validation."""

from __future__ import annotations

import json
import math
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.core.geometry.raycast import ray_capsules, ray_plane
from kinefuse.core.geometry.transforms import apply_transform, look_at, make_transform
from kinefuse.core.skeleton import JOINT_INDEX, standing_pose
from kinefuse.errors import InputError
from kinefuse.sim.depth import (
    DEFAULT_DEPTH_NOISE,
    DepthNoiseParams,
    Scene,
    SurfaceLabel,
    axial_sigma_m,
    render_depth,
    render_depth_m,
    render_geometry,
    systematic_offset_m,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DOCS = Path(__file__).resolve().parents[1] / "docs"
KINECT = Intrinsics()
# a quarter-resolution camera with the Kinect v2's field of view, for the heavier checks
SMALL = Intrinsics(width=128, height=106, fx=91.25, fy=91.25, cx=63.5, cy=52.5)

# every error switched off: tests switch on one term at a time
QUIET = replace(
    DEFAULT_DEPTH_NOISE,
    axial_c0_mm=0.0,
    axial_c1_mm_per_m=0.0,
    axial_c2_mm_per_m2=0.0,
    axial_angle_mm_per_m1_5=0.0,
    lateral_sigma_px=0.0,
    offset_at_1m_mm=0.0,
    offset_slope_mm_per_m=0.0,
    wiggle_amplitude_mm=0.0,
    flying_prob=0.0,
    edge_invalid_prob=0.0,
    multipath_max_mm=0.0,
)

_RIGHT_HAND_RAISED = {
    "ElbowRight": (0.2, -0.3, 1.3),
    "WristRight": (0.4, -0.3, 1.45),
    "HandRight": (0.48, -0.3, 1.5),
    "HandTipRight": (0.55, -0.3, 1.53),
    "ThumbRight": (0.48, -0.26, 1.52),
}
POSE = standing_pose()  # at the origin facing +x, right hand raised in front (metres)
for _name, _xyz in _RIGHT_HAND_RAISED.items():
    POSE[JOINT_INDEX[_name]] = _xyz


def _pole_scene(distance_m: float = 2.0, radius_m: float = 0.1) -> tuple[Scene, np.ndarray]:
    """A vertical pole ``distance_m`` in front of a level camera that faces the wall x = -4."""
    cam = np.array([0.0, 0.0, 1.5])
    scene = Scene(
        a=[[-distance_m, 0.0, 0.2]],
        b=[[-distance_m, 0.0, 2.8]],
        radius=[radius_m],
    )
    return scene, look_at(cam, cam + np.array([-1.0, 0.0, 0.0]))


# --- geometry ------------------------------------------------------------------------------


def test_culled_renderer_matches_brute_force_all_pixels_all_capsules() -> None:
    rng = np.random.default_rng(0)
    rays_s = SMALL.pixel_rays().reshape(-1, 3)
    checked = 0
    for _ in range(6):
        pose = POSE + np.r_[rng.uniform(-1.5, 1.5, size=2), 0.0]
        scene = Scene.from_pose(
            pose,
            1.75,
            wand_centre=pose[JOINT_INDEX["HandRight"]] + (0.0, 0.0, 0.5),
            wand_handle_dir=rng.normal(size=3),
        )
        s2w = look_at(
            rng.uniform([-3.5, -3.5, 0.3], [3.5, 3.5, 2.5]),
            rng.uniform([-1.0, -1.0, 0.5], [1.0, 1.0, 1.5]),
            roll_rad=rng.uniform(-0.3, 0.3),
        )
        geo = render_geometry(scene, s2w, SMALL)
        rot, o = s2w[:3, :3], s2w[:3, 3]
        d_w = rays_s @ rot.T
        a, b, r, _ = scene.primitives()
        t = np.minimum(ray_capsules(o, d_w, a, b, r).min(axis=1), ray_plane(o, d_w, 0, (0, 0, 1)))
        for axis, val in ((0, -4.0), (0, 4.0), (1, -4.0), (1, 4.0)):
            n = np.eye(3)[axis]
            tw = ray_plane(o, d_w, n * val, n)
            t = np.minimum(t, np.where(o[2] + tw * d_w[:, 2] <= 3.0, tw, np.inf))
        z_brute = (t * rays_s[:, 2]).reshape(SMALL.height, SMALL.width)
        assert np.array_equal(np.isfinite(z_brute), np.isfinite(geo.z_m))
        fin = np.isfinite(z_brute)
        np.testing.assert_allclose(geo.z_m[fin], z_brute[fin], atol=1e-9)  # 1 nm
        checked += int((geo.label >= SurfaceLabel.BODY).sum())
    assert checked > 1000  # the bodies were in view


def test_capsule_partly_behind_the_camera_is_still_drawn() -> None:
    # a horizontal bar beside the camera, from 1 m behind it to 1.5 m in front
    cam = np.array([0.0, 0.0, 1.5])
    s2w = look_at(cam, cam + np.array([1.0, 0.0, 0.0]))
    scene = Scene(a=[[-1.0, -0.6, 1.5]], b=[[1.5, -0.6, 1.5]], radius=[0.2], walls=False)
    geo = render_geometry(scene, s2w, SMALL)
    rays_s = SMALL.pixel_rays().reshape(-1, 3)
    d_w = rays_s @ s2w[:3, :3].T
    t = ray_capsules(cam, d_w, scene.a, scene.b, scene.radius)[:, 0]
    z_brute = (t * rays_s[:, 2]).reshape(SMALL.height, SMALL.width)
    body = geo.label == SurfaceLabel.BODY
    assert body.sum() > 50
    np.testing.assert_allclose(geo.z_m[body], z_brute[body], atol=1e-9)  # 1 nm
    assert np.array_equal(body, np.isfinite(z_brute))


def test_sphere_centre_pixel_reads_centre_z_minus_radius() -> None:
    intr = Intrinsics(cx=256.0, cy=212.0)  # principal point on a pixel centre
    for dist in (2.0, 3.0, 4.0):
        cam = np.array([0.0, 0.0, 1.2])
        s2w = look_at(cam, cam + np.array([1.0, 0.0, 0.0]))
        centre = cam + np.array([dist, 0.0, 0.0])
        scene = Scene(wand=Wand(), wand_centre=centre, walls=False)
        d_m = render_depth_m(scene, s2w, intr)
        d_mm = render_depth(scene, s2w, intr, np.random.default_rng(0), noise=False)
        assert abs(d_m[212, 256] - (dist - 0.10)) < 1e-3  # 1 mm
        assert abs(int(d_mm[212, 256]) - 1000 * (dist - 0.10)) <= 1  # 1 mm
        # 0.10 m sphere at 2-4 m is 18-36 px across
        row = np.flatnonzero(render_geometry(scene, s2w, intr).label[212] == 4)
        assert abs(row.size - 2 * 365.0 * 0.10 / math.sqrt(dist**2 - 0.01)) <= 2


def test_off_axis_sphere_hit_along_its_centre_ray() -> None:
    intr = KINECT
    s2w = look_at((3.0, -2.0, 1.0), (0.0, 0.0, 1.3))
    u, v = 400, 90
    ray = intr.backproject(np.array([u, v], dtype=float), 1.0)
    centre_s = ray / np.linalg.norm(ray) * 2.7
    scene = Scene(
        wand=Wand(radius_m=0.1),
        wand_centre=apply_transform(s2w, centre_s),
        wand_handle_dir=(0, 0, -1),
    )
    d = render_depth_m(scene, s2w, intr)
    expected = (2.7 - 0.1) * centre_s[2] / 2.7  # z of the point at range |c| - r on that ray
    assert abs(d[v, u] - expected) < 1e-9  # 1 nm
    assert render_geometry(scene, s2w, intr).label[v, u] == SurfaceLabel.WAND_SPHERE


def test_backprojected_floor_lies_on_z0() -> None:
    s2w = look_at((2.5, 1.0, 1.1), (0.0, 0.0, 0.3), roll_rad=0.05)
    scene = Scene()
    geo = render_geometry(scene, s2w, KINECT)
    d_m = render_depth_m(scene, s2w, KINECT)
    d_mm = render_depth(scene, s2w, KINECT, np.random.default_rng(0), noise=False)
    floor = (geo.label == SurfaceLabel.FLOOR) & np.isfinite(d_m)
    assert floor.sum() > 20000
    v, u = np.nonzero(floor)
    uv = np.stack([u, v], -1).astype(float)
    p_world = apply_transform(s2w, KINECT.backproject(uv, d_m[floor]))
    np.testing.assert_allclose(p_world[:, 2], 0.0, atol=1e-9)  # 1 nm
    p_world_mm = apply_transform(s2w, KINECT.backproject(uv, d_mm[floor] / 1000.0))
    assert np.abs(p_world_mm[:, 2]).max() < 1e-3  # 1 mm: rounding to mm
    # the walls stand where the room says
    vw, uw = np.nonzero(geo.label == SurfaceLabel.WALL)  # beyond the range: use the geometry
    assert vw.size > 10000
    pw = apply_transform(
        s2w, KINECT.backproject(np.stack([uw, vw], -1).astype(float), geo.z_m[vw, uw])
    )
    on_a_wall = np.minimum(np.abs(np.abs(pw[:, 0]) - 4.0), np.abs(np.abs(pw[:, 1]) - 4.0))
    assert on_a_wall.max() < 1e-9  # 1 nm
    assert pw[:, 2].max() <= 3.0 + 1e-9


def test_person_occludes_the_wall() -> None:
    cam = np.array([2.5, 0.0, 1.2])
    s2w = look_at(cam, (-4.0, 0.0, 1.2))
    d_empty = render_depth_m(Scene(), s2w, KINECT)
    d = render_depth_m(Scene.from_pose(POSE), s2w, KINECT)
    uv = KINECT.project(apply_transform(np.linalg.inv(s2w), POSE[JOINT_INDEX["SpineMid"]]))
    u, v = np.rint(uv).astype(int)
    assert np.isnan(d_empty[v, u])  # the wall behind is 6.5 m away: beyond the range
    assert 2.2 < d[v, u] < 2.5  # the chest, 2.5 m minus the trunk's radius
    # the other way round: a near wall behind the person
    cam2 = np.array([-1.5, 0.0, 1.2])
    s2w2 = look_at(cam2, (4.0, 0.0, 1.2))
    d2_empty = render_depth_m(Scene(room_max_xy_m=(2.0, 4.0)), s2w2, KINECT)
    d2 = render_depth_m(Scene.from_pose(POSE, room_max_xy_m=(2.0, 4.0)), s2w2, KINECT)
    uv2 = KINECT.project(apply_transform(np.linalg.inv(s2w2), POSE[JOINT_INDEX["SpineMid"]]))
    u2, v2 = np.rint(uv2).astype(int)
    assert abs(d2_empty[v2, u2] - 3.5) < 1e-6  # 1 um: the wall at x = 2
    assert d2[v2, u2] < 1.5


def test_out_of_range_reads_zero() -> None:
    rng = np.random.default_rng(3)
    cam = np.array([3.0, 0.0, 1.5])
    s2w = look_at(cam, (-4.0, 0.0, 1.5))  # wall 7 m ahead, floor beyond 4.5 m cut
    d = render_depth(Scene(walls=True), s2w, KINECT, rng)
    geo = render_geometry(Scene(), s2w, KINECT)
    assert (geo.z_m > 7.0 - 1e-9).sum() > 50000  # the wall, out of range
    assert d[geo.z_m > 4.6].max() == 0  # 0.1 m beyond the range: far more than the noise
    assert d.max() <= 4500 + 30  # in range (noise may add a few mm past the true 4.5 m)
    # too near: a sphere 0.3 m in front fills the centre with no reading
    near = Scene(wand=Wand(radius_m=0.1), wand_centre=cam + np.array([-0.4, 0.0, 0.0]))
    d_near = render_depth(near, s2w, KINECT, rng)
    assert d_near[200:224, 244:268].max() == 0
    geo_near = render_geometry(near, s2w, KINECT)
    assert (geo_near.label[200:224, 244:268] == SurfaceLabel.WAND_SPHERE).all()


def test_grazing_incidence_reads_zero() -> None:
    cam = np.array([0.0, 0.0, 0.35])  # low camera: the floor ahead is seen at grazing angles
    s2w = look_at(cam, (-4.0, 0.0, 0.2))
    scene = Scene()
    geo = render_geometry(scene, s2w, KINECT)
    theta = np.degrees(geo.incidence_rad)
    d = render_depth(scene, s2w, KINECT, np.random.default_rng(0), noise=False)
    floor = (geo.label == SurfaceLabel.FLOOR) & (geo.z_m < 4.4)
    assert (d[floor & (theta > DEFAULT_DEPTH_NOISE.grazing_max_deg)] == 0).all()
    assert (d[floor & (theta < DEFAULT_DEPTH_NOISE.grazing_max_deg - 0.1)] > 0).all()
    # the noisy camera drops a rising share of pixels between the soft and the hard limit
    d_noisy = render_depth(scene, s2w, KINECT, np.random.default_rng(1), QUIET)
    lo, hi = QUIET.grazing_soft_deg, QUIET.grazing_max_deg
    ramp = floor & (theta > lo) & (theta < hi)
    assert ramp.sum() > 2000
    dropped = (d_noisy[ramp] == 0).mean()
    expected = ((theta[ramp] - lo) / (hi - lo)).mean()
    assert abs(dropped - expected) < 0.03


# --- noise -----------------------------------------------------------------------------------


def test_same_seed_same_image_other_seed_other_image() -> None:
    scene = Scene.from_pose(POSE, wand_centre=POSE[JOINT_INDEX["HandRight"]] + (0, 0, 0.45))
    s2w = look_at((2.5, 0.5, 1.1), (0.0, 0.0, 1.0))
    a = render_depth(scene, s2w, KINECT, np.random.default_rng(42))
    b = render_depth(scene, s2w, KINECT, np.random.default_rng(42))
    c = render_depth(scene, s2w, KINECT, np.random.default_rng(43))
    assert a.dtype == np.uint16 and a.shape == (424, 512)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def _wall_std(yaw_deg: float, dist: float, params: DepthNoiseParams, frames: int):
    """Per-pixel temporal std (m) of a wall patch and the noise-free depth and incidence."""
    cam = np.array([-4.0 + dist, 0.0, 1.5])
    yaw = math.radians(yaw_deg)
    s2w = look_at(cam, cam + np.array([-math.cos(yaw), math.sin(yaw), 0.0]))
    scene = Scene()
    rng = np.random.default_rng(7)
    patch = (slice(192, 232), slice(236, 276))
    stack = np.stack(
        [render_depth(scene, s2w, KINECT, rng, params)[patch] for _ in range(frames)]
    ).astype(float)
    assert (stack > 0).all()
    geo = render_geometry(scene, s2w, KINECT)
    return stack.std(axis=0, ddof=1) / 1000.0, geo.z_m[patch], geo.incidence_rad[patch]


@pytest.mark.parametrize(("yaw_deg", "dist"), [(0.0, 2.0), (0.0, 4.0), (45.0, 2.0), (60.0, 1.5)])
def test_axial_noise_matches_fankhauser_model(yaw_deg: float, dist: float) -> None:
    params = replace(DEFAULT_DEPTH_NOISE, lateral_sigma_px=0.0)  # axial noise alone
    std, z, theta = _wall_std(yaw_deg, dist, params, frames=12)
    expected = np.sqrt(axial_sigma_m(z, theta) ** 2 + (1e-3) ** 2 / 12)  # + 1 mm quantization
    ratio = std.mean() / expected.mean()
    assert 0.8 < ratio < 1.2, ratio
    if yaw_deg == 0.0 and dist == 2.0:
        assert abs(expected.mean() - 1.7e-3) < 0.1e-3  # 1.5 - 1.0 + 1.2 mm at 2 m, head-on


def test_lateral_noise_on_a_slanted_wall_adds_its_depth_gradient() -> None:
    params = replace(DEFAULT_DEPTH_NOISE, lateral_sigma_px=0.5)
    std, z, theta = _wall_std(45.0, 2.0, params, frames=12)
    dz_du = np.gradient(z, axis=1)  # m per pixel on the slanted wall (dz/dv = 0: level camera)
    clipped_var = 0.973  # variance of a unit normal clipped at +-3
    lateral = np.abs(dz_du) * 0.5 * math.sqrt(clipped_var)
    expected = np.sqrt(axial_sigma_m(z, theta) ** 2 + lateral**2 + (1e-3) ** 2 / 12)
    ratio = std.mean() / expected.mean()
    assert 0.85 < ratio < 1.15, ratio
    assert lateral.mean() > axial_sigma_m(z, theta).mean()  # the lateral term is visible


def test_lateral_noise_moves_silhouettes_by_the_expected_amount() -> None:
    sigma = 0.5
    params = replace(
        QUIET,
        lateral_sigma_px=sigma,
        grazing_soft_deg=89.9,
        grazing_max_deg=89.9,
    )
    scene, s2w = _pole_scene(2.0, 0.1)
    rows = slice(150, 274)  # the straight part of the pole
    clean_fg = (render_depth_m(scene, s2w, KINECT, params) < 3.0)[rows]
    rng = np.random.default_rng(11)
    flips = []
    for _ in range(6):
        d = render_depth(scene, s2w, KINECT, rng, params)[rows]
        fg = (d > 0) & (d < 3000)
        flips.append((fg != clean_fg).sum(axis=1).mean())
    # the silhouette columns of a vertical cylinder seen by a level camera
    half = math.asin(0.1 / 2.0)
    u_edges = [KINECT.cx + KINECT.fx * math.tan(s * half) for s in (-1, 1)]
    cols = np.arange(KINECT.width)
    phi = np.vectorize(lambda x: 0.5 * math.erfc(x / math.sqrt(2)))
    expected = sum(
        float(np.where(np.abs(cols - ue) < 3 * sigma, phi(np.abs(cols - ue) / sigma), 0).sum())
        for ue in u_edges
    )
    assert abs(np.mean(flips) / expected - 1.0) < 0.2, (np.mean(flips), expected)


def test_flying_pixels_sit_between_foreground_and_background_at_silhouettes() -> None:
    scene, s2w = _pole_scene(2.0, 0.1)
    clean = render_depth_m(scene, s2w, KINECT)
    fg = clean < 3.0
    near_edge = np.zeros_like(fg)
    for shift in (-3, -2, -1, 1, 2, 3):  # the lateral jitter moves edges by up to 1.5 px
        near_edge |= np.roll(fg, shift, axis=1) != fg
    d = render_depth(scene, s2w, KINECT, np.random.default_rng(5)).astype(float) / 1000.0
    between = (d > 2.2) & (d < 3.8)  # pole at 1.9-2.0 m, wall at 4.0 m
    rows = slice(150, 274)
    assert between[rows].sum() > 0.5 * (274 - 150)  # about one mixed pixel per edge and row
    assert not (between & ~near_edge)[rows].any()
    off = render_depth(
        scene, s2w, KINECT, np.random.default_rng(5), replace(DEFAULT_DEPTH_NOISE, flying_prob=0.0)
    ).astype(float)
    assert not ((off > 2200) & (off < 3800))[rows].any()
    # the SDK-like edge filter leaves holes at the silhouette only
    holes = (d == 0) & np.isfinite(clean)
    assert holes[rows].sum() > 0
    assert not (holes[rows] & ~near_edge[rows]).any()


def test_systematic_offset_is_added_along_the_ray() -> None:
    params = replace(QUIET, offset_at_1m_mm=5.0, offset_slope_mm_per_m=3.0, wiggle_amplitude_mm=2.0)
    cam = np.array([-2.0, 0.0, 1.5])
    s2w = look_at(cam, cam + np.array([-1.0, 0.0, 0.0]))
    d = render_depth(Scene(), s2w, KINECT, np.random.default_rng(0), params).astype(float)
    clean = render_depth_m(Scene(), s2w, KINECT)
    qn = np.linalg.norm(KINECT.backproject(np.array([[256.0, 212.0], [10.0, 10.0]]), 1.0), axis=1)
    for (u, v), q in zip(((256, 212), (10, 10)), qn, strict=True):
        expected_mm = 1000 * (clean[v, u] + systematic_offset_m(clean[v, u] * q, params) / q)
        assert abs(d[v, u] - expected_mm) <= 0.51  # rounding to mm
    # b0 + b1 (r - 1) + A sin(2 pi r / P): at r = P the sine is 0, at r = 1.25 P it is 1
    r = np.array([0.47, 0.47 * 1.25])
    np.testing.assert_allclose(
        systematic_offset_m(r, params), [5e-3 - 3e-3 * 0.53, 5e-3 - 3e-3 * 0.4125 + 2e-3], atol=1e-8
    )  # 0.01 um


def test_multipath_lengthens_concave_corners() -> None:
    params = replace(QUIET, multipath_max_mm=10.0, multipath_extent_m=0.3)
    cam = np.array([-1.5, 0.0, 1.2])
    s2w = look_at(cam, (-4.0, 0.0, 0.2))
    scene = Scene()
    d = render_depth(scene, s2w, KINECT, np.random.default_rng(0), params).astype(float)
    d0 = render_depth(scene, s2w, KINECT, np.random.default_rng(0), noise=False).astype(float)
    geo = render_geometry(scene, s2w, KINECT)
    both = (d > 0) & (d0 > 0)
    qn = KINECT.backproject(
        np.stack(np.meshgrid(np.arange(512), np.arange(424)), -1).astype(float), 1.0
    )
    qn = np.linalg.norm(qn, axis=-1)
    expected = 10.0 * np.clip(1 - geo.corner_dist_m / 0.3, 0, 1) / qn
    corner = both & (geo.corner_dist_m < 0.1)
    assert corner.sum() > 500
    assert np.abs((d - d0)[corner] - expected[corner]).max() <= 1.01  # two roundings to mm
    far = both & (geo.corner_dist_m > 0.3)
    assert np.abs((d - d0)[far]).max() == 0


def test_axial_sigma_values_from_the_paper() -> None:
    # sigma_z(z, 0) = 1.5 - 0.5 z + 0.3 z^2 mm
    np.testing.assert_allclose(
        axial_sigma_m([1.0, 2.0, 3.0], 0.0), [1.3e-3, 1.7e-3, 2.7e-3], atol=1e-12
    )
    # the incidence term at 45 deg: 0.1 z^1.5 (pi/4)^2 / (pi/4)^2 = 0.1 z^1.5 mm
    assert abs(axial_sigma_m(4.0, math.pi / 4) - (1.5 - 2.0 + 4.8 + 0.8) * 1e-3) < 1e-12


# --- real data -------------------------------------------------------------------------------


def test_real_kinect_v2_joints_land_on_the_rendered_body() -> None:
    """A real Kinect v2 frame (camera-space joints, their depth-image pixels, the floor plane):
    the capsule body rendered from the same viewpoint covers the pixels where the SDK put the
    trunk joints, at a depth just in front of them (the SDK's joints lie inside the body)."""
    path = DATA / "kinect" / "kinect2_tracking" / "walker.json"
    if not path.exists():
        pytest.skip(f"real Kinect v2 sample not found at {path}")
    frames = json.loads(path.read_text())["bodyFrame"]
    checked = 0
    for frame in frames[60:300:60]:
        body = next(b for b in frame["bodies"] if b["tracked"])
        joints = sorted(body["joints"], key=lambda j: j["jointType"])
        cam = np.array([[j["cameraX"], j["cameraY"], j["cameraZ"]] for j in joints])
        uv_sdk = np.array([[j["depthX"] * 512, j["depthY"] * 424] for j in joints])
        # the SDK's image is mirrored: its columns follow camera x, rows follow -y
        p_s = cam * (1.0, -1.0, 1.0)
        # this unit's intrinsics, fitted from the SDK's own joint-to-pixel mapping
        a_u = np.c_[p_s[:, 0] / p_s[:, 2], np.ones(len(p_s))]
        a_v = np.c_[p_s[:, 1] / p_s[:, 2], np.ones(len(p_s))]
        (fx, cx), *_ = np.linalg.lstsq(a_u, uv_sdk[:, 0], rcond=None)
        (fy, cy), *_ = np.linalg.lstsq(a_v, uv_sdk[:, 1], rcond=None)
        assert 355 < fx < 375 and 355 < fy < 375  # a Kinect v2 depth camera
        intr = Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy)
        # the world: floor from the SDK's floor clip plane (a x + b y + c z + d = 0, y up)
        fc = frame["floorClipPlane"]
        n = np.array([fc["x"], -fc["y"], fc["z"]])
        fwd = np.array([0.0, 0.0, 1.0]) - n[2] * n
        fwd /= np.linalg.norm(fwd)
        world2sensor = make_transform(np.stack([fwd, np.cross(n, fwd), n]).T, np.zeros(3))
        s2w = np.linalg.inv(world2sensor)
        s2w[:3, 3] = (0.0, 0.0, fc["w"])
        s2w[3] = (0, 0, 0, 1)
        pose_w = apply_transform(s2w, p_s)
        assert np.abs(pose_w[[JOINT_INDEX["FootLeft"], JOINT_INDEX["FootRight"]], 2]).max() < 0.2
        scene = Scene.from_pose(pose_w, 1.75, walls=False)
        geo = render_geometry(scene, s2w, intr)
        for name in ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head"):
            j = JOINT_INDEX[name]
            if joints[j]["trackingState"] != 2:
                continue
            u, v = np.rint(uv_sdk[j]).astype(int)
            assert geo.label[v, u] == SurfaceLabel.BODY, name
            # the visible surface is in front of the joint: the trunk (about its radius, 0.14
            # m) or an arm swinging in front of it (the walker is seen half from the side)
            assert 0.05 < p_s[j, 2] - geo.z_m[v, u] < 0.3, name
            checked += 1
    assert checked >= 10


# --- parameters and documentation --------------------------------------------------------------


def test_every_noise_parameter_has_unit_kind_and_source_and_is_documented() -> None:
    doc_path = DOCS / "error_model_depth.md"
    doc = doc_path.read_text() if doc_path.exists() else None
    for f in fields(DepthNoiseParams):
        assert f.metadata["unit"], f.name
        assert f.metadata["kind"] in ("measurement", "assumption"), f.name
        assert len(f.metadata["source"]) > 5, f.name
        if doc is not None:
            assert f"`{f.name}`" in doc, f"{f.name} missing from {doc_path}"
    assert doc is not None, f"{doc_path} is missing"


def test_scene_from_pose_builds_24_capsules_and_the_wand() -> None:
    s = Scene.from_pose(POSE, 1.75, wand_centre=(1.0, 0.0, 1.5))
    a, b, r, lab = s.primitives()
    assert a.shape == (26, 3) and b.shape == (26, 3) and r.shape == (26,)
    assert (lab[:24] == SurfaceLabel.BODY).all()
    assert lab[24] == SurfaceLabel.WAND_SPHERE and lab[25] == SurfaceLabel.WAND_STICK
    np.testing.assert_allclose(a[24], (1.0, 0.0, 1.5))
    np.testing.assert_allclose(a[25], (1.0, 0.0, 1.4))  # the stick hangs down from the sphere
    np.testing.assert_allclose(b[25], (1.0, 0.0, 1.0))
    # a taller subject has thicker capsules
    assert (Scene.from_pose(POSE, 2.0).radius > Scene.from_pose(POSE, 1.5).radius).all()


# --- bad input -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"a": [[0, 0, 0]], "b": [[0, 0, 1]], "radius": [-0.1]}, "radius must be > 0"),
        ({"a": [[0, 0]], "b": [[0, 0]], "radius": [0.1]}, "shape (C, 3)"),
        ({"a": [[0, 0, 0]], "b": [[0, 0, 1], [0, 0, 2]], "radius": [0.1]}, "Scene.b must"),
        ({"a": [[0, 0, np.nan]], "b": [[0, 0, 1]], "radius": [0.1]}, "finite"),
        ({"wand": Wand()}, "needs wand_centre"),
        ({"wand_centre": (0, 0, 1)}, "without a wand"),
        ({"wand": Wand(), "wand_centre": (0, 0, 1), "wand_handle_dir": (0, 0, 0)}, "non-zero"),
        ({"room_min_xy_m": (1.0, -4.0), "room_max_xy_m": (0.0, 4.0)}, "room_min_xy_m"),
        ({"wall_height_m": 0.0}, "wall_height_m"),
    ],
)
def test_bad_scene_is_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Scene(**kwargs)


def test_bad_pose_is_refused() -> None:
    with pytest.raises(InputError, match=r"shape \(25, 3\)"):
        Scene.from_pose(np.zeros((24, 3)))
    with pytest.raises(InputError, match="finite"):
        Scene.from_pose(np.full((25, 3), np.nan))
    with pytest.raises(InputError, match="height"):
        Scene.from_pose(POSE, 3.0)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"flying_prob": 1.5}, "probability"),
        ({"flying_prob": 0.9, "edge_invalid_prob": 0.2}, "must not exceed 1"),
        ({"lateral_sigma_px": -0.1}, ">= 0"),
        ({"lateral_sigma_px": 10.0}, "at most 5 px"),
        ({"grazing_soft_deg": 85.0, "grazing_max_deg": 80.0}, "grazing_soft_deg <= grazing_max"),
        ({"grazing_max_deg": 90.0}, "< 90"),
        ({"wiggle_period_m": 0.0}, "must be > 0"),
        ({"axial_c0_mm": -5.0}, "must be >= 0 for z"),
        ({"axial_c0_mm": float("nan")}, "finite number"),
    ],
)
def test_bad_noise_params_are_refused(change: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        replace(DEFAULT_DEPTH_NOISE, **change)


def test_bad_render_arguments_are_refused() -> None:
    scene = Scene()
    s2w = look_at((0.0, 0.0, 1.0), (1.0, 0.0, 1.0))
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="one \\(4, 4\\) transform"):
        render_depth(scene, s2w[:3], KINECT, rng)
    with pytest.raises(InputError, match="rigid transform"):
        render_depth(scene, s2w * 2.0, KINECT, rng)
    with pytest.raises(InputError, match="finite"):
        render_depth_m(scene, np.full((4, 4), np.nan), KINECT)
    with pytest.raises(InputError, match="outside the room"):
        render_depth(scene, look_at((5.0, 0.0, 1.0), (0.0, 0.0, 1.0)), KINECT, rng)
    with pytest.raises(InputError, match="above the floor"):
        render_depth_m(Scene(walls=False), look_at((0.0, 0.0, -1.0), (1.0, 0.0, 0.0)), KINECT)
    with pytest.raises(InputError, match=r"numpy\.random\.Generator"):
        render_depth(scene, s2w, KINECT, 42)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="must be a Scene"):
        render_depth_m("room", s2w, KINECT)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="must be an Intrinsics"):
        render_geometry(scene, s2w, {"fx": 365})  # type: ignore[arg-type]
    with pytest.raises(InputError, match="must be a DepthNoiseParams"):
        render_depth(scene, s2w, KINECT, rng, {"lateral_sigma_px": 1})  # type: ignore[arg-type]
    # a camera outside the room is fine without walls
    assert np.isfinite(
        render_depth_m(Scene(walls=False), look_at((5.0, 0, 1.0), (0, 0, 0)), KINECT)
    ).any()
