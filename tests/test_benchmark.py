"""recipes/benchmark.py: a tiny suite writes its table, JSON and heat map; seeds; errors before any work."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest
import torch

from torchnav.controllers import CONTROLLERS, make_controller
from torchnav.envs import NavEnv
from torchnav.evaluation import eval_config, run_episodes
from torchnav.policy import load_policy
from torchnav.tasks import NavConfig

ROOT = Path(__file__).resolve().parents[1]
CKPT = ROOT / "checkpoints" / "td3_arena_actor.pt"
sys.path.insert(0, str(ROOT / "recipes"))
benchmark = importlib.import_module("benchmark")

TINY = [str(CKPT), "--maps", "arena", "empty", "--families", "rooms", "--levels", "easy=0.2", "--controllers", "reactive", "astar",
        "--episodes", "3", "--threads", "1"]
CELLS = ["arena", "empty", "rooms/easy"]


def test_tiny_suite_writes_table_json_and_heatmap(tmp_path):
    doc = benchmark.main(TINY + ["--out", str(tmp_path)])
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved == json.loads(json.dumps(doc)) and saved["complete"]
    assert saved["methods"] == ["td3_arena_actor", "reactive", "astar"]
    assert [c["label"] for c in saved["cells"]] == CELLS
    shipped = benchmark.available_maps()
    seeds = [benchmark.SEED_BASE + benchmark.SEED_STRIDE * i
             for i in (shipped.index("arena"), shipped.index("empty"), benchmark.MAP_SLOTS + benchmark.MAX_LEVELS * list(benchmark.FAMILIES).index("rooms"))]
    assert [c["seed"] for c in saved["cells"]] == seeds
    for cell in saved["cells"]:
        assert set(cell["configs"]) == {"td3_arena_actor", "reactive", "astar"}
        cfg = cell["configs"]["reactive"]
        assert cfg["curriculum"]["mode"] == "off" and not cfg["worlds"]["curriculum"]
        assert cfg["worlds"]["families"] == ({} if cell["kind"] == "map" else {"rooms": 1.0})
        assert cell["kind"] == "world" or cfg["map"] == cell["name"]
    rooms = saved["cells"][2]
    assert rooms["difficulty"] == rooms["configs"]["td3_arena_actor"]["worlds"]["difficulty"] == 0.2
    for m in saved["methods"]:
        for label in CELLS:
            if m == "astar" and label == "rooms/easy":  # the planners need a map's spec
                assert saved["results"][m][label] is None
                continue
            s = saved["results"][m][label]["success"]
            assert saved["results"][m][label]["episodes"] == 3 and 0 <= s["rate"] <= 1
            assert s["ci95"][0] - 1e-9 <= s["rate"] <= s["ci95"][1] + 1e-9
            outcomes = saved["results"][m][label]["outcomes"]  # one letter per episode, counted as the summary counts
            assert len(outcomes) == 3 and all(outcomes.count(k[0].upper()) == saved["results"][m][label][k]["count"]
                                              for k in ("success", "collision", "timeout"))
    assert set(saved["planning"]["astar"]) == {"arena", "empty"}
    md = (tmp_path / "results.md").read_text()
    assert "| cell | seed | td3_arena_actor | reactive | astar |" in md
    table, rest = md.split("Paired against td3_arena_actor")
    paired, rest = rest.split("Time to goal over the optimal time")
    timing, smooth = rest.split("Smoothness:")
    assert all(table.count(f"| {c} |") == 1 for c in CELLS) and table.count("| n/a |") == 1
    # time over the optimal time and smoothness: a row per cell, n/a where the planner did not run
    for t in (timing, smooth):
        assert "| cell | td3_arena_actor | reactive | astar |" in t and all(t.count(f"| {c} |") == 1 for c in CELLS) and t.count("n/a") == 1
    for m in saved["methods"]:
        for label in CELLS:
            r = saved["results"][m][label]
            if r is None:
                continue
            assert r["time_score"]["mean"] <= 1 and r["no_reference"] == 0 and r["speed_change"]["mean"] > 0
            assert r["success"]["count"] == 0 or r["time_ratio"]["mean"] >= 0.5
    assert set(saved["shortest_paths"]) == set(CELLS) and all(v["no_path"] == 0 for v in saved["shortest_paths"].values())
    # the paired table: a row per cell, a column per other method, n/a where the planner did not run
    assert "| cell | reactive | astar |" in paired and all(paired.count(f"| {c} |") == 1 for c in CELLS)
    assert paired.count("n/a") == 1 and paired.count(", p ") == 5
    assert (tmp_path / "heatmap.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the same arguments give the same episodes and results
    again = benchmark.main(TINY + ["--out", str(tmp_path / "again")])
    assert again["results"] == doc["results"] and again["cells"] == doc["cells"]


def test_seeds_depend_on_the_cell_only_and_avoid_training_seeds():
    levels = benchmark.parse_levels(list(benchmark.DEFAULT_LEVELS))
    full = benchmark.suite(benchmark.available_maps(), list(benchmark.FAMILIES), levels, benchmark.SEED_BASE)
    seeds = {c.label: c.seed for c in full}
    assert len(full) == len(benchmark.available_maps()) + 3 * len(benchmark.FAMILIES) == len(set(seeds.values()))
    subset = benchmark.suite(["maze"], ["forest"], levels, benchmark.SEED_BASE)
    assert {c.label: c.seed for c in subset} == {k: seeds[k] for k in ("maze", "forest/easy", "forest/medium", "forest/hard")}
    assert min(seeds.values()) >= 1_000_000  # training uses seed, 10000 + seed and 20000 + seed
    assert [c.difficulty for c in full if c.name == "cave"] == [0.2, 0.5, 0.8]


def test_every_shipped_map_has_a_fixed_seed_slot_that_adding_a_map_does_not_move():
    # Seeds were once the map's position in available_maps(), so a new shipped map shifted the
    # seeds (and the recorded figures) of every map after it in alphabetical order.
    assert set(benchmark.available_maps()) <= set(benchmark.MAP_INDEX)
    assert sorted(benchmark.MAP_INDEX.values()) == list(range(len(benchmark.MAP_INDEX)))
    assert len(benchmark.MAP_INDEX) <= benchmark.MAP_SLOTS
    seeds = {c.label: c.seed for c in benchmark.suite(["arena", "warehouse"], [], {}, benchmark.SEED_BASE)}
    # the seeds every figure in docs/results.md was measured with
    assert seeds == {"arena": 1_000_000, "warehouse": 1_000_000 + 4 * benchmark.SEED_STRIDE}


def test_exactly_the_controllers_that_refuse_generated_worlds_run_on_map_cells_only():
    arena, forest = benchmark.suite(["arena"], ["forest"], {"easy": 0.2}, 0)
    env = NavEnv(forest.config(NavConfig()), num_envs=2, seed=0)
    env.reset()
    for name in CONTROLLERS:
        ctrl = make_controller(name)
        try:
            ctrl.bind(env)
            refused = False
        except ValueError:
            refused = True
        assert benchmark.runs_on(ctrl, arena) and benchmark.runs_on(ctrl, forest) != refused, name
    assert benchmark.runs_on(load_policy(CKPT).policy, forest)
    # in the table, n/a (does not run there) differs from – (not run yet, in a partial results.md)
    assert "| arena | 0 | – | n/a |" in benchmark.markdown({"policy": {}, "planner": {"arena": None}}, [arena], 3)


def test_eval_config_replaces_worlds_and_maps_turn_them_off():
    trained = NavConfig.from_dict({"worlds": {"families": {"rooms": 1.0, "cave": 2.0}, "curriculum": True}})
    forest = eval_config(trained, worlds={"families": {"forest": 1.0}, "difficulty": 0.8})
    assert forest.worlds.families == {"forest": 1.0} and forest.worlds.difficulty == 0.8 and not forest.worlds.curriculum
    assert forest.curriculum.mode == "off"
    arena = eval_config(trained, map="arena")
    assert arena.map == "arena" and arena.worlds.families == {}
    with pytest.raises(ValueError, match="not both"):
        eval_config(trained, map="arena", worlds={"difficulty": 0.5})
    # a policy trained on another map plays family cells too (its map is not used there)
    on_maze = eval_config(NavConfig.from_dict({"map": "maze"}), worlds={"families": {"forest": 1.0}, "difficulty": 0.5})
    assert on_maze.worlds.families == {"forest": 1.0} and on_maze.map == "arena"
    # training's shares of easier episodes never reach evaluation: each cell plays its own difficulty
    mixed = NavConfig.from_dict({"worlds": {"families": {"rooms": 1.0}, "curriculum": True, "max_difficulty": 0.8,
                                            "anywhere_goals": 0.3, "below_level": 0.5}})
    for ev in (eval_config(mixed), eval_config(mixed, worlds={"families": {"forest": 1.0}, "difficulty": 0.5})):
        assert (ev.worlds.anywhere_goals, ev.worlds.below_level) == (0.0, 0.0)
    assert eval_config(mixed).worlds.difficulty == 0.8


@pytest.mark.parametrize("args, message", [
    (["--maps", "nowhere"], "unknown map 'nowhere'"),
    (["--families", "jungle"], "unknown family 'jungle'"),
    (["--controllers", "astr"], "unknown controller 'astr'"),
    (["--controllers", "reactive", "--perturb", "wind"], "--perturb: unknown perturbation 'wind'"),
    (["--levels", "hard"], "expected NAME=DIFFICULTY"),
    (["--levels", "hard=x"], "is not a number"),
    (["--levels", "hard=1.5"], "must be in [0, 1]"),
    (["--levels", "a=0.1", "a=0.2"], "given twice"),
    (["--maps", "--families"], "no cells"),
    (["--map-file", "nowhere/lab.yaml"], "--map-file: nowhere/lab.yaml: map file not found"),
    (["--map-file", "arena"], "expected a .yaml or .yml map file (a shipped map: --maps arena)"),
    (["--map-file", "tests/data/dense_room.png"], "expected a .yaml or .yml map file"),
    (["--map-file", "examples/maps/lab.yaml", "--map-file", "./examples/maps/lab.yaml"], "given twice"),
    (["--maps", "arena", "arena"], "given twice"),
    (["--episodes", "0"], "--episodes must be >= 1"),
])
def test_bad_arguments_stop_before_any_work(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit):
        benchmark.main(args + ["--out", str(tmp_path / "out")])
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_bad_map_file_is_refused_before_any_work(tmp_path, capsys):
    (tmp_path / "lab.yaml").write_text("image: lab.pgm\nresolution: -0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n")
    with pytest.raises(SystemExit):
        benchmark.main(["--map-file", str(tmp_path / "lab.yaml"), "--out", str(tmp_path / "out")])
    assert f"--map-file: {tmp_path / 'lab.yaml'}: resolution: expected a positive number" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_map_files_are_map_cells_whose_seeds_follow_the_file(tmp_path):
    lab = ROOT / "examples" / "maps" / "lab.yaml"
    (tmp_path / "copy.yaml").write_bytes(lab.read_bytes())
    cells = benchmark.suite(["arena"], ["rooms"], {"easy": 0.2}, benchmark.SEED_BASE, [str(lab), str(tmp_path / "copy.yaml")])
    assert [c.kind for c in cells] == ["map", "map", "map", "world"] and cells[1].label == str(lab) and cells[1].name == str(lab)
    assert cells[1].seed == cells[2].seed  # the same bytes wherever the file lies
    alone = benchmark.suite([], [], {}, benchmark.SEED_BASE, [str(lab)])
    assert alone[0].seed == cells[1].seed  # nor on the other cells
    assert {c.label: c.seed for c in cells if c.label in ("arena", "rooms/easy")} == {
        c.label: c.seed for c in benchmark.suite(["arena"], ["rooms"], {"easy": 0.2}, benchmark.SEED_BASE)}
    index = benchmark.file_index(str(lab))
    assert benchmark.FILE_BASE <= index < benchmark.FILE_BASE + benchmark.FILE_SLOTS
    assert benchmark.FILE_BASE > benchmark.MAP_SLOTS + benchmark.MAX_LEVELS * len(benchmark.FAMILIES)  # past every family's slots
    assert benchmark.SEED_BASE + benchmark.SEED_STRIDE * (benchmark.FILE_BASE + benchmark.FILE_SLOTS) < 2**31
    cfg = cells[1].config(NavConfig())
    assert cfg.map == str(lab) and cfg.curriculum.mode == "off"
    assert all(benchmark.runs_on(make_controller(n), cells[1]) for n in CONTROLLERS)  # the planners plan on its spec


@pytest.mark.slow  # about 15 s: a tool's end-to-end run, outside the default suite's budget
def test_a_map_server_file_cell_runs_end_to_end(tmp_path):
    lab = "examples/maps/lab.yaml"
    doc = benchmark.main(["--maps", "--families", "--map-file", str(ROOT / lab), "--controllers", "reactive", "astar",
                          "--episodes", "2", "--threads", "1", "--out", str(tmp_path)])
    (cell,) = doc["cells"]
    assert cell["label"] == str(ROOT / lab) and cell["configs"]["astar"]["map"] == str(ROOT / lab)
    assert cell["seed"] == benchmark.SEED_BASE + benchmark.SEED_STRIDE * benchmark.file_index(str(ROOT / lab))
    for m in ("reactive", "astar"):
        assert doc["results"][m][cell["label"]]["episodes"] == 2
    assert set(doc["planning"]["astar"]) == {cell["label"]}


def test_missing_or_corrupt_checkpoint_is_named(tmp_path):
    bad = tmp_path / "corrupt.pt"
    bad.write_bytes(b"not a checkpoint")
    for path, error in ((tmp_path / "missing.pt", FileNotFoundError), (bad, ValueError)):
        with pytest.raises(error, match=path.name):
            benchmark.main([str(path), "--maps", "arena", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_paired_successes_is_the_exact_mcnemar_test():
    from torchnav.evaluation import paired_successes

    d = paired_successes([True] * 10 + [False] * 5, [False] * 15)
    assert (d["only_a"], d["only_b"], d["difference"]) == (10, 0, pytest.approx(10 / 15))
    assert d["p"] == pytest.approx(2 / 2**10)  # 10 discordant episodes all one way
    # 3 against 12: 2 * P(X <= 3), X ~ Binomial(15, 1/2) = 2 * (1 + 15 + 105 + 455) / 2^15
    d = paired_successes([True] * 3 + [False] * 12 + [True] * 5, [False] * 3 + [True] * 12 + [True] * 5)
    assert (d["only_a"], d["only_b"], d["episodes"]) == (3, 12, 20) and d["p"] == pytest.approx(2 * 576 / 2**15)
    assert paired_successes([True, False], [True, False])["p"] == 1.0  # no discordant episode
    assert paired_successes([True, False, True, False], [False, True, False, True])["p"] == 1.0  # capped at 1
    with pytest.raises(ValueError, match="same episodes"):
        paired_successes([True], [True, False])


def outcome_letters(res: dict) -> str:
    """``run_episodes``' result as one letter per episode: S(uccess), C(ollision) or T(imeout)."""
    return "".join("S" if s else "C" if c else "T" for s, c in zip(res["success"].tolist(), res["collision"].tolist()))


