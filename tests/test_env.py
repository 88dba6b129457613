"""Gymnasium envs: registration, API conformance, determinism, batching equivalence, episode ends, info."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pydantic import ValidationError

import proxybench
from proxybench.domain.env import LaneFollowingEnv, LaneFollowingVectorEnv, RewardWeights
from proxybench.domain.lane_pose import LANE_POSE_FIELDS, LP, LanePose

TS = 0.585
SMALL = {"image_width": 80, "image_height": 60}
# randomness everywhere it can be: sensor noise, latency jitter, surface grain, motion blur
NOISY = {**SMALL, "noise_std": 6.0, "delay_jitter": 0.05, "texture_noise": 0.06, "blur_time": 0.05}


def test_import_registers_the_env():
    assert proxybench.__version__
    spec = gym.spec("proxybench/LaneFollowing-v0")
    assert spec.entry_point == "proxybench.domain.env:LaneFollowingEnv"
    env = gym.make("proxybench/LaneFollowing-v0", params=SMALL)
    try:
        assert isinstance(env.unwrapped, LaneFollowingEnv)
        obs, _ = env.reset(seed=0)
        assert obs.shape == (60, 80, 3)
    finally:
        env.close()


def test_make_vec_uses_the_batched_env():
    envs = gym.make_vec("proxybench/LaneFollowing-v0", num_envs=3, vectorization_mode="vector_entry_point",
                        params=SMALL)
    try:
        assert isinstance(envs.unwrapped, LaneFollowingVectorEnv)
        obs, _ = envs.reset(seed=0)
        assert obs.shape == (3, 60, 80, 3)
    finally:
        envs.close()


def rollout(envs, steps: int = 6) -> list[np.ndarray]:
    """Observations of a few steps of a vector env (reset with seed 3: env i gets seed 3 + i)."""
    obs, _ = envs.reset(seed=3)
    out = [obs.copy()]
    for k in range(steps):
        obs, *_ = envs.step(np.full((envs.num_envs, 2), 0.25 + 0.02 * k, dtype=np.float32))
        out.append(obs.copy())
    return out


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_sync_and_async_equal_the_batched_env(mode):
    """Gymnasium's own vector envs (async: one forked worker per env) give the batched env's frames,
    also after this process has run the renderer on all its threads (GNU OpenMP aborted forked children)."""
    from proxybench.domain.parallelism import force_parallel

    big = {**SMALL, "image_width": 320, "image_height": 240}
    force_parallel(True)
    try:
        warm = LaneFollowingEnv(params=big)
        warm.reset(seed=0)
        warm.step(np.array([0.3, 0.3]))  # the parent enters the threading layer before the fork
    finally:
        force_parallel(None)
    envs = gym.make_vec("proxybench/LaneFollowing-v0", num_envs=3, vectorization_mode=mode, params=big)
    batched = gym.make_vec("proxybench/LaneFollowing-v0", num_envs=3, vectorization_mode="vector_entry_point",
                           params=big)
    try:
        for a, b in zip(rollout(envs), rollout(batched), strict=True):
            np.testing.assert_array_equal(a, b)
    finally:
        envs.close()
        batched.close()


def test_check_env_passes_camera():
    env = gym.make("proxybench/LaneFollowing-v0", params=NOISY)
    try:
        # made through gym.make, the env has a spec, so the checker also tries every advertised render mode
        check_env(env.unwrapped)
    finally:
        env.close()


def test_check_env_passes_state_observation_without_render_modes():
    check_env(LaneFollowingEnv(params=SMALL, observation="state"), skip_render_check=True)


def test_check_env_passes_state_observation_through_make():
    env = gym.make("proxybench/LaneFollowing-v0", params=SMALL, observation="state")
    try:
        check_env(env.unwrapped)
    finally:
        env.close()


def test_spaces():
    env = LaneFollowingEnv(params=SMALL)
    assert env.observation_space == gym.spaces.Box(0, 255, (60, 80, 3), np.uint8)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    state_env = LaneFollowingEnv(params=SMALL, observation="state")
    obs, _ = state_env.reset(seed=0)
    assert obs.shape == (4,) and obs.dtype == np.float32
    assert env.metadata["render_fps"] == 15.0


# ---------------------------------------------------------------------------------------------------
# Determinism and batching


def _actions(seed: int, n: int, shape=(2,)) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.2, 1.0, (n, *shape)).astype(np.float32)


def test_same_seed_bit_identical_episodes():
    envs = [LaneFollowingEnv(params=NOISY) for _ in range(2)]
    first = [e.reset(seed=42) for e in envs]
    np.testing.assert_array_equal(first[0][0], first[1][0])
    for a in _actions(0, 50):
        (o0, r0, te0, tr0, i0), (o1, r1, te1, tr1, i1) = (e.step(a) for e in envs)
        np.testing.assert_array_equal(o0, o1)
        np.testing.assert_array_equal(i0["pose"], i1["pose"])
        np.testing.assert_array_equal(envs[0].sim.lane, envs[1].sim.lane)  # NaN where off the lanes
        assert r0 == r1 and te0 == te1 and tr0 == tr1
        assert i0["reward_terms"] == i1["reward_terms"]
        # (no break at termination: the physics runs on, and must stay identical)


def test_different_seed_different_start():
    env = LaneFollowingEnv(params=SMALL)
    _, a = env.reset(seed=1)
    _, b = env.reset(seed=2)
    assert not np.array_equal(a["pose"], b["pose"])


def test_reset_with_pose_option():
    env = LaneFollowingEnv(map="straight_road", params=SMALL)
    _, info = env.reset(seed=0, options={"pose": (1.0, 1.28 * TS + 0.02, 0.1)})
    np.testing.assert_allclose(info["pose"], [1.0, 1.28 * TS + 0.02, 0.1])
    assert info["lane_pose"].lateral == pytest.approx(0.02, abs=1e-9)
    assert info["lane_pose"].heading_error == pytest.approx(0.1, abs=1e-9)
    assert "reward_terms" not in info


def _compare(vec_obs, vec_info, i, obs, info, env):
    np.testing.assert_array_equal(vec_obs[i], obs)
    np.testing.assert_array_equal(vec_info["pose"][i], info["pose"])
    np.testing.assert_array_equal(vec_info["velocity"][i], info["velocity"])
    np.testing.assert_array_equal(vec_info["lane_pose"][i], env.sim.lane[0])
    lp = LanePose.from_row(vec_info["lane_pose"][i])
    assert (lp.valid, lp.segment, lp.in_lane, lp.on_road) == (
        info["lane_pose"].valid, info["lane_pose"].segment, info["lane_pose"].in_lane, info["lane_pose"].on_road
    )
    assert vec_info["on_road"][i] == info["on_road"]
    assert vec_info["time"][i] == info["time"]


def test_vector_env_equals_single_envs_across_autoreset():
    n, seed, steps = 4, 100, 60
    vec = LaneFollowingVectorEnv(num_envs=n, params=NOISY, episode_seconds=1.5)
    singles = [LaneFollowingEnv(params=NOISY, episode_seconds=1.5) for _ in range(n)]
    vobs, vinfo = vec.reset(seed=seed)
    assert vobs.shape == (n, 60, 80, 3)
    for i, env in enumerate(singles):
        obs, info = env.reset(seed=seed + i)
        _compare(vobs, vinfo, i, obs, info, env)
    actions = _actions(5, steps, (n, 2))
    actions[:, 0] = (1.0, 0.1)  # robot 0 turns hard right: off the road, terminated
    actions[:, 1, 1] = 1.0
    done = np.zeros(n, dtype=bool)
    n_resets, n_terminated, n_truncated = 0, 0, 0
    for t in range(steps):
        vobs, vrew, vterm, vtrunc, vinfo = vec.step(actions[t])
        assert set(vinfo["reward_terms"]) == {"progress", "lateral", "heading", "off_road"}
        for i, env in enumerate(singles):
            if done[i]:
                # next-step autoreset: this step only resets robot i, with nothing earned
                obs, info = env.reset(seed=None)
                assert vrew[i] == 0.0 and not vterm[i] and not vtrunc[i]
                assert all(v[i] == 0.0 for v in vinfo["reward_terms"].values())
                assert vinfo["time"][i] == 0.0
                n_resets += 1
            else:
                obs, rew, term, trunc, info = env.step(actions[t, i])
                assert vrew[i] == rew
                assert vterm[i] == term and vtrunc[i] == trunc
                assert {k: v[i] for k, v in vinfo["reward_terms"].items()} == info["reward_terms"]
            _compare(vobs, vinfo, i, obs, info, env)
        done = vterm | vtrunc
        n_terminated += int(vterm.sum())
        n_truncated += int(vtrunc.sum())
    # both kinds of episode end happened, and the robots came back from them
    assert n_terminated >= 1 and n_truncated >= 1
    assert n_resets >= n


def test_vector_env_explicit_seed_list_and_errors():
    vec = LaneFollowingVectorEnv(num_envs=2, params=SMALL, observation="state")
    _, a = vec.reset(seed=[7, 9])
    single = LaneFollowingEnv(params=SMALL, observation="state")
    _, b = single.reset(seed=9)
    np.testing.assert_array_equal(a["pose"][1], b["pose"])
    with pytest.raises(ValueError, match="3 seeds for 2 envs"):
        vec.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="num_envs"):
        LaneFollowingVectorEnv(num_envs=0, params=SMALL)
    assert a["lane_pose"].shape == (2, len(LANE_POSE_FIELDS))


# ---------------------------------------------------------------------------------------------------
# Episode ends


def test_driving_straight_across_a_curve_terminates():
    env = LaneFollowingEnv(map="loop_3x3", params={**SMALL, "command_delay": 0.0}, observation="state")
    # bottom-left curve, entering from the north in the right lane, heading south: the road turns east
    _, info = env.reset(seed=0, options={"pose": (0.28 * TS, TS - 0.01, -math.pi / 2)})
    assert info["on_road"]
    steps = 0
    while steps < 60:
        _, reward, terminated, truncated, info = env.step(np.array([1.0, 1.0], dtype=np.float32))
        steps += 1
        if terminated:
            break
    assert terminated and not truncated
    assert not info["on_road"]
    assert not info["lane_pose"].on_road
    assert info["reward_terms"]["off_road"] == -RewardWeights().off_road
    assert reward < -9.0
    assert steps < 30  # within 2 s at full speed


def test_off_road_penalty_only_once():
    env = LaneFollowingEnv(map="straight_road", params=SMALL, observation="state")
    env.reset(seed=0, options={"pose": (2.0, 1.28 * TS, math.pi / 2)})  # heading north, across the road
    penalties, terminations = [], []
    for _ in range(30):  # keep driving after the termination: the penalty is not repeated
        _, _, term, _, info = env.step(np.ones(2, dtype=np.float32))
        penalties.append(info["reward_terms"]["off_road"])
        terminations.append(term)
    assert penalties.count(-10.0) == 1 and penalties.count(0.0) == 29
    first = terminations.index(True)
    assert penalties[first] == -10.0
    assert all(terminations[first:])


def test_truncation_at_episode_seconds():
    env = LaneFollowingEnv(map="straight_road", params=SMALL, observation="state", episode_seconds=1.0)
    env.reset(seed=0, options={"pose": (1.0, 1.28 * TS, 0.0)})
    for t in range(15):
        _, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        assert not terminated
        assert truncated == (t == 14)
    assert info["time"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="episode_seconds"):
        LaneFollowingEnv(params=SMALL, episode_seconds=0.0)


def test_info_contents_and_reward_terms_sum():
    env = LaneFollowingEnv(params=SMALL)
    _, info = env.reset(seed=3)
    assert isinstance(info["lane_pose"], LanePose)
    for a in _actions(1, 20):
        _, reward, terminated, truncated, info = env.step(a)
        pose = info["pose"]
        assert pose.shape == (3,)
        np.testing.assert_array_equal(pose, env.sim.state[0, :3])
        assert isinstance(info["lane_pose"], LanePose)
        assert info["lane_pose"].lateral == env.sim.lane[0, LP.LATERAL] or not info["lane_pose"].valid
        np.testing.assert_array_equal(
            info["wheels_in_lane"], [info["lane_pose"].left_in_lane, info["lane_pose"].right_in_lane]
        )
        terms = info["reward_terms"]
        assert set(terms) == {"progress", "lateral", "heading", "off_road"}
        assert sum(terms.values()) == pytest.approx(reward, abs=1e-12)
        lp = info["lane_pose"]
        if lp.valid:
            assert terms["lateral"] == pytest.approx(-2.0 * abs(lp.lateral))
            assert terms["heading"] == pytest.approx(-0.5 * abs(lp.heading_error))
            assert terms["progress"] == pytest.approx(info["velocity"][0] * math.cos(lp.heading_error))
        if terminated or truncated:
            break


def test_custom_reward_weights():
    env = LaneFollowingEnv(map="straight_road", params=SMALL, observation="state",
                           reward=RewardWeights(progress=0.0, lateral=1.0, heading=0.0, off_road=0.0))
    env.reset(seed=0, options={"pose": (1.0, 1.28 * TS + 0.03, 0.0)})
    _, reward, *_ = env.step(np.zeros(2, dtype=np.float32))
    assert reward == pytest.approx(-0.03, abs=1e-9)


# ---------------------------------------------------------------------------------------------------
# Rendering and arguments


def test_render_modes_return_uint8_images():
    env = LaneFollowingEnv(params=SMALL, render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape == (60, 80, 3)
    np.testing.assert_array_equal(frame, obs)
    top = LaneFollowingEnv(params=SMALL, render_mode="rgb_array", render_view="top_down")
    top.reset(seed=0)
    img = top.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3 and img.shape[0] > 10
    assert LaneFollowingEnv(params=SMALL).render() is None
    vec = LaneFollowingVectorEnv(num_envs=2, params=SMALL, render_mode="rgb_array", render_view="top_down")
    vec.reset(seed=0)
    img = vec.render()
    assert img.dtype == np.uint8 and img.ndim == 3
    vec_rgb = LaneFollowingVectorEnv(num_envs=2, params=SMALL, render_mode="rgb_array")
    vobs, _ = vec_rgb.reset(seed=0)
    np.testing.assert_array_equal(vec_rgb.render(), vobs)


def test_rgb_array_renders_camera_on_demand_for_state_observation():
    env = LaneFollowingEnv(params=SMALL, observation="state", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    camera_env = LaneFollowingEnv(params=SMALL, render_mode="rgb_array")
    obs, _ = camera_env.reset(seed=0)
    assert frame.shape == (60, 80, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, obs)


def test_bad_render_mode():
    with pytest.raises(ValueError, match=r"render_mode must be one of .*'x'"):
        LaneFollowingEnv(params=SMALL, render_mode="x")


def test_bad_render_mode_vector_env():
    with pytest.raises(ValueError, match="'x'"):
        LaneFollowingVectorEnv(num_envs=2, params=SMALL, render_mode="x")


@pytest.mark.parametrize("cls", [LaneFollowingEnv, LaneFollowingVectorEnv])
def test_bad_observation(cls):
    with pytest.raises(ValueError, match=r"observation must be one of .*'x'"):
        cls(params=SMALL, observation="x")


@pytest.mark.parametrize("cls", [LaneFollowingEnv, LaneFollowingVectorEnv])
def test_misspelled_param_names_the_field(cls):
    with pytest.raises(ValidationError, match="trimm"):
        cls(params={"trimm": 0.1})


def test_bad_map_name():
    with pytest.raises(ValueError, match="no_such_map"):
        LaneFollowingEnv(map="no_such_map", params=SMALL)


def test_set_params_takes_effect_at_next_reset():
    env = LaneFollowingEnv(params=SMALL, observation="state")
    env.reset(seed=0)
    env.set_params(env.params.replace(trim=0.2))
    assert env.params.trim == 0.0
    env.reset(seed=0)
    assert env.params.trim == 0.2
