"""Old names still work and warn, naming the new one."""

import pytest
import torch

from torchnav.envs import NavEnv, make_env, make_nav_env
from torchnav.tasks import CurriculumState, LineConfig, LineTask, NavConfig, NavTask


def test_make_env_is_make_nav_env_with_a_warning():
    with pytest.warns(DeprecationWarning, match="make_env is deprecated: use torchnav.envs.nav_env.make_nav_env"):
        env = make_env("arena", num_envs=2, max_steps=7)
    assert isinstance(env, NavEnv) and env.cfg == make_nav_env("arena", num_envs=2, max_steps=7).cfg


def test_obs_dim_is_frame_size_with_a_warning():
    task = NavTask(NavConfig(), num_envs=2)
    with pytest.warns(DeprecationWarning, match="NavTask.obs_dim is deprecated: use frame_size"):
        assert task.obs_dim == task.frame_size == task.obs_size // task.cfg.observation.history


def test_gen_keyword_is_generator_with_a_warning():
    nav = NavTask(NavConfig(), num_envs=2)
    cur = CurriculumState.initial(nav.cfg.curriculum)
    with pytest.warns(DeprecationWarning, match=r"initial_state\(gen=...\) is deprecated: use generator="):
        old, _ = nav.initial_state(cur, gen=torch.Generator().manual_seed(0))
    new, _ = nav.initial_state(cur, generator=torch.Generator().manual_seed(0))
    assert torch.equal(old.sim.pose, new.sim.pose) and torch.equal(old.goal, new.goal)
    line = LineTask(LineConfig(), num_envs=2)
    with pytest.warns(DeprecationWarning, match="generator="):
        a = line.start_poses(3, gen=torch.Generator().manual_seed(1))[0]
    assert torch.equal(a, line.start_poses(3, torch.Generator().manual_seed(1))[0])
    with pytest.raises(TypeError, match="both gen= .* and generator="):  # never one of them silently dropped
        line.start_poses(3, gen=torch.Generator(), generator=torch.Generator())


def test_moving_circles_names_are_movers_with_a_warning():
    """``MapSpec.moving_circles`` also held moving boxes: it is ``MapSpec.movers`` now, a ``RandomMovers``."""
    from torchnav.maps import parse_map
    from torchnav.maps import spec as spec_module

    spec = parse_map({"size": [6.0, 6.0], "moving_circles": {"count": 4, "radius": [0.2, 0.3], "speed": [0.1, 0.2]}})
    with pytest.warns(DeprecationWarning, match="MapSpec.moving_circles is deprecated: use movers"):
        assert spec.moving_circles is spec.movers and spec.movers.count == 4
    with pytest.warns(DeprecationWarning, match="MovingCircles is deprecated: use torchnav.maps.spec.RandomMovers"):
        assert spec_module.MovingCircles is spec_module.RandomMovers
    with pytest.raises(AttributeError, match="NoSuchThing"):
        spec_module.NoSuchThing