def test_failure_paths_plays_the_benchmark_cells_episodes():
    """docs/scripts/failure_paths.py keeps each episode's goal-distance grid to read the path
    distance after every step; that must leave the cell's episodes as the benchmark plays them."""
    sys.path.insert(0, str(ROOT / "docs" / "scripts"))
    failure_paths = importlib.import_module("failure_paths")
    ckpt = ROOT / "checkpoints" / "ppo_generalist_actor.pt"
    levels = benchmark.parse_levels(list(benchmark.DEFAULT_LEVELS))
    (cell,) = [c for c in benchmark.suite([], ["corridors"], levels, benchmark.SEED_BASE) if c.level == "medium"]
    assert cell.seed == 2170819  # the seed docs/results.md quotes for corridors/medium
    ep = failure_paths.play(str(ckpt), cell, 12)
    outcomes, path, xy, steps = ep.outcomes, ep.path, ep.xy, ep.steps
    sp = load_policy(ckpt)
    res = run_episodes(sp.policy, eval_config(sp.config(), worlds={"families": {"corridors": 1.0}, "difficulty": 0.5}), 12, seed=2170819)
    assert outcomes == outcome_letters(res)
    assert steps.tolist() == res["length"].long().tolist()
    assert path.shape == (12, int(steps.max()) + 1) and xy.shape == (12, int(steps.max()), 2)
    assert bool(path[:, 0].isfinite().all())  # every generated start has a known path to its goal
    for i, o in enumerate(outcomes):
        if o == "S":  # a success ends within the goal tolerance (0.3 m), read through the coarse grid (cells of 0.15-0.3 m here)
            assert float(path[i, int(steps[i])]) < 0.3 + 0.25


