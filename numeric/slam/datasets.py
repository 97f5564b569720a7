"""Where the Freiburg benchmark logs live: ``$CHIZU_SLAM_DATA``, else
``../shared/data/slam`` beside the repository, else ``/work/shared/data/slam``."""

from __future__ import annotations

import os
from pathlib import Path

_REPO = Path(__file__).resolve().parents[2]


def slam_data_dir() -> Path | None:
    """The first existing candidate directory, or ``None``."""
    env = os.environ.get("CHIZU_SLAM_DATA")
    for cand in ([Path(env)] if env else []) + [_REPO.parent / "shared" / "data" / "slam",
                                                 Path("/work/shared/data/slam")]:
        if cand.is_dir():
            return cand
    return None
