"""The Gymnasium interface: spaces, check_env, SAME_STEP autoreset, registration, SB3 on a tiny budget."""

import numpy as np
import pytest
import torch

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import torchnav.gym as tg  # noqa: E402


@pytest.mark.parametrize("env_id,kwargs", [("torchnav/Navigation-v0", {}), ("torchnav/LineFollowing-v0", {}),
                                           ("torchnav/Navigation-v0", {"action": {"mode": "discrete"}})])
def test_single_env_passes_gymnasium_check_env(env_id, kwargs):
    env = gymnasium.make(env_id, **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    obs2, *_ = env.step(env.action_space.sample())
    assert obs2.shape == obs.shape


def test_single_env_reset_is_seeded_and_episodes_end():
    env = tg.navigation_env(max_steps=20)
    a, _ = env.reset(seed=7)
    b, _ = env.reset(seed=7)
    c, _ = env.reset(seed=8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    for t in range(20):
        _, r, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        assert isinstance(r, float) and set(info) >= {"success", "collision"}
        if terminated or truncated:
            break
    assert terminated or truncated, "a 20-step episode must end within 20 steps"
    assert "is_success" in info


def test_vector_env_same_step_autoreset():
    envs = gymnasium.make_vec("torchnav/Navigation-v0", num_envs=8, vectorization_mode="vector_entry_point", max_steps=5)
    assert envs.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.SAME_STEP
    obs, info = envs.reset(seed=0)
    assert obs.shape == (8, envs.single_observation_space.shape[0]) and info["success"].shape == (8,)
    ended = np.zeros(8, bool)
    for _ in range(5):
        prev = obs
        obs, reward, terminated, truncated, info = envs.step(np.zeros((8, 2), np.float32))
        assert reward.shape == (8,) and reward.dtype == np.float32
        done = terminated | truncated
        if done.any():
            assert np.array_equal(info["_final_obs"], done)
            # the returned observation of a finished env is its next episode's first one
            assert not np.allclose(obs[done], info["final_obs"][done]) or not np.allclose(obs[done], prev[done])
        ended |= done
    assert ended.all(), "every env's 5-step episode ends by step 5"
    envs.close()


def test_vector_env_refuses_wrong_action_shapes():
    envs = tg.navigation_vector_env(num_envs=4)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(4, 2\)"):
        envs.step(np.zeros((4, 3), np.float32))
    disc = tg.navigation_vector_env(num_envs=4, action={"mode": "discrete"})
    disc.reset(seed=0)
    with pytest.raises(ValueError, match="integers in"):
        disc.step(np.full(4, 99))
    obs, *_ = disc.step(disc.action_space.sample())
    assert obs.shape[0] == 4


def test_unknown_config_key_is_named():
    from torchnav.config import ConfigError

    with pytest.raises(ConfigError, match="curiculum"):
        gymnasium.make("torchnav/Navigation-v0", curiculum={"mode": "off"})
    with pytest.raises(ConfigError, match="num_envs"):  # one robot: a batch size is a mistake, not ignored
        gymnasium.make("torchnav/Navigation-v0", num_envs=4)


def test_sb3_ppo_trains_on_the_single_env():
    sb3 = pytest.importorskip("stable_baselines3")
    env = gymnasium.make("torchnav/Navigation-v0", max_steps=50)
    model = sb3.PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu", verbose=0)
    model.learn(total_timesteps=128)
    obs, _ = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action.astype(np.float32))


def _first_episodes(model, normalizer, episodes: int = 200) -> tuple[float, float]:
    """Mean return and success rate of the deterministic policy over the first episode of each of
    ``episodes`` envs on ``empty`` with goals anywhere (the same episodes for every policy)."""
    import torchnav.gym as tg

    envs = tg.navigation_vector_env(num_envs=episodes, seed=10_000, map="empty", max_steps=200, curriculum={"mode": "off"})
    obs, _ = envs.reset(seed=10_000)
    ret, success, live = np.zeros(episodes), np.zeros(episodes, bool), np.ones(episodes, bool)
    while live.any():
        action, _ = model.predict(normalizer.normalize_obs(obs), deterministic=True)
        obs, reward, terminated, truncated, info = envs.step(action)
        ret += reward * live
        ended = (terminated | truncated) & live
        if ended.any():
            success[ended] = info["final_info"]["success"][ended]
        live &= ~(terminated | truncated)
    return float(ret.mean()), float(success.mean())


def test_sb3_ppo_learns_through_the_vec_env():
    """SB3's PPO learns through the SB3 VecEnv adapter: 150k steps raise the deterministic policy's mean
    return on the same 200 episodes from about -75 to about +53 and its success from 3% to 12-15.5%
    (seeds 0 and 1)."""
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import VecNormalize

    torch.manual_seed(0)
    envs = VecNormalize(tg.sb3_vec_env(tg.navigation_vector_env(num_envs=256, seed=0, map="empty", max_steps=200,
                                                                curriculum={"mode": "off"})), gamma=0.99)
    model = sb3.PPO("MlpPolicy", envs, n_steps=32, batch_size=2048, n_epochs=4, learning_rate=2e-3,
                    policy_kwargs={"net_arch": [64, 64]}, seed=0, device="cpu", verbose=0)
    envs.training = False
    ret0, success0 = _first_episodes(model, envs)
    envs.training = True
    model.learn(total_timesteps=150_000)
    envs.training = False
    ret1, success1 = _first_episodes(model, envs)
    assert ret1 > ret0 + 50, (ret0, ret1)
    assert success1 >= success0 + 0.05, (success0, success1)


def test_sb3_vec_env_steps_the_whole_batch_and_refuses_per_env_attributes():
    pytest.importorskip("stable_baselines3")
    vec = tg.sb3_vec_env(tg.navigation_vector_env(num_envs=4, max_steps=3))
    obs = vec.reset()
    assert obs.shape == (4, vec.observation_space.shape[0])
    ended = np.zeros(4, dtype=bool)
    for _ in range(3):  # 3-step episodes: every env ends within 3 steps and reports SB3's terminal keys when it does
        vec.step_async(np.zeros((4, 2), dtype=np.float32))
        obs, reward, done, infos = vec.step_wait()
        assert all("terminal_observation" in info for info, d in zip(infos, done) if d)
        ended |= done
    assert ended.all() and obs.shape == (4, vec.observation_space.shape[0])
    assert vec.get_attr("num_envs") == [4] * 4
    vec.set_attr("spare", 1)  # every env at once: fine
    with pytest.raises(ValueError, match="share their attributes"):
        vec.set_attr("spare", 2, indices=[0])
    with pytest.raises(NotImplementedError):
        vec.env_method("reset")