@pytest.mark.slow  # about 15-25 s: tools' end-to-end runs, outside the default suite's budget
def test_failure_paths_on_a_map_cell_and_its_picture(tmp_path):
    """On a shipped map (no goal grid) failure_paths measures straight-line distances, plays the
    benchmark's episodes of that map, and --picture draws the failures it names."""
    sys.path.insert(0, str(ROOT / "docs" / "scripts"))
    failure_paths = importlib.import_module("failure_paths")
    ckpt = ROOT / "checkpoints" / "ppo_generalist_actor.pt"
    (cell,) = benchmark.suite(["warehouse"], [], {}, benchmark.SEED_BASE)
    ep = failure_paths.play(str(ckpt), cell, 8)
    sp = load_policy(ckpt)
    res = run_episodes(sp.policy, eval_config(sp.config(), map="warehouse"), 8, seed=cell.seed)
    assert ep.outcomes == outcome_letters(res)
    torch.testing.assert_close(ep.path[:, 0], res["straight_line"].to(ep.path.dtype))  # the start's straight line to its goal
    for i, o in enumerate(ep.outcomes):
        if o == "S":
            assert float(ep.path[i, int(ep.steps[i])]) < 0.3
    out = tmp_path / "failures.png"
    drawn = failure_paths.picture(ep, "S", "successes", out)
    assert drawn == min(6, ep.outcomes.count("S")) and drawn > 0 and out.stat().st_size > 10_000


