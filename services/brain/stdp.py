"""STDP, paper eq. 1 and 2 (Gerstner 1996; Song, Miller & Abbott 2000).

dt = t_pre_arrival - t_post_spike, in ticks:
  dt <= 0 (pulse arrived before or when the post neuron fired): w += A+ exp(dt / tau+)
  dt >  0 (pulse arrived after the post neuron fired):        w -= A- exp(-dt / tau-)
only for window_neg <= dt <= window_pos; w is clipped to [w_min, w_max] after every change.

dt is a whole number of ticks inside a bounded window, so the engine does not call exp per pair:
`stdp_table` tabulates W(dt) once per neuron with the same compiled exp.
"""

import math

import numpy as np
from numba import njit


@njit(cache=True)
def weight_change(dt, a_plus, a_minus, tau_plus, tau_minus, window_neg, window_pos):
    """W(dt): the change of w for one (arrival, post spike) pair dt ticks apart."""
    if dt < window_neg or dt > window_pos:
        return 0.0
    if dt <= 0:
        return a_plus * math.exp(dt / tau_plus)
    return -a_minus * math.exp(-dt / tau_minus)


def stdp_table(neuron_types) -> tuple[np.ndarray, int]:
    """W(dt) per neuron: table[n, dt + offset] for offset = -min(window_neg), zero outside each window."""
    offset = -min(t.window_neg for t in neuron_types)
    width = offset + max(t.window_pos for t in neuron_types) + 1
    table = np.zeros((len(neuron_types), width))
    for n, t in enumerate(neuron_types):
        for k in range(width):
            table[n, k] = weight_change(
                k - offset, t.a_plus, t.a_minus, t.tau_plus, t.tau_minus, t.window_neg, t.window_pos
            )
    return table, offset
