"""The block-delay scan's cubic interpolation of the command, compiled (numba).

:meth:`es_calibration.search.blockdelay._Scan.inputs` weights the four commands around
each instant (four gathers of (n, A) and a Python ``sum`` of their products: about 0.9 of
its 2.3 ms, 6,000 times a calibration). Here one pass writes the weighted sum straight
into the (A, n) layout the model reads. It does the same IEEE operations in the same order
as the numpy path (0 + w0 c0 + w1 c1 + w2 c2 + w3 c3, no fused multiply-add), so both give
the same numbers (tests/es_calibration/test_caches.py).

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`),
as :mod:`es_calibration.model.lowpass_loop`.
"""

from __future__ import annotations

import numba

from es_common.arrays import FloatArray, IndexArray


@numba.njit(cache=True, nogil=True)
def interpolate_rows(command: FloatArray, first: IndexArray, weights: FloatArray,
                     out: FloatArray) -> None:
    """Write sum_k weights[k, i] command[first[i] + k] into ``out[:, i]``.

    ``command`` is (N, A), ``first`` (n,) the first of each sample's four command rows
    (in [0, N - 4]), ``weights`` (4, n), ``out`` (A, n).
    """
    columns = command.shape[1]
    for i in range(first.shape[0]):
        j = first[i]
        w0 = weights[0, i]
        w1 = weights[1, i]
        w2 = weights[2, i]
        w3 = weights[3, i]
        for c in range(columns):
            out[c, i] = (
                0.0 + w0 * command[j, c] + w1 * command[j + 1, c] + w2 * command[j + 2, c]
                + w3 * command[j + 3, c]
            )
