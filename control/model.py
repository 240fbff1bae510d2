"""Rigid-body model of the arm and the per-step `Dynamics` snapshot every consumer shares.

Task frame: the TCP in LOCAL_WORLD_ALIGNED (origin at the TCP, axes of the world), ordered
[px py pz rx ry rz]. Notation follows [T 1-5]: M q̈ + μ = τ + τ^e, Λx = (J M⁻¹ Jᵀ)⁻¹,
J̄ = M⁻¹ Jᵀ Λx, N = I − J̄ J, Λn = (N M⁻¹ Nᵀ)#.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pinocchio as pin

from control.kernels.chain import chain_constants
from control.kernels.snapshot import (
    SNAPSHOT_FIELDS,
    snapshot_into,
    snapshot_record_dtype,
    snapshot_reference,
    snapshot_work,
)

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

# Λx⁻¹ eigenvalues below this (in 1/kg or 1/(kg m²)) count as singular: the inverse is damped.
SINGULAR_EIGENVALUE = 1e-6


def _fields_of(records: np.ndarray) -> dict[str, np.ndarray]:
    """Each field of a record array as an array of its own (a view)."""
    return {name: records[name] for name in records.dtype.names or ()}


class _Field:
    """A `Dynamics` array: the view of its record's field of the same name, made on first use (then
    a plain attribute of the snapshot)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, obj: Any, owner: Any = None) -> np.ndarray:
        return obj.field_view(self.name)


class SnapshotRecords:
    """Snapshot records handed out one by one from blocks of `size` (a record of its own costs
    about 1.5 µs to allocate, a slice of a block 0.1 µs): each record is a one-element slice of a
    block, never handed out twice; a block lives as long as one of its snapshots does."""

    def __init__(self, n: int, size: int = 64):
        self.dtype, self.size = snapshot_record_dtype(n), size
        self._new_block()

    def _new_block(self) -> None:
        self.block = np.empty(self.size, self.dtype)
        self.fields = _fields_of(self.block)
        self.next = 0

    def take(self) -> tuple[np.ndarray, dict[str, np.ndarray], int]:
        """(record, the block's field arrays, the record's index in them); the record's fields are
        not initialised."""
        if self.next == self.size:
            self._new_block()
        at = self.next
        self.next = at + 1
        return self.block[at : at + 1], self.fields, at


