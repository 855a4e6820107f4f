"""Recording episodes inside jit and drawing them on numpy: paths, lasers, GIFs."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import jaxnav
from jaxnav import render

RIGHT, FORWARD = 3, 0
pytestmark = pytest.mark.xdist_group("render")  # one worker records the shared episodes once


def constant(action: int):
    return lambda key, obs: jnp.full(obs.shape[:1], action)


def test_grid_path_runs_through_cell_centres_until_the_wall(open_maze):
    """Always 'right' from column 1 of an empty 7x7 grid: 5 moves, then a collision."""
    env, params = open_maze
    obs, state = jax.vmap(env.reset_to, in_axes=(None, None, 0, 0))(
        jax.random.key(0), params, jnp.array([[2, 1]]), jnp.array([[6, 0]])
    )
    (ep,) = render.record(env, params, constant(RIGHT), obs, state)
    assert render.OUTCOMES[int(ep["outcome"])] == "collision" and int(ep["steps"]) == 6
    size = 7
    expected_x = [1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 6.5]  # the robot stays put on collision
    np.testing.assert_allclose(ep["xy"][:, 0], expected_x)
    np.testing.assert_allclose(ep["xy"][:, 1], size - 2 - 0.5)  # row 2, row 0 at the top
    np.testing.assert_allclose(ep["goal"], [0.5, 0.5])
    assert ep["walls"].shape == (0, 4)  # no obstacles
    assert float(ep["return"]) == pytest.approx(-1.0)


@pytest.fixture(scope="module")
def robot_episodes():
    env, params = jaxnav.make("RobotSimple-v0")
    keys = jax.random.split(jax.random.key(1), 3)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    return env, params, state, render.record(env, params, constant(FORWARD), obs, state)


def test_robot_record_holds_poses_and_the_lasers_of_each(robot_episodes):
    env, params, state, episodes = robot_episodes
    for i, ep in enumerate(episodes):
        steps = int(ep["steps"])
        assert ep["xy"].shape == (steps + 1, 2) and ep["lasers"].shape == (steps + 1, 7)
        np.testing.assert_allclose(ep["xy"][0], state.pose[i, :2])
        np.testing.assert_allclose(ep["heading"], state.pose[i, 2], atol=1e-5)  # no turns
        pose = jnp.append(jnp.asarray(ep["xy"][-1]), ep["heading"][-1])
        np.testing.assert_allclose(
            ep["lasers"][-1], env.lasers(pose, state.layout[i], params), rtol=1e-5
        )
        assert render.OUTCOMES[int(ep["outcome"])] in ("success", "collision")  # never turns
        assert ep["walls"].shape[1] == 4 and (ep["walls"][:, 2:] > 0).all()


def test_gif_has_a_frame_per_step_and_is_written_whole(robot_episodes, tmp_path):
    *_, episodes = robot_episodes
    path = tmp_path / "robot.gif"
    frames = render.save_gif(episodes[:2], path, fps=20, max_frames=40)
    longest = max(int(ep["steps"]) for ep in episodes[:2])
    stride = -(-(longest + 1) // 40)  # every step, or every k-th past 40 frames
    shown = sorted({*range(0, longest + 1, stride), longest})  # always ends on the last step
    assert frames == len(shown)
    with Image.open(path) as img:
        assert img.format == "GIF" and img.n_frames == frames
    assert [p.name for p in tmp_path.iterdir()] == ["robot.gif"]


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--episodes", "0"], "--episodes 0"),
        (["--out", "x.mp4"], "x.mp4"),
        (["--out", "no/such/dir/x.gif"], "no/such/dir"),
    ],
)
def test_render_cli_refuses_bad_input(args, named, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert render.main([str(tmp_path), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert named in err and err.count("\n") == 0
    assert list(tmp_path.iterdir()) == []


def test_render_cli_refuses_a_directory_that_is_no_run(tmp_path, capsys):
    assert render.main([str(tmp_path), "--out", str(tmp_path / "t.gif")]) == 2
    assert "not a run directory" in capsys.readouterr().err


def legend_labels(fig) -> list[str]:
    (legend,) = fig.legends
    return [t.get_text() for t in legend.get_texts()]


def ray_segments(ax) -> list[np.ndarray]:
    """Every laser ray drawn in ``ax``, as [2, 2] (start, end) segments."""
    found = [c for c in ax.collections if c.get_label() == "laser rays"]
    return [np.asarray(s) for c in found for s in c.get_segments()]


def test_gif_frame_has_a_legend_and_the_rays_of_the_current_pose(robot_episodes):
    import matplotlib.pyplot as plt

    *_, episodes = robot_episodes
    fig, show = render.animation_figure(episodes[:2], title="two episodes")
    try:
        assert legend_labels(fig) == ["robot", "goal", "laser rays", "path", "start"]
        show(3)
        for ax, ep in zip(fig.axes, episodes[:2], strict=False):
            rays = ray_segments(ax)
            t = min(3, int(ep["steps"]))
            assert len(rays) == 7  # one pose's lasers
            np.testing.assert_allclose([r[0] for r in rays], np.tile(ep["xy"][t], (7, 1)))
            lengths = [np.linalg.norm(r[1] - r[0]) for r in rays]
            np.testing.assert_allclose(lengths, ep["lasers"][t], rtol=1e-5)
            assert ax.get_title() == f"step {t}"
    finally:
        plt.close(fig)


def test_png_draws_the_rays_of_the_last_pose_only_and_titles_carry_metres(robot_episodes):
    import matplotlib.pyplot as plt

    *_, episodes = robot_episodes
    fig = render.trajectories_figure(episodes, "three episodes")
    try:
        assert legend_labels(fig) == ["robot", "goal", "laser rays", "path", "start"]
        for ax, ep in zip(fig.axes, episodes, strict=False):
            rays = ray_segments(ax)
            assert len(rays) == 7
            np.testing.assert_allclose([r[0] for r in rays], np.tile(ep["xy"][-1], (7, 1)))
            orange = [ln for ln in ax.lines if ln.get_color() == render.RAY_COLOR]
            assert orange == []  # no rays of other poses drawn as lines
            if float(ep["shortest_path"]) > 0:
                assert f"{float(ep['shortest_path']):.3g} m)" in ax.get_title().replace("\n", " ")
    finally:
        plt.close(fig)


def test_grid_lengths_are_in_cells(open_maze):
    env, params = open_maze
    obs, state = jax.vmap(env.reset_to, in_axes=(None, None, 0, 0))(
        jax.random.key(0), params, jnp.array([[2, 1]]), jnp.array([[6, 0]])
    )
    (ep,) = render.record(env, params, constant(RIGHT), obs, state)
    assert render.describe(ep).endswith(f"(shortest {float(ep['shortest_path']):.3g} cells)")


def test_waypoint_is_recorded_and_in_the_legend():
    import matplotlib.pyplot as plt

    env, params = jaxnav.make("RobotSimple-v0", waypoint_distance=1.0)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(jax.random.key(2), 1), params
    )
    (ep,) = render.record(env, params, constant(FORWARD), obs, state)
    assert ep["waypoint"].shape == (int(ep["steps"]) + 1, 2)
    fig, show = render.animation_figure([ep])
    try:
        assert "waypoint" in legend_labels(fig)
        show(0)
        (marker,) = [ln for ln in fig.axes[0].lines if ln.get_label() == "waypoint"]
        np.testing.assert_allclose(np.ravel(marker.get_xydata()), ep["waypoint"][0])
    finally:
        plt.close(fig)


def test_long_render_says_its_progress_on_stderr(robot_episodes, tmp_path, capsys):
    *_, episodes = robot_episodes
    progress = render.Progress(after=0.0, every=0.0)  # every frame counts as long
    frames = render.save_gif(episodes[:1], tmp_path / "x.gif", progress=progress)
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [f"frame {i}/{frames}" for i in range(1, frames + 1)]
    render.save_gif(episodes[:1], tmp_path / "y.gif", progress=render.Progress(quiet=True))
    assert capsys.readouterr().err == ""


def test_a_slow_step_says_what_it_waits_for(capsys):
    import time

    with render.Progress(after=0.01).waiting("compiling the episodes..."):
        time.sleep(0.5)
    with render.Progress(after=0.01, quiet=True).waiting("compiling the episodes..."):
        time.sleep(0.1)
    assert capsys.readouterr().err == "compiling the episodes...\n"


def test_failed_gif_leaves_no_file_and_no_figure(robot_episodes, tmp_path):
    import matplotlib.pyplot as plt

    *_, episodes = robot_episodes
    broken = {k: v for k, v in episodes[0].items() if k != "lasers"}
    with pytest.raises(KeyError):
        render.save_gif([episodes[1], broken], tmp_path / "x.gif")
    assert list(tmp_path.iterdir()) == []
    assert plt.get_fignums() == []
