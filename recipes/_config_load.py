"""Reading a recipe's config: its YAML file, the command line's ``key=value`` overrides, and the
config a resumed run was started with, into the recipe's class (``_config.RECIPES``).

Each override's key is checked against the class's fields as it is put into the file's content
(an unknown key is named with the closest valid one; a key of the layout before the ``task``
section was the task's config is named with its new key); then ``torchnav.config.from_dict``
builds the class, checking every value at once.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import re
import sys
import typing
from pathlib import Path
from typing import Any

import yaml
from _config import RECIPES, Recipe

from torchnav.config import ConfigError, from_dict, to_dict

CONFIG_DIR = Path(__file__).resolve().parent / "configs"

# Keys of the layout before the task section became the task's own config: old key -> new key.
MOVED = {"env.map": "task.map", "env.max_steps": "task.max_steps", "env.goal_tolerance": "task.goal_tolerance",
         "env.track": "task.track", "curriculum": "task.curriculum", "reward": "task.reward"}


def moved(key: str) -> str | None:
    """The new name of a key of the old layout (None for any other key)."""
    for old, new in MOVED.items():
        if key == old or key.startswith(old + "."):
            return new + key[len(old):]
    return None


def _moved_in(data: dict[str, Any]) -> list[str]:
    """The old-layout keys (``MOVED``) present in a config as nested dicts."""
    return [old for old in MOVED if _lookup(data, old) is not _ABSENT]


_ABSENT = object()


def _lookup(data: Any, key: str) -> Any:
    for part in key.split("."):
        if not isinstance(data, dict) or part not in data:
            return _ABSENT
        data = data[part]
    return data


def _put(cls: type, data: dict[str, Any], key: str, value: Any) -> None:
    """Set dotted ``key`` of ``data`` (a config of class ``cls`` as nested dicts), after checking that
    each part of it names a field: an unknown key is a ConfigError naming it and the closest valid one."""
    tp: Any = cls
    parts = key.split(".")
    for i, part in enumerate(parts):
        if dataclasses.is_dataclass(tp):
            names = [f.name for f in dataclasses.fields(tp)]
            if part not in names:
                where = ".".join(parts[:i])
                close = difflib.get_close_matches(part, names, n=1)
                hint = f" (did you mean '{where + '.' if where else ''}{close[0]}'?)" if close else ""
                raise ConfigError(f"unknown config key '{key}'{hint}; valid keys{' of ' + where if where else ''}: {', '.join(names)}")
            tp = typing.get_type_hints(tp)[part]
        else:
            tp = None  # inside a mapping-valued field (task.reward.weights, task.worlds.families): any key
        if i == len(parts) - 1:
            data[part] = value
        else:
            if not isinstance(data.get(part), dict):
                data[part] = {}
            data = data[part]


class _Values(yaml.SafeLoader):
    """Command-line values read as YAML, with 1e-3, nan and inf as floats and only true/false as booleans."""


_Values.yaml_implicit_resolvers = {c: [r for r in rs if r[0] != "tag:yaml.org,2002:bool"] for c, rs in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Values.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF"))
_Values.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+|nan|inf)$", re.I),
                              list("-+0123456789.nNiI"))


def parse_override(text: str) -> tuple[str, Any]:
    """``key.sub=value`` as ``(key, value)``, the value read as YAML (``[16,16]`` a list, ``null`` None)."""
    key, _, raw = text.partition("=")
    try:
        return key, yaml.load(raw, Loader=_Values)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as e:
        raise ConfigError(f"{key}={raw}: not a readable value ({str(e).splitlines()[0]})") from None


def parse_cli(name: str, argv: list[str]) -> tuple[Path, list[str]]:
    """The config file and the ``key.sub=value`` overrides of a recipe's command line.

    ``--config PATH`` replaces ``configs/<name>.yaml``; ``--resume [RUN_DIR]`` sets
    ``checkpoint.resume``; ``-h`` prints the usage and exits.
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
            path = Path(next(it, ""))
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
    return path, overrides


