"""Chunked parallel runs of many independent points, results as arrays (no per-point Python).

The compiled engine (:func:`.engine.run_many`, numba ``prange``) does not look at Python's
signal flags while it runs, so a long call cannot be interrupted. This module cuts the work
into chunks of about ``target_chunk_s`` of wall time (sized from the measured cost of the
chunks already run), so that control comes back to Python often: a pending Ctrl-C /
SIGTERM handler runs between chunks (within about one chunk's time), and a progress bar
moves as chunks finish.

Results depend only on each point's parameters and initial state, never on how the points
are chunked (each point is one independent ``run_core`` call), so chunked and unchunked
runs agree exactly.

Continuation protocols (physics.md section 3) run many *rows* in parallel: every row is a
sequence of points, each starting from the previous point's end state; one call per column
runs that column of all rows in parallel.
"""
from __future__ import annotations

import math
import time

import numba
import numpy as np

from ..interrupts import deferred_call
from . import engine as E

#: default wall time per chunk [s]: short enough that an interrupt lands within ~1 s
TARGET_CHUNK_S = 0.2


def continuation_state(final: np.ndarray) -> np.ndarray:
    """Initial states [x_r, v_r, X_c = 0, V_c] (n, 4) from engine end states (n, 6) [SI]."""
    s = np.zeros((final.shape[0], 4))
    s[:, 0] = final[:, 0]
    s[:, 1] = final[:, 1]
    s[:, 3] = final[:, 3]
    return s


def run_many(P: np.ndarray, opts: np.ndarray, states0: np.ndarray, n_transient: int, n_record: int):
    """:func:`.engine.run_many` with the points dealt to the threads like cards.

    numba splits a ``prange`` into one contiguous block per thread, and neighbours on a map cost alike (a
    chaotic region runs every period, a settled one stops early): the eq 23 map ran on 1.5 of 2 cores.
    Points i, i + T, i + 2T, ... (T threads) form thread i's block, and the results go back in order; each
    point's result does not depend on which thread ran it. (One point at a time, numba's chunk size 1 under
    OpenMP, cost more than it gained: 107-121 s against 105-108 s for Fig 19.)

    SIGINT / SIGTERM are held during the compiled call (:func:`deferred_call`; not while it is first compiled) and
    delivered when it returns:
    every caller (sweeps, maps, the dynamics loop's progression speeds) then sees KeyboardInterrupt, not a
    SystemError that ``except Exception`` would take for a failure (a Ctrl-C once let ``diagnose`` run on)."""
    n = P.shape[0]
    nt = int(numba.get_num_threads())
    if nt < 2 or n <= nt:
        return deferred_call(E.run_many, P, opts, states0, n_transient, n_record)
    perm = np.concatenate([np.arange(t, n, nt) for t in range(nt)])
    st, per, en, fin = deferred_call(E.run_many, np.ascontiguousarray(P[perm]), opts,
                                     np.ascontiguousarray(states0[perm]), n_transient, n_record)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(n)
    return st[inv], per[inv], en[inv], fin[inv]


def _next_size(done: int, elapsed_s: float, target_s: float, remaining: int, minimum: int, last: int = 0) -> int:
    """Chunk size [points] so that the next chunk takes about ``target_s`` at the measured rate, at most
    twice the last chunk (``last``): point costs differ by tens of times across a map, and a rate measured
    on a few cheap points once made a chunk of 1468 points and 5 s (no interrupt, no progress meanwhile)."""
    if done <= 0 or elapsed_s <= 0.0:
        return min(remaining, minimum)
    per_point = elapsed_s / done
    k = max(minimum, math.floor(target_s / per_point))
    if last > 0:
        k = min(k, 2 * last)
    return int(min(remaining, k))


def run_points(P: np.ndarray, opts: np.ndarray, states0: np.ndarray, n_transient: int, n_record: int,
               progress=None, target_chunk_s: float = TARGET_CHUNK_S, chunk: int | None = None):
    """Run independent points in chunks; return (status (n,), periods (n, n_record, cols), final (n, N_FINAL)).

    P: (n, N_PARAMS) engine parameter vectors [SI]; states0: (n, 4) initial states [SI].
    ``chunk`` fixes the chunk size [points]; by default the size adapts so a chunk takes
    about ``target_chunk_s`` [s], never fewer points than threads (the first chunk has one per thread).
    ``progress(k)`` is called with the number of points finished after each chunk.
    """
    P = np.ascontiguousarray(P, dtype=float)
    states0 = np.ascontiguousarray(states0, dtype=float)
    n = P.shape[0]
    status = np.zeros(n, dtype=np.int64)
    periods = np.zeros((n, int(n_record), E.N_PERIOD_COLS))
    final = np.zeros((n, E.N_FINAL))
    minimum = int(numba.get_num_threads())
    i = 0
    k = 0
    t_run = 0.0
    while i < n:
        k = int(chunk) if chunk else _next_size(i, t_run, target_chunk_s, n - i, minimum, k)
        k = max(1, min(k, n - i))
        t0 = time.perf_counter()
        st, per, _, fin = run_many(P[i:i + k], opts, states0[i:i + k], int(n_transient), int(n_record))
        t_run += time.perf_counter() - t0
        status[i:i + k] = st
        periods[i:i + k] = per
        final[i:i + k] = fin
        i += k
        if progress:
            progress(k)
    return status, periods, final