def test_failure_paths_gap_probe_pins_starts_and_goals():
    """failure_paths --probe (docs/results.md, "Why: a 0.65 m gap read as a wall"): 168 episodes under
    the gaps of warehouse's rack row, goals across it; play(given=...) starts each episode where the
    probe puts it, in free space, and refuses pins of the wrong shape or on a generated-world cell."""
    sys.path.insert(0, str(ROOT / "docs" / "scripts"))
    failure_paths = importlib.import_module("failure_paths")
    from torchnav.sim import points_clearance

    starts, goals, rows = failure_paths.gap_probe()
    assert starts.shape == (168, 3) and goals.shape == (168, 2) and len(rows) == 168
    assert bool((goals[:, 1] - starts[:, 1] > 2.5).all()) and bool((starts[:, 0].abs() <= 9.7).all())
    ckpt = ROOT / "checkpoints" / "ppo_generalist_actor.pt"
    (cell,) = benchmark.suite(["warehouse"], [], {}, benchmark.SEED_BASE)
    pick = [0, 2, 61, 100, 167]  # other gaps, offsets and headings
    ep = failure_paths.play(str(ckpt), cell, len(pick), given=(starts[pick], goals[pick]))
    torch.testing.assert_close(ep.goal, goals[pick])
    torch.testing.assert_close(ep.path[:, 0], (starts[pick, :2] - goals[pick]).norm(dim=-1))  # started at the given spot
    radius = load_policy(ckpt).config().robot.radius
    assert bool((points_clearance(starts[pick, None, :2], ep.world)[:, 0] > radius).all())
    with pytest.raises(ValueError, match=r"start must be \(3, 3\)"):  # NavEnv.reset_to checks the shapes
        failure_paths.play(str(ckpt), cell, 3, given=(starts[:2], goals[:2]))
    levels = benchmark.parse_levels(list(benchmark.DEFAULT_LEVELS))
    world_cell = benchmark.suite([], ["corridors"], levels, benchmark.SEED_BASE)[0]
    with pytest.raises(ValueError, match="need a map cell"):
        failure_paths.play(str(ckpt), world_cell, 2, given=(starts[:2], goals[:2]))
    for argv in ([str(ckpt), "--probe"], [str(ckpt), "--map", "warehouse", "--probe", "--episodes", "5"]):
        with pytest.raises(SystemExit):  # the probe is warehouse's and plays its own 168 episodes
            failure_paths.main(argv)


