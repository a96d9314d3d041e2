"""The end-to-end recipes, installed as console scripts (run them from any directory).

| console script | module | what it runs |
| --- | --- | --- |
| ``simdist-quadruped`` | ``simdist.recipes.simdist_quadruped`` | SimDist on the quadruped, with baselines |
| ``simdist-train-expert`` | ``simdist.recipes.train_expert`` | the state-based SAC expert |
| ``simdist-dataset`` | ``simdist.recipes.generate_dataset`` | a perturbed-expert dataset |
| ``simdist-evaluate`` | ``simdist.recipes.evaluate`` | any saved agent in any task and target |

``python -m simdist.recipes.<module>`` and, in a checkout, ``python recipes/<module>.py``
run the same code. (The TWIST recipe is still only ``recipes/twist_dmc.py`` in a checkout.) Each script's ``--help`` lists its flags with their defaults. The
recipes are scripts, not API: import them only to reuse a recipe's ``Config``.
"""