class Dynamics:
    """One snapshot of the arm's dynamics at (q, q̇), computed once per control step.

    Its arrays are views of one record, `record` (`control.kernels.snapshot.snapshot_record_dtype`),
    which the compiled kernels take whole and read by field name (`snap[0].Lambda`): write into an
    array (`dyn.M[:] = …`), never rebind it."""

    q = _Field()  # (n,) rad
    dq = _Field()  # (n,) rad/s
    M = _Field()  # (n, n) joint inertia incl. armature
    M_inv = _Field()  # (n, n)
    h = _Field()  # (n,) μ = C q̇ + g, Coriolis + gravity torques [T1]
    tcp_rotation_world = _Field()  # (3, 3)
    tcp_position_world = _Field()  # (3,) m
    J = _Field()  # (6, n) TCP Jacobian, LOCAL_WORLD_ALIGNED, [linear; angular]
    dJ_dq = _Field()  # (6,) J̇ q̇, classical acceleration of the TCP at q̈ = 0
    Lambda_inv = _Field()  # (6, 6) J M⁻¹ Jᵀ
    Lambda = _Field()  # (6, 6) Λx task inertia [T3], damped near singularities
    J_bar = _Field()  # (n, 6) dynamically consistent inverse M⁻¹ Jᵀ Λx [T2-3]
    N = _Field()  # (n, n) nullspace projector I − J̄ J [T4]
    Lambda_n = _Field()  # (n, n) nullspace inertia (N M⁻¹ Nᵀ)# [T5]
    record: np.ndarray  # the one-element record the arrays above view (`snapshot_record_dtype(n)`)
    near_singular: bool  # Λx was damped
    min_eig_known: float  # see `__init__`
    _block: dict[str, np.ndarray]  # the field arrays of the record's block
    _at: int  # the record's index in them

    def __init__(
        self,
        record: np.ndarray,
        near_singular: bool,
        min_eig_known: float = math.nan,
        block: dict[str, np.ndarray] | None = None,
        at: int = 0,
    ):
        d = self.__dict__
        d["record"] = record
        # where the views are taken from: the field arrays of the record's block and its index there
        d["_block"], d["_at"] = (_fields_of(record) if block is None else block), at
        d["near_singular"] = near_singular  # Λx was damped
        # smallest eigenvalue of J M⁻¹ Jᵀ when the snapshot computed it (near a singularity), else
        # NaN: read `min_eig_Lambda_inv`, which computes it on first use
        d["min_eig_known"] = min_eig_known

    @classmethod
    def of(cls, near_singular: bool, min_eig_known: float = math.nan, **arrays: np.ndarray) -> Dynamics:
        """A snapshot from its arrays by name (every field of `SNAPSHOT_FIELDS`), copied into a new record."""
        record = np.zeros(1, snapshot_record_dtype(len(arrays["q"])))
        for name, _ in SNAPSHOT_FIELDS:
            record[name][0] = arrays[name]
        record["near_singular"][0] = near_singular
        return cls(record, bool(near_singular), min_eig_known)

    def field_view(self, name: str) -> np.ndarray:
        """The view of the record's field `name`, kept as the snapshot's attribute of that name."""
        view = self.__dict__[name] = self._block[name][self._at]
        return view

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _FIELD_NAMES:
            raise AttributeError(f"Dynamics.{name} is a view of the snapshot's record: write into it ({name}[...] = …)")
        if name in ("record", "_block", "_at"):  # the compiled kernels take the record whole
            raise AttributeError(f"Dynamics.{name} is fixed at construction: write into the record's fields")
        object.__setattr__(self, name, value)

    def __getstate__(self) -> dict:
        return {k: self.__dict__[k] for k in ("record", "near_singular", "min_eig_known")}

    def __setstate__(self, state: dict) -> None:
        record = state["record"]
        self.__dict__.update(state, _block=_fields_of(record), _at=0)

    @property
    def min_eig_Lambda_inv(self) -> float:
        """Smallest eigenvalue of Λx⁻¹ = J M⁻¹ Jᵀ (computed on first use away from a singularity:
        the control step needs only whether it lies below SINGULAR_EIGENVALUE)."""
        if math.isnan(self.min_eig_known):
            self.min_eig_known = float(np.linalg.eigvalsh(self.Lambda_inv)[0])
        return self.min_eig_known


_FIELD_NAMES = frozenset(name for name, _ in SNAPSHOT_FIELDS)


