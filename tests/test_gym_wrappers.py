"""Gymnasium around the env: per-episode domain randomisation, standard render modes, Gymnasium's own
image wrappers (with the ``gym-wrappers`` extra), and ``check_env`` on wrapped envs."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import proxybench  # noqa: F401 - registers the env
from proxybench.domain import env_render
from proxybench.domain.env import LaneFollowingEnv, LaneFollowingVectorEnv
from proxybench.domain.params import DomainParams, ParamSpace
from proxybench.domain.randomization import DomainRandomization
from proxybench.media import side_by_side

SMALL = {"image_width": 40, "image_height": 30}
DISTS = {"trim": {"uniform": [-0.2, 0.2]}, "camera_pitch": {"normal": [19.0, 2.0]},
         "light_rgb": {"uniform": [0.7, 1.3]}}


def make(**kwargs) -> gym.Env:
    return gym.make("proxybench/LaneFollowing-v0", params=SMALL, episode_seconds=2.0, **kwargs)


def rollout(env: gym.Env, seed: int | None, steps: int = 5) -> tuple[dict, np.ndarray]:
    obs, info = env.reset(seed=seed)
    frames = [obs]
    for _ in range(steps):
        obs, *_ = env.step(np.array([0.4, 0.5], dtype=np.float32))
        frames.append(obs)
    return info["params"], np.stack(frames)


# ---------------------------------------------------------------------------------------------------
# Domain randomisation


def test_each_reset_draws_a_new_theta_that_the_episode_runs_in():
    env = DomainRandomization(make(), DISTS)
    thetas = []
    for k in range(4):
        _, info = env.reset(seed=None if k else 1)
        thetas.append(info["params"])
        sim_params = env.unwrapped.sim.params[0]
        assert sim_params == env.params  # the episode runs in the drawn θ
        assert sim_params.trim == info["params"]["trim"] and sim_params.image_width == 40
    assert len({t["trim"] for t in thetas}) == 4
    assert all(-0.2 <= t["trim"] <= 0.2 and len(t["light_rgb"]) == 3 for t in thetas)


def test_the_same_seed_gives_the_same_theta_and_episode_and_the_same_sequence_after_it():
    a, b = DomainRandomization(make(), DISTS), DomainRandomization(make(), DISTS, seed=99)
    for env in (a, b):  # b has another construction seed and history: the reset seed decides
        env.reset(seed=123)
    runs_a = [rollout(a, s) for s in (7, None, None)]
    runs_b = [rollout(b, s) for s in (7, None, None)]
    for (ta, fa), (tb, fb) in zip(runs_a, runs_b, strict=True):
        assert ta == tb
        np.testing.assert_array_equal(fa, fb)
    assert runs_a[0][0] != runs_a[1][0]
    assert rollout(a, 8)[0] != runs_a[0][0]


def test_the_construction_seed_fixes_the_thetas_before_any_seeded_reset():
    t1 = [DomainRandomization(make(), DISTS, seed=5).reset()[1]["params"] for _ in range(2)]
    assert t1[0] == t1[1]


def test_a_space_with_its_own_base_and_bad_inputs():
    space = ParamSpace(DomainParams(**SMALL, trim=0.3), {"command_delay": {"choice": [0.0, 0.1]}})
    env = DomainRandomization(make(), space)
    env.reset(seed=0)
    assert env.unwrapped.params.trim == 0.3 and env.unwrapped.params.command_delay in (0.0, 0.1)
    with pytest.raises(ValueError, match="the space's base has image_width=640, the env 40"):
        DomainRandomization(make(), ParamSpace(None, {"trim": {"uniform": [0, 0.1]}}))
    with pytest.raises(TypeError, match="needs a proxybench env"):
        DomainRandomization(gym.make("CartPole-v1"), DISTS)
    with pytest.raises(ValueError, match="unknown domain parameter 'trimm'"):
        DomainRandomization(make(), {"trimm": {"uniform": [0, 1]}})


def test_check_env_passes_on_the_wrapped_env():
    env = DomainRandomization(gym.make("proxybench/LaneFollowing-v0", params=SMALL, render_mode="rgb_array"),
                              DISTS)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version.*")
        check_env(env)
    state = DomainRandomization(gym.make("proxybench/LaneFollowing-v0", params=SMALL, observation="state"), DISTS)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version.*")
        check_env(state, skip_render_check=True)


def test_make_vec_with_the_wrapper_gives_each_robot_its_own_theta():
    envs = gym.make_vec("proxybench/LaneFollowing-v0", num_envs=3, vectorization_mode="sync",
                        params=SMALL, observation="state", wrappers=[lambda e: DomainRandomization(e, DISTS)])
    try:
        _, infos = envs.reset(seed=0)
        assert len(set(infos["params"]["trim"])) == 3
    finally:
        envs.close()


# ---------------------------------------------------------------------------------------------------
# Render modes


def test_render_modes_are_gymnasiums():
    assert LaneFollowingEnv.metadata["render_modes"] == ["rgb_array", "human"]
    assert LaneFollowingVectorEnv.metadata["render_modes"] == ["rgb_array"]
    with pytest.raises(ValueError, match=r"render_view='top_down'"):
        LaneFollowingEnv(params=SMALL, render_mode="top_down")
    with pytest.raises(ValueError, match="render_view must be one of"):
        LaneFollowingEnv(params=SMALL, render_view="side")


@pytest.mark.parametrize("view", ["camera", "top_down", "both"])
def test_rgb_array_views(view):
    env = LaneFollowingEnv(params=SMALL, render_mode="rgb_array", render_view=view)
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    if view == "camera":
        np.testing.assert_array_equal(frame, obs)
    elif view == "both":  # the camera on the left, beside the map, both scaled to one height
        top = env_render.view_frame(env.sim, 0, "top_down")
        np.testing.assert_array_equal(frame, side_by_side(obs, top))
    vec = LaneFollowingVectorEnv(num_envs=2, params=SMALL, render_mode="rgb_array", render_view=view)
    vec.reset(seed=0)
    vframes = vec.render()
    assert vframes.dtype == np.uint8 and vframes.ndim == (3 if view == "top_down" else 4)


def test_rgb_array_list_through_make():
    env = make(render_mode="rgb_array_list")
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.zeros(2, dtype=np.float32))
    frames = env.render()
    assert isinstance(frames, list) and len(frames) == 4 and frames[0].shape == (30, 40, 3)


def test_human_mode_without_a_screen_warns_once_and_runs(monkeypatch):
    monkeypatch.setattr(env_render, "has_screen", lambda: False)
    env = make(render_mode="human")
    with pytest.warns(UserWarning, match="render_mode='human' shows nothing here") as record:
        env.reset(seed=0)
        for _ in range(3):
            env.step(np.zeros(2, dtype=np.float32))
    assert sum("shows nothing" in str(w.message) for w in record) == 1
    assert env.render() is None
    env.close()


def test_human_mode_shows_every_frame_in_a_window(monkeypatch):
    import matplotlib

    matplotlib.use("Agg")  # no screen in tests: drive the window code on the non-interactive backend
    monkeypatch.setattr(env_render, "has_screen", lambda: True)
    shown = []
    monkeypatch.setattr(env_render.HumanWindow, "show", lambda self, frame: shown.append(frame))
    env = LaneFollowingEnv(params=SMALL, render_mode="human", render_view="both")
    assert env.metadata["render_fps"] == 15.0
    env.reset(seed=0)
    obs, *_ = env.step(np.zeros(2, dtype=np.float32))
    assert env.render() is None and len(shown) == 2
    np.testing.assert_array_equal(shown[-1], side_by_side(obs, env_render.view_frame(env.sim, 0, "top_down")))
    env.close()


def test_the_human_window_draws_the_frames_it_is_given():
    import matplotlib

    matplotlib.use("Agg")
    frames = [np.full((30, 40, 3), v, dtype=np.uint8) for v in (10, 200)]
    window = env_render.HumanWindow("t", fps=1000.0)
    for frame in frames:
        window.show(frame)
    np.testing.assert_array_equal(np.asarray(window.image.get_array()), frames[1])
    window.close()


# ---------------------------------------------------------------------------------------------------
# Gymnasium's image wrappers: ResizeObservation needs OpenCV, RecordVideo MoviePy (the extra gym-wrappers)


def test_resize_and_grayscale_observation_wrappers():
    env = gym.wrappers.GrayscaleObservation(gym.wrappers.ResizeObservation(make(), (15, 20)), keep_dim=True)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (15, 20, 1) and obs.dtype == np.uint8
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version.*")
        check_env(env, skip_render_check=True)


def test_record_video_wrapper_writes_an_mp4(tmp_path):
    env = gym.wrappers.RecordVideo(make(render_mode="rgb_array", render_view="both"), str(tmp_path / "videos"),
                                   episode_trigger=lambda k: True, disable_logger=True)
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.array([0.4, 0.4], dtype=np.float32))
    env.close()
    (video,) = (tmp_path / "videos").glob("*.mp4")
    assert video.stat().st_size > 1000
