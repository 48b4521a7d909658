"""Orchestration: everything that runs the physics core over many designs and phantoms.

The physics core (:mod:`latticeopt.design`, :mod:`latticeopt.mesh`, :mod:`latticeopt.mechanics`,
:mod:`latticeopt.electrics`, :mod:`latticeopt.coupled`) imports nothing from here.

- :mod:`.config`: study TOML files, validated into a frozen :class:`~.config.Study`, and the evaluation
  settings whose hash keys the store;
- :mod:`.phantoms`: seeded random phantoms, press series and the probe grid with its uniformity;
- :mod:`.sweep`: runs a study through its estimator (:mod:`.estimators`: plain, two-level, adaptive, probes), which
  evaluates through :mod:`.engine` (resumable, in parallel on :mod:`latticeopt.execution`);
  :mod:`.walltime` estimates how long that takes;
- :mod:`.store`: the SQLite results store and the output-folder lock;
- :mod:`.report`: summaries, CSV files and plots of a finished sweep (:mod:`.probe_report` for the probe grid);
- :mod:`.objectives`: design scores for the optimizer;
- :mod:`.calibrate` and :mod:`.sensitivity`: fitting physics parameters to measured presses, and re-running a
  study under changed inputs.

Submodules are imported on first use (``from latticeopt.study.sweep import run_sweep``), so importing the
package costs nothing.
"""