def run_rows_continuation(P: np.ndarray, opts: np.ndarray, states0: np.ndarray, n_transient: int, n_record: int,
                          progress=None):
    """Continuation along the columns of a grid of points, all rows in parallel.

    P: (rows, cols, N_PARAMS), each row in run order; states0: (rows, 4), the first point's
    initial state of each row. Point (r, j) starts from the end state of (r, j - 1) (X_c reset
    to 0). Returns (status (rows, cols), periods (rows, cols, n_record, ncols)).
    A row whose point fails keeps running from that point's end state; the caller raises on
    the first bad status. ``progress(k)`` gets the number of points finished after each column.
    """
    rows, cols = P.shape[0], P.shape[1]
    status = np.zeros((rows, cols), dtype=np.int64)
    periods = np.zeros((rows, cols, int(n_record), E.N_PERIOD_COLS))
    state = np.ascontiguousarray(states0, dtype=float).copy()
    for j in range(cols):
        st, per, _, fin = run_many(np.ascontiguousarray(P[:, j]), opts, state, int(n_transient), int(n_record))
        status[:, j] = st
        periods[:, j] = per
        state = continuation_state(fin)
        if progress:
            progress(rows)
    return status, periods


# ---------------------------------------------------------------------------
# per-point summaries over the recorded periods, vectorised over points


def period_numbers(xr: np.ndarray, vr: np.ndarray, max_period: int = 8, rel_tol: float = 1e-5) -> np.ndarray:
    """Vectorised :func:`.sweep.period_number` over rows: (n, m) Poincare X_r [m], V_r [m/s] -> (n,) int.

    Smallest p <= max_period with P_{i+p} = P_i over each row's records (0 if none), points
    compared relative to the spread of the response (1 um, 1 mm/s floors).
    """
    xr = np.asarray(xr, dtype=float)
    vr = np.asarray(vr, dtype=float)
    n, m = xr.shape
    out = np.zeros(n, dtype=np.int64)
    if m < 2 or n == 0:
        return out
    sx = np.maximum(np.maximum(np.ptp(xr, axis=1), 1e-6), np.max(np.abs(xr), axis=1) * 1e-3)
    sv = np.maximum(np.maximum(np.ptp(vr, axis=1), 1e-3), np.max(np.abs(vr), axis=1) * 1e-3)
    for p in range(1, min(max_period, m - 1) + 1):
        dx = np.max(np.abs(xr[:, p:] - xr[:, :-p]), axis=1) / sx
        dv = np.max(np.abs(vr[:, p:] - vr[:, :-p]), axis=1) / sv
        hit = (out == 0) & (np.maximum(dx, dv) < rel_tol)
        out[hit] = p
    return out


def summarize(periods: np.ndarray, Pd_N: np.ndarray, f_Hz: np.ndarray) -> dict[str, np.ndarray]:
    """Per-point summaries of recorded periods (n, m, cols) as arrays (SI and table units).

    velocity_mm_s: capsule displacement over the records / their duration; Af = max|F_i| / P_d
    (seed 000 eq 24; NaN for P_d = 0); impacts/back impacts/stick fraction: means per period.
    """
    n, m = periods.shape[0], periods.shape[1]
    Pd_N = np.broadcast_to(np.asarray(Pd_N, dtype=float), (n,))
    f_Hz = np.broadcast_to(np.asarray(f_Hz, dtype=float), (n,))
    if m == 0:
        nan = np.full(n, np.nan)
        return {"velocity_mm_s": nan, "impacts_per_period": nan, "back_impacts_per_period": nan,
                "max_Fi_N": nan, "Af": nan, "stick_fraction": nan, "period_number": np.zeros(n, np.int64)}
    col = lambda c: np.ascontiguousarray(periods[:, :, c])  # noqa: E731  (row sums as in 1-D, bit for bit)
    maxF = col(E.P_MAXF).max(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        Af = np.where(Pd_N > 0, maxF / np.where(Pd_N > 0, Pd_N, 1.0), np.nan)
    return {
        "velocity_mm_s": col(E.P_DISP).sum(axis=1) / (m * (1.0 / f_Hz)) * 1e3,
        "impacts_per_period": col(E.P_NFRONT).mean(axis=1),
        "back_impacts_per_period": col(E.P_NBACK).mean(axis=1),
        "max_Fi_N": maxF,
        "Af": Af,
        "stick_fraction": col(E.P_STICK).mean(axis=1),
        "period_number": period_numbers(col(E.P_XR0), col(E.P_VR0)),
    }