class RobotModel:
    """Pinocchio model of the arm with a TCP frame; computes `Dynamics` snapshots and ∂Λx/∂q."""

    def __init__(self, model: pin.Model, tcp_frame: str = "tcp"):
        if not model.existFrame(tcp_frame):
            raise ValueError(f"model has no frame {tcp_frame!r}")
        self.model = model
        self.data = model.createData()
        self.nv = model.nv
        self.tcp_frame_id = model.getFrameId(tcp_frame)
        # Gravity-free copy for ∂M/∂q from RNEA derivatives (at q̇ = 0 they give ∂(M a)/∂q).
        self._model_no_gravity = model.copy()
        self._model_no_gravity.gravity = pin.Motion.Zero()
        self._data_no_gravity = self._model_no_gravity.createData()
        self._data_hessian = model.createData()
        self._zeros = np.zeros(self.nv)
        self._work = snapshot_work(self.nv)  # scratch of the snapshot kernel
        self._records = SnapshotRecords(self.nv)  # where each snapshot's record comes from
        self._lower = np.tril_indices(self.nv, -1)
        # ∂J/∂q from J alone (control.kernels) holds for a serial chain of 1-DoF revolute joints
        self.revolute_chain = all(
            model.parents[i] == i - 1
            and model.joints[i].nv == 1
            and model.joints[i].shortname().startswith(("JointModelR", "JointModelRevoluteUnaligned"))
            and not model.joints[i].shortname().startswith("JointModelRUB")
            for i in range(1, model.njoints)
        )
        self.chain = chain_constants(model) if self.revolute_chain else ()  # for the ∂M/∂q kernel

    # ---- snapshot -------------------------------------------------------------------------
    def compute(self, q: np.ndarray, dq: np.ndarray) -> Dynamics:
        """Fill one `Dynamics` snapshot at (q, q̇).

        Pinocchio gives M (CRBA), h and J in one `computeAllTerms`; the algebra of [T2-5] runs in one
        compiled kernel (`control.kernels.snapshot.snapshot_into`, tested against its numpy reference), which
        also forms J̇q̇ from J and q̇ on a serial revolute chain (else Pinocchio's classical acceleration).
        """
        model, data, fid = self.model, self.data, self.tcp_frame_id
        record, f, at = self._records.take()  # every field is written below or by the kernel
        f["q"][at], f["dq"][at] = q, dq
        q, dq = f["q"][at], f["dq"][at]
        pin.computeAllTerms(model, data, q, dq)  # M (upper), h, joint Jacobians, data.a at q̈ = 0
        oMf = pin.updateFramePlacement(model, data, fid)
        f["J"][at] = pin.getFrameJacobian(model, data, fid, LWA)
        f["h"][at], f["tcp_rotation_world"][at], f["tcp_position_world"][at] = data.nle, oMf.rotation, oMf.translation
        if not self.revolute_chain:  # else J̇q̇ from J in the kernel (`tcp_bias_acceleration_reference`)
            f["dJ_dq"][at] = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector
        near_singular, min_eig = snapshot_into(data.M, SINGULAR_EIGENVALUE, record, self._work, self.revolute_chain)
        dyn = Dynamics(record, near_singular, min_eig, f, at)
        dyn.__dict__["q"], dyn.__dict__["dq"] = q, dq  # the views made above
        return dyn

    def compute_reference(self, q: np.ndarray, dq: np.ndarray) -> Dynamics:
        """`compute` with the plain-numpy algebra (`control.kernels.snapshot.snapshot_reference`): the readable
        statement of [T2-5] that the compiled snapshot is tested against."""
        model, data, fid = self.model, self._data_hessian, self.tcp_frame_id
        q = np.array(q, dtype=float)
        dq = np.array(dq, dtype=float)
        pin.computeAllTerms(model, data, q, dq)
        pin.updateFramePlacements(model, data)
        J = pin.getFrameJacobian(model, data, fid, LWA)
        dJ_dq = pin.getFrameClassicalAcceleration(model, data, fid, LWA).vector.copy()
        M, M_inv, Lambda_inv, Lambda, J_bar, N, Lambda_n, min_eig, near = snapshot_reference(
            data.M.copy(), J, SINGULAR_EIGENVALUE
        )
        oMf = data.oMf[fid]
        return Dynamics.of(
            bool(near),
            float(min_eig),
            q=q,
            dq=dq,
            M=M,
            M_inv=M_inv,
            h=data.nle,
            tcp_rotation_world=oMf.rotation,
            tcp_position_world=oMf.translation,
            J=J,
            dJ_dq=dJ_dq,
            Lambda_inv=Lambda_inv,
            Lambda=Lambda,
            J_bar=J_bar,
            N=N,
            Lambda_n=Lambda_n,
        )

    # ---- kinematics helpers ---------------------------------------------------------------
    def frame_pose(self, q: np.ndarray, frame: str) -> pin.SE3:
        """World pose of a named frame at q."""
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, q)
        return data.oMf[self.model.getFrameId(frame)].copy()

    def tcp_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(6, n) TCP Jacobian at q (LOCAL_WORLD_ALIGNED)."""
        return pin.computeFrameJacobian(self.model, self._data_hessian, q, self.tcp_frame_id, LWA)

    def tcp_jacobian_derivative(self, q: np.ndarray) -> np.ndarray:
        """(n, 6, n) ∂J/∂q_k stacked on k, from Pinocchio's kinematic Hessian.

        Pinocchio 4.1 returns the LOCAL_WORLD_ALIGNED frame Hessian with a wrong memory layout;
        reading it back in Fortran order gives H[a, i, k] = ∂J[a, i]/∂q_k (checked against finite
        differences in tests/test_model.py so that an upstream fix is noticed).
        """
        data = self._data_hessian
        pin.computeJointJacobians(self.model, data, q)
        pin.computeJointKinematicHessians(self.model, data, q)
        pin.updateFramePlacements(self.model, data)
        H = pin.getFrameKinematicHessian(self.model, data, self.tcp_frame_id, LWA)
        H = np.asarray(H).ravel().reshape((6, self.nv, self.nv), order="F")
        return H.transpose(2, 0, 1)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torques g(q)."""
        return pin.computeGeneralizedGravity(self.model, self._data_hessian, q).copy()

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint inertia M(q) including armature."""
        M = pin.crba(self.model, self._data_hessian, q).copy()
        M[self._lower] = M.T[self._lower]
        return M

    def joint_origins(self, q: np.ndarray) -> np.ndarray:
        """(njoints, 3) world positions of the joint frames' origins at q (row 0: the universe)."""
        data = self._data_hessian
        pin.forwardKinematics(self.model, data, np.asarray(q, dtype=float))
        return np.array([data.oMi[j].translation for j in range(self.model.njoints)])

    def mass_matrix_derivative_times(self, q: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n, n) ∂(M b)/∂q at q: RNEA's ∂τ/∂q at q̇ = 0 and q̈ = b without gravity (armature is
        constant); aᵀ ∂M/∂q_k b = (∂(M b)/∂q)ᵀ a."""
        return np.asarray(
            pin.computeRNEADerivatives(self._model_no_gravity, self._data_no_gravity, q, self._zeros, b)[0]
        )

    # ---- ∂Λx/∂q ---------------------------------------------------------------------------
    def dLambda_dq(self, dyn: Dynamics) -> np.ndarray:
        """(n, 6, 6) analytic ∂Λx/∂q_k.

        ∂Λx = −Λx ∂(J M⁻¹ Jᵀ) Λx with ∂(J M⁻¹ Jᵀ) = ∂J X + Xᵀ∂Jᵀ − Xᵀ ∂M X, X = M⁻¹Jᵀ.
        Xᵀ ∂M_k X comes from RNEA derivatives at q̇ = 0 without gravity: ∂(M a)/∂q with a = X[:, c].
        """
        q = dyn.q
        n = self.nv
        X = dyn.M_inv @ dyn.J.T  # (n, 6)
        dJ = self.tcp_jacobian_derivative(q)  # (n, 6, n)
        S = dJ @ X  # (n, 6, 6): ∂J_k X
        XdMX = np.empty((n, 6, 6))
        for c in range(6):
            dtau_dq = pin.computeRNEADerivatives(
                self._model_no_gravity, self._data_no_gravity, q, self._zeros, X[:, c]
            )[0]
            XdMX[:, :, c] = np.asarray(dtau_dq).T @ X  # [k, r] = X[:, r]·∂M_k X[:, c]
        dA = S + S.transpose(0, 2, 1) - XdMX
        return -dyn.Lambda @ dA @ dyn.Lambda

    def dLambda_dq_fd(self, q: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        """(n, 6, 6) ∂Λx/∂q_k by central differences (reference for the analytic version)."""
        out = np.empty((self.nv, 6, 6))
        dq0 = self._zeros
        for k in range(self.nv):
            qp = np.array(q, dtype=float)
            qm = np.array(q, dtype=float)
            qp[k] += eps
            qm[k] -= eps
            out[k] = (self.compute(qp, dq0).Lambda - self.compute(qm, dq0).Lambda) / (2 * eps)
        return out
