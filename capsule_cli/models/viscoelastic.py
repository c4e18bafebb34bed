"""Linear viscoelasticity of the intestinal wall: generalised Maxwell (Prony) relaxation.

Pure functions, numpy in and out, SI units ([Pa], [Pa·s], [s]).

* :func:`prony_modulus_Pa`: E(t) = Σ_i E_i exp(-t E_i/η_i) + E_∞ (seed 004 eq 1).
* :func:`maxwell_relaxation_pressure_Pa`: the three-element model (one arm and a
  parallel spring, seed 003 eq 11) as a contact pressure, P(t) = factor · E(t)
  with factor = t_i,e ε / R_c (seed 003 eqs 9-13; see
  :func:`capsule_cli.models.contact.relaxation_pressure_factor`).
* :func:`prony_pressure_Pa`: the same series written with pressure amplitudes
  and time constants, the form that is fitted to relaxation records.

References
----------
seed 004 eq 1 (Prony series); seed 003 eq 11 and Table 1 (three-element model:
E_1 = 196.43 kPa, E_2 = 757.48 kPa, η_1 = 5.36 MPa·s); seed 003 Fig 5a (the
five-element model, two arms).
"""
from __future__ import annotations

import numpy as np


def relaxation_time_s(E_Pa, eta_Pa_s):
    """Return the relaxation time τ = η/E [s] of a spring-dashpot arm (27.3 s for seed 003 Table 1)."""
    return np.asarray(eta_Pa_s, float) / np.asarray(E_Pa, float)


def prony_modulus_Pa(t_s, arm_moduli_Pa, arm_viscosities_Pa_s, E_inf_Pa):
    """Return the relaxation modulus E(t) [Pa] of a generalised Maxwell model.

    Parameters
    ----------
    t_s : time since the step strain [s] (array)
    arm_moduli_Pa : spring moduli E_i of the n arms [Pa] (sequence, n >= 0)
    arm_viscosities_Pa_s : dashpot viscosities η_i of the arms [Pa·s]
    E_inf_Pa : equilibrium modulus E_∞ [Pa] (the parallel spring)

    Notes
    -----
    seed 004 eq 1: E(t) = Σ_i E_i exp(-E_i t / η_i) + E_∞.
    """
    t = np.asarray(t_s, float)
    E = np.atleast_1d(np.asarray(arm_moduli_Pa, float))
    eta = np.atleast_1d(np.asarray(arm_viscosities_Pa_s, float))
    if E.shape != eta.shape:
        raise ValueError("arm_moduli_Pa and arm_viscosities_Pa_s must have the same length")
    out = np.asarray(E_inf_Pa, float) + np.zeros_like(t)
    for Ei, ei in zip(E, eta):
        out = out + Ei * np.exp(-t * Ei / ei)
    return out


def maxwell_relaxation_pressure_Pa(t_s, E1_Pa, E2_Pa, eta1_Pa_s, factor):
    """Return the contact pressure [Pa] of the three-element model after a step stretch: factor · E(t).

    E(t) = E_1 exp(-E_1 t/η_1) + E_2 (seed 003 eq 11 divided by ε); the
    pressure on the capsule is P(t) = t_i,e ε E(t) / R_c (seed 003 eq 13), so
    ``factor`` = t_i,e ε / R_c [-] (0.01153 for R_i = 5 mm, R_c = 5.5 mm).

    Parameters
    ----------
    t_s : time since the capsule stopped [s]
    E1_Pa, E2_Pa : arm and equilibrium spring moduli [Pa]
    eta1_Pa_s : arm viscosity [Pa·s]
    factor : geometric factor t_i,e ε / R_c [-]
    """
    return np.asarray(factor, float) * prony_modulus_Pa(t_s, [E1_Pa], [eta1_Pa_s], E2_Pa)


def prony_pressure_Pa(t_s, amplitudes_Pa, time_constants_s, equilibrium_Pa):
    """Return P(t) = Σ_j A_j exp(-t/τ_j) + P_∞ [Pa], the Prony series in pressure form.

    ``amplitudes_Pa`` A_j = factor · E_j [Pa], ``time_constants_s`` τ_j = η_j/E_j [s],
    ``equilibrium_Pa`` P_∞ = factor · E_∞ [Pa] (seed 004 eq 1 times the geometric factor).
    """
    t = np.asarray(t_s, float)
    out = np.full(t.shape, float(equilibrium_Pa))
    for A, tau in zip(np.atleast_1d(amplitudes_Pa), np.atleast_1d(time_constants_s)):
        out = out + float(A) * np.exp(-t / float(tau))
    return out
