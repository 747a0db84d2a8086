"""Fidelity studies: how far our labels can be trusted, measured against references, not asserted in tests.

Each module is a script, run from the repository root as ``python -m studies.<name> --help``; it prints its tables
and writes ``studies/results_<name>.json`` (gitignored). ``studies/README.md`` has one section per study: its
question, command, result files and the doc page that reports it. The throughput benchmarks are in ``bench/``.

Against ACRONYM's FleX labels on the calibration grasps (:mod:`studies.calibration` finds and reads them):

- :mod:`studies.fidelity`: agreement, Cohen's kappa and score AUCs per protocol; ``--sweep``, ``--speed``;
- :mod:`studies.gripper_agreement`: two grippers' labels from two :mod:`studies.fidelity` runs on the same grasps (a
  gripper given as a robot model against the bundled hand it stands for);
- :mod:`studies.fidelity_disagreement`: which grasp properties separate FleX-held from FleX-lost among our successes;
- :mod:`studies.second_reference` (Bullet) and :mod:`studies.compliant_reference` (Drake, compliant contact):
  other simulators on the same grasps (``pip install -e '.[reference]'``);
- :mod:`studies.disputed_grasps`: which MuJoCo setting decides the grasps MuJoCo and Bullet disagree on;
- :mod:`studies.label_stability_protocols`: do the labels survive half the timestep, per protocol;
- :mod:`studies.object_grasps_mug`: the calibration mug through the object-centric labelling;
- :mod:`studies.hull_slack`: how far CoACD's convex parts stand out of the true surface, per setting.

On a finished pipeline run: :mod:`studies.label_stability` (a finer simulation) and :mod:`studies.outcome_histogram`
(outcomes per object). Without references: :mod:`studies.mechanics` (cases with an analytic threshold) and
:mod:`studies.learnability` (does a network learn from the labels).
"""
