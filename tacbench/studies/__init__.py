"""The published studies' reproduction code, one module per study, each of one shape:
``commands(...)`` lists the study's ``tacbench run`` commands and ``analyse(results, ...)``
returns its tables by name, which ``tacbench study NAME analyse`` prints and writes as
``<name>.csv`` (``tacbench/cli/study.py``).

- ``adaptive``: learned q and alpha against the fixed values (docs/adaptive.md);
- ``parity``: TAC at q = 1 against stable-baselines3's SAC (docs/parity.md);
- ``sequential``: AdaStop's comparisons checked on the paper-q-grid study and on synthetic
  grids (docs/sequential.md); its ``analyse`` also takes the number of synthetic grids.
"""
