"""Builders shared by the recipes: config loading, run directories, logging, checkpoints, evaluation.

Kept out of ``torchnav/`` on purpose: the package never imports recipes.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import random
import signal
import sys
from pathlib import Path
from typing import Any

import torch
import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ConfigKeyError

from torchnav.config import ConfigError, merge, to_dict
from torchnav.tasks import NavConfig

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
# Sections whose keys are validated by NavConfig rather than by the YAML file.
_FREE_SECTIONS = ("task", "reward.weights")


def load_config(name: str, argv: list[str]) -> DictConfig:
    """Load ``configs/<name>.yaml`` and apply ``key.sub=value`` overrides from ``argv``.

    ``--config PATH`` replaces the default file; ``--resume [RUN_DIR]`` sets
    ``checkpoint.resume``. Unknown keys are errors that name the key; ``task.*``
    keys are checked against NavConfig when the env is built.
    """
    path = CONFIG_DIR / f"{name}.yaml"
    overrides: list[str] = []
    it = iter(argv)
    for a in it:
        if a in ("-h", "--help"):
            print(f"usage: python recipes/{name}.py [--config FILE] [--resume[=RUN_DIR]] [key.sub=value ...]\n"
                  f"defaults and documentation of every key: {path}")
            sys.exit(0)
        if a == "--config":
            path = Path(next(it))
        elif a.startswith("--config="):
            path = Path(a.split("=", 1)[1])
        elif a == "--resume":
            overrides.append("checkpoint.resume=true")
        elif a.startswith("--resume="):
            overrides.append(f"checkpoint.resume={a.split('=', 1)[1]}")
        elif "=" in a and not a.startswith("-"):
            overrides.append(a)
        else:
            raise ConfigError(f"unrecognised argument {a!r}: expected key=value, --config FILE or --resume")
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    cfg = OmegaConf.create(yaml.safe_load(path.read_text()) or {})
    for sec in _FREE_SECTIONS:
        if OmegaConf.select(cfg, sec) is None:
            OmegaConf.update(cfg, sec, {}, force_add=True)
    OmegaConf.set_struct(cfg, True)
    for sec in _FREE_SECTIONS:
        OmegaConf.set_struct(OmegaConf.select(cfg, sec), False)
    try:
        cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(overrides))
    except (ConfigAttributeError, ConfigKeyError) as e:
        key = getattr(e, "full_key", None) or str(e).splitlines()[0]
        raise ConfigError(f"unknown config key '{key}'{_did_you_mean(cfg, str(key))} (see {path} for every valid key)") from None
    return cfg


def _did_you_mean(cfg: DictConfig, key: str) -> str:
    """A close valid key for an unknown dotted ``key``, as a message suffix."""
    import difflib

    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if not isinstance(node, DictConfig):
        return ""
    close = difflib.get_close_matches(leaf, [str(k) for k in node.keys()], n=1)
    return f" (did you mean '{parent + '.' if parent else ''}{close[0]}'?)" if close else ""


def nav_config(cfg: DictConfig, **extra: Any) -> NavConfig:
    """The NavConfig described by a recipe config's ``env``, ``curriculum``, ``reward`` and ``task`` sections."""
    d: dict[str, Any] = OmegaConf.to_container(cfg.task, resolve=True)  # type: ignore[assignment]
    env = OmegaConf.to_container(cfg.env, resolve=True)
    nav = {k: v for k, v in env.items() if k not in ("num_envs",)}
    d = merge(d, nav)
    d = merge(d, {"curriculum": OmegaConf.to_container(cfg.curriculum, resolve=True), "reward": OmegaConf.to_container(cfg.reward, resolve=True)})
    return NavConfig.from_dict(merge(d, extra), where="config")


def make_run_dir(cfg: DictConfig, name: str) -> Path:
    """``<logger.root>/<name>_<timestamp>`` unless ``logger.run_dir`` is set."""
    if cfg.logger.run_dir:
        run = Path(cfg.logger.run_dir)
    else:
        stamp = _dt.datetime.now().strftime("%Y%m%d_%H%M%S")
        run = Path(cfg.logger.root) / f"{name}_{stamp}_seed{cfg.seed}"
    run.mkdir(parents=True, exist_ok=True)
    return run


def save_config(cfg: DictConfig, run: Path) -> None:
    (run / "config.yaml").write_text(OmegaConf.to_yaml(cfg))


def make_logger(cfg: DictConfig, run: Path):
    """TorchRL logger writing into the run directory (CSV by default)."""
    from torchrl.record.loggers import get_logger

    backend = cfg.logger.backend
    if backend not in ("csv", "tensorboard"):
        raise ConfigError(f"logger.backend must be 'csv' or 'tensorboard', got {backend!r}")
    return get_logger(backend, logger_name=str(run), experiment_name="logs")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


def rng_states() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "python": list(random.getstate()[1])}


def set_rng_states(sd: dict[str, Any]) -> None:
    torch.set_rng_state(sd["torch"])
    st = random.getstate()
    random.setstate((st[0], tuple(sd["python"]), st[2]))


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    """Atomic save: write a temporary file, then rename, so a crash never leaves a torn checkpoint."""
    tmp = path.with_suffix(".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - re-raised with the file named
        raise RuntimeError(f"cannot load checkpoint {path}: {e}") from e


def find_resume_dir(cfg: DictConfig) -> Path | None:
    """The run directory to resume: an explicit path, or the newest run of this recipe."""
    r = cfg.checkpoint.resume
    if r in (False, None, "", "false"):
        return None
    if r is True or r == "true":
        if cfg.logger.run_dir:
            return Path(cfg.logger.run_dir)
        runs = sorted((p for p in Path(cfg.logger.root).glob("*") if (p / "checkpoint.pt").is_file()), key=lambda p: p.stat().st_mtime)
        if not runs:
            raise FileNotFoundError(f"--resume: no run with a checkpoint.pt under {cfg.logger.root}")
        return runs[-1]
    return Path(str(r))


class StopFlag:
    """Turns SIGTERM and SIGINT into a flag the training loop polls, so it can checkpoint and exit."""

    def __init__(self) -> None:
        self.stop = False
        self._old = {}
        for sig in (signal.SIGTERM, signal.SIGINT):
            self._old[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:  # noqa: ARG002
        if self.stop:  # second signal: give up immediately
            signal.signal(signum, self._old[signum])
            raise KeyboardInterrupt
        self.stop = True
        print(f"\nreceived signal {signum}: finishing this batch, writing a checkpoint, then exiting", file=sys.stderr, flush=True)

    def restore(self) -> None:
        for sig, h in self._old.items():
            signal.signal(sig, h)


def write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=2))


def config_dict(cfg: DictConfig) -> dict[str, Any]:
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]


__all__ = [
    "load_config", "nav_config", "make_run_dir", "save_config", "make_logger", "seed_everything", "rng_states",
    "set_rng_states", "save_checkpoint", "load_checkpoint", "find_resume_dir", "StopFlag", "write_json",
    "config_dict", "to_dict",
]
