"""The loop for dynamics data (kinds ``progression`` and ``trajectory``): synth, compare, diagnose.

A dynamics model file (contract section 4) is run by the event-driven engine through
:mod:`capsule_cli.dynamics.system` (``build_system``, ``progression``, ``trajectory``) under the
file's ``protocol`` (defaults: every condition from rest, 120 transient and 60 recorded periods).

Comparison rows
---------------
* progression: one row per measured condition; the model's average velocity over the recorded
  periods at that condition.
* trajectory: per run, the capsule position at every frame time (``compared = position``);
  where the calibrated model's response at the run's drive is irregular (no period <= 8:
  phase drift, chaos) and its path from rest is not predictable over the run (starts 1-10 um
  from rest part by more than PREDICTABLE_SPREAD_MM at some frame), the run is compared by its
  average velocity over whole periods instead, as one row holding the drift over those periods
  in mm (``compared = average_velocity``); its frames up to the last one before the starts part are
  still compared by position when that covers MIN_HORIZON_PERIODS drive periods or more (mode
  ``position to T s``: both).

Error model
-----------
Each comparison row i has SD_i = sqrt(sigma^2 + s_i^2): sigma the measurement noise
(:func:`.residual_tests.noise_estimate`, replicates when present), s_i the spread of the
model's own response there: the SD of the average velocity over the recorded periods estimated
from 4 windows (window SD / 2), zero for a periodic response; for a progression the larger of that
and the spread over starting states (every condition rerun from the displacements START_OFFSETS_M,
periodic ones too: a periodic response can coexist with another attractor; under a continuation
protocol each sweep is rerun with the offset added to the state every condition starts from; the
prediction is then the mean over the starts). A held-out row's s_i is the larger of the fold's and
the full fit's: a fold refit may put every start in one basin of a response that is multistable at the fit
(40 conditions, a hidden secondary constraint: one condition's starts gave -0.5 and 112 mm/s at the fit, 112 at
every start of its fold, and held the whole held-out error, 17.9 mm/s against 0.60 without it). Held-out
errors, BIC and the verdict use the standardised squared errors r_i^2 sigma^2 / SD_i^2, so chaos
and coexisting attractors are not mistaken for a missing effect. Calibration never minimises a
cost whose weights move with the parameters (the optimiser would prefer parameters whose response
is chaotic: a large spread excuses any misfit): a progression is fitted first by a robust loss,
then by least squares with weights fixed at the robust optimum (:func:`calibrate`).

Calibration
-----------
Bounded, multi-start, derivative-free (the objective is piecewise and non-smooth in the
parameters: impacts appear and vanish): a scrambled Sobol scan of the box, then bounded
Nelder-Mead (scipy) from the best scan points and the start values, in coordinates scaled to
[0, 1]. Each evaluation runs all conditions in parallel (numba ``prange`` in ``run_many``).
Cross-validation: grouped K-fold (:mod:`..crossval`; never splitting a run or replicates),
each fold warm-started from the full fit. 95 % intervals: the fit +- t(0.975, nu) bootstrap
standard errors, a parametric bootstrap (the fit plus the noise, each draw refitted warm-started),
stated in the metrics (:func:`bootstrap_intervals`).

Modules
-------
One module per stage of the loop, each importing only from the ones before it:
:mod:`.bound` (the model bound to a table, budgets, shared constants), :mod:`.calibration`, :mod:`.noise`,
:mod:`.evaluation` (cross-validation, intervals, held-out expectation), :mod:`.outliers`, :mod:`.report`,
:mod:`.verdicts`, and the three commands :mod:`.compare`, :mod:`.diagnose`, :mod:`.synth`.
Every public name of the modules is re-exported here, as the single module had them (the CLI, benchmarks
and tests use ``dynamics_loop.<name>``). To replace a function for a test, patch it in the module that calls it
(``dynamics_loop.evaluation.calibrate``).
"""
from __future__ import annotations

