"""Linear-quadratic tracker design for the feedback-linearized subsystems (Eq. 17–23).

After feedback linearization each subsystem is three decoupled double integrators,
state ``[q1, q̇1, q2, q̇2, q3, q̇3]`` and input ``[q̈1, q̈2, q̈3]``. The gains come from
``control.lqr`` (Eq. 20–21); the steady-state reference of Eq. (23) is computed from the
system matrices, not assumed.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

__all__ = [
    "LqTracker",
    "design_tracker",
    "triple_double_integrator",
]


@dataclass(frozen=True)
class LqTracker:
    """A designed LQ tracker: ``u = (u_d + K x_d) − K x`` with ``[x_d; u_d] = M y_d``."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray  # (m, n) optimal gain, Eq. (21)
    P: np.ndarray  # (n, n) Riccati solution, Eq. (20)
    closed_loop_poles: np.ndarray
    x_d_from_y_d: np.ndarray  # (n, l) from Eq. (23)
    u_d_from_y_d: np.ndarray  # (m, l) from Eq. (23)

    def per_axis_gains(self) -> np.ndarray:
        """(3, 2) array of ``[k_position, k_rate]`` per axis of a triple double integrator.

        Raises
        ------
        ValueError
            If the gain matrix is not block diagonal (the axes would be coupled).
        """
        gains = np.array([[self.K[i, 2 * i], self.K[i, 2 * i + 1]] for i in range(3)])
        off_block = self.K.copy()
        for i in range(3):
            off_block[i, 2 * i : 2 * i + 2] = 0.0
        if np.max(np.abs(off_block)) > 1e-9 * max(1.0, np.max(np.abs(self.K))):
            raise ValueError(f"LQ gain is not block diagonal:\n{self.K}")
        return gains

    def input(self, x: np.ndarray, y_d: np.ndarray) -> np.ndarray:
        """Eq. (22): the control input for state ``x`` and desired output ``y_d``."""
        x_d = self.x_d_from_y_d @ y_d
        u_d = self.u_d_from_y_d @ y_d
        return u_d + self.K @ x_d - self.K @ x


def triple_double_integrator() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C, D) of three decoupled double integrators with position outputs."""
    A = np.zeros((6, 6))
    B = np.zeros((6, 3))
    C = np.zeros((3, 6))
    for i in range(3):
        A[2 * i, 2 * i + 1] = 1.0
        B[2 * i + 1, i] = 1.0
        C[i, 2 * i] = 1.0
    return A, B, C, np.zeros((3, 3))


def design_tracker(q_diag: tuple[float, ...], r_diag: tuple[float, ...]) -> LqTracker:
    """Design the LQ tracker of Eq. (17)–(23) for a triple double integrator.

    Parameters
    ----------
    q_diag : sequence of 6 float
        Diagonal of the state weight Q (Eq. 29 or 32).
    r_diag : sequence of 3 float
        Diagonal of the input weight R (Eq. 30 or 33).
    """
    A, B, C, D = triple_double_integrator()
    K, P, poles = control.lqr(A, B, np.diag(q_diag), np.diag(r_diag))
    K = np.asarray(K, dtype=float)
    # Eq. (23): [x_d; u_d] = [[A, B], [C, D]]^-1 [0; y_d]
    n, m = B.shape
    big = np.block([[A, B], [C, D]])
    rhs = np.vstack([np.zeros((n, C.shape[0])), np.eye(C.shape[0])])
    sol = np.linalg.solve(big, rhs)
    return LqTracker(
        A=A,
        B=B,
        C=C,
        D=D,
        K=K,
        P=np.asarray(P, dtype=float),
        closed_loop_poles=np.asarray(poles),
        x_d_from_y_d=sol[:n],
        u_d_from_y_d=sol[n : n + m],
    )
