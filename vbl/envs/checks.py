"""Input checks shared by the environments' non-jitted entry points."""

from collections.abc import Sequence
from typing import Any

import numpy as np


def check_action_index(action: Any, num_actions: int, env_name: str,
                       labels: Sequence[str]) -> None:
    """Raise ValueError unless ``action`` is a () integer in [0, num_actions)."""
    a = np.asarray(action)
    if a.shape != ():
        raise ValueError(f"action must be a scalar index (shape ()), got shape {a.shape}; "
                         "vmap the env for a batch")
    if a.dtype.kind not in "iu":
        raise ValueError(f"action must be an integer index, got dtype {a.dtype}")
    if not 0 <= int(a) < num_actions:
        raise ValueError(f"action {int(a)} out of range for {env_name}: must be in "
                         f"[0, {num_actions - 1}] ({', '.join(labels)})")
