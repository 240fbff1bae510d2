"""Pure control math for torquelab: dynamics snapshots, coupling metrics, controllers, estimators.

Depends only on numpy, numba, pinocchio and the QP solvers (daqp, osqp); never on the simulator or
the web UI.
"""
