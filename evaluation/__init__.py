"""The evaluation bench: the one package that imports both ``companion`` and ``plant_sim``.

Nothing imports it (DESIGN.md, "What the product is"); the two flight processes stand on
their own. What lives here:

* :mod:`evaluation.harness`: the in-process lockstep harness (plant, camera and the
  companion's pure pipeline, no sockets), and :mod:`evaluation.scenes` its scenes;
* :mod:`evaluation.montecarlo` and ``mc_*``: Monte Carlo batches, local or on a cluster,
  their results and reports;
* :mod:`evaluation.sil`, :mod:`evaluation.sitl`: the networked rigs that start plant-sim
  (or ArduCopter SITL) and the companion as real processes;
* :mod:`evaluation.plots`, :mod:`evaluation.report`, :mod:`evaluation.view`: figures,
  verdicts and viewers;
* :mod:`evaluation.cli`: the ``stereo-avoid`` command.
"""
