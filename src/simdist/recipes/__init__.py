"""The end-to-end recipes, installed as console scripts (run them from any directory).

- ``simdist-quadruped`` (:mod:`simdist.recipes.simdist_quadruped`): SimDist on the
  quadruped, with the whole-model ablation and the continued-SAC baseline.
- ``simdist-train-expert`` (:mod:`simdist.recipes.train_expert`): the state-based SAC
  expert.
- ``simdist-dataset`` (:mod:`simdist.recipes.generate_dataset`): a perturbed-expert
  dataset on disk.
- ``simdist-evaluate`` (:mod:`simdist.recipes.evaluate`): any saved agent in any task and
  target.
- ``simdist-twist`` (:mod:`simdist.recipes.twist_dmc`): TWIST on the control suite, with
  its ablations and the pixel-Dreamer baselines.

``python -m simdist.recipes.<module>`` and, in a checkout, ``python recipes/<module>.py``
run the same code; each script's ``--help`` lists its flags with their defaults. The recipes are
scripts, not API: the stages and configs they run are :mod:`simdist.pipelines.simdist` and
:mod:`simdist.pipelines.twist`, which Python users import and compose.
"""

import importlib


def run_from_checkout(name: str, caller: str, namespace: dict) -> None:
    """What ``recipes/<name>.py`` in a checkout does: run the recipe when executed as a
    script (``caller == "__main__"``), else expose its names in ``namespace`` (a module
    imported by path, e.g. by tests or benchmarks)."""
    recipe = importlib.import_module(f"{__name__}.{name}")
    if caller == "__main__":
        recipe.main()
    else:
        namespace.update({k: v for k, v in vars(recipe).items() if not k.startswith("__")})
