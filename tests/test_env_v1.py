"""The swarm_env_v1 contract: fixed teams, reset infos, max_steps, reward v1, the map in state(), a sound generator."""

from __future__ import annotations

import numpy as np
import pytest

import swarm_env
from swarm_env.env import SwarmEnv
from swarm_env.geometry.formation import virtual_slot_trajectory
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import RewardSpec, ScenarioError
from swarm_env.scenarios.generator import KNOB_LIMITS, RandomScenarioConfig, random_scenario, slot_speed_violations
from swarm_env.scoring.rewards import INFO_CONTACT_KEYS, INFO_REWARD_KEYS, REWARD_TERMS, contact_counts, reward_terms
from tests.test_physics import _scenario

ALL = swarm_env.list_scenarios()


def _step_random(env: SwarmEnv):
    return env.step({a: env.action_space(a).sample() for a in env.agents})


# --------------------------------------------------------------------------- fixed teams


@pytest.mark.parametrize("name", ALL)
def test_every_reset_has_every_possible_agent(name: str) -> None:
    env = swarm_env.parallel_env(name, max_cycles=3)
    for seed in range(8 if name == "random" else 2):
        obs, infos = env.reset(seed=seed)
        assert env.agents == env.possible_agents == list(obs) == list(infos)


def test_team_size_range_is_drawn_once_per_instance_from_team_seed() -> None:
    sizes = set()
    for team_seed in range(12):
        env = SwarmEnv("random", n_followers=(2, 8), team_seed=team_seed, max_cycles=2)
        n = len(env.possible_agents)
        assert 2 <= n <= 8 and env.state_space.shape == (env.state_layout["occupancy"].stop,)
        sizes.add(n)
        for seed in range(5):
            env.reset(seed=seed)
            assert env.agents == env.possible_agents and env.world_state().n_followers == n
        again = SwarmEnv("random", n_followers=(2, 8), team_seed=team_seed)
        assert again.possible_agents == env.possible_agents  # the same seed, the same team
    assert len(sizes) > 2  # the seed really varies the team


def test_default_random_team_is_four_followers() -> None:
    assert SwarmEnv("random").possible_agents == [f"follower_{i}" for i in range(4)]


# --------------------------------------------------------------------------- infos, limits, fps


@pytest.mark.parametrize("name", ALL)
def test_reset_infos_have_the_step_infos_keys(name: str) -> None:
    env = swarm_env.parallel_env(name, max_cycles=4)
    _, reset_infos = env.reset(seed=1)
    expected = [*INFO_REWARD_KEYS, "slot_distance", *INFO_CONTACT_KEYS, "collision_terminated"]
    for info in reset_infos.values():
        assert list(info) == expected
        assert set(reward_terms(info).values()) == {0.0} and set(contact_counts(info).values()) == {0}
        assert info["collision_terminated"] is False and info["slot_distance"] >= 0.0
    _, rewards, _, _, step_infos = _step_random(env)
    for a in env.possible_agents:
        assert list(step_infos[a]) == expected  # the same keys, in the same order
        # Flat: one number per key (TorchRL and BenchMARL make a tensor of every info value).
        assert all(isinstance(v, (int, float, bool)) for v in step_infos[a].values())
        assert abs(sum(reward_terms(step_infos[a]).values()) - rewards[a]) < 1e-9


@pytest.mark.parametrize("name,max_cycles", [("paper_vo_0", None), ("paper_cbs_switch", None), ("random", 17)])
def test_max_steps_is_public_before_reset_and_is_the_truncation_step(name: str, max_cycles: int | None) -> None:
    env = swarm_env.parallel_env(name, max_cycles=max_cycles)
    scn = env.scenario
    expected = int(np.floor(scn.world.max_time / scn.world.dt + 1e-9))
    if max_cycles is not None:
        expected = min(expected, max_cycles)
    assert isinstance(env.max_steps, int) and env.max_steps == expected
    env.reset(seed=0)
    steps = 0
    while env.agents:
        _, _, terms, truncs, _ = _step_random(env)
        steps += 1
    assert steps == expected and all(truncs.values()) and not any(terms.values())
    assert env.episode_metrics()["termination"] == "time_limit"


def test_render_fps_is_one_frame_per_step_and_never_zero() -> None:
    assert SwarmEnv.metadata["render_fps"] == 10 == swarm_env.parallel_env("paper_vo_0").metadata["render_fps"]
    assert swarm_env.parallel_env("paper_cbs_switch").metadata["render_fps"] == 2  # dt = 0.5 s
    slow = swarm_env.parallel_env("random", dt=5.0, max_time=60.0, substeps=70, n_humans=0)
    assert slow.metadata["render_fps"] == 1


# --------------------------------------------------------------------------- reward v1


