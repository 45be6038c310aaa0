"""Evaluation of PoseidonSLAM runs: every metric and report, each defined once.

Services never import this package (they import only ``common``); the ``poseidon``
command, benchmarks and tests do.

- :mod:`eval.rundata` -- the run model: one pass over a run recording (``load_run`` -> ``RunData``), used by
  every command here and by the report;
- :mod:`eval.trajectory` -- ``Trajectory`` (NED track), ``PoseSeries`` (poses as published), rigid alignment,
  ATE, RPE, drift (frame conventions and angle helpers: :mod:`common.geometry`);
- :mod:`eval.frontend` -- LVC revisit recall/precision, false associations, VPR window ok_ratio;
- :mod:`eval.run_eval` -- ``poseidon eval``: ``evaluate_run`` (loop closures, recall, ATE, proxies);
- :mod:`eval.cli` -- the command lines of ``poseidon eval`` and ``poseidon vpr`` (arguments, text output) over
  their computing modules;
- :mod:`eval.audit` -- ``poseidon audit``: ``audit_run`` (event-evidence association, sequence gaps);
- :mod:`eval.compare` -- ``poseidon compare``: ``compare_runs`` (Tables 5.2-5.4 and our additions);
- :mod:`eval.summary` -- the evaluation block of ``poseidon run`` / ``demo``;
- :mod:`eval.deadreckon` -- ``poseidon deadreckon``: robot_state offline against plain integration;
- :mod:`eval.corrected` -- the map-corrected trajectory (``poseidon export --tum``), TUM files;
- :mod:`eval.relations` -- the Freiburg benchmark's relation error (``poseidon eval --relations``);
- :mod:`eval.report.benchmark` -- the benchmark section of ``poseidon report --relations`` (laser point maps, loop closures over time, published results).
"""