from ..verdict import ALPHA_STRUCTURE
from .bound import (Budget, choose_modes, COLD_STEP, drift_noise_factor, drift_weights, DRIVE_COLS, DYN_KINDS, DynBound,
                    EFFORTS, engine_threads, FATOL_NOISE, frames_by_position, GRADUATED_ROUNDS, is_dynamics,
                    MEMO_POINTS, MEMO_VALUES, merge_modes, MIN_HORIZON_PERIODS, MIN_NOISE_FRAMES, MODE_PASSES,
                    ModelNotRunnable, MULTISTABLE_SPREAD_FRACTION, PARALLEL_ABOVE_S, PENALTY, position_horizon_s,
                    position_rows, position_until, predictable, PREDICTABLE_SPREAD_MM, PROBE_TRIGGER, PROBE_Z,
                    protocol_of, RESPONSE, RESPONSE_CLASSES, ROBUST_SCALE, row_variance, RUN_CLASS_PROTOCOL, run_drift,
                    SERIAL_BELOW_PERIODS, START_OFFSETS_M, UNIT, WARM_STEP, whole_periods_s, XATOL)
from .calibration import (axis_scan, AXIS_SCAN_POINTS, box_map, calibrate, DynEvaluation, Fit, HORIZON_BRANCHES,
                          HORIZON_PERIODS, LINE_LEVELS, LINE_POINTS, line_refine, line_search_points, _nelder_mead,
                          RACE_DROP, RACE_FIRST, _std_sq)
from .noise import (blocked_caveat, blocked_in_row_order, correlated_noise, detrended_by_run, MIN_REPLICATE_DOF,
                    noise_of, noise_rho, progression_noise, public_record, record_serial, replicate_noise_without_chaos,
                    residual_fits, serial_noise, simulated_everywhere, standardised_residual_sd, trajectory_noise)
from .evaluation import (above_linear_expectation, bootstrap_intervals, data_stream, dominant_cause, dominant_group,
                         DOMINANT_MIN_GROUPS, DOMINANT_SHARE, evaluate, HELD_OUT_DRAWS, held_out_of_truth,
                         held_out_record, interval_dof, KNIFE_EDGE_FACTOR, KNIFE_EDGE_FIT, knife_edge_fit_limit,
                         knife_edge_records, KNIFE_EDGE_REL, knife_edge_runs, noise_draw, REFIT_NOISE_RATIO,
                         refit_progression, refit_with_noise, with_design_expectation)
from .outliers import (ALPHA_SCATTER, best_fit, best_fit_level, concentrated_rows, drift_frame_outliers,
                       fit_outlier_rows, flaggable, no_effect_named, outlier_rows, OUTLIER_RULE, PROGRESSION_RULE,
                       rows_chi2, scattered_caveat, scattered_level, scattered_rows, scattered_verdict)
from .report import (box_edges, by_class, diagnosis_markdown, drawn_left_out, param_table, plain_summary,
                     _plot_residuals, regime_of, residual_frame, residual_schema, run_drift_records, run_drift_table,
                     run_drift_words, RUN_DRIFT_Z, RUN_MISFIT_Z, run_residual_rates, slope_se, summary_of)
from .verdicts import (column_probes, concentrated_verdict, dynamics_covariates, dynamics_verdict,
                       left_out_level_verdict, NOT_COVARIATES)
from .compare import _compare_fit, compare_outlier_words, compare_outliers, run_compare, _setup
from .diagnose import (consistent_base, fit_candidate, modes_of_best, needs_probes, nested_first, nested_starts,
                       noise_excess, probe_verdict, run_diagnose)
from .synth import synthesize_progression, synthesize_trajectory, write_synthetic
from . import bound, calibration, compare, diagnose, evaluation, noise, outliers, report, synth, verdicts