def _head_on(**kwargs) -> tuple[SwarmEnv, list]:
    env = SwarmEnv(_scenario([[3.0, 5.0, 0.0], [7.0, 5.0, np.pi]]), **kwargs)
    push = np.array([1.0, 0.0], np.float32)
    env.reset(seed=0)
    infos = []
    while env.agents and len(infos) < 100:
        infos.append(env.step({a: push for a in env.agents})[4])
    return env, infos


def test_every_contact_step_is_penalised_once_per_body_in_touch() -> None:
    env, infos = _head_on()
    touching = [i["follower_0"]["contacts_robot"] for i in infos]
    assert sum(touching) > 30  # they keep pushing each other for seconds
    for info in infos:
        for a in ("follower_0", "follower_1"):
            n = info[a]["contacts_robot"]
            assert info[a]["reward_contact_robot"] == -2.0 * n
    onset_steps = [k for k, i in enumerate(infos) if i["follower_0"]["reward_collision"] < 0]
    assert len(onset_steps) == 1 and touching[onset_steps[0]] == 1  # the onset is charged on top, once
    assert env.episode_metrics()["collisions"]["robot_robot"] == 1  # metrics still count onsets


def test_reward_v0_keyword_charges_onsets_only() -> None:
    _, infos = _head_on(reward="v0")
    totals = {t: sum(reward_terms(i["follower_0"])[t] for i in infos) for t in REWARD_TERMS}
    assert totals["collision"] == -10.0
    assert all(totals[t] == 0.0 for t in REWARD_TERMS if t.startswith("contact_") or t == "clearance")
    assert SwarmEnv("paper_vo_0", reward="v0").reward_spec == RewardSpec.v0()
    assert SwarmEnv("paper_vo_0", reward={"contact": 4.0}).reward_spec.contact == 4.0
    assert SwarmEnv("random", reward="v0").scenario.reward == RewardSpec.v0()
    with pytest.raises(ValueError, match="reward must be one of"):
        SwarmEnv("paper_vo_0", reward="v7")


def test_clearance_shaping_is_on_by_default_and_zero_when_clear() -> None:
    env, infos = _head_on()
    clear = [i["follower_0"]["reward_clearance"] for i in infos]
    assert clear[0] == 0.0  # 4 m apart
    assert min(clear) == pytest.approx(-1.0, abs=0.05)  # in touch: no clearance left
    assert RewardSpec().clearance > 0 and RewardSpec().clearance_margin == 0.2


def test_terminate_on_collision_ends_the_episode_for_all_with_the_offenders_in_infos() -> None:
    env, infos = _head_on(terminate_on_collision=True)
    last = infos[-1]
    assert env.agents == [] and len(infos) < 100
    assert all(info["collision_terminated"] for info in last.values())
    assert all(info["contacts_robot"] == 1 for info in last.values())  # both are the offenders
    assert not any(info["collision_terminated"] for step in infos[:-1] for info in step.values())
    metrics = env.episode_metrics()
    assert metrics["termination"] == "collision"
    assert metrics["terminal_contacts"] == [{"kind": "robot_robot", "robot": 0, "other": 1}]


def test_terminations_flag_a_collision_end() -> None:
    env = SwarmEnv(_scenario([[3.0, 5.0, 0.0], [7.0, 5.0, np.pi]]), terminate_on_collision=True)
    push = np.array([1.0, 0.0], np.float32)
    env.reset(seed=0)
    while env.agents:
        _, _, terms, truncs, _ = env.step({a: push for a in env.agents})
    assert all(terms.values()) and not any(truncs.values())


# --------------------------------------------------------------------------- state() sees the map


def test_state_has_the_map() -> None:
    env = swarm_env.parallel_env("paper_cbs_switch")
    env.reset(seed=0)
    state = env.state()
    layout = env.state_layout
    assert env.state_space.contains(state) and state.shape == env.state_space.shape
    grid = state[layout["occupancy"]].reshape(16, 16)
    static = env.world_state().static
    w, h = static.size
    centres = np.stack(np.meshgrid((np.arange(16) + 0.5) * w / 16, (np.arange(16) + 0.5) * h / 16), -1)
    inside = static.distance(centres.reshape(-1, 2), walls=False).reshape(16, 16) < -0.5 * max(w, h) / 16
    assert np.all(grid[inside] == 1.0)  # cells deep inside an obstacle are full
    far = static.distance(centres.reshape(-1, 2), walls=False).reshape(16, 16) > 0.75 * max(w, h) / 16
    assert np.all(grid[far] == 0.0) and grid.sum() > 0  # cells far from every obstacle are empty
    near = state[layout["follower_clearance"]].reshape(-1, 3)
    ws = env.world_state()
    d = static.distance(ws.follower_pose[:, :2])
    np.testing.assert_allclose(near[:, 0], np.clip(d / 5.0, 0, 1), atol=1e-6)
    np.testing.assert_allclose(np.hypot(near[:, 1], near[:, 2]), 1.0, atol=1e-6)


