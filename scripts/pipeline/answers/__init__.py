"""Answers with a stated error: questions on a case's parameter space answered by the cheapest
method whose stated error reaches the wanted accuracy, every CPU second counted.

Modules (one concept each):

* ``questions``  the questions file (JSON): parameter box, distributions, questions, accuracy;
* ``backend``    models as backends: parameters [n, d] and seeds [n] in, QoI values [n] and CPU
  seconds out (``SyntheticFamily`` of correlated models with known moments, ``PredictBackend``
  running crowd_predict on the exact model or a reduced setting of a ROM file);
* ``ledger``     the cost ledger (CPU seconds per stage and model);
* ``intervals``  the ``Answer`` record and the single-sample statistics with their intervals;
* ``mfmc``       multi-fidelity Monte Carlo: allocation, estimators, variances;
* ``acv``        approximate control variates (MFMC, ACV-MF, ACV-IS layouts): variance, allocation, estimators;
* ``surrogate``  Gaussian-process surrogates (single- and multi-fidelity), posterior propagation;
* ``methods``    M0 (exact Monte Carlo), M1 (GP), M2 (low fidelity alone), M3 (multi-fidelity);
* ``select``     the cheapest method per question and accuracy; table, JSON, figure;
* ``coverage``   repetitions of an estimator against a known truth;
* ``reference``  the honest reference: large exact samples in resumable chunks, the truth with
  its Monte Carlo error;
* ``pool``       models served from runs made beforehand (lookup, a pool drawn without
  replacement) for the coverage repetitions.

The command-line driver is ``scripts/pipeline/crowd_answers.py``; the page is ``docs/answers.md``.
"""