def test_perturb_plays_each_method_under_each_perturbation(tmp_path):
    from torchnav.evaluation import PERTURBATIONS, perturbed
    from torchnav.tasks import NavConfig

    doc = benchmark.main(["--maps", "arena", "--families", "rooms", "--levels", "easy=0.2", "--controllers", "reactive", "astar",
                          "--episodes", "3", "--perturb", "delay", "acceleration", "--out", str(tmp_path)])
    assert set(doc["robustness"]) == {"delay", "acceleration"} and doc["perturbations"]["delay"] == PERTURBATIONS["delay"]
    assert set(doc["robustness"]["delay"]["reactive"]) == {"arena", "rooms/easy"}
    assert set(doc["robustness"]["delay"]["astar"]) == {"arena"}  # the planner runs on map cells only
    md = (tmp_path / "results.md").read_text()
    assert "Robustness of reactive" in md and "| cell | none | delay | acceleration |" in md
    assert md.split("Robustness of astar")[1].count("| n/a | n/a | n/a |") == 1
    cfg = perturbed(NavConfig(), "acceleration")
    assert (cfg.robot.lin_acc_max, cfg.robot.ang_acc_max) == (1.0, 3.0) and perturbed(NavConfig(), "delay").randomize.delay == (1, 1)
    with pytest.raises(ValueError, match="unknown perturbation 'wind'"):
        perturbed(NavConfig(), "wind")


