"""TD3 on batched lidar navigation, with TorchRL.

    python recipes/td3_lidar.py                       # arena, classic curriculum, CPU, a few minutes
    python recipes/td3_lidar.py env.map=warehouse env.num_envs=256 curriculum.growth=0.01
    python recipes/td3_lidar.py --resume              # continue the newest run

Reads top to bottom: config -> env -> networks -> loss -> collector -> train loop
(collect, store, update critics every step and the actor every `policy_delay`
steps, soft-update targets) -> periodic evaluation -> checkpoints -> final
evaluation on `eval.final_episodes` episodes with goals anywhere. Every config key
is documented in recipes/configs/td3_lidar.yaml.
"""

from __future__ import annotations

import collections
import sys
import time
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import MLP, AdditiveGaussianModule, ValueOperator
from torchrl.objectives import SoftUpdate, TD3Loss
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402

from torchnav.envs import NavEnv  # noqa: E402
from torchnav.policy import Actor, policy_payload, save_policy  # noqa: E402
from torchnav.evaluation import eval_config, format_summary, record_episodes, run_episodes, summarize  # noqa: E402

REPLAY_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "terminated"))


def make_actor(obs_size: int, act_size: int, hidden) -> TensorDictModule:
    return TensorDictModule(Actor(obs_size, act_size, hidden), in_keys=["observation"], out_keys=["action"])


def make_critic(obs_size: int, act_size: int, hidden) -> ValueOperator:
    net = MLP(in_features=obs_size + act_size, out_features=1, num_cells=list(hidden), activation_class=nn.ReLU)
    return ValueOperator(net, in_keys=["observation", "action"])