__all__ = ["ALPHA_STRUCTURE", "Budget", "choose_modes", "COLD_STEP", "drift_noise_factor", "drift_weights",
           "DRIVE_COLS", "DYN_KINDS", "DynBound", "EFFORTS", "engine_threads", "FATOL_NOISE", "frames_by_position",
           "GRADUATED_ROUNDS", "is_dynamics", "MEMO_POINTS", "MEMO_VALUES", "merge_modes", "MIN_HORIZON_PERIODS",
           "MIN_NOISE_FRAMES", "MODE_PASSES", "ModelNotRunnable", "MULTISTABLE_SPREAD_FRACTION", "PARALLEL_ABOVE_S",
           "PENALTY", "position_horizon_s", "position_rows", "position_until", "predictable", "PREDICTABLE_SPREAD_MM",
           "PROBE_TRIGGER", "PROBE_Z", "protocol_of", "RESPONSE", "RESPONSE_CLASSES", "ROBUST_SCALE", "row_variance",
           "RUN_CLASS_PROTOCOL", "run_drift", "SERIAL_BELOW_PERIODS", "START_OFFSETS_M", "UNIT", "WARM_STEP",
           "whole_periods_s", "XATOL", "axis_scan", "AXIS_SCAN_POINTS", "box_map", "calibrate", "DynEvaluation", "Fit",
           "HORIZON_BRANCHES", "HORIZON_PERIODS", "LINE_LEVELS", "LINE_POINTS", "line_refine", "line_search_points",
           "_nelder_mead", "RACE_DROP", "RACE_FIRST", "_std_sq", "blocked_caveat", "blocked_in_row_order",
           "correlated_noise", "detrended_by_run", "MIN_REPLICATE_DOF", "noise_of", "noise_rho", "progression_noise",
           "public_record", "record_serial", "replicate_noise_without_chaos", "residual_fits", "serial_noise",
           "simulated_everywhere", "standardised_residual_sd", "trajectory_noise", "above_linear_expectation",
           "bootstrap_intervals", "data_stream", "dominant_cause", "dominant_group", "DOMINANT_MIN_GROUPS",
           "DOMINANT_SHARE", "evaluate", "HELD_OUT_DRAWS", "held_out_of_truth", "held_out_record", "interval_dof",
           "KNIFE_EDGE_FACTOR", "KNIFE_EDGE_FIT", "knife_edge_fit_limit", "knife_edge_records", "KNIFE_EDGE_REL",
           "knife_edge_runs", "noise_draw", "REFIT_NOISE_RATIO", "refit_progression", "refit_with_noise",
           "with_design_expectation", "ALPHA_SCATTER", "best_fit", "best_fit_level", "concentrated_rows",
           "drift_frame_outliers", "fit_outlier_rows", "flaggable", "no_effect_named", "outlier_rows", "OUTLIER_RULE",
           "PROGRESSION_RULE", "rows_chi2", "scattered_caveat", "scattered_level", "scattered_rows",
           "scattered_verdict", "box_edges", "by_class", "diagnosis_markdown", "drawn_left_out", "param_table",
           "plain_summary", "_plot_residuals", "regime_of", "residual_frame", "residual_schema", "run_drift_records",
           "run_drift_table", "run_drift_words", "RUN_DRIFT_Z", "RUN_MISFIT_Z", "run_residual_rates", "slope_se",
           "summary_of", "column_probes", "concentrated_verdict", "dynamics_covariates", "dynamics_verdict",
           "left_out_level_verdict", "NOT_COVARIATES", "_compare_fit", "compare_outlier_words", "compare_outliers",
           "run_compare", "_setup", "consistent_base", "fit_candidate", "modes_of_best", "needs_probes", "nested_first",
           "nested_starts", "noise_excess", "probe_verdict", "run_diagnose", "synthesize_progression",
           "synthesize_trajectory", "write_synthetic", "bound", "calibration", "noise", "evaluation", "outliers",
           "report", "verdicts", "compare", "diagnose", "synth"]