def test_set_lays_task_keys_over_every_method(tmp_path):
    """--set changes every method's config, a checkpoint's and the controllers'; a preset there replaces the
    checkpoint's saved body (which holds every robot key); a bad key is named before any episode."""
    from torchnav.config import ConfigError

    doc = benchmark.main([str(CKPT), "--maps", "arena", "--families", "--controllers", "reactive", "--episodes", "2", "--threads", "1",
                          "--set", "robot.preset=turtlebot3_burger", "max_steps=40", "--out", str(tmp_path / "out")])
    assert doc["set"] == ["robot.preset=turtlebot3_burger", "max_steps=40"]
    configs = doc["cells"][0]["configs"]
    assert set(configs) == {"td3_arena_actor", "reactive"}
    for cfg in configs.values():
        assert (cfg["robot"]["radius"], cfg["robot"]["v_max"], cfg["max_steps"]) == (0.105, 0.22, 40)
    assert all(r["arena"]["episodes"] == 2 for r in doc["results"].values())
    with pytest.raises(ConfigError, match=r"--set.robot: unknown key .nope."):
        benchmark.main(["--maps", "arena", "--families", "--controllers", "reactive", "--set", "robot.nope=1", "--out", str(tmp_path / "bad")])
    assert not (tmp_path / "bad").exists()