def main(argv: list[str]) -> dict:
    cfg = C.load_config("td3_lidar", argv)
    resume_dir = C.find_resume_dir(cfg)
    ckpt = None
    if resume_dir is not None:
        ckpt = C.load_checkpoint(resume_dir / "checkpoint.pt")
        if ckpt.get("format") != "torchnav-td3-v2":
            raise RuntimeError(f"{resume_dir / 'checkpoint.pt'} is not a TD3 training checkpoint (format {ckpt.get('format')!r})")
        cfg.logger.run_dir = str(resume_dir)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    C.seed_everything(cfg.seed)
    device = torch.device(cfg.device)
    nav = C.nav_config(cfg)
    run = C.make_run_dir(cfg, "td3_lidar")
    C.save_config(cfg, run)
    logger = C.make_logger(cfg, run)
    tc = cfg.train

    # -- env and networks --------------------------------------------------------------------
    env = NavEnv(nav, num_envs=cfg.env.num_envs, device=device, seed=cfg.seed)
    if nav.action.mode != "continuous":
        raise C.ConfigError("TD3 needs task.action.mode=continuous")
    obs_size, act_size = env.task.obs_size, 2
    actor = make_actor(obs_size, act_size, tc.hidden).to(device)
    critic = make_critic(obs_size, act_size, tc.hidden).to(device)
    exploration = AdditiveGaussianModule(
        spec=env.action_spec_unbatched, sigma_init=float(tc.expl_sigma_init), sigma_end=float(tc.expl_sigma_end),
        annealing_num_steps=int(tc.expl_anneal_frames), device=device,
    )
    policy = TensorDictSequential(actor, exploration)

    loss = TD3Loss(
        actor_network=actor, qvalue_network=critic, action_spec=env.action_spec_unbatched, num_qvalue_nets=2,
        policy_noise=tc.policy_noise, noise_clip=tc.noise_clip, loss_function="l2", delay_actor=True, delay_qvalue=True,
    )
    loss.make_value_estimator(gamma=tc.gamma)
    target_update = SoftUpdate(loss, tau=tc.tau)
    opt_actor = torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=tc.lr_actor)
    opt_critic = torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=tc.lr_critic)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(tc.buffer_size, device=device), batch_size=tc.batch_size)

    counters = {"frames": 0, "updates": 0, "batches": 0, "wall_time": 0.0, "time_to_target": None, "frames_to_target": None}
    if ckpt is not None:
        loss.load_state_dict(ckpt["loss"])
        opt_actor.load_state_dict(ckpt["opt_actor"])
        opt_critic.load_state_dict(ckpt["opt_critic"])
        exploration.load_state_dict(ckpt["exploration"])
        env.load_state_dict(ckpt["env"])
        C.set_rng_states(ckpt["rng"])
        counters.update(ckpt["counters"])
        print(f"resuming {run} at {counters['frames']} frames, curriculum radius {env.curriculum.radius.item():.2f} m")

    policy_meta = {"task": "nav", "task_config": C.to_dict(nav), "algorithm": "td3"}

    def save(path: Path) -> None:
        C.save_checkpoint(path, {
            "format": "torchnav-td3-v2", "loss": loss.state_dict(), "opt_actor": opt_actor.state_dict(),
            "opt_critic": opt_critic.state_dict(), "exploration": exploration.state_dict(), "env": env.state_dict(),
            "rng": C.rng_states(), "counters": dict(counters), "config": C.config_dict(cfg),
            "policy": policy_payload(actor.module, **policy_meta),
        })
        save_policy(run / "actor.pt", actor.module, **policy_meta)

    # -- collection ------------------------------------------------------------------------
    remaining = int(tc.total_frames) - int(counters["frames"])
    fresh = ckpt is None
    collector = Collector(
        env, policy, frames_per_batch=int(tc.frames_per_batch), total_frames=max(remaining, int(tc.frames_per_batch)),
        init_random_frames=int(tc.init_random_frames) if fresh else 0, device=device, auto_register_policy_transforms=False,
    ) if remaining > 0 else None

    eval_cfg = eval_config(nav)
    recent = collections.deque(maxlen=500)  # (success, collision) of recent training episodes
    stop = C.StopFlag()
    bar = tqdm(total=int(tc.total_frames), initial=int(counters["frames"]), unit="fr", disable=not cfg.logger.progress, dynamic_ncols=True)
    last_ckpt = last_eval = counters["frames"]
    t_start = time.perf_counter() - counters["wall_time"]
    try:
        for batch in collector or ():
            n = batch.numel()
            counters["frames"] += n
            counters["batches"] += 1
            exploration.step(n)
            flat = batch.reshape(-1)
            buffer.extend(flat.select(*REPLAY_KEYS))

            # training statistics of the episodes that ended in this batch
            done = flat["next", "done"].reshape(-1)
            if done.any():
                nxt = flat["next"][done]
                for s, c in zip(nxt["success"].reshape(-1).tolist(), nxt["collision"].reshape(-1).tolist()):
                    recent.append((s, c))
                ep = nxt["episode"]
                logger.log_scalar("train/episode_return", ep["return"].mean().item(), step=counters["frames"])
                logger.log_scalar("train/episode_length", ep["length"].mean().item(), step=counters["frames"])
                for k in env.task.term_names:
                    logger.log_scalar(f"reward/{k}", ep[f"term_{k}"].mean().item(), step=counters["frames"])

            # updates: critics every step, actor and targets every `policy_delay` steps
            if len(buffer) >= int(tc.init_random_frames):
                for _ in range(int(tc.updates_per_batch)):
                    sample = buffer.sample()
                    q_loss, _ = loss.value_loss(sample)
                    opt_critic.zero_grad(set_to_none=True)
                    q_loss.backward()
                    opt_critic.step()
                    counters["updates"] += 1
                    if counters["updates"] % int(tc.policy_delay) == 0:
                        a_loss, _ = loss.actor_loss(sample)
                        opt_actor.zero_grad(set_to_none=True)
                        a_loss.backward()
                        opt_actor.step()
                        target_update.step()
                if counters["batches"] % 10 == 0:
                    logger.log_scalar("loss/qvalue", q_loss.item(), step=counters["frames"])

            counters["wall_time"] = time.perf_counter() - t_start
            sr = sum(s for s, _ in recent) / max(len(recent), 1)
            cr = sum(c for _, c in recent) / max(len(recent), 1)
            radius = env.curriculum.radius.item()
            fps = counters["frames"] / max(counters["wall_time"], 1e-9)
            bar.update(n)
            bar.set_postfix_str(f"success {100 * sr:.0f}% collide {100 * cr:.0f}% radius {radius:.2f}m {fps:,.0f} fr/s")
            if counters["batches"] % 10 == 0:
                for k, v in (("train/success_rate", sr), ("train/collision_rate", cr), ("curriculum/radius", radius), ("perf/frames_per_s", fps)):
                    logger.log_scalar(k, v, step=counters["frames"])
                logger.log_scalar("time/wall_s", counters["wall_time"], step=counters["frames"])

            if cfg.eval.interval_frames and counters["frames"] - last_eval >= cfg.eval.interval_frames:
                last_eval = counters["frames"]
                s = summarize(run_episodes(actor, eval_cfg, cfg.eval.episodes, seed=10_000 + cfg.seed, device=device))
                counters["wall_time"] = time.perf_counter() - t_start
                logger.log_scalar("eval/success_rate", s["success"]["rate"], step=counters["frames"])
                logger.log_scalar("eval/collision_rate", s["collision"]["rate"], step=counters["frames"])
                logger.log_scalar("eval/wall_s", counters["wall_time"], step=counters["frames"])
                bar.write(f"[eval @ {counters['frames']:,} frames, {counters['wall_time']:.0f} s] success {100 * s['success']['rate']:.1f}% "
                          f"collision {100 * s['collision']['rate']:.1f}% timeout {100 * s['timeout']['rate']:.1f}%")
                if counters["time_to_target"] is None and s["success"]["rate"] >= cfg.eval.target_success:
                    counters["time_to_target"], counters["frames_to_target"] = counters["wall_time"], counters["frames"]

            if counters["frames"] - last_ckpt >= cfg.checkpoint.interval_frames:
                last_ckpt = counters["frames"]
                save(run / "checkpoint.pt")
            if stop.stop:
                break
    except KeyboardInterrupt:
        print("\ninterrupted: writing a checkpoint", file=sys.stderr)
        stop.stop = True
    finally:
        bar.close()
        stop.restore()
        if collector is not None:
            collector.shutdown()
        save(run / "checkpoint.pt")
    if stop.stop:
        print(f"stopped at {counters['frames']:,} frames; checkpoint in {run / 'checkpoint.pt'}; continue with --resume={run}")
        return {"run_dir": str(run), "stopped": True, "counters": counters}

    # -- final evaluation --------------------------------------------------------------------
    t0 = time.perf_counter()
    summary = summarize(run_episodes(actor, eval_cfg, cfg.eval.final_episodes, seed=20_000 + cfg.seed, device=device))
    result = {
        "run_dir": str(run), "map": nav.map, "frames": counters["frames"], "updates": counters["updates"],
        "train_wall_s": counters["wall_time"], "time_to_target_s": counters["time_to_target"],
        "frames_to_target": counters["frames_to_target"], "eval": summary, "eval_wall_s": time.perf_counter() - t0,
    }
    logger.log_scalar("final/success_rate", summary["success"]["rate"], step=counters["frames"])
    if cfg.eval.record_episodes:
        rec = record_episodes(actor, eval_cfg, run / "episodes.mcap", int(cfg.eval.record_episodes), seed=20_000 + cfg.seed,
                              device=device, metadata={"checkpoint": str(run / "actor.pt"), "config": C.config_dict(cfg)})
        result["episodes_mcap"] = None if rec.error else str(run / "episodes.mcap")
    C.write_json(run / "summary.json", result)
    print()
    print(format_summary(summary, title=f"final evaluation on {nav.map}, goals anywhere, deterministic policy"))
    print(f"  trained {counters['frames']:,} frames, {counters['updates']:,} updates in {counters['wall_time']:.0f} s"
          + (f"; reached {100 * cfg.eval.target_success:.0f}% at {counters['time_to_target']:.0f} s" if counters["time_to_target"] else ""))
    print(f"  run directory: {run}  (actor.pt, checkpoint.pt, summary.json, logs/)")
    return result


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except (C.ConfigError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