def test_state_of_an_empty_map_has_an_empty_grid() -> None:
    env = swarm_env.parallel_env("random", n_obstacles=0, max_cycles=2)
    env.reset(seed=0)
    assert env.state()[env.state_layout["occupancy"]].sum() == 0.0


# --------------------------------------------------------------------------- a sound generator


@pytest.mark.slow
def test_slot_targets_never_outrun_the_followers_over_1000_seeds() -> None:
    cfg = RandomScenarioConfig()
    for seed in range(1000):
        scn = random_scenario(np.random.default_rng(seed), cfg)
        bad = slot_speed_violations(scn)
        assert len(bad) == 0, (seed, bad[:3])


@pytest.mark.parametrize("n", [16, 32, 64])
def test_big_swarms_fit_and_stay_feasible(n: int) -> None:
    env = SwarmEnv("random", n_followers=n, max_cycles=2)
    assert len(env.possible_agents) == n
    for seed in range(3):
        env.reset(seed=seed)
        assert len(slot_speed_violations(env.scenario)) == 0
        _step_random(env)
    w, _ = env.scenario.world.size
    assert w >= 20.0 and (n < 32 or w > 20.0)  # the world grew with the team


def test_the_feasibility_check_sees_what_the_env_computes() -> None:
    env = swarm_env.parallel_env("random", n_followers=6)
    for seed in (0, 7):
        env.reset(seed=seed)
        scn = env.scenario
        slots, _ = virtual_slot_trajectory(scn, StaticMap.from_obstacles(scn.world.size, scn.obstacles), 40)
        got = [env.world_state().slot_targets.copy()]
        for _ in range(40):
            _step_random(env)
            got.append(env.world_state().slot_targets.copy())
        np.testing.assert_array_equal(np.stack(got), slots)  # bit for bit


def test_the_feasibility_check_catches_a_sharp_corner() -> None:
    scn = swarm_env.load_scenario("paper_cbs_switch")  # a virtual leader turning on the spot at its corners
    assert len(slot_speed_violations(scn)) > 0


def test_the_generated_turns_are_rounded() -> None:
    # A v0 path turned up to 60 degrees at once; now the heading changes by small steps.
    for seed in range(30):
        scn = random_scenario(np.random.default_rng(seed), RandomScenarioConfig(n_followers=8))
        p = np.asarray(scn.leader.path)
        if len(p) < 3:
            continue
        h = np.unwrap(np.arctan2(*np.diff(p, axis=0).T[::-1]))
        assert np.abs(np.diff(h)).max() < 0.05


@pytest.mark.parametrize("knob", sorted(KNOB_LIMITS))
def test_count_knobs_out_of_range_name_the_knob_and_the_range(knob: str) -> None:
    with pytest.raises(ScenarioError, match=rf"{knob}: expected values in \[\d+, {KNOB_LIMITS[knob]}\]"):
        SwarmEnv("random", **{knob: KNOB_LIMITS[knob] + 1})


def test_generated_scenarios_pass_the_yaml_gate() -> None:
    from swarm_env.scenarios.loader import scenario_from_dict, scenario_to_dict

    for seed in range(10):
        scn = random_scenario(np.random.default_rng(seed), RandomScenarioConfig(n_followers=(2, 12)))
        assert scenario_from_dict(scenario_to_dict(scn), source=scn.source) == scn


def test_the_clearance_reward_screen_changes_no_value() -> None:
    from swarm_env.harness.policies import load_policy
    from swarm_env.scoring.rewards import clearance

    inside = 0
    for seed, kind in ((0, "virtual"), (1, "robot")):
        env = swarm_env.parallel_env("random", n_followers=8, n_humans=3, leader_kind=kind, max_cycles=300)
        obs, _ = env.reset(seed=seed)
        policy = load_policy("pursuit", env)
        policy.reset(env, seed)
        while env.agents:
            obs, *_ = env.step(policy.act(obs, env.world_state()))
            full, fast = clearance(env.world_state()), clearance(env.world_state(), below=0.2)
            near = full < 0.2
            inside += int(near.sum())
            np.testing.assert_array_equal(fast[near], full[near])  # exact inside the margin
            assert np.all(fast[~near] >= 0.2)  # and known to be outside it elsewhere
    assert inside > 50  # pursuit really brushes things


def test_render_accepts_its_own_mode_positionally() -> None:
    # RLlib's PettingZoo wrapper calls env.render(render_mode).
    env = swarm_env.parallel_env("paper_vo_0", render_mode="rgb_array", max_cycles=2)
    env.reset(seed=0)
    assert env.render("rgb_array").shape[2] == 3
    with pytest.raises(ValueError, match="differs from the env's render_mode"):
        env.render("human")
