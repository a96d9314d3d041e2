"""The arithmetic precisions a world model may train or plan in, by name.

``SimDistConfig.mixed_precision`` (training updates) and ``PlannerConfig.precision``
(the planner's candidate rollouts) take the same names; each maps to the dtype that
``torch.autocast`` runs matmuls in (``None``: no autocast, float32 throughout).

Examples:
    >>> AUTOCAST_DTYPES["bfloat16"]
    torch.bfloat16
"""

import torch

AUTOCAST_DTYPES = {"none": None, "bfloat16": torch.bfloat16}
