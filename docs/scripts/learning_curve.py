"""Plot success rate against wall-clock time and against frames for one or more recipe runs.

    python docs/scripts/learning_curve.py RUN_DIR [RUN_DIR ...] --out docs/img/td3_learning_curve.png
    python docs/scripts/learning_curve.py runs/study18/*/seed* --by-parent --logx --out docs/img/apg_ppo_td3_curves.png

Reads the CSV scalars the recipe logs (eval/success_rate, eval/wall_s, train/success_rate).
With ``--by-parent`` the runs are grouped (one colour, one legend entry) by their parent
directory, e.g. ``bench/training.py``'s ``--out`` folder of each recipe.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from _figures import save  # noqa: E402

from torchnav.render import read_scalars  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("runs", nargs="+")
    p.add_argument("--out", default="runs/learning_curve.png", help="picture to write (default runs/learning_curve.png; the docs picture is docs/img/td3_learning_curve.png)")
    p.add_argument("--by-parent", action="store_true", help="one colour and legend entry per parent directory (method)")
    p.add_argument("--logx", action="store_true", help="logarithmic x axes (methods whose budgets differ by orders of magnitude)")
    a = p.parse_args()
    fig, (ax_t, ax_f) = plt.subplots(1, 2, figsize=(9, 3.4))
    groups: dict[str, str] = {}
    for run in a.runs:
        s = read_scalars(run)
        if "eval/success_rate" not in s:
            raise SystemExit(f"{run}: no eval/success_rate logged")
        ev, wall = s["eval/success_rate"], s["eval/wall_s"]
        label, color = Path(run).name, None
        if a.by_parent:
            group = Path(run).resolve().parent.name
            label = None if group in groups else group  # one legend entry per group
            color = groups.setdefault(group, f"C{len(groups)}")
        ax_f.plot(ev[:, 0], 100 * ev[:, 1], marker="o", ms=3, label=label, color=color)
        ax_t.plot(wall[:, 1], 100 * ev[:, 1], marker="o", ms=3, label=label, color=color)
    for ax, xl in ((ax_t, "wall-clock time [s]"), (ax_f, "frames (env steps)")):
        ax.axhline(95, color="0.5", ls="--", lw=0.8)
        ax.set_xlabel(xl)
        ax.set_ylabel("eval success [%] (goals anywhere)")
        ax.set_ylim(0, 100)
        ax.grid(alpha=0.3)
    if a.logx:
        for ax in (ax_t, ax_f):
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())  # minor labels overlap
    else:
        ax_f.xaxis.set_major_formatter(lambda x, _: f"{x / 1000:.0f}k")
    ax_f.legend(fontsize=7)
    save(fig, a.out, dpi=110)


if __name__ == "__main__":
    main()
