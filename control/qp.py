"""The one QP interface of both executors, with a dense and an OSQP backend.

    min_x ½ xᵀ P x + qᵀ x   s.t.   lb ≤ x ≤ ub,   l ≤ A x ≤ u,   the last `n_eq` rows of A equalities

`make_qp(backend, n, m, ...)` sets a problem of a fixed shape up once; every `solve(P, q, A, l, u,
lb, ub)` updates it in place (P or A may be None: unchanged since the last call) and warm-starts
from the previous solution. Both executors call only this module: the [T] nullspace velocity QP
[T15–17] (`control.nullspace`) and the [C] acceleration QP [C9, C10, C17–24]
(`control.compliance_qp`).

Backends (`BACKENDS`):
- "dense": DAQP's dual active-set solver (`daqp.Model`, workspace allocated once): exact to its
  tolerances, ~5 µs for these 7-variable problems on the bench machine. The box is passed as
  DAQP's simple bounds, equalities with its "equality" sense. Before DAQP, one compiled call
  loads the data and returns the unconstrained optimum −P⁻¹q when it is feasible, the optimum
  then (~2 µs; `DenseBackend`). (The 7-joint nullspace QP is solved in closed form before it
  reaches this backend: `control.nullspace`.)
- "osqp": OSQP with an explicit fixed sparsity pattern (zeros kept, so updates may fill them;
  DESIGN §9), updated with Px/Ax in that CSC order: the reference backend. Its polishing
  (`QPSettings.polish`) is done here on OSQP's solution (`polish_active_set`), not by OSQP, whose
  own prints a line on every solve without an active set whatever `verbose` says.

Closed forms (this module is the one door to every way a QP is solved; the executors ask it and
never test a backend's type):
- the dense backend's fast path (above), also run inside the [C] executor's compiled step on its
  objective: a backend says whether it has one (`QP.fast_path`) and takes the optimum the caller
  found with it (`QP.take_fast_path`), so its warm start stays consistent;
- the 7-joint nullspace QP [T15-17] on the dense backend: its kernel is a line, the optimum a
  clipped projection (`line_qp_applies`, `solve_line_qp`; the [T] executor's compiled step solves
  it inside the law when `line_qp_applies` and hands the result back through `line_qp_result`).

OSQP's private extension object (`OSQP._solver`) is used only here, only on the OSQP versions it
was checked on (`OSQP_INTERNAL_VERSIONS`), and tests compare it with the public
`update`/`solve` path. A solve never raises on bad numbers: its `status` says what happened and
`solved` whether `x` may be used; the executors fall back on their own.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from control.gains import DEFAULT_QP_BACKEND, QP_BACKENDS
from control.kernels import dense_qp
from control.kernels.line_qp import nullspace_line_qp_fused

INF = 1e30  # what "no bound" becomes (OSQP_INFTY); callers may pass ±inf or ±INF

# one status vocabulary for every backend
SOLVED = "solved"
SOLVED_INACCURATE = "solved inaccurate"
MAX_ITER = "max iter"  # iteration cap reached: x is the last iterate (approximate)
INFEASIBLE = "infeasible"
NON_FINITE = "non-finite"  # the solver returned NaN/inf
FAILED = "failed"
RELAXED = "relaxed"  # an executor's least-violation solution of an infeasible problem ("relaxed: why")
USABLE = (SOLVED, SOLVED_INACCURATE)
# numeric codes for the step log (OSQP 1.x's `SolverStatus` values where it has one)
STATUS_CODES = {SOLVED: 1, SOLVED_INACCURATE: 2, INFEASIBLE: 3, MAX_ITER: 7, FAILED: 11, NON_FINITE: -1}

BACKENDS = QP_BACKENDS  # declared with the solver's parameter group (`control.gains.SolverParams`)
DEFAULT_BACKEND = DEFAULT_QP_BACKEND
BACKEND_ENV = "TORQUELAB_QP_BACKEND"  # overrides DEFAULT_BACKEND (set by the CLI's --qp-backend)
OSQP_INTERNAL_VERSIONS = ((1, 1, 3), (1, 2, 0))  # [first checked, first unchecked) for `OSQP._solver`


class QPResult(NamedTuple):
    """One solve: x and what the backend said (`fallback` is set by the executor that replaced x)."""

    x: np.ndarray  # (n,) solution (NaN-free only when `solved`, or the caller's fallback)
    status: str  # one of SOLVED, SOLVED_INACCURATE, MAX_ITER, INFEASIBLE, NON_FINITE, FAILED or a reason
    iterations: int
    solve_us: float  # wall time of the backend's update + solve, µs
    backend: str
    fallback: bool = False

    @property
    def solved(self) -> bool:
        """The backend found an optimum (to its tolerance)."""
        return self.status in USABLE

    @property
    def status_code(self) -> float:
        """Numeric status for logs (see STATUS_CODES; 0 for an executor's own reason)."""
        return float(STATUS_CODES.get(self.status, 0))


@dataclass(frozen=True)
class QPSettings:
    """Solver tolerances. eps: OSQP absolute/relative tolerance and DAQP's primal tolerance;
    max_iter: iteration cap; polish: OSQP's solution refined on its active set (`polish_active_set`);
    check_termination: OSQP's check interval (0 = OSQP's default)."""

    eps: float = 1e-6
    max_iter: int = 400
    polish: bool = False
    check_termination: int = 0

    def __post_init__(self) -> None:
        if not (self.eps > 0 and self.max_iter > 0 and self.check_termination >= 0):
            raise ValueError(f"QPSettings needs eps > 0, max_iter > 0, check_termination ≥ 0, got {self}")


class QP(Protocol):
    """A QP of fixed shape, set up once and solved many times."""

    backend: str
    n: int
    m: int
    fast_path: bool  # the backend tries x = −P⁻¹q first (exact when feasible; see DenseBackend)

    def take_fast_path(self, x: np.ndarray, solve_us: float) -> QPResult:
        """The result for the optimum x = −P⁻¹q a caller found feasible with this backend's fast path
        (`kernels.dense_qp.unconstrained_optimum_fused`): what `solve` would have returned; the
        backend's next solve starts as after its own fast path."""
        ...

    def solve(
        self,
        P: np.ndarray | None,
        q: np.ndarray,
        A: np.ndarray | None,
        l: np.ndarray,
        u: np.ndarray,
        lb: np.ndarray,
        ub: np.ndarray,
    ) -> QPResult:
        """Update the data (P, A None: unchanged) and solve, warm-started."""
        ...


def default_backend() -> str:
    """The backend for executors built without one: $TORQUELAB_QP_BACKEND, else DEFAULT_BACKEND
    (an environment variable, so worker processes of experiments and sweeps inherit it)."""
    return check_backend(os.environ.get(BACKEND_ENV) or DEFAULT_BACKEND)


def check_backend(name: object) -> str:
    """The backend name, or ValueError naming the choices."""
    if name not in BACKENDS:
        raise ValueError(f"unknown QP backend {name!r}; choose one of {', '.join(BACKENDS)}")
    return str(name)


def make_qp(
    backend: str,
    n: int,
    m: int,
    n_eq: int = 0,
    P_pattern: np.ndarray | None = None,
    A_pattern: np.ndarray | None = None,
    settings: QPSettings | None = None,
    osqp_internal: bool | None = None,
) -> QP:
    """A QP with n variables, a box on them and m rows of A (the last n_eq of them equalities).

    P_pattern (n, n) / A_pattern (m, n) are the entries that may ever be non-zero (default: all);
    only OSQP uses them. `osqp_internal` (OSQP only): None = the extension object when this OSQP
    version was checked, False = the public API, True = the extension object or ValueError.
    """
    settings = settings or QPSettings()
    if not 0 <= n_eq <= m:
        raise ValueError(f"n_eq must lie in 0..{m}, got {n_eq}")
    if check_backend(backend) == "osqp":
        return OSQPBackend(n, m, n_eq, P_pattern, A_pattern, settings, osqp_internal)
    return DenseBackend(n, m, n_eq, settings)


def _clip_inf(src: np.ndarray, out: np.ndarray) -> np.ndarray:
    """src with ±inf (and anything beyond ±INF) replaced by ±INF, written into out."""
    return np.clip(src, -INF, INF, out=out)


def _finite(*arrays: np.ndarray | None) -> bool:
    """No NaN/inf in any of the arrays (one dot product each; None is skipped)."""
    total = 0.0
    for a in arrays:
        if a is not None:
            r = np.asarray(a, dtype=float).ravel()
            total += float(r @ r)
    return math.isfinite(total)


class DenseBackend:
    """DAQP's dense dual active-set solver on a workspace set up when first needed.

    The data is copied into one preallocated buffer [P, A, q, lower, upper] by one compiled call
    (`control.dense_qp.dense_qp_load_fused`), which also refuses NaN and crossed bounds and
    tries the exact fast path: for P positive definite and no equality rows, the unconstrained
    minimiser −P⁻¹q, when it meets every bound and row to the primal tolerance, is the optimum
    (all multipliers zero) and is returned without DAQP (iterations 0). That is the test DAQP
    itself runs first on the same candidate; it then clears its working set, and so does this
    backend: the next DAQP solve starts from an empty working set (the fast path's active set).
    DAQP's own workspace is allocated once (`daqp.Model`).
    """

    backend = "dense"
    fast_path = True

    def __init__(self, n: int, m: int, n_eq: int, settings: QPSettings):
        import daqp  # the dense backend's one dependency

        self._daqp = daqp
        self.n, self.m, self.n_eq = n, m, n_eq
        self.settings = settings
        self._model: Any = None
        self._model_current = False  # DAQP's workspace holds the data of the last solve
        self._sense = np.zeros(n + m, dtype=np.int32)
        self._sense[n + m - n_eq :] = 5  # DAQP: equality (active, immutable)
        self._data = dense_qp.dense_qp_buffer(n, m)
        self._P, self._A, self._q, self._lo, self._hi = dense_qp.dense_qp_views(self._data, n, m)
        self._P[:] = np.eye(n)  # P starts as the identity (as OSQP's pattern), A as zeros
        self._x = np.zeros(n)
        self._setup = dense_qp.dense_qp_setup(n, m, n_eq, INF, settings.eps)

    def take_fast_path(self, x: np.ndarray, solve_us: float) -> QPResult:
        """`QP.take_fast_path`: the next DAQP solve loads all data and starts from an empty working
        set, as after its own fast-path solve."""
        self._model_current = False
        return QPResult(x, SOLVED, 0, solve_us, self.backend)

    def solve(self, P, q, A, l, u, lb, ub) -> QPResult:
        """Update and solve (see `QP.solve`)."""
        n = self.n
        t0 = time.perf_counter()
        code = dense_qp.dense_qp_load_fused(self._data, self._setup, P, q, A, l, u, lb, ub, self._x)
        if code == dense_qp.FAST_SOLVED:
            self._model_current = False
            return QPResult(self._x.copy(), SOLVED, 0, _us(t0), self.backend)
        if code == dense_qp.NON_FINITE_DATA:
            return QPResult(np.full(n, np.nan), NON_FINITE, 0, _us(t0), self.backend)
        if code == dense_qp.CROSSED_BOUNDS:  # DAQP would pick one side of a crossed row silently
            return QPResult(np.full(n, np.nan), INFEASIBLE, 0, _us(t0), self.backend)
        try:
            if self._model is None:
                model = self._daqp.Model()
                model.settings = {"primal_tol": self.settings.eps}
                model.setup(self._P, self._q, self._A, self._hi, self._lo, self._sense)
                self._model = model
            elif not self._model_current:  # after fast-path solves: all data, empty working set
                self._model.update(H=self._P, f=self._q, A=self._A, bupper=self._hi, blower=self._lo, sense=self._sense)
            else:
                self._model.update(
                    H=None if P is None else self._P,
                    f=self._q,
                    A=None if A is None else self._A,
                    bupper=self._hi,
                    blower=self._lo,
                )
            x, _, flag, info = self._model.solve()
        except (ValueError, TypeError, RuntimeError, ArithmeticError) as exc:
            self._model = None  # set up afresh next time
            return QPResult(np.full(n, np.nan), f"{FAILED}: {exc}", 0, _us(t0), self.backend)
        self._model_current = True
        status = _DAQP_STATUS.get(int(flag), FAILED)
        if not math.isfinite(float(x @ x)):
            status = NON_FINITE
        if status not in USABLE:
            self._model = None  # set up afresh next time (no warm start from a failed solve)
        return QPResult(x, status, int(info["iterations"]), _us(t0), self.backend)


# DAQP exit flags: 1 optimal, 2 soft optimal, -1 infeasible, -2 cycling, -3 unbounded,
# -4 iteration limit, -5 non-convex, -6 overdetermined initial active set
_DAQP_STATUS = {1: SOLVED, 2: SOLVED, -1: INFEASIBLE, -4: MAX_ITER}


def _us(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e6


def osqp_internal_supported(version: str | None = None) -> bool:
    """True when this OSQP version lies in OSQP_INTERNAL_VERSIONS (the extension object's API
    was checked there against the public path)."""
    import osqp

    text = osqp.__version__ if version is None else version
    try:
        parts = tuple(int(p) for p in text.split("+")[0].split(".")[:3])
    except ValueError:
        return False
    lo, hi = OSQP_INTERNAL_VERSIONS
    return lo <= parts < hi


class OSQPBackend:
    """OSQP over the constraint matrix [I; A] with a fixed CSC pattern (DESIGN §9)."""

    backend = "osqp"
    fast_path = False  # OSQP iterates from its warm start; `take_fast_path` is never asked of it
    _EXT_API = ("update_data_vec", "update_data_mat", "solve", "info", "solution")

    def __init__(self, n, m, n_eq, P_pattern, A_pattern, settings: QPSettings, internal: bool | None):
        import osqp
        import scipy.sparse as sp

        self.n, self.m, self.n_eq = n, m, n_eq
        P_mask = np.ones((n, n), dtype=bool) if P_pattern is None else np.asarray(P_pattern, dtype=bool)
        A_mask = np.ones((m, n), dtype=bool) if A_pattern is None else np.asarray(A_pattern, dtype=bool)
        if P_mask.shape != (n, n) or A_mask.shape != (m, n):
            raise ValueError(f"patterns must be ({n}, {n}) and ({m}, {n}), got {P_mask.shape}, {A_mask.shape}")
        # P: upper triangle in column-major order (OSQP's Px order)
        P_mask = np.triu(P_mask | P_mask.T | np.eye(n, dtype=bool))
        cols, rows = np.nonzero(P_mask.T)
        self._P_rows, self._P_cols = rows, cols
        P_csc = sp.csc_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
        P_csc.data[:] = np.where(P_csc.indices == np.repeat(np.arange(n), np.diff(P_csc.indptr)), 1.0, 0.0)
        # constraints [I; A]: column j holds row j (the box), then A's rows n + i with A_mask[i, j]
        full = np.vstack([np.eye(n, dtype=bool), A_mask])
        cols_c, rows_c = np.nonzero(full.T)
        C_csc = sp.csc_matrix((np.ones(rows_c.size), (rows_c, cols_c)), shape=(n + m, n))
        self._is_A = C_csc.indices >= n
        self._A_rows = C_csc.indices[self._is_A] - n
        self._A_cols = np.repeat(np.arange(n), np.diff(C_csc.indptr))[self._is_A]
        self._Ax = np.where(self._is_A, 0.0, 1.0)
        self._Px = P_csc.data.copy()
        C_csc.data[:] = self._Ax
        self._lo = np.full(n + m, -INF)
        self._hi = np.full(n + m, INF)
        # polishing here (`polish_active_set`): dense copies of P (OSQP starts from I) and [I; A]
        self._polish, self._eps = settings.polish, settings.eps
        self._P_dense = np.eye(n)
        self._C_dense = np.vstack([np.eye(n), np.zeros((m, n))])
        self._solver = osqp.OSQP()
        options: dict = {
            "verbose": False,
            "warm_starting": True,
            "polishing": False,  # OSQP's own prints a line per solve (module docstring)
            "eps_abs": settings.eps,
            "eps_rel": settings.eps,
            "max_iter": settings.max_iter,
        }
        if settings.check_termination:
            options["check_termination"] = settings.check_termination
        self._solver.setup(P=P_csc, q=np.zeros(n), A=C_csc, l=self._lo, u=self._hi, **options)
        supported = osqp_internal_supported()
        ext = getattr(self._solver, "_solver", None)
        has_api = ext is not None and all(hasattr(ext, a) for a in self._EXT_API)
        if internal and not (supported and has_api):
            raise ValueError(f"OSQP {osqp.__version__}: the extension object is not checked for this version")
        self._ext = ext if (internal is None and supported and has_api) or internal else None
        st = osqp.SolverStatus
        self._codes = {
            int(st.OSQP_SOLVED.value): SOLVED,
            int(st.OSQP_SOLVED_INACCURATE.value): SOLVED_INACCURATE,
            int(st.OSQP_MAX_ITER_REACHED.value): MAX_ITER,
            int(st.OSQP_PRIMAL_INFEASIBLE.value): INFEASIBLE,
            int(st.OSQP_PRIMAL_INFEASIBLE_INACCURATE.value): INFEASIBLE,
        }

    @property
    def internal(self) -> bool:
        """True when solves go through OSQP's extension object (skips ~20–40 µs of wrapper)."""
        return self._ext is not None

    def take_fast_path(self, x: np.ndarray, solve_us: float) -> QPResult:
        """`QP.take_fast_path` (OSQP has no fast path: the result only, its warm start unchanged)."""
        return QPResult(x, SOLVED, 0, solve_us, self.backend)

    def solve(self, P, q, A, l, u, lb, ub) -> QPResult:
        """Update (Px/Ax in the fixed CSC order) and solve (see `QP.solve`)."""
        n = self.n
        t0 = time.perf_counter()
        _clip_inf(lb, self._lo[:n])
        _clip_inf(l, self._lo[n:])
        _clip_inf(ub, self._hi[:n])
        _clip_inf(u, self._hi[n:])
        if not _finite(P, q, A, self._lo, self._hi):  # never hand NaN to the warm start
            return QPResult(np.full(n, np.nan), NON_FINITE, 0, _us(t0), self.backend)
        if (self._lo > self._hi).any():  # OSQP would refuse the update and solve the old data
            return QPResult(np.full(n, np.nan), INFEASIBLE, 0, _us(t0), self.backend)
        Px = None if P is None else np.asarray(P, dtype=float)[self._P_rows, self._P_cols]
        Ax = None
        if A is not None:
            self._Ax[self._is_A] = np.asarray(A, dtype=float)[self._A_rows, self._A_cols]
            Ax = self._Ax
        try:
            if self._ext is not None:
                ext = self._ext
                ext.update_data_vec(q=q, l=self._lo, u=self._hi)
                if Px is not None or Ax is not None:
                    ext.update_data_mat(P_x=Px, P_i=None, A_x=Ax, A_i=None)
                ext.solve()
                info, x, y = ext.info, ext.solution.x, ext.solution.y
            else:
                kwargs = {} if Px is None else {"Px": Px}
                if Ax is not None:
                    kwargs["Ax"] = Ax.copy()  # the wrapper keeps a reference to it
                self._solver.update(q=q, l=self._lo, u=self._hi, **kwargs)
                res = self._solver.solve(raise_error=False)
                info, x, y = res.info, res.x, res.y
            code, iters = int(info.status_val), int(info.iter)
        except (ValueError, TypeError, RuntimeError, ArithmeticError) as exc:
            return QPResult(np.full(n, np.nan), f"{FAILED}: {exc}", 0, _us(t0), self.backend)
        status = self._codes.get(code, FAILED)
        x = np.full(n, np.nan) if x is None else np.array(x, dtype=float)
        if self._polish:
            if P is not None:  # OSQP reads the upper triangle
                self._P_dense[:] = np.triu(P) + np.triu(P, 1).T
            if A is not None:
                self._C_dense[n:] = A
            if status == SOLVED and y is not None:
                q_ = np.asarray(q, dtype=float)
                x_polished = polish_active_set(self._P_dense, q_, self._C_dense, self._lo, self._hi, x, y, self._eps)
                x = x if x_polished is None else x_polished
        if not math.isfinite(float(x @ x)):
            status = NON_FINITE if status in (*USABLE, MAX_ITER) else status
        if status not in (*USABLE, MAX_ITER):  # an infeasible problem's iterates diverge: start afresh
            self._solver.warm_start(x=np.zeros(n), y=np.zeros(n + self.m))
        return QPResult(x, status, iters, _us(t0), self.backend)


def polish_active_set(
    P: np.ndarray,
    q: np.ndarray,
    C: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    eps: float,
) -> np.ndarray | None:
    """OSQP's polishing on its solution (x, y) of min ½xᵀPx + qᵀx s.t. lo ≤ C x ≤ hi: the rows its
    rule marks active (lower when C x − lo < −y, upper when hi − C x < y; equality rows always)
    held as equalities, the KKT system [P Cₐᵀ; Cₐ 0] [x; yₐ] = [−q; bₐ] solved exactly. The
    polished x when it meets every row to ~eps and its multipliers have the right signs (then it is
    the exact optimum); None otherwise (no active row: nothing to polish; a singular or wrong
    active set: OSQP's x stands, as after OSQP's own failed polish)."""
    n = x.size
    z = C @ x
    equal = lo == hi
    lower = (z - lo < -y) & ~equal
    upper = (hi - z < y) & ~equal & ~lower
    active = lower | upper | equal
    k = int(active.sum())
    if k == 0 or k > n:
        return None
    Ca = C[active]
    kkt = np.zeros((n + k, n + k))
    kkt[:n, :n], kkt[:n, n:], kkt[n:, :n] = P, Ca.T, Ca
    try:
        sol = np.linalg.solve(kkt, np.r_[-q, np.where(upper, hi, lo)[active]])
    except np.linalg.LinAlgError:
        return None
    xp, ya = sol[:n], sol[n:]
    zp = C @ xp
    tol = 10.0 * eps * (1.0 + float(np.max(np.abs(zp)))) if math.isfinite(float(zp @ zp)) else -1.0
    violation = max(float(np.max(lo - zp)), float(np.max(zp - hi)))
    dual_tol = 10.0 * eps * (1.0 + float(np.max(np.abs(ya))))
    if not (violation <= tol and math.isfinite(float(ya @ ya))):
        return None
    if (ya[lower[active]] > dual_tol).any() or (ya[upper[active]] < -dual_tol).any():
        return None
    return xp


# ---- closed forms ------------------------------------------------------------------------------------
def line_qp_applies(backend: str, n: int, n_eq: int) -> bool:
    """The nullspace QP min ½‖x‖² + gᵀx s.t. J x = 0, l ≤ x ≤ u [T15-17] has a closed form here: the
    dense backend (its exact answer, not OSQP's iterate) and a one-dimensional kernel (n − n_eq = 1,
    the 7-joint arm with a 6-row task)."""
    return backend == "dense" and n - n_eq == 1


def solve_line_qp(J: np.ndarray, g: np.ndarray, lower: np.ndarray, upper: np.ndarray, backend: str) -> QPResult | None:
    """The closed form of `line_qp_applies` (`kernels.line_qp.nullspace_line_qp_fused`): the optimum
    t z on the kernel line z of J, t = −gᵀz clipped to the box [T17]; iterations = active bounds (0 or
    1); None when it does not apply (J rank deficient, no point of the line in the box, NaN)."""
    t0 = time.perf_counter()
    x = np.empty(J.shape[1])
    active = nullspace_line_qp_fused(J, g, lower, upper, x)
    if active < 0:
        return None
    return QPResult(x, SOLVED, int(active), _us(t0), backend)


class LineQPFirst:
    """A nullspace QP [T15-17] that tries `solve_line_qp`'s closed form first, when `closed_form`
    (`line_qp_applies`, set by the subclass), and otherwise, or when it does not apply to this J,
    asks `solve_general`. The closed form runs in `solve`'s own call: it costs about 1 µs, and one
    more Python call around it would add a tenth of that to every step."""

    n: int
    backend: str
    closed_form: bool
    last: QPResult | None

    def solve(self, J: np.ndarray, g: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QPResult:
        """min ½‖x‖² + gᵀx s.t. J x = 0, lower ≤ x ≤ upper: the closed form (iterations = active
        bounds, 0 or 1) or `solve_general`."""
        if self.closed_form:
            t0 = time.perf_counter()
            x = np.empty(self.n)
            active = nullspace_line_qp_fused(J, g, lower, upper, x)
            if active >= 0:
                self.last = res = QPResult(x, SOLVED, active, (time.perf_counter() - t0) * 1e6, self.backend)
                return res
        return self.solve_general(J, g, lower, upper)

    def solve_general(self, J: np.ndarray, g: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QPResult:
        """The QP where the closed form does not apply (the subclass's solver)."""
        raise NotImplementedError


def line_qp_result(x: np.ndarray, active: int, backend: str) -> QPResult:
    """The result of the closed form of `solve_line_qp` when a compiled step solved it inside its own
    call (`kernels.law.projection_step_fused`): its time is part of that call's, so NaN here."""
    return QPResult(x, SOLVED, int(active), math.nan, backend)