def build(name: str, data: dict[str, Any], overrides: list[str], source: str, run_dir: Path | None = None) -> Recipe:
    """Recipe ``name``'s config from ``data`` (a config file's content) and dotted ``overrides``,
    every value validated; ``run_dir`` sets ``logger.run_dir`` (a resumed run's directory)."""
    cls = RECIPES.get(name)
    if cls is None:
        raise ConfigError(f"unknown recipe {name!r}; recipes: {', '.join(RECIPES)}")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of config sections, got {type(data).__name__}")
    old = _moved_in(data)
    if old:
        raise ConfigError(f"{source}: " + "; ".join(f"{k} is now {MOVED[k]}" for k in old)
                          + " (the task section is the task's NavConfig or LineConfig: docs/training.md#configuration)")
    data = copy.deepcopy(data)
    for text in overrides:
        key, value = parse_override(text)
        if (new := moved(key)) is not None:
            raise ConfigError(f"{key} is now {new} (the task section is the task's NavConfig or LineConfig: docs/training.md#configuration)")
        _put(cls, data, key, value)
    if run_dir is not None:
        _put(cls, data, "logger.run_dir", str(run_dir))
    return from_dict(cls, data, where="")


def load_config(name: str, argv: list[str]) -> Recipe:
    """``configs/<name>.yaml`` (or ``--config FILE``) with the command line's overrides, validated."""
    path, overrides = parse_cli(name, argv)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    return build(name, yaml.safe_load(path.read_text()) or {}, overrides, str(path))


def migrated(saved: dict[str, Any]) -> dict[str, Any]:
    """A config saved by an older torchnav (``env.map``, ``curriculum``, ...) in the current layout."""
    saved = copy.deepcopy(saved)
    for old in _moved_in(saved):
        *parents, leaf = old.split(".")
        node = saved
        for p in parents:
            node = node[p]
        *new_parents, new_leaf = MOVED[old].split(".")
        dest = saved
        for p in new_parents:
            dest = dest.setdefault(p, {})
        dest[new_leaf] = node.pop(leaf)
    return saved


# What a resumed run may change from the config it was started with: its length, evaluation,
# logging, checkpoint cadence, threads and device. Anything else would make it another experiment.
RESUME_CHANGES = ("train.total_frames", "eval.", "logger.", "checkpoint.", "threads", "device")


def _leaves(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for k, v in node.items():
            out.update(_leaves(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: node}


def resumed_config(saved: dict[str, Any], argv: list[str], name: str, run: Path | str | None,
                   source: Path | str | None = None) -> tuple[Recipe, list[str]]:
    """The config a resumed run continues with: the one it was started with (``saved``, from its
    checkpoint ``source``) plus the command line's overrides, of which only :data:`RESUME_CHANGES` may
    change a value, and ``logger.run_dir`` set to ``run`` (None: a new automatic run directory). Returns
    the config and one line per changed value; a refused change is a ConfigError."""
    _, overrides = parse_cli(name, argv)
    saved = migrated(saved)
    label = source or run  # what --resume named
    source = str(source or f"{run}/config.yaml")
    old = _leaves(to_dict(build(name, saved, [], source)))
    if run is None:
        saved = {**saved, "logger": {**saved.get("logger", {}), "run_dir": None}}
    cfg = build(name, saved, overrides, source, run_dir=run)
    new = _leaves(to_dict(cfg))
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k) and k not in ("checkpoint.resume", "logger.run_dir")]
    refused = [k for k in changed if not any(k == p or (p.endswith(".") and k.startswith(p)) for p in RESUME_CHANGES)]
    if refused:
        raise ConfigError(f"--resume={label}: cannot change {', '.join(f'{k} ({old.get(k)!r} -> {new.get(k)!r})' for k in refused)}; "
                          f"a resumed run keeps the config it was started with except {', '.join(RESUME_CHANGES)}. Start a new run instead.")
    return cfg, [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed]


def save_config(cfg: Recipe, run: Path) -> None:
    """``<run>/config.yaml``: every key, the task's defaults included; ``--config`` reads it back to the same config."""
    (run / "config.yaml").write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))
