"""Renderer (pygame, headless) and video writer tests, on a hand-made WorldState."""

import os

os.environ["SDL_VIDEODRIVER"] = "dummy"  # before pygame is imported anywhere
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import copy  # noqa: E402
import pickle  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from swarm_env.geometry.static_map import StaticMap  # noqa: E402
from swarm_env.harness.video import VideoWriter, save_frame_png  # noqa: E402
from swarm_env.render import (  # noqa: E402
    BACKGROUND,
    CONTACT,
    FLASH_STEPS,
    FOLLOWER_COLOURS,
    HUMAN_FILL,
    LEADER,
    OBSTACLE_FILL,
    Renderer,
    _dashes,
    _mix,
)
from swarm_env.scenario import (  # noqa: E402
    CircleObstacle,
    FormationSpec,
    LeaderSpec,
    PolygonObstacle,
    RectangleObstacle,
    RobotSpec,
    Scenario,
    WorldSpec,
)
from swarm_env.state import Contact, WorldState  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
W, H = 16.0, 10.0


def make_scenario(leader_kind: str = "robot", size: tuple[float, float] = (W, H)) -> Scenario:
    return Scenario(
        name="render-test",
        world=WorldSpec(size=size, dt=0.1),
        robots=RobotSpec(count=3),
        leader=LeaderSpec(kind=leader_kind, path=((1.0, 5.0), (6.0, 5.0), (10.0, 7.0), (15.0, 7.0)), speed=0.5),
        formations=(FormationSpec(at=0.0, shape="v"), FormationSpec(at=20.0, shape="line")),
        obstacles=(
            CircleObstacle((8.0, 2.5), 0.8),
            RectangleObstacle((4.0, 8.0), (1.5, 1.0), 20.0),
            PolygonObstacle(((11.0, 8.2), (13.0, 8.2), (12.0, 9.5))),
        ),
    )


def make_state(
    scenario: Scenario | None = None,
    *,
    time: float = 12.3,
    follower_xy: np.ndarray | None = None,
    contacts: tuple[Contact, ...] = (),
    static: StaticMap | None = None,
) -> WorldState:
    sc = scenario if scenario is not None else make_scenario()
    if static is None:
        static = StaticMap.from_obstacles(sc.world.size, sc.obstacles)
    xy = np.array([[5.0, 6.5], [5.0, 3.5], [3.0, 1.5]]) if follower_xy is None else np.asarray(follower_xy, float)
    pose = np.column_stack([xy, [0.0, 0.5, -1.0]])
    return WorldState(
        time=time,
        step=int(round(time / sc.world.dt)),
        follower_pose=pose,
        follower_vel=np.zeros((3, 2)),
        follower_twist=np.zeros((3, 2)),
        follower_radius=np.full(3, 0.25),
        leader_pose=np.array([7.0, 5.5, 0.4]),
        leader_vel=np.array([0.46, 0.19]),
        leader_twist=np.array([0.5, 0.0]),
        leader_radius=0.25 if sc.leader.kind == "robot" else 0.0,
        leader_done=False,
        human_pos=np.array([[13.0, 2.0]]),
        human_vel=np.array([[-0.4, 0.3]]),
        human_radius=np.array([0.3]),
        slot_targets=np.array([[6.0, 7.5], [6.0, 4.0], [2.0, 3.0]]),
        formation_index=0,
        next_switch_time=20.0,
        contacts=contacts,
        static=static,
        scenario=sc,
    )


def pixel(r: Renderer, img: np.ndarray, xy: tuple[float, float]) -> tuple[int, ...]:
    px, py = np.round(r.world_to_pixels(np.array(xy))).astype(int)
    return tuple(int(v) for v in img[py, px])


def colour_near(r: Renderer, img: np.ndarray, xy: tuple[float, float], colour: tuple[int, int, int], rad: int) -> bool:
    px, py = np.round(r.world_to_pixels(np.array(xy))).astype(int)
    patch = img[py - rad : py + rad + 1, px - rad : px + rad + 1]
    return bool(np.all(patch == np.array(colour, np.uint8), axis=-1).any())


@pytest.fixture()
def rendered() -> tuple[Renderer, WorldState, np.ndarray]:
    state = make_state()
    r = Renderer("rgb_array", state.scenario)
    r.reset()
    r.record(state)
    return r, state, r.render(state)


def test_rgb_array_size_and_type(rendered) -> None:
    r, state, img = rendered
    w, h = r.size
    assert img.shape == (h, w, 3) and img.dtype == np.uint8
    assert max(w, h) == 800 and w % 2 == 0 and h % 2 == 0
    assert w > h  # a 16 x 10 m world is wider than high
    # a fresh array every call: scribbling on one frame does not show in the next
    img[:] = 0
    again = r.render(state)
    assert again is not img and again.max() == 255


