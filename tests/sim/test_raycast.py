"""Ray-cast visibility (sim/raycast.py): exact hits, and agreement with the rendered depth test."""

from pathlib import Path

import numpy as np
import pytest

import uav_struct_env
from localization.geometry.transforms import look_at
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.raycast import RayScene
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site, random_site

DUPLEX = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"


def _box_mesh(lo, hi):
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=float)
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return v, np.array(faces)


def test_first_hits_are_exact_on_boxes_a_ground_rectangle_and_an_oriented_box():
    ground = (np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], float),
              np.array([[0, 1, 2], [0, 2, 3]]))
    scene = RayScene([ground, _box_mesh((1, -1, 0), (3, 1, 2))])
    assert scene.n_triangles == 12  # the ground is intersected as its rectangle
    o = np.array([0.0, 0.0, 1.0])
    d = np.array([[1.0, 0, 0],       # hits the box face x = 1 at t = 1
                  [0, 0, -0.5],      # hits the ground at t = 2
                  [-1.0, 0, 0],      # misses everything
                  [1.0, 0, -0.25]])  # ground at x = 4 is behind the box: box face at t = 1
    np.testing.assert_allclose(scene.first_hit(o, d), [1.0, 2.0, np.inf, 1.0])
    assert scene.first_hit(o, d[:1], t_min=1.5)[0] == pytest.approx(3.0)  # the far face
    turned = np.eye(4)
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    turned[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    turned[:3, 3] = [-3.0, 0.0, 1.0]
    scene.boxes = [(turned, np.array([0.5, 0.5, 0.5]))]  # a 1 m cube turned 45 deg, corner at -x
    np.testing.assert_allclose(scene.first_hit(o, d[2:3]), [3.0 - 0.5 * np.sqrt(2)])


def test_several_oriented_boxes_are_tested_at_once_rays_along_an_axis_included():
    scene = RayScene([])
    near_box, far_box = np.eye(4), np.eye(4)
    near_box[:3, 3] = [2.0, 0.0, 0.0]  # faces at x = 1.5 and 2.5
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    far_box[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    far_box[:3, 3] = [5.0, 0.0, 0.0]  # turned 45 deg: its near corner at x = 5 - sqrt(2)/2
    half = np.array([0.5, 0.5, 0.5])
    scene.boxes = [(far_box, half), (near_box, half)]
    o = np.zeros(3)
    d = np.array([[1.0, 0, 0],   # along x (zero y, z): the near box's face first
                  [0, 1.0, 0],   # along y: nothing
                  [1.0, 0, 0.5]])  # climbs over both
    np.testing.assert_allclose(scene.first_hit(o, d), [1.5, np.inf, np.inf])
    scene.boxes = [(far_box, half)]
    assert scene.first_hit(o, d[:1])[0] == pytest.approx(5.0 - np.sqrt(0.5))
    assert scene.first_hit(o, d[:1], t_min=4.0)[0] == pytest.approx(5.0 - np.sqrt(0.5))
    assert scene.first_hit(o, d[:1], t_min=4.5)[0] == np.inf  # entered before t_min: no hit
    # each box alone gives the same first hits as both at once
    scene.boxes = [(near_box, half)]
    alone = np.minimum(scene.first_hit(o, d), RayScene([]).first_hit(o, d))
    scene.boxes = [(far_box, half), (near_box, half)]
    np.testing.assert_array_equal(scene.first_hit(o, d), alone)


def _agreement(world: SiteWorld, site, n_views: int, seed: int, camera: Camera) -> tuple[int, int]:
    rng = np.random.default_rng(seed)
    body = world.add_body((0.161, 0.121, 0.042))
    c = np.asarray(site.center)
    total = disagree = 0
    for _ in range(n_views):
        az, r = rng.uniform(0, 2 * np.pi), rng.uniform(8, 45)
        eye = np.array([c[0] + r * np.cos(az), c[1] + r * np.sin(az), rng.uniform(3, 35)])
        T = look_at(eye, c + rng.uniform(-5, 5, 3))
        B = np.eye(4)
        B[:3, 3] = eye + (c - eye) * rng.uniform(0.05, 0.3)  # an airframe in the line of sight
        world.move_body(body, B)
        rendered = world.render(T, camera, depth=True)
        for name in ("slab_corners", "opening_corners", "column_tops", "aruco"):
            a = world.landmark_truth(name, T, camera, rendered)
            b = world.landmark_truth_raycast(name, T, camera)
            np.testing.assert_array_equal(a["in_frame"], b["in_frame"])
            np.testing.assert_allclose(a["uv"], b["uv"])
            total += int(a["in_frame"].sum())
            disagree += int((a["visible"] != b["visible"]).sum())
    return total, disagree


def _sites():
    sites = [paper_site("columns"), paper_site("slab"), random_site(np.random.default_rng(3))]
    try:
        import ifcopenshell  # noqa: F401
    except ImportError:
        return sites
    from uav_struct_env.site import load_ifc

    return [*sites, load_ifc(DUPLEX, "Level 2/slab")]


def _check(n_views: int) -> None:
    total = disagree = 0
    for k, site in enumerate(_sites()):
        camera = Camera().scaled(128, 72) if k % 2 else Camera().scaled(320, 180)
        # The smallest textures: the depth test and the ray casts see only the geometry, which
        # texture_size leaves unchanged (the same meshes; drawing 512 px textures was most of the cost).
        with SiteWorld(site, renderer="tiny", image_size=(camera.width, camera.height),
                       texture_size=16) as world:
            t, d = _agreement(world, site, n_views, k, camera)
        total, disagree = total + t, disagree + d
    assert total > 40 * n_views
    # Measured (benchmarks/raycast.py --views 60): 4 of 13,414 landmark-views disagree with
    # TinyRenderer and 6 with EGL on six sites; the four are the duplex's opening corners in one
    # view (ray cast: hidden), the EGL extras marker corners on the 1 cm tiles (16-bit depth).
    assert disagree <= 0.001 * total, f"{disagree} of {total} landmark-views disagree"


def test_raycast_visibility_agrees_with_the_rendered_depth_test():
    _check(n_views=12)


@pytest.mark.slow
def test_raycast_visibility_agrees_on_thousands_of_views():
    _check(n_views=500)


def test_an_env_without_images_renders_nothing_and_gives_the_same_truth():
    kw = dict(renderer="tiny", image_size=(160, 90), marker_size=1.0)
    with_images = uav_struct_env.parallel_env(**kw)
    without = uav_struct_env.parallel_env(observe_image=False, **kw)
    try:
        assert "image" not in without.observation_space("uav_0").spaces
        obs_a, info_a = with_images.reset(seed=4, options={"viewpoint": 3})
        obs_b, info_b = without.reset(seed=4, options={"viewpoint": 3})
        for agent in with_images.agents:
            assert set(obs_b[agent]) == {"gnss", "attitude"}
            np.testing.assert_array_equal(obs_a[agent]["gnss"], obs_b[agent]["gnss"])
            for name, truth in info_a[agent]["landmarks"].items():
                np.testing.assert_array_equal(truth["visible"], info_b[agent]["landmarks"][name]["visible"])
    finally:
        with_images.close()
        without.close()


def test_many_oriented_boxes_hit_as_one_by_one_and_a_skipped_box_is_passed_through():
    """The culled, vectorized box test equals a plain per-box slab test on random boxes and rays."""
    rng = np.random.default_rng(4)
    scene = RayScene([])
    boxes = []
    for _ in range(40):
        a, b = rng.uniform(-np.pi, np.pi, 2)
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        Ry = np.array([[np.cos(b), 0, -np.sin(b)], [0, 1, 0], [np.sin(b), 0, np.cos(b)]])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rz @ Ry, rng.uniform(-15, 15, 3)
        boxes.append((T, rng.uniform(0.05, 3.0, 3)))
    scene.boxes = boxes
    o = np.array([0.5, -0.3, 0.2])
    d = rng.normal(size=(500, 3)) * rng.uniform(0.2, 3.0, (500, 1))

    def reference(skip=None):
        best = np.full(len(d), np.inf)
        for i, ray in enumerate(d):
            for k, (T, half) in enumerate(boxes):
                if skip is not None and skip[i] == k:
                    continue
                ob, db = T[:3, :3].T @ (o - T[:3, 3]), T[:3, :3].T @ ray
                with np.errstate(divide="ignore"):
                    t1, t2 = (-half - ob) / db, (half - ob) / db
                lo, hi = np.minimum(t1, t2).max(), np.maximum(t1, t2).min()
                if hi >= lo and lo >= 0:
                    best[i] = min(best[i], lo)
        return best

    expected = reference()
    assert np.isfinite(expected).sum() > 50  # many rays hit something
    np.testing.assert_allclose(scene.first_hit(o, d), expected, rtol=1e-12)
    skip = rng.integers(-1, len(boxes), len(d))
    np.testing.assert_allclose(scene.first_hit(o, d, skip_box=skip), reference(skip), rtol=1e-12)


def test_first_hit_refuses_a_skip_list_of_the_wrong_length():
    scene = RayScene([])
    with pytest.raises(ValueError, match=r"skip_box must hold one box index per ray \(3\)"):
        scene.first_hit(np.zeros(3), np.ones((3, 3)), skip_box=[0, 1])


def test_raycast_visibility_refuses_a_negative_window_radius():
    from uav_struct_env.sim.raycast import raycast_visibility

    camera = Camera()
    pose = look_at(np.array([20.0, 0.0, 10.0]), np.zeros(3))
    with pytest.raises(ValueError, match="radius"):
        raycast_visibility(RayScene([]), np.zeros((1, 3)), [0], pose, camera, radius=-1)
    out = raycast_visibility(RayScene([]), np.zeros((1, 3)), [0], pose, camera, radius=0)
    assert out["in_frame"][0] and out["visible"][0]  # nothing in the scene hides it


def test_the_rays_pass_through_a_skipped_body_such_as_the_cameras_own_airframe():
    site = paper_site("columns")
    camera = Camera().scaled(128, 72)
    with SiteWorld(site, renderer="tiny", image_size=(128, 72)) as world:
        eye = np.asarray(site.center) + [0.0, -25.0, 15.0]
        T = look_at(eye, site.center)
        bare = world.landmark_truth_raycast("column_tops", T, camera)
        assert bare["visible"].sum() >= 8
        ahead = np.eye(4)  # a box 6-14 m ahead of the camera, across the whole view
        view = (np.asarray(site.center) - eye) / np.linalg.norm(np.asarray(site.center) - eye)
        ahead[:3, 3] = eye + 10.0 * view
        body = world.add_body((4.0, 4.0, 4.0), world_from_body=ahead)
        assert not world.landmark_truth_raycast("column_tops", T, camera)["visible"].any()
        skipped = world.landmark_truth_raycast("column_tops", T, camera, skip_body=body)
        np.testing.assert_array_equal(skipped["visible"], bare["visible"])
        with pytest.raises(ValueError, match="skip_body 12345 was not added with add_body"):
            world.landmark_truth_raycast("column_tops", T, camera, skip_body=12345)
