"""Deprecated: line following's evaluation is in :mod:`torchnav.evaluation`, next to navigation's
(the same names; ``OUTCOMES`` is ``LINE_OUTCOMES`` there)."""

import warnings

from .evaluation import LINE_OUTCOMES as OUTCOMES, format_lap_summary, lap_outcome, run_line_episodes, summarize_laps  # noqa: F401

warnings.warn("torchnav.line_evaluation is deprecated: import run_line_episodes, lap_outcome, summarize_laps, format_lap_summary "
              "and LINE_OUTCOMES from torchnav.evaluation", DeprecationWarning, stacklevel=2)