def test_pixels_per_metre_sets_size() -> None:
    sc = make_scenario()
    r = Renderer("rgb_array", sc, pixels_per_metre=20.0)
    assert r.pixels_per_metre == 20.0
    img = r.render(make_state(sc))
    assert img.shape[1] >= 16 * 20 and img.shape[0] >= 10 * 20
    # a world of another size re-lays the image out
    small = make_scenario(size=(8.0, 12.0))
    img2 = r.render(make_state(small, follower_xy=[[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]))
    assert img2.shape[0] > img2.shape[1] and r.scenario is small


def test_world_to_pixels_flips_y(rendered) -> None:
    r, _, _ = rendered
    bottom_left, top_right = r.world_to_pixels(np.array([[0.0, 0.0], [W, H]]))
    assert top_right[0] > bottom_left[0] and top_right[1] < bottom_left[1]
    assert np.isclose(top_right[0] - bottom_left[0], W * r.pixels_per_metre)


def test_obstacles_gray_and_background_white(rendered) -> None:
    r, _, img = rendered
    assert pixel(r, img, (8.0, 2.5)) == OBSTACLE_FILL  # circle centre
    assert pixel(r, img, (4.0, 8.0)) == OBSTACLE_FILL  # rotated rectangle centre
    assert pixel(r, img, (12.0, 8.7)) == OBSTACLE_FILL  # triangle interior
    assert pixel(r, img, (10.5, 3.5)) == BACKGROUND  # empty, off the grid lines
    assert pixel(r, img, (1.5, 8.5)) == BACKGROUND


def test_robots_humans_and_slots_drawn_in_their_colours(rendered) -> None:
    r, state, img = rendered
    rad = int(0.15 * r.pixels_per_metre)  # well inside a 0.25 m disc
    for i, xy in enumerate(state.follower_pose[:, :2]):
        assert colour_near(r, img, tuple(xy), FOLLOWER_COLOURS[i], rad), i
        # its slot target: a light disc of the same colour
        assert pixel(r, img, tuple(state.slot_targets[i])) == _mix(FOLLOWER_COLOURS[i], 0.25)
    assert colour_near(r, img, (13.0, 2.0), HUMAN_FILL, rad)
    assert colour_near(r, img, (7.0, 5.5), LEADER, rad)
    # followers are placed by world y up: follower 0 (y = 6.5) is drawn above follower 1 (y = 3.5)
    rows = [np.nonzero(np.all(img == np.array(FOLLOWER_COLOURS[i], np.uint8), axis=-1))[0].mean() for i in (0, 1)]
    assert rows[0] < rows[1]


def test_virtual_leader_is_a_black_dot() -> None:
    sc = make_scenario("virtual")
    state = make_state(sc)
    r = Renderer("rgb_array", sc)
    img = r.render(state)
    assert pixel(r, img, (7.0, 5.5)) == LEADER
    assert pixel(r, img, (7.0 + 0.22, 5.5)) != LEADER  # smaller than a 0.25 m robot disc


def test_contact_flash_and_collision_count() -> None:
    sc = make_scenario()
    static = StaticMap.from_obstacles(sc.world.size, sc.obstacles)
    r = Renderer("rgb_array", sc)
    ring = 0.25 + 3.0 / r.pixels_per_metre  # the ring is drawn 3 px outside the disc
    hit = make_state(sc, static=static, contacts=(Contact("robot_robot", 0, 1), Contact("robot_wall", 2, 0)))
    r.record(hit)
    img = r.render(hit)
    assert r.collisions == 2
    for i in range(3):
        x, y = hit.follower_pose[i, :2]
        assert colour_near(r, img, (x + ring, y), CONTACT, 2), i
    calm = make_state(sc, static=static)
    for _ in range(FLASH_STEPS):
        r.record(calm)
    img = r.render(calm)
    assert not np.all(img == np.array(CONTACT, np.uint8), axis=-1).any()
    assert r.collisions == 2  # counted so far, not per step
    r.reset()
    assert r.collisions == 0


def test_trails_follow_recorded_positions() -> None:
    sc = make_scenario()
    static = StaticMap.from_obstacles(sc.world.size, sc.obstacles)
    r = Renderer("rgb_array", sc, trail_length=10)
    empty_spot = (2.3, 6.5)  # off the 1 m grid lines
    for k in range(20):  # follower 0 walks left to right along y = 6.5
        xy = np.array([[1.0 + 0.2 * k, 6.5], [5.0, 3.5], [3.0, 1.5]])
        r.record(make_state(sc, follower_xy=xy, static=static))
    img = r.render(make_state(sc, follower_xy=xy, static=static))
    # only the last 10 positions (x from 2.8 to 4.8) are kept: x = 2.3 was forgotten
    assert pixel(r, img, empty_spot) == BACKGROUND
    px = np.round(r.world_to_pixels(np.array([3.5, 6.5]))).astype(int)
    column = img[px[1] - 2 : px[1] + 3, px[0]].astype(int)
    assert (np.abs(column - np.array(BACKGROUND)).sum(axis=1) > 30).any()  # a visible trail pixel
    r.reset()
    img = r.render(make_state(sc, follower_xy=xy, static=static))
    assert np.all(img[px[1] - 2 : px[1] + 3, px[0]] == np.array(BACKGROUND, np.uint8))


def test_text_overlay_and_missing_font(rendered, monkeypatch) -> None:
    r, state, img = rendered
    header = img[: r.header, : r.size[0] // 2]
    assert (header.sum(axis=-1) < 200).any()  # dark text pixels

    import pygame

    def no_font(*args, **kwargs):
        raise RuntimeError("no fonts here")

    monkeypatch.setattr(pygame.font, "Font", no_font)
    bare = Renderer("rgb_array", state.scenario)
    img2 = bare.render(state)
    assert np.all(img2[: bare.header - 2, : bare.size[0] // 2] == 255)


def test_pickle_and_deepcopy_after_render(rendered) -> None:
    r, state, img = rendered
    clone = pickle.loads(pickle.dumps(r))
    assert np.array_equal(clone.render(state), img)
    twin = copy.deepcopy(r)
    assert np.array_equal(twin.render(state), img)
    assert r._canvas is not None and twin._canvas is not r._canvas


def test_import_does_not_import_pygame() -> None:
    code = "import sys, swarm_env.render, swarm_env.harness.video, swarm_env; assert 'pygame' not in sys.modules, 'pygame imported'"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr


def test_human_mode_under_dummy_driver() -> None:
    state = make_state()
    r = Renderer("human", state.scenario, fps=1000)
    r.record(state)
    assert r.render(state) is None
    import pygame

    assert pygame.display.get_surface().get_size() == r.size
    assert r.render(state) is None
    r.close()
    assert r._window is None
    pickle.dumps(r)
    assert r.render(state) is None  # reopens after close
    r.close()


def test_bad_arguments() -> None:
    sc = make_scenario()
    with pytest.raises(ValueError, match="render mode"):
        Renderer("ansi", sc)
    with pytest.raises(ValueError, match="pixels_per_metre"):
        Renderer("rgb_array", sc, pixels_per_metre=0.0)


def test_dashes_cover_the_path_periodically() -> None:
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0]])
    dashes = _dashes(pts, 3.0, 2.0)
    assert len(dashes) == 3  # starts at 0, 5, 10 along a 15-long path
    lengths = [np.hypot(*np.diff(d, axis=0).T).sum() for d in dashes]
    assert np.allclose(lengths, 3.0)
    assert np.allclose(dashes[2][[0, -1]], [[10.0, 0.0], [10.0, 3.0]])
    bent = dashes[1]  # from 5 to 8 along x: straight
    assert np.allclose(bent[[0, -1]], [[5.0, 0.0], [8.0, 0.0]])


def test_video_mp4_round_trip(tmp_path) -> None:
    import imageio.v2 as iio

    path = tmp_path / "clip.mp4"
    rng = np.random.default_rng(0)
    with VideoWriter(path, fps=10) as video:
        for k in range(7):
            frame = np.full((21, 33, 3), 20 * k, np.uint8)  # odd sides: padded to even
            frame[:5, :5] = rng.integers(0, 255, (5, 5, 3))
            video.append(frame)
    assert video.n_frames == 7
    reader = iio.get_reader(path)
    frames = [f for f in reader]  # not list(reader): its length hint is inf for mp4
    reader.close()
    assert len(frames) == 7
    assert frames[0].shape == (22, 34, 3)
    assert abs(int(frames[6][15, 20, 0]) - 120) < 8  # lossy, but close


def test_video_gif_and_png(tmp_path, rendered) -> None:
    import imageio.v3 as iio3

    _, _, img = rendered
    gif = tmp_path / "clip.gif"
    with VideoWriter(gif, fps=5) as video:
        for k in range(3):  # distinct frames: pillow merges identical consecutive GIF frames
            video.append(np.roll(img, 40 * k, axis=1))
    assert iio3.imread(gif, index=None).shape[0] == 3
    png = tmp_path / "frame.png"
    save_frame_png(png, img)
    assert np.array_equal(iio3.imread(png), img)


def test_video_rejects_bad_input(tmp_path) -> None:
    with pytest.raises(ValueError, match="unsupported"):
        VideoWriter(tmp_path / "x.avi", fps=10)
    with pytest.raises(ValueError, match="fps"):
        VideoWriter(tmp_path / "x.mp4", fps=0)
    video = VideoWriter(tmp_path / "x.gif", fps=10)
    video.append(np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match="differs"):
        video.append(np.zeros((8, 10, 3), np.uint8))
    with pytest.raises(TypeError):
        video.append(np.zeros((8, 8, 3), np.float32))
    video.close()
    with pytest.raises(RuntimeError):
        video.append(np.zeros((8, 8, 3), np.uint8))
